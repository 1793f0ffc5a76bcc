//! A ROS 2 robot in place of the simulated plant (docs/ros2.md): where its Zenoh router
//! is, and the names of its topics.

use serde::{Deserialize, Serialize};

/// `plant.kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PlantKind {
    /// The simulated unicycle (crate `plant`).
    Sim,
    /// A ROS 2 robot on rmw_zenoh's wire format (`[ros2]`), in real time only.
    Ros2,
}

/// `ros2.wire`: how the robot's topics are laid on Zenoh.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Ros2Wire {
    /// rmw_zenoh's keys, attachments and liveliness tokens: a robot whose nodes run
    /// `rmw_zenoh_cpp`.
    RmwZenoh,
    /// zenoh-bridge-ros2dds's keys (the topic's name alone): a DDS robot behind that
    /// bridge.
    Bridge,
}

/// The robot of `plant.kind = "ros2"`: the pipeline is a ROS 2 node on its graph that
/// publishes the commands and takes the odometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// The robot's Zenoh router (`ros2 run rmw_zenoh_cpp rmw_zenohd`): `tcp/ADDR:PORT`
    /// (loopback, or with `--insecure`) or `tls/ADDR:PORT` (with `--tls-*`).
    pub endpoint: String,
    /// `ROS_DOMAIN_ID`, 0 to 232.
    pub domain_id: u32,
    /// The node's namespace (`/` or empty: none); relative topics live under it.
    pub namespace: String,
    /// The node's name on the graph.
    pub node: String,
    /// The robot's ROS 2 distribution, whose type hashes are in the data keys: `jazzy`
    /// or `kilted`.
    pub distro: String,
    /// `rmw_zenoh`, or `bridge` for a DDS robot behind zenoh-bridge-ros2dds.
    pub wire: Ros2Wire,
    /// Where every inner tick's command (forward speed, turn rate) goes.
    pub cmd_vel: String,
    /// `geometry_msgs/msg/TwistStamped` (Jazzy's `diff_drive_controller`, Nav2); `false`:
    /// `geometry_msgs/msg/Twist`.
    pub stamped: bool,
    /// Where the `nav_msgs/msg/Odometry` measured comes from.
    pub odom: String,
    /// Where a `geometry_msgs/msg/PoseStamped` goal comes from (RViz's "2D Goal Pose").
    pub goal_topic: String,
    /// Wait for a goal on `goal_topic` before the run starts (`robot.goal` is then
    /// replaced by it); `false`: `robot.goal`, in the odometry's frame.
    pub wait_for_goal: bool,
    /// Odometry older than this stops the robot (zero twist) and, once twice as old,
    /// ends the run `aborted`, s.
    pub odom_timeout_s: f64,
    /// With a lidar: where its `sensor_msgs/msg/LaserScan` comes from (the lidar's pose
    /// on the base from `tf_static`, else `lidar.offset`).
    pub scan: String,
    /// With a lidar: a scan older than this stops the robot (zero twist) and, once twice
    /// as old, ends the run `aborted`, s.
    pub scan_timeout_s: f64,
    /// How long the run waits for the robot's first odometry (with a lidar, then for its
    /// first scan) before it ends with an error naming what it waited for, s. A base that
    /// takes longer to come up after its driver starts needs more.
    pub first_message_timeout_s: f64,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Ros2Config {
            endpoint: "tcp/127.0.0.1:7447".into(),
            domain_id: 0,
            namespace: String::new(),
            node: "scmpc".into(),
            distro: "jazzy".into(),
            wire: Ros2Wire::RmwZenoh,
            cmd_vel: "cmd_vel".into(),
            stamped: true,
            odom: "odom".into(),
            goal_topic: "goal_pose".into(),
            wait_for_goal: false,
            odom_timeout_s: 0.2,
            scan: "scan".into(),
            scan_timeout_s: 0.5,
            first_message_timeout_s: 5.0,
        }
    }
}

/// Largest `ROS_DOMAIN_ID` ROS 2 accepts.
pub const MAX_DOMAIN_ID: u32 = 232;

impl Ros2Config {
    /// Every problem of the section, with its key (`ros2.*`).
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        if let Err(e) = crate::endpoint::Endpoint::parse(&self.endpoint) {
            problems.push(("ros2.endpoint", e));
        }
        if self.domain_id > MAX_DOMAIN_ID {
            problems.push((
                "ros2.domain_id",
                format!("{} is not in 0..={MAX_DOMAIN_ID}", self.domain_id),
            ));
        }
        match ros2::Node::new(self.domain_id, "", &self.namespace, &self.node) {
            Err(e) if ros2::keys::namespace(&self.namespace).is_err() => {
                problems.push(("ros2.namespace", e.to_string()))
            }
            Err(e) => problems.push(("ros2.node", e.to_string())),
            Ok(_) => {}
        }
        if ros2::Distro::parse(&self.distro).is_none() {
            let known: Vec<&str> = ros2::Distro::ALL.iter().map(|d| d.as_str()).collect();
            problems.push((
                "ros2.distro",
                format!("`{}` is not one of {}", self.distro, known.join(", ")),
            ));
        }
        let namespace = ros2::keys::namespace(&self.namespace).unwrap_or_else(|_| "/".into());
        for (key, topic) in [
            ("ros2.cmd_vel", &self.cmd_vel),
            ("ros2.odom", &self.odom),
            ("ros2.goal_topic", &self.goal_topic),
            ("ros2.scan", &self.scan),
        ] {
            if let Err(e) = ros2::keys::qualified_topic(&namespace, topic) {
                problems.push((key, e.to_string()));
            }
        }
        for (key, timeout_s) in [
            ("ros2.odom_timeout_s", self.odom_timeout_s),
            ("ros2.scan_timeout_s", self.scan_timeout_s),
            ("ros2.first_message_timeout_s", self.first_message_timeout_s),
        ] {
            if !(timeout_s.is_finite() && timeout_s > 0.0) {
                problems.push((key, format!("{timeout_s} is not a positive number")));
            }
        }
        problems
    }
}
