//! The plant role played by a ROS 2 robot (`plant.kind = "ros2"`, docs/ros2.md): a node on
//! the robot's graph that publishes each inner tick's command on `cmd_vel` and measures
//! the robot by its odometry, over rmw_zenoh's wire format (crate `ros2`) on a Zenoh
//! client session to the robot's router ([`link`]). [`RobotTask`] is that node as the
//! plant's task; [`first_contact`] is what the orchestrator learns before a run starts:
//! the start pose and, if asked, the goal.

pub mod link;
pub mod scan;
pub mod task;
pub mod watchdog;

pub use link::{Heard, Link, first_contact, odometry_key, scan_key, watched_keys};
pub use scan::ScanTask;
pub use task::RobotTask;

/// What can go wrong with the robot.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    #[error("the robot's router at {endpoint}: {reason}")]
    Router { endpoint: String, reason: String },
    #[error("`{key}`: {reason}")]
    Key { key: String, reason: String },
    #[error("no odometry within {waited_s} s on `{key}` through the router at {endpoint}; {graph}")]
    NoOdometry {
        waited_s: f64,
        key: String,
        endpoint: String,
        graph: String,
    },
    #[error(
        "no scan within {waited_s} s on `{key}` through the router at {endpoint} (a robot \
         without a lidar: remove [lidar]); {graph}"
    )]
    NoScan {
        waited_s: f64,
        key: String,
        endpoint: String,
        graph: String,
    },
    #[error("stopped while waiting for the robot")]
    Stopped,
    #[error("the odometry on `{key}` stopped: the robot was sent a zero twist")]
    OdometryStopped { key: String },
    #[error("the scans on `{key}` stopped: the robot was sent a zero twist")]
    ScanStopped { key: String },
}
