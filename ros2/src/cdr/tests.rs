//! Byte layouts of rmw_zenoh's CDR, as `rosbags` 0.11.9 (`Typestore.serialize_cdr`)
//! writes them for Jazzy (docs/ros2.md).

use super::*;

fn header(frame_id: &str) -> Header {
    Header {
        stamp: Time { sec: 1, nanosec: 2 },
        frame_id: frame_id.into(),
    }
}

fn pose() -> Pose {
    Pose {
        position: [1.0, 2.0, 0.0],
        orientation: [0.0, 0.0, 0.0, 1.0],
    }
}

#[test]
fn a_twist_stamped_is_laid_out_byte_for_byte() {
    let message = TwistStamped {
        header: header("odom"),
        twist: Twist {
            linear: [1.0, 0.0, 0.0],
            angular: [0.0, 0.0, 0.5],
        },
    };
    let bytes = message.to_cdr();
    let mut expected = vec![0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 5, 0, 0, 0];
    expected.extend_from_slice(b"odom\0");
    expected.extend_from_slice(&[0; 7]); // to 24 after the header, an 8-byte boundary
    expected.extend_from_slice(&1.0f64.to_le_bytes());
    expected.extend_from_slice(&[0; 32]);
    expected.extend_from_slice(&0.5f64.to_le_bytes());
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), 76);
    assert_eq!(TwistStamped::from_cdr(&bytes), Ok(message));
    // With an empty frame: the twist at 16 after the header.
    let bare = TwistStamped::default().to_cdr();
    assert_eq!(bare.len(), 68);
    assert_eq!(bare[12..17], [1, 0, 0, 0, 0]);
    assert_eq!(Twist::default().to_cdr().len(), 52);
}

#[test]
fn odometry_and_a_pose_stamped_have_rosbags_sizes_and_offsets() {
    let mut odometry = Odometry {
        header: header("odom"),
        child_frame_id: "base_link".into(),
        pose: pose(),
        pose_covariance: [0.0; 36],
        twist: Twist {
            linear: [0.3, 0.0, 0.0],
            angular: [0.0, 0.0, -0.2],
        },
        twist_covariance: [0.0; 36],
    };
    odometry.pose_covariance[35] = 0.01;
    let bytes = odometry.to_cdr();
    assert_eq!(bytes.len(), 724);
    // After the 4-byte header: the child frame's length at 20, the pose at 40, its
    // covariance at 96, the twist at 384.
    assert_eq!(bytes[4 + 20..4 + 24], 10u32.to_le_bytes());
    assert_eq!(bytes[4 + 40..4 + 48], 1.0f64.to_le_bytes());
    assert_eq!(bytes[4 + 384..4 + 392], 0.3f64.to_le_bytes());
    assert_eq!(bytes[4 + 376..4 + 384], 0.01f64.to_le_bytes());
    assert_eq!(Odometry::from_cdr(&bytes), Ok(odometry));
    let stamped = PoseStamped {
        header: header("odom"),
        pose: pose(),
    };
    assert_eq!(stamped.to_cdr().len(), 84);
}

#[test]
fn a_path_is_its_header_a_count_and_its_poses_each_aligned_anew() {
    let stamped = PoseStamped {
        header: header("odom"),
        pose: pose(),
    };
    let path = Path {
        header: header("odom"),
        poses: vec![stamped.clone(), stamped],
    };
    let bytes = path.to_cdr();
    assert_eq!(bytes.len(), 188);
    assert_eq!(bytes[4 + 20..4 + 24], 2u32.to_le_bytes());
    // The second pose's header at 104, its position at 128.
    assert_eq!(bytes[4 + 104..4 + 108], 1i32.to_le_bytes());
    assert_eq!(bytes[4 + 128..4 + 136], 1.0f64.to_le_bytes());
    assert_eq!(Path::from_cdr(&bytes), Ok(path.clone()));
    let empty = Path {
        header: header("odom"),
        poses: Vec::new(),
    };
    assert_eq!(empty.to_cdr().len(), 28);
}

#[test]
fn payloads_that_are_not_the_message_are_refused_with_where() {
    let bytes = TwistStamped::default().to_cdr();
    assert_eq!(
        TwistStamped::from_cdr(&bytes[..40]),
        Err(CdrError::Truncated(40))
    );
    let mut big_endian = bytes.clone();
    big_endian[1] = 0;
    assert_eq!(
        TwistStamped::from_cdr(&big_endian),
        Err(CdrError::Encapsulation([0, 0]))
    );
    let mut unterminated = bytes;
    unterminated[16] = b'x';
    assert_eq!(
        TwistStamped::from_cdr(&unterminated),
        Err(CdrError::String(16))
    );
    // A path that claims more poses than its bytes hold.
    let mut lying = Path::default().to_cdr();
    lying[20..24].copy_from_slice(&1_000_000u32.to_le_bytes());
    assert!(matches!(
        Path::from_cdr(&lying),
        Err(CdrError::Truncated(_))
    ));
}

#[test]
fn a_marker_array_reads_back_and_a_marker_with_points_is_refused() {
    let marker = Marker {
        header: header("odom"),
        ns: "obstacles".into(),
        id: 2,
        kind: Marker::CYLINDER,
        action: Marker::ADD,
        pose: pose(),
        scale: [1.0, 1.0, 0.2],
        color: [1.0, 0.5, 0.0, 0.8],
        ..Marker::default()
    };
    let array = MarkerArray {
        markers: vec![marker.clone(), marker],
    };
    let bytes = array.to_cdr();
    assert_eq!(MarkerArray::from_cdr(&bytes), Ok(array.clone()));
    // The first marker's `points` count follows its `frame_locked` byte, aligned to 4.
    let one = array.markers[0].to_cdr();
    let mut w = Writer::default();
    let m = &array.markers[0];
    m.header.write(&mut w);
    w.string(&m.ns);
    [m.id, m.kind, m.action].iter().for_each(|&v| w.i32(v));
    m.pose.write(&mut w);
    w.f64s(&m.scale);
    m.color.iter().for_each(|&c| w.f32(c));
    m.lifetime.write(&mut w);
    w.bool(m.frame_locked);
    let fields = w.into_bytes().len() - ENCAPSULATION_LE.len();
    let points_at = ENCAPSULATION_LE.len() + fields.next_multiple_of(4);
    let mut with_points = one.clone();
    with_points[points_at] = 1;
    assert_eq!(
        Marker::from_cdr(&with_points),
        Err(CdrError::Unsupported("a marker's points"))
    );
}
