//! Goals from a live view's clients (docs/foxglove.md, "Goals from the viewer"): a client
//! advertises a `/goal` channel (in a fleet's view `/robot<id>/goal`, one per robot) and
//! publishes `geometry_msgs/PoseStamped` as JSON, as Foxglove's 3D panel publishes a pose.
//! A goal is checked as RViz's would be ([`protocol::Scenario::live_goal`]) and handed to
//! the run, which sets it at a sample boundary for every role of its robot; a client is
//! told, in a status message, what became of it. Nothing else a client sends changes the
//! run.

use foxglove::websocket::{Client, ClientChannel, Status};
use protocol::{Goal, Scenario};
use record::goals::GoalInbox;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

/// The topic a client publishes a run's goals on; a fleet robot's is under its id
/// ([`record::mcap::fleet_topic`]: `/robot1/goal`).
pub const GOAL_TOPIC: &str = "/goal";

/// Where the goals go, and what they are checked against. A fleet's view shares it with
/// the server's listener, and each robot's record joins it as it starts
/// ([`GoalDesk::join`]).
#[derive(Clone)]
pub(crate) struct GoalDesk {
    /// Why the run takes no goals; `None` when it takes them.
    refused: Option<&'static str>,
    /// The topics a goal may come on.
    topics: Arc<[String]>,
    /// Each topic's robot, as it joins.
    robots: Arc<Mutex<HashMap<String, Robot>>>,
}

/// A robot that takes goals.
struct Robot {
    /// What a goal for it is checked against.
    scenario: Scenario,
    /// Its record, which sets the goal, and shows where the robot may come to rest (its
    /// goal in force, and one sent and not set yet): no other robot's goal may take
    /// either place.
    run: GoalInbox,
}

/// Why a run without `live.accept_goals` refuses a goal.
const NOT_ACCEPTED: &str = "this run takes no goals from a viewer (live.accept_goals = false)";

impl GoalDesk {
    /// A run's desk: goals on `/goal`, checked against `scenario`, go to `run`.
    pub(crate) fn new(scenario: &Scenario, run: GoalInbox) -> GoalDesk {
        let desk = GoalDesk::of(scenario, vec![GOAL_TOPIC.to_string()]);
        desk.join(GOAL_TOPIC, scenario, run);
        desk
    }

    /// A fleet's desk: robot `i`'s goals on `/robot<i>/goal`, once its record joins.
    pub(crate) fn fleet(fleet: &Scenario) -> GoalDesk {
        let topics = (0..fleet.robot_count())
            .map(|robot| record::mcap::fleet_topic(robot, GOAL_TOPIC))
            .collect();
        GoalDesk::of(fleet, topics)
    }

    fn of(scenario: &Scenario, topics: Vec<String>) -> GoalDesk {
        let accept = scenario.live.as_ref().is_some_and(|l| l.accept_goals);
        GoalDesk {
            refused: (!accept).then_some(NOT_ACCEPTED),
            topics: topics.into(),
            robots: Arc::default(),
        }
    }

    /// Goals on `topic`, checked against `scenario`, go to `run` from now on.
    pub(crate) fn join(&self, topic: &str, scenario: &Scenario, run: GoalInbox) {
        let mut robots = self.robots.lock().unwrap_or_else(PoisonError::into_inner);
        let robot = Robot {
            scenario: scenario.clone(),
            run,
        };
        robots.insert(topic.to_string(), robot);
    }

    /// Whether a goal may come on `channel`.
    fn takes(&self, channel: &ClientChannel) -> bool {
        channel.encoding == "json" && self.topics.contains(&channel.topic)
    }

    /// A client advertised `channel`: anything but a goal's topic in JSON is told it is
    /// ignored.
    pub(crate) fn advertised(&self, client: &Client, channel: &ClientChannel) {
        if !self.takes(channel) {
            let topics = match &self.topics[..] {
                [one] => one.clone(),
                [first, .., last] => format!("{first} … {last}"),
                [] => String::new(),
            };
            client.send_status(Status::warning(format!(
                "{} ({}) is ignored: this run takes only {topics} \
                 (geometry_msgs/PoseStamped as JSON)",
                channel.topic, channel.encoding
            )));
        }
    }

    /// A message on a client's channel: a goal on a goal's topic, taken or refused.
    pub(crate) fn published(&self, client: &Client, channel: &ClientChannel, payload: &[u8]) {
        if !self.takes(channel) {
            return; // told at its advertisement that it is ignored
        }
        let status = match self.take(&channel.topic, payload) {
            Ok(goal) => Status::info(format!(
                "goal accepted: driving to ({:.3}, {:.3})",
                goal.position[0], goal.position[1]
            )),
            Err(why) => Status::error(format!("goal refused: {why}")),
        };
        client.send_status(status);
    }

    fn take(&self, topic: &str, payload: &[u8]) -> Result<Goal, String> {
        if let Some(why) = self.refused {
            return Err(why.to_string());
        }
        let robots = self.robots.lock().unwrap_or_else(PoisonError::into_inner);
        let over = || match topic {
            GOAL_TOPIC => "the run is over".to_string(),
            _ => format!(
                "the robot of {topic} takes none now (its record has not begun or has ended)"
            ),
        };
        let robot = robots.get(topic).ok_or_else(over)?;
        let goal = robot.scenario.live_goal(pose_stamped(payload)?)?;
        for (other_topic, other) in robots.iter().filter(|(t, _)| *t != topic) {
            let own = &robot.scenario.robot;
            let room = own.radius_m + other.scenario.robot.radius_m + own.goal_tolerance_m;
            let (in_force, waiting) = other.run.goals();
            let nearest = std::iter::once(in_force).chain(waiting);
            let apart = (nearest.map(|place| protocol::distance(goal.position, place)))
                .fold(f64::INFINITY, f64::min);
            if apart <= room {
                let [x, y] = goal.position;
                return Err(format!(
                    "({x}, {y}) is {apart:.3} m from the goal of the robot of {other_topic}; \
                     two robots resting there need their radii and robot.goal_tolerance_m, \
                     {room:.3} m"
                ));
            }
        }
        robot.run.send(goal).map_err(|_| over())?;
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

    /// A `geometry_msgs/PoseStamped` at `(x, y)` as JSON, no heading.
    fn pose(x: f64, y: f64) -> Vec<u8> {
        format!(r#"{{"pose":{{"position":{{"x":{x},"y":{y}}}}}}}"#).into_bytes()
    }

    #[test]
    fn a_fleet_robots_goal_goes_to_it_alone_and_not_onto_another_robots_goal() {
        let mut fleet =
            Scenario::from_toml(include_str!("../../scenarios/swap4.toml"), "swap4").unwrap();
        fleet.live = Some(protocol::LiveConfig {
            accept_goals: true,
            ..protocol::LiveConfig::default()
        });
        let desk = GoalDesk::fleet(&fleet);
        let topic = |robot| record::mcap::fleet_topic(robot, GOAL_TOPIC);
        let dir = std::env::temp_dir().join(format!("scmpc-goal-desk-{}", std::process::id()));
        let mut records: Vec<_> = (0..2)
            .map(|robot| {
                let member = fleet.member(robot);
                let record =
                    record::Recorder::create(&dir.join(format!("robot{robot}")), &member, &[])
                        .unwrap();
                desk.join(&topic(robot), &member, record.goal_inbox());
                record
            })
            .collect();
        assert_eq!(
            desk.take(&topic(1), &pose(1.0, 4.0)).unwrap().position,
            [1.0, 4.0]
        );
        assert!(
            records[0].requested_goal().is_none(),
            "robot 0 got robot 1's goal"
        );
        assert_eq!(records[1].requested_goal().unwrap().position, [1.0, 4.0]);
        // Onto robot 0's goal (-3, 0), then onto robot 1's, taken and not set yet.
        let refused = desk.take(&topic(1), &pose(-3.2, 0.1)).unwrap_err();
        assert!(refused.contains("the robot of /robot0/goal"), "{refused}");
        let refused = desk.take(&topic(0), &pose(1.2, 4.0)).unwrap_err();
        assert!(refused.contains("the robot of /robot1/goal"), "{refused}");
        // Robot 1's record ends before it sets that goal (its outcome, as an in-process
        // fleet ends a member's record): the robot drives on to the goal in force, and
        // the place is free; the goal in force is not.
        let member = fleet.member(1);
        let outcome = record::judge::Outcome::Stalled;
        (records
            .remove(1)
            .finish(&member, "in-process", outcome, 1.0, None, None))
        .unwrap();
        assert!(desk.take(&topic(0), &pose(1.2, 4.0)).is_ok());
        let [x, y] = fleet.member(1).robot.goal.position;
        let refused = desk.take(&topic(0), &pose(x + 0.1, y)).unwrap_err();
        assert!(refused.contains("the robot of /robot1/goal"), "{refused}");
        // Robot 2 has not joined; robot 1 takes no more.
        for robot in [2, 1] {
            let refused = desk.take(&topic(robot), &pose(5.0, 5.0)).unwrap_err();
            assert!(refused.contains("takes none now"), "{refused}");
        }
        drop(records);
        std::fs::remove_dir_all(&dir).unwrap();
    }

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
