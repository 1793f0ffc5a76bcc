//! Goals from a live view's clients (docs/foxglove.md, "Goals from the viewer"): a client
//! advertises a `/goal` channel and publishes `geometry_msgs/PoseStamped` as JSON, as
//! Foxglove's 3D panel publishes a pose. A goal is checked as RViz's would be
//! ([`protocol::Scenario::live_goal`]) and handed to the run, which sets it at a sample
//! boundary for every role; a client is told, in a status message, what became of it.
//! Nothing else a client sends changes the run.

use foxglove::websocket::{Client, ClientChannel, Status};
use protocol::{Goal, Scenario};
use std::sync::mpsc::Sender;

/// The one topic a client may publish on.
pub const GOAL_TOPIC: &str = "/goal";

/// Where the goals go, and what they are checked against.
pub(crate) struct GoalDesk {
    /// The scenario a goal is checked against and the run it goes to; or why the run
    /// takes none.
    to: Result<(Scenario, Sender<Goal>), &'static str>,
}

impl GoalDesk {
    pub(crate) fn new(scenario: &Scenario, run: Sender<Goal>) -> GoalDesk {
        let accept = scenario.live.as_ref().is_some_and(|l| l.accept_goals);
        GoalDesk {
            to: if accept {
                Ok((scenario.clone(), run))
            } else {
                Err("this run takes no goals from a viewer (live.accept_goals = false)")
            },
        }
    }

    /// A desk that refuses every goal, saying `why`.
    pub(crate) fn refusing(why: &'static str) -> GoalDesk {
        GoalDesk { to: Err(why) }
    }

    /// A client advertised `channel`: anything but `/goal` in JSON is told it is ignored.
    pub(crate) fn advertised(&self, client: &Client, channel: &ClientChannel) {
        if channel.topic != GOAL_TOPIC || channel.encoding != "json" {
            client.send_status(Status::warning(format!(
                "{} ({}) is ignored: this run takes only {GOAL_TOPIC} \
                 (geometry_msgs/PoseStamped as JSON)",
                channel.topic, channel.encoding
            )));
        }
    }

    /// A message on a client's channel: a goal on `/goal`, taken or refused.
    pub(crate) fn published(&self, client: &Client, channel: &ClientChannel, payload: &[u8]) {
        if channel.topic != GOAL_TOPIC || channel.encoding != "json" {
            return; // told at its advertisement that it is ignored
        }
        let status = match self.take(payload) {
            Ok(goal) => Status::info(format!(
                "goal accepted: driving to ({:.3}, {:.3})",
                goal.position[0], goal.position[1]
            )),
            Err(why) => Status::error(format!("goal refused: {why}")),
        };
        client.send_status(status);
    }

    fn take(&self, payload: &[u8]) -> Result<Goal, String> {
        let (scenario, run) = self.to.as_ref().map_err(|why| why.to_string())?;
        let goal = scenario.live_goal(pose_stamped(payload)?)?;
        run.send(goal).map_err(|_| "the run is over".to_string())?;
        Ok(goal)
    }
}

/// The goal in a `geometry_msgs/PoseStamped` as JSON: its position, and its heading when
/// its orientation is a rotation (a zero quaternion is none).
pub(crate) fn pose_stamped(payload: &[u8]) -> Result<Goal, String> {
    let json: serde_json::Value = serde_json::from_slice(payload)
        .map_err(|e| format!("not JSON ({e}); expected geometry_msgs/PoseStamped"))?;
    let pose = &json["pose"];
    let number = |v: &serde_json::Value, key: &str| {
        v[key]
            .as_f64()
            .ok_or_else(|| format!("no number at pose.{key}: expected geometry_msgs/PoseStamped"))
    };
    let position = &pose["position"];
    let (x, y) = (number(position, "x")?, number(position, "y")?);
    let q = &pose["orientation"];
    let yaw = match ["x", "y", "z", "w"].map(|k| q[k].as_f64()) {
        [Some(qx), Some(qy), Some(qz), Some(qw)] if qx * qx + qy * qy + qz * qz + qw * qw > 0.0 => {
            Some((2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz)))
        }
        _ => None,
    };
    Ok(Goal {
        position: [x, y],
        yaw_rad: yaw,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pose_stamped_gives_its_position_and_the_heading_of_its_quaternion() {
        let half = std::f64::consts::FRAC_PI_4;
        let json = format!(
            r#"{{"header":{{"frame_id":"world","stamp":{{"sec":1,"nsec":0}}}},
               "pose":{{"position":{{"x":1.5,"y":-2,"z":0}},
                        "orientation":{{"x":0,"y":0,"z":{},"w":{}}}}}}}"#,
            half.sin(),
            half.cos()
        );
        let goal = pose_stamped(json.as_bytes()).unwrap();
        assert_eq!(goal.position, [1.5, -2.0]);
        assert!((goal.yaw_rad.unwrap() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let no_turn =
            r#"{"pose":{"position":{"x":1,"y":2},"orientation":{"x":0,"y":0,"z":0,"w":0}}}"#;
        assert_eq!(pose_stamped(no_turn.as_bytes()).unwrap().yaw_rad, None);
        for bad in [r#"{"pose":{"position":{"x":1}}}"#, "[1, 2]", "not json"] {
            assert!(pose_stamped(bad.as_bytes()).is_err(), "{bad}");
        }
    }
}
