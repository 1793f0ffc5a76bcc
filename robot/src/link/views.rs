//! What RViz shows of the MPC (docs/ros2.md): its plan and the route as
//! `nav_msgs/msg/Path`, the obstacles as a `visualization_msgs/msg/MarkerArray` of
//! cylinders, all in the odometry's frame.

use super::{Link, RosPublisher, ros_time, wall_ns};
use crate::RobotError;
use ros2::cdr::{self, Message};

/// How the obstacles are drawn: cylinders this tall (m), this colour (RGBA).
const OBSTACLE_HEIGHT_M: f64 = 0.5;
const OBSTACLE_COLOR: [f32; 4] = [0.85, 0.2, 0.15, 0.6];

/// The publishers of what RViz shows.
pub(super) struct Views {
    pub(super) plan: RosPublisher,
    pub(super) route: RosPublisher,
    pub(super) obstacles: RosPublisher,
}

impl Link {
    /// A header in the odometry's frame, stamped now.
    fn view_header(&self) -> cdr::Header {
        cdr::Header {
            stamp: ros_time(wall_ns()),
            frame_id: self.frame.get().cloned().unwrap_or_default(),
        }
    }

    /// A path through `poses` (`[x_m, y_m, yaw_rad]`) in the odometry's frame.
    fn path(&self, poses: impl Iterator<Item = [f64; 3]>) -> Vec<u8> {
        let header = self.view_header();
        let poses = poses
            .map(|[x, y, yaw]| cdr::PoseStamped {
                header: header.clone(),
                pose: cdr::Pose {
                    position: [x, y, 0.0],
                    orientation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
                },
            })
            .collect();
        cdr::Path { header, poses }.to_cdr()
    }

    /// Shows the MPC's plan: `poses` its predicted positions and headings.
    pub fn show_plan(&mut self, poses: impl Iterator<Item = [f64; 3]>) -> Result<(), RobotError> {
        let payload = self.path(poses);
        let topic = self.names.plan.clone();
        self.views
            .plan
            .put(payload)
            .map_err(|reason| RobotError::Key { key: topic, reason })
    }

    /// Shows the route through `waypoints` (`[x_m, y_m]`, each headed to the next).
    pub fn show_route(&mut self, waypoints: &[[f64; 2]]) -> Result<(), RobotError> {
        let heading = |i: usize| {
            let [a, b] = [waypoints[i], waypoints[(i + 1).min(waypoints.len() - 1)]];
            (b[1] - a[1]).atan2(b[0] - a[0])
        };
        let payload = self.path((0..waypoints.len()).map(|i| {
            let [x, y] = waypoints[i];
            [x, y, heading(i)]
        }));
        let topic = self.names.route.clone();
        self.views
            .route
            .put(payload)
            .map_err(|reason| RobotError::Key { key: topic, reason })
    }

    /// Shows the obstacles: `(id, [x_m, y_m], radius_m)` each, as cylinders.
    pub fn show_obstacles(
        &mut self,
        discs: impl Iterator<Item = (i32, [f64; 2], f64)>,
    ) -> Result<(), RobotError> {
        let header = self.view_header();
        let markers = discs
            .map(|(id, [x, y], radius)| cdr::Marker {
                header: header.clone(),
                ns: "obstacles".into(),
                id,
                kind: cdr::Marker::CYLINDER,
                action: cdr::Marker::ADD,
                pose: cdr::Pose {
                    position: [x, y, OBSTACLE_HEIGHT_M / 2.0],
                    orientation: [0.0, 0.0, 0.0, 1.0],
                },
                scale: [2.0 * radius, 2.0 * radius, OBSTACLE_HEIGHT_M],
                color: OBSTACLE_COLOR,
                ..cdr::Marker::default()
            })
            .collect();
        let payload = cdr::MarkerArray { markers }.to_cdr();
        let topic = self.names.obstacles.clone();
        self.views
            .obstacles
            .put(payload)
            .map_err(|reason| RobotError::Key { key: topic, reason })
    }
}
