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
