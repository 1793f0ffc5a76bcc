use super::*;
use ros2::cdr::{Header, LaserScan, TransformStamped};
use std::f64::consts::FRAC_PI_2;

fn transform(parent: &str, child: &str, x: f64, y: f64, yaw: f64) -> TransformStamped {
    TransformStamped {
        header: Header {
            frame_id: parent.into(),
            ..Header::default()
        },
        child_frame_id: child.into(),
        translation: [x, y, 0.3],
        rotation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
    }
}

#[test]
fn a_chain_of_mounts_is_composed_up_to_the_base_and_a_broken_one_is_none() {
    let mounts: BTreeMap<String, Mount> = [
        transform("base_link", "mast", 0.2, 0.0, FRAC_PI_2),
        transform("mast", "laser", 0.1, 0.0, FRAC_PI_2),
        transform("odom", "camera", 1.0, 1.0, 0.0),
    ]
    .iter()
    .map(|t| (t.child_frame_id.clone(), Mount::of(t)))
    .collect();
    let [x, y, yaw] = mount_of(&mounts, "laser", "base_link").unwrap();
    // The mast turned a quarter: the laser's 0.1 m forward on it is 0.1 m to the left.
    assert!(
        (x - 0.2).abs() < 1e-12 && (y - 0.1).abs() < 1e-12,
        "{x} {y}"
    );
    assert!((yaw - 2.0 * FRAC_PI_2).abs() < 1e-12);
    assert_eq!(mount_of(&mounts, "base_link", "base_link"), Some([0.0; 3]));
    assert_eq!(mount_of(&mounts, "camera", "base_link"), None);
    assert_eq!(mount_of(&mounts, "unheard", "base_link"), None);
}

#[test]
fn a_laser_scan_becomes_a_scan_with_rep_117_ranges_and_at_most_max_beams() {
    let ros = LaserScan {
        angle_min: -1.0,
        angle_increment: 0.01,
        range_min: 0.1,
        range_max: 8.0,
        ranges: vec![1.5, 0.0, 9.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN],
        ..LaserScan::default()
    };
    let scan = scan_of(&ros).unwrap();
    assert_eq!(scan.beams, 6);
    assert_eq!(scan.angle_min_rad, -1.0);
    let r = scan.ranges();
    assert_eq!(r[0], 1.5);
    // Outside [range_min, range_max]: discarded, as sensor_msgs says.
    assert!(r[1].is_nan() && r[2].is_nan());
    assert_eq!((r[3], r[4]), (f32::INFINITY, f32::NEG_INFINITY));
    assert!(r[5].is_nan());

    let dense = LaserScan {
        ranges: (0..2000).map(|i| 1.0 + i as f32 * 1e-3).collect(),
        ..ros.clone()
    };
    let scan = scan_of(&dense).unwrap();
    // 2000 beams two at a time: 1000 beams twice as far apart, each the nearer of two.
    assert_eq!(scan.beams, 1000);
    assert!((scan.angle_increment_rad - 0.02).abs() < 1e-9);
    assert_eq!(scan.ranges()[1], 1.002);
    let mut pole = dense.clone();
    pole.ranges[3] = 0.5; // seen by one beam only: the second of the second pair
    assert_eq!(scan_of(&pole).unwrap().ranges()[1], 0.5);
    assert!(scan_of(&LaserScan::default()).is_none());
}
