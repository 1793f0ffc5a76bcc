//! The crate `ros2` writes rmw_zenoh's wire format as a ROS 2 peer reads it: `rosbags`
//! (PyPI, pinned in the tests' venv: [`common::python`]) deserializes every message it
//! encodes to the values put in, serializes them back to the same bytes, and computes
//! the same RIHS01 type hashes for Jazzy and Kilted.

use crate::common;

use common::python::{repo, run_python};
use ros2::cdr::{
    Header, LaserScan, Marker, MarkerArray, Message, Odometry, Path, Pose, PoseStamped, TfMessage,
    Time, TransformStamped, Twist, TwistStamped,
};
use ros2::{Distro, MessageType};

fn header(frame_id: &str) -> Header {
    Header {
        stamp: Time {
            sec: 1_764_000_000,
            nanosec: 123_456_789,
        },
        frame_id: frame_id.into(),
    }
}

#[test]
fn rosbags_reads_what_the_crate_writes_and_computes_the_same_type_hashes() {
    let _machine = common::machine_shared();
    let pose = Pose {
        position: [1.5, -2.25, 0.0],
        orientation: [0.0, 0.0, 0.38268343236508984, 0.9238795325112867],
    };
    let mut odometry = Odometry {
        header: header("odom"),
        child_frame_id: "base_link".into(),
        pose,
        pose_covariance: [0.0; 36],
        twist: Twist {
            linear: [0.4, 0.0, 0.0],
            angular: [0.0, 0.0, -0.3],
        },
        twist_covariance: [0.0; 36],
    };
    odometry.pose_covariance[0] = 0.01;
    odometry.twist_covariance[35] = 0.02;
    let twist = TwistStamped {
        header: header("base_link"),
        twist: Twist {
            linear: [0.7, 0.0, 0.0],
            angular: [0.0, 0.0, 1.25],
        },
    };
    let stamped = PoseStamped {
        header: header("map"),
        pose,
    };
    let path = Path {
        header: header("odom"),
        poses: vec![stamped.clone(); 3],
    };
    let obstacle = |id, text: &str| Marker {
        header: header("odom"),
        ns: "obstacles".into(),
        id,
        kind: Marker::CYLINDER,
        action: Marker::ADD,
        pose,
        scale: [3.0, 3.0, 0.5],
        color: [0.75, 0.25, 0.125, 0.5],
        lifetime: Time {
            sec: 1,
            nanosec: 500,
        },
        frame_locked: true,
        text: text.into(),
    };
    let markers = MarkerArray {
        markers: vec![obstacle(0, ""), obstacle(7, "person")],
    };
    let scan = LaserScan {
        header: header("laser"),
        angle_min: -3.125,
        angle_max: 3.125,
        angle_increment: 0.015625,
        time_increment: 0.0,
        scan_time: 0.1,
        range_min: 0.1,
        range_max: 8.0,
        ranges: vec![1.5, 2.25, 8.5],
        intensities: vec![100.0],
    };
    let mount = |child: &str, x| TransformStamped {
        header: header("base_link"),
        child_frame_id: child.into(),
        translation: [x, -0.5, 0.25],
        rotation: [0.0, 0.0, 0.38268343236508984, 0.9238795325112867],
    };
    let tf = TfMessage {
        transforms: vec![mount("laser", 0.125), mount("camera", 0.0)],
    };
    let hex = |bytes: Vec<u8>| bytes.iter().map(|b| format!("{b:02x}")).collect::<String>();
    let lines = [
        (MessageType::Twist, hex(twist.twist.to_cdr())),
        (MessageType::TwistStamped, hex(twist.to_cdr())),
        (MessageType::Odometry, hex(odometry.to_cdr())),
        (MessageType::PoseStamped, hex(stamped.to_cdr())),
        (MessageType::Path, hex(path.to_cdr())),
        (MessageType::MarkerArray, hex(markers.to_cdr())),
        (MessageType::LaserScan, hex(scan.to_cdr())),
        (MessageType::TfMessage, hex(tf.to_cdr())),
    ];
    let stdin: String = lines
        .iter()
        .map(|(t, payload)| format!("{} {payload}\n", t.name()))
        .collect();
    let names: Vec<&std::path::Path> = MessageType::ALL
        .iter()
        .map(|t| std::path::Path::new(t.name()))
        .collect();
    let script = repo().join("tests/python/ros2_peer.py");
    let out: serde_json::Value =
        serde_json::from_str(&run_python(&script, &names, stdin.as_bytes())).unwrap();

    for distro in Distro::ALL {
        for t in MessageType::ALL {
            assert_eq!(
                out["hashes"][distro.as_str()][t.name()],
                t.type_hash(distro),
                "{} in {}",
                t.name(),
                distro.as_str()
            );
        }
    }
    let messages = out["messages"].as_array().unwrap();
    assert_eq!(messages.len(), lines.len());
    for m in messages {
        assert_eq!(m["same_bytes"], true, "{m}");
    }
    let [
        twist_only,
        twist,
        odometry,
        stamped,
        path,
        markers,
        scan,
        tf,
    ] = &messages[..]
    else {
        panic!("{messages:?}")
    };
    assert_eq!(twist_only["message"]["angular"]["z"], 1.25);
    let t = &twist["message"];
    assert_eq!(t["header"]["frame_id"], "base_link");
    assert_eq!(t["header"]["stamp"]["nanosec"], 123_456_789);
    assert_eq!(t["twist"]["linear"]["x"], 0.7);
    let o = &odometry["message"];
    assert_eq!(o["child_frame_id"], "base_link");
    assert_eq!(o["pose"]["pose"]["orientation"]["w"], 0.9238795325112867);
    assert_eq!(o["pose"]["covariance"][0], 0.01);
    assert_eq!(o["twist"]["twist"]["angular"]["z"], -0.3);
    assert_eq!(o["twist"]["covariance"][35], 0.02);
    assert_eq!(stamped["message"]["pose"]["position"]["y"], -2.25);
    let poses = path["message"]["poses"].as_array().unwrap();
    assert_eq!(poses.len(), 3);
    assert_eq!(poses[2]["header"]["frame_id"], "map");
    let person = &markers["message"]["markers"][1];
    assert_eq!(person["id"], 7);
    assert_eq!(person["type"], Marker::CYLINDER);
    assert_eq!(person["scale"]["x"], 3.0);
    assert_eq!(person["color"]["b"], 0.125);
    assert_eq!(person["lifetime"]["nanosec"], 500);
    assert_eq!(person["frame_locked"], true);
    assert_eq!(person["text"], "person");
    assert_eq!(person["mesh_file"]["filename"], "");
    let s = &scan["message"];
    assert_eq!(s["header"]["frame_id"], "laser");
    assert_eq!(s["angle_increment"], 0.015625);
    assert_eq!(s["range_max"], 8.0);
    assert_eq!(s["ranges"], serde_json::json!([1.5, 2.25, 8.5]));
    assert_eq!(s["intensities"], serde_json::json!([100.0]));
    let mounts = tf["message"]["transforms"].as_array().unwrap();
    assert_eq!(mounts.len(), 2);
    assert_eq!(mounts[0]["child_frame_id"], "laser");
    assert_eq!(mounts[0]["header"]["frame_id"], "base_link");
    assert_eq!(mounts[0]["transform"]["translation"]["x"], 0.125);
    assert_eq!(mounts[1]["transform"]["rotation"]["z"], 0.38268343236508984);
}
