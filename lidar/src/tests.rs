use super::*;
use protocol::task::SimulatedTime;
use protocol::{LidarConfig, Obstacle, Scenario};

fn truth(tick: u64, pose: [f64; 3], dt_s: f64) -> GroundTruth {
    GroundTruth {
        header: Header {
            tick,
            time_s: tick as f64 * dt_s,
            ..Header::default()
        },
        pose,
        ..GroundTruth::default()
    }
}

#[test]
fn a_scan_is_made_at_every_perception_tick_and_sees_a_moving_obstacle_where_it_is_then() {
    let s = Scenario {
        obstacles: vec![Obstacle {
            velocity: [0.0, 1.0],
            ..Obstacle::fixed(3.0, 0.0, 0.5)
        }],
        lidar: Some(LidarConfig {
            noise_std: 0.0,
            ..LidarConfig::default()
        }),
        ..Scenario::default()
    };
    let scenario = s.validated("test").expect("valid");
    let dt = scenario.timing.dt_s();
    let period = scenario.perception_ticks();
    let mut task = LidarTask::new(&scenario, 0, ()).expect("made");
    let context = SimulatedTime::at(0, dt);
    let mut scans = Vec::new();
    for tick in 0..=2 * period {
        task.hear(LidarInput::Truth(truth(tick, [0.0; 3], dt)), 0, &context);
        scans.extend(task.step(&context).map(|p| p.output));
    }
    let ticks: Vec<u64> = scans.iter().map(|s| s.header.tick).collect();
    assert_eq!(ticks, [0, period, 2 * period]);
    // Straight ahead at t = 0 the disc's near edge is 2.5 m away; by the third scan it has
    // moved up by 2 periods at 1 m/s, and the beam along +y at its new centre's bearing
    // meets it while the one straight ahead may not.
    let ahead = scans[0].ranges()[(scans[0].beams / 2) as usize];
    assert!((f64::from(ahead) - 2.5).abs() < 1e-6, "{ahead}");
    let t = scans[2].header.time_s;
    let bearing = t.atan2(3.0);
    let beam = ((bearing - scans[2].angle_min_rad) / scans[2].angle_increment_rad).round();
    let range = f64::from(scans[2].ranges()[beam as usize]);
    let expected = (9.0 + t * t).sqrt() - 0.5;
    assert!((range - expected).abs() < 0.02, "{range} vs {expected}");
}

#[test]
fn in_a_fleet_the_lidar_sees_another_robot_where_its_truths_before_the_tick_put_it() {
    let toml = "[lidar]\nnoise_std = 0.0\n[mpc]\nv_max = 1.0\n\
                [[robots]]\nstart = [0.0, 0.0, 0.0]\ngoal = [5.0, 0.0]\n\
                [[robots]]\nstart = [3.0, 0.0, 3.14159]\ngoal = [-3.0, 0.0]\nradius_m = 0.4\n";
    let fleet = Scenario::from_toml(toml, "fleet.toml").expect("parsed");
    let scenario = fleet.member(0).validated("robot 0").expect("valid");
    let dt = scenario.timing.dt_s();
    let mut task = LidarTask::new(&scenario, 0, ()).expect("made");
    assert_eq!(task.peer_topics(), [protocol::topics::TRUTH]);
    let context = SimulatedTime::at(0, dt);
    let ahead = |scan: &Scan| f64::from(scan.ranges()[(scan.beams / 2) as usize]);
    let peer = |tick: u64, x: f64| {
        let mut truth = truth(tick, [x, 0.0, 0.0], dt);
        truth.header.robot = 1;
        Data::Truth(truth)
    };

    // Before any truth of it, it is at its start: its near edge 3 - 0.4 m ahead.
    task.hear(LidarInput::Truth(truth(0, [0.0; 3], dt)), 0, &context);
    let scan = task.step(&context).expect("a scan at tick 0").output;
    assert!((ahead(&scan) - 2.6).abs() < 1e-6, "{}", ahead(&scan));

    // Its truths of the two ticks before the scan's (coming at 1 m/s), and one of the
    // scan's own tick, which is not yet its to see: the scan sees it moved on by a tick.
    let tick = 11 * scenario.perception_ticks();
    task.hear_peer(&peer(tick - 2, 2.0));
    task.hear_peer(&peer(tick - 1, 2.0 - dt));
    task.hear_peer(&peer(tick, -9.0));
    task.hear_peer(&Data::Truth(truth(tick - 1, [1.0, 0.0, 0.0], dt))); // robot 0: itself
    task.hear(LidarInput::Truth(truth(tick, [0.0; 3], dt)), 0, &context);
    let scan = task.step(&context).expect("a scan").output;
    let expected = 2.0 - 2.0 * dt - 0.4;
    assert!(
        (ahead(&scan) - expected).abs() < 1e-6,
        "{} vs {expected}",
        ahead(&scan)
    );

    // Its truths stop there (its pipeline ended): a scan much later sees it a tick on from
    // its last, not moving on for ever.
    let mut task = LidarTask::new(&scenario, 0, ()).expect("made");
    task.hear_peer(&peer(tick - 2, 2.0));
    task.hear_peer(&peer(tick - 1, 2.0 - dt));
    let later = tick + 10 * scenario.perception_ticks();
    task.hear(LidarInput::Truth(truth(later, [0.0; 3], dt)), 0, &context);
    let scan = task.step(&context).expect("a scan").output;
    assert!((ahead(&scan) - expected).abs() < 1e-6, "{}", ahead(&scan));
}
