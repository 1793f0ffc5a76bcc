use super::*;
use protocol::Scenario;

/// The paper with one obstacle crossing at `velocity` and `sets` applied.
fn crossing(velocity: [f64; 2], sets: &[&str]) -> Validated {
    let mut s = Scenario::default();
    s.obstacles.push(Obstacle {
        velocity,
        ..Obstacle::fixed(-3.0, 2.0, 0.3)
    });
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    s.with_overrides(&sets).unwrap().validated("test").unwrap()
}

fn track_after(tracker: &mut Tracker, samples: usize, ts_s: f64) -> Track {
    for k in 0..samples {
        tracker.measure(k as f64 * ts_s);
    }
    let mut tracks = Tracks::default();
    tracker.tracks(&mut tracks);
    assert_eq!(tracks.count, 1, "only the moving obstacle is tracked");
    tracks.tracks[0]
}

#[test]
fn without_noise_the_filter_learns_a_constant_velocity() {
    let s = crossing([1.0, -0.5], &["perception.noise_std=0"]);
    let mut tracker = Tracker::new(&s);
    let track = track_after(&mut tracker, 40, 0.05);
    let t = 39.0 * 0.05;
    let truth = s.obstacles[1].center_at(t);
    for axis in 0..2 {
        assert!((track.center[axis] - truth[axis]).abs() < 1e-6, "{track:?}");
        assert!(
            (track.velocity[axis] - [1.0, -0.5][axis]).abs() < 1e-3,
            "{track:?}"
        );
    }
    assert_eq!(track.obstacle, 1);
    assert_eq!(track.radius_m, 0.3);
}

#[test]
fn with_noise_the_truth_stays_within_three_sigma_and_the_sigmas_settle() {
    let s = crossing([0.8, 0.3], &[]);
    let mut tracker = Tracker::new(&s);
    let mut outside = 0;
    let samples = 400;
    let mut sigmas = (f64::INFINITY, f64::INFINITY);
    for k in 0..samples {
        let t = k as f64 * 0.05;
        tracker.measure(t);
        let mut tracks = Tracks::default();
        tracker.tracks(&mut tracks);
        let track = tracks.tracks[0];
        sigmas = track.sigmas();
        let truth = s.obstacles[1].center_at(t);
        let c = &track.covariance;
        for (axis, var) in [(0, c[0]), (1, c[3])] {
            if (track.center[axis] - truth[axis]).abs() > 3.0 * var.sqrt() {
                outside += 1;
            }
        }
    }
    assert!(
        outside <= samples * 2 / 100,
        "{outside} of {} coordinates",
        2 * samples
    );
    // Below the measurement's own 0.02 m, and a velocity known to a few cm/s.
    assert!(sigmas.0 < 0.02 && sigmas.1 < 0.15, "{sigmas:?}");
}

#[test]
fn a_prediction_without_measurement_grows_the_covariance() {
    let s = crossing([1.0, 0.0], &[]);
    let mut tracker = Tracker::new(&s);
    let before = track_after(&mut tracker, 20, 0.05);
    tracker.predict_to(20.0 * 0.05);
    let mut tracks = Tracks::default();
    tracker.tracks(&mut tracks);
    let after = tracks.tracks[0];
    assert!(after.sigmas().0 > before.sigmas().0);
    assert!((after.center[0] - before.center[0] - 0.05 * before.velocity[0]).abs() < 1e-12);
}

#[test]
fn the_paper_tracks_nothing_and_track_tracks_every_obstacle() {
    let paper = Scenario::default().validated("test").unwrap();
    assert_eq!(paper.tracked().count(), 0);
    let all = crossing([0.0, 0.0], &["perception.kind=track"]);
    assert_eq!(all.tracked().count(), 2);
}
