use super::*;
use lidar::Lidar;
use protocol::{Header, LidarConfig, Obstacle, Scenario, Track};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A scenario with a lidar (exact unless `noise_std` says) and `obstacles`.
fn world(obstacles: Vec<Obstacle>, noise_std: f64) -> Validated {
    let s = Scenario {
        obstacles,
        lidar: Some(LidarConfig {
            noise_std,
            ..LidarConfig::default()
        }),
        ..Scenario::default()
    };
    s.validated("test").expect("valid")
}

/// An obstacle not in the map, at rest.
fn unknown(x: f64, y: f64, radius: f64) -> Obstacle {
    Obstacle {
        known: Some(false),
        ..Obstacle::fixed(x, y, radius)
    }
}

/// The scan of `scenario`'s world at scan `k` (time `k / rate_hz`) from `pose`.
fn scan_at(scenario: &Validated, k: u64, pose: [f64; 3], rng: &mut ChaCha8Rng) -> Scan {
    let config = scenario.lidar.clone().expect("a lidar");
    let lidar = Lidar::of(&config);
    let time_s = k as f64 / config.rate_hz;
    let discs: Vec<_> = (scenario.obstacles.iter())
        .map(|o| (o.center_at(time_s), o.radius))
        .collect();
    let header = Header {
        tick: k,
        time_s,
        ..Header::default()
    };
    lidar.scan_message(header, pose, &discs, rng)
}

/// The confirmed tracks, phantoms left out.
fn confirmed(perception: &Perception) -> Vec<Track> {
    let mut tracks = Tracks::default();
    perception.tracks(&mut tracks);
    (tracks.tracks().iter())
        .filter(|t| !t.is_phantom())
        .copied()
        .collect()
}

#[test]
fn a_box_not_in_the_map_is_a_track_once_seen_in_confirm_scans_and_a_known_pillar_never_is() {
    let s = world(
        vec![Obstacle::fixed(0.0, 3.0, 1.0), unknown(3.0, 0.5, 0.4)],
        0.01,
    );
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for k in 0..u64::from(s.perception.confirm) {
        assert!(
            confirmed(&perception).is_empty(),
            "confirmed before scan {k}"
        );
        perception.take(&scan_at(&s, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
        assert_eq!(perception.groups().len(), 1, "only the box is a group");
    }
    let tracks = confirmed(&perception);
    assert_eq!(tracks.len(), 1, "{tracks:?}");
    let track = tracks[0];
    // Its disc holds the face of the box the lidar sees.
    let face = [3.0 - 0.4, 0.5];
    let reach = geometry::distance(track.center, face);
    assert!(reach <= track.radius_m, "{track:?}");
    assert!(
        geometry::distance(track.center, [3.0, 0.5]) < 0.4,
        "{track:?}"
    );
    assert!(track.velocity.iter().all(|v| v.abs() < 0.2), "{track:?}");
}

#[test]
fn a_walking_person_keeps_one_track_whose_velocity_is_learnt() {
    let person = Obstacle {
        velocity: [0.0, 1.0],
        ..Obstacle::fixed(4.0, -3.0, 0.3)
    };
    let s = world(vec![person.clone()], 0.01);
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut ids = std::collections::BTreeSet::new();
    for k in 0..40 {
        perception.take(&scan_at(&s, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
        ids.extend(confirmed(&perception).iter().map(|t| t.obstacle));
    }
    assert_eq!(ids.len(), 1, "one track all along: {ids:?}");
    let track = confirmed(&perception)[0];
    assert!((track.velocity[1] - 1.0).abs() < 0.2, "{track:?}");
    assert!(track.velocity[0].abs() < 0.2, "{track:?}");
    let truth = person.center_at(39.0 / 10.0);
    assert!(
        geometry::distance(track.center, truth) < 0.3,
        "{track:?} vs {truth:?}"
    );
}

#[test]
fn a_person_behind_a_pillar_is_predicted_while_hidden_and_dropped_once_lost() {
    // The person walks up behind a known pillar (from the lidar at the origin) and stays.
    let person = Obstacle {
        path: vec![[0.0, 5.0, -2.0], [2.0, 5.0, 0.0]],
        ..unknown(f64::NAN, f64::NAN, 0.3)
    };
    let pillar = Obstacle::fixed(2.5, 0.0, 0.6);
    let s = world(vec![pillar, person], 0.0);
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let hidden_from = (0..30)
        .find(|&k| {
            perception.take(&scan_at(&s, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
            perception.groups().is_empty()
        })
        .expect("the pillar hides the person");
    assert_eq!(confirmed(&perception).len(), 1, "kept while hidden");
    let lost_scans = (s.perception.lost_s * 10.0).round() as u64;
    for k in hidden_from + 1..=hidden_from + lost_scans + 1 {
        perception.take(&scan_at(&s, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
    }
    assert!(confirmed(&perception).is_empty(), "dropped once lost");
}

#[test]
fn a_box_behind_the_robot_is_one_group_across_the_seam_of_a_scan_all_around() {
    let s = world(vec![unknown(-2.0, 0.0, 0.5)], 0.0);
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    perception.take(&scan_at(&s, 0, [0.0; 3], &mut rng), [0.0; 3], &[]);
    assert_eq!(perception.groups().len(), 1, "{:?}", perception.groups());
    let (centre, radius) = perception.groups()[0].disc;
    assert!(
        geometry::distance(centre, [-1.5, 0.0]) <= radius,
        "{centre:?} {radius}"
    );
}

#[test]
fn a_box_casts_a_phantom_at_each_shadow_edge_that_grows_at_the_phantom_speed() {
    let mut s = world(vec![unknown(3.0, 0.0, 0.5)], 0.0).into_inner();
    s.perception.phantoms = true;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let scan = scan_at(&s.clone().validated("t").unwrap(), 0, [0.0; 3], &mut rng);
    let phantoms_of = |s: &Scenario| {
        let mut perception = Perception::new(&s.clone().validated("t").unwrap());
        perception.take(&scan, [0.0; 3], &[]);
        let mut tracks = Tracks::default();
        perception.tracks(&mut tracks);
        (tracks.tracks().iter())
            .filter(|t| t.is_phantom())
            .copied()
            .collect::<Vec<_>>()
    };
    let phantoms = phantoms_of(&s);
    assert_eq!(phantoms.len(), 2, "{phantoms:?}");
    // Either side of the box, in its shadow: a phantom's radius off the lidar's tangent
    // (within a beam's spacing), on the box's side of it, level with the last return on
    // the box (a beam's spacing short of the silhouette: 0.17 m at this range).
    let tangent = (0.5f64 / 3.0).asin();
    let silhouette = (3.0f64 * 3.0 - 0.5 * 0.5).sqrt();
    for (phantom, side) in phantoms.iter().zip([-1.0, 1.0]) {
        let [x, y] = phantom.center;
        let off_tangent = (x * (side * tangent).sin() - y * (side * tangent).cos()) * side;
        assert!(
            (off_tangent - 0.3).abs() < 0.06,
            "{phantom:?}: {off_tangent}"
        );
        let along = x * tangent.cos() + y * (side * tangent).sin();
        assert!((along - silhouette).abs() < 0.2, "{phantom:?}: {along}");
        assert_eq!(phantom.radius_m, s.perception.phantom_radius);
        let kappa = s.mpc.uncertainty_sigmas;
        let growth = protocol::prediction_growth_m(phantom, 2.0, kappa, 0.0);
        assert!(
            (growth - 2.0 * s.perception.phantom_speed).abs() < 1e-9,
            "{growth}"
        );
    }
    s.perception.phantoms = false;
    assert!(phantoms_of(&s).is_empty());
}

#[test]
fn a_pillar_of_the_map_casts_its_phantoms_behind_it_not_in_it() {
    // The box of the test above, but known: the phantoms touch the same tangents, pushed
    // along them until they clear the pillar, less the margin of its returns and the beam
    // spacing at the silhouette (0.16 m and 0.05 m at 3 m): 0.6 m past the silhouette.
    let mut s = world(vec![Obstacle::fixed(3.0, 0.0, 0.5)], 0.0).into_inner();
    s.perception.phantoms = true;
    let s = s.validated("t").unwrap();
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    perception.take(&scan_at(&s, 0, [0.0; 3], &mut rng), [0.0; 3], &[]);
    let mut tracks = Tracks::default();
    perception.tracks(&mut tracks);
    let phantoms: Vec<_> = (tracks.tracks().iter())
        .filter(|t| t.is_phantom())
        .collect();
    assert_eq!(phantoms.len(), 2, "{phantoms:?}");
    let tangent = (0.5f64 / 3.0).asin();
    let silhouette = (3.0f64 * 3.0 - 0.5 * 0.5).sqrt();
    let lidar = s.lidar.as_ref().expect("a lidar");
    let spacing = lidar.fov_deg.to_radians() / f64::from(lidar.beams);
    // (Taken at the silhouette's range: the last beam on the pillar is up to 0.17 m nearer,
    // its margin and spacing 6 mm less.)
    let keep =
        0.5 + s.perception.phantom_radius - known_margin_m(silhouette) - silhouette * spacing;
    for (phantom, side) in phantoms.iter().zip([-1.0, 1.0]) {
        let [x, y] = phantom.center;
        let clear = geometry::distance(phantom.center, [3.0, 0.0]);
        assert!(
            (clear - keep).abs() < 0.01,
            "{phantom:?}: {clear} against {keep}"
        );
        let off_tangent = (x * (side * tangent).sin() - y * (side * tangent).cos()) * side;
        assert!(
            (off_tangent - 0.3).abs() < 0.06,
            "{phantom:?}: {off_tangent}"
        );
        let along = x * tangent.cos() + y * (side * tangent).sin();
        assert!(
            (along - silhouette - 0.6).abs() < 0.1,
            "{phantom:?}: {along}"
        );
    }
}

#[test]
fn the_phantoms_keep_their_places_among_the_tracks_when_many_boxes_are_tracked() {
    // 30 small boxes in a ring at 3 m: more tracks than the message holds with phantoms.
    let boxes = (0..30)
        .map(|i| {
            let a = f64::from(i) * std::f64::consts::TAU / 30.0;
            unknown(3.0 * a.cos(), 3.0 * a.sin(), 0.1)
        })
        .collect();
    let mut s = world(boxes, 0.0).into_inner();
    s.perception.phantoms = true;
    let s = s.validated("t").unwrap();
    let mut perception = Perception::new(&s);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for k in 0..5 {
        perception.take(&scan_at(&s, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
    }
    let mut tracks = Tracks::default();
    perception.tracks(&mut tracks);
    let phantoms = tracks.tracks().iter().filter(|t| t.is_phantom()).count();
    assert_eq!(phantoms, phantoms::MAX_PHANTOMS);
    assert_eq!(
        tracks.count as usize, MAX_TRACKS,
        "the tracks fill what the phantoms leave"
    );
}

#[test]
fn a_scan_that_arrives_late_places_a_walker_where_they_are_at_its_tick_and_grows_its_phantoms() {
    // A robot's scan reaches the tracker most of a scan period after it was taken
    // (`age_ticks`); the person walks across the line of sight at 1.5 m/s, crossing it
    // at the last scan.
    let person = Obstacle {
        velocity: [0.0, 1.5],
        ..unknown(4.0, -5.85, 0.3)
    };
    let mut s = world(vec![person.clone()], 0.0).into_inner();
    s.perception.phantoms = true;
    let s = s.validated("t").unwrap();
    let period_s = 1.0 / s.lidar.as_ref().expect("a lidar").rate_hz;
    let age_ticks = (0.9 * period_s / s.timing.dt_s()).round() as u32;
    let age_s = f64::from(age_ticks) * s.timing.dt_s();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut perception = Perception::new(&s);
    let mut scan = Scan::default();
    for k in 0..40 {
        scan = scan_at(&s, k, [0.0; 3], &mut rng);
        scan.age_ticks = age_ticks;
        scan.header.tick += u64::from(age_ticks);
        scan.header.time_s += age_s;
        perception.take(&scan, [0.0; 3], &[]);
    }
    let track = confirmed(&perception)[0];
    let truth = person.center_at(scan.header.time_s);
    // Along its walk (across the beams, where a one-sided fit has no bias) the track is
    // where the person is at the tick, not where they were `age_s` before.
    let behind = truth[1] - track.center[1];
    assert!(
        behind.abs() < 0.25 * 1.5 * age_s,
        "{behind} m behind, the scan {age_s} s old"
    );
    let mut tracks = Tracks::default();
    perception.tracks(&mut tracks);
    let phantoms: Vec<_> = tracks.tracks().iter().filter(|t| t.is_phantom()).collect();
    assert!(!phantoms.is_empty());
    for phantom in phantoms {
        let grown = s.perception.phantom_radius + s.perception.phantom_speed * age_s;
        assert!((phantom.radius_m - grown).abs() < 1e-9, "{phantom:?}");
    }
}

#[test]
fn another_robots_returns_are_left_out_and_its_slot_kept_free_of_what_the_lidar_sees() {
    // Two boxes; the one at (2, 0) is another robot of a fleet, where it says it is.
    let s = world(vec![unknown(2.0, 0.0, 0.3), unknown(0.0, 2.0, 0.3)], 0.0);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let scan = scan_at(&s, 0, [0.0; 3], &mut rng);
    let mut perception = Perception::new(&s);
    perception.take(&scan, [0.0; 3], &[]);
    assert_eq!(perception.groups().len(), 2);
    perception.take(&scan, [0.0; 3], &[([2.02, 0.0], 0.3)]);
    assert_eq!(perception.groups().len(), 1, "{:?}", perception.groups());
    assert!(geometry::distance(perception.groups()[0].disc.0, [0.0, 2.0]) < 0.3);

    // A fleet of 4: three slots of the tracks are the others', whatever the lidar sees.
    let fleet = Scenario::from_toml(include_str!("../../../scenarios/swap4.toml"), "swap4")
        .expect("parsed");
    let mut member = fleet.member(0);
    member.lidar = Some(LidarConfig::default());
    member.perception.phantoms = true;
    let member = member.validated("robot 0").expect("valid");
    let mut perception = Perception::new(&member);
    let mut crowd = Scenario::clone(&s);
    crowd.obstacles = (0..40)
        .map(|k| {
            let bearing = k as f64 * std::f64::consts::TAU / 40.0;
            unknown(2.0 * bearing.cos(), 2.0 * bearing.sin(), 0.05)
        })
        .collect();
    let crowd = crowd.validated("crowd").expect("valid");
    for k in 0..5 {
        perception.take(&scan_at(&crowd, k, [0.0; 3], &mut rng), [0.0; 3], &[]);
    }
    let mut tracks = Tracks::default();
    perception.tracks(&mut tracks);
    assert_eq!(tracks.count as usize, MAX_TRACKS - 3);
}
