//! The robot's side of Zenoh: a client session to the robot's router, announced on the
//! ROS 2 graph as a node with its publisher and subscriptions (liveliness tokens), the
//! commands it sends, and the newest odometry (and goal) it has heard.

use crate::RobotError;
use protocol::endpoint::Endpoint;
use protocol::{Ros2Config, Ros2Wire};
use ros2::cdr::{self, Message};
use ros2::{Attachment, Distro, EntityKind, MessageType, Node, Qos};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

mod graph;
pub mod scan;
mod views;
use graph::{Awaited, graph_text};
use views::Views;

/// How long a graph listing waits for the router's answer.
const GRAPH_QUERY: Duration = Duration::from_secs(1);
/// Every endpoint's QoS: reliable, volatile, keep-last 10 (a ROS 2 node's default).
const QOS: Qos = Qos {
    reliable: true,
    transient_local: false,
    depth: 10,
};
/// A scan subscription's QoS: best effort, as lidar drivers publish (the sensor data
/// profile, keep-last 5).
pub(crate) const SCAN_QOS: Qos = Qos {
    reliable: false,
    transient_local: false,
    depth: 5,
};
/// The frame a command is stamped in: the robot's body.
const BASE_FRAME: &str = "base_link";

/// The robot's link as its task's resource ([`protocol::task::Resources`]): opened, with
/// the robot's first odometry heard, before the task is made. It stamps each odometry's
/// arrival on the runtime's clock (`runtime::clock::monotonic_ns`), the one a role
/// process's context reads: the watchdog compares the two, so the robot runs in a role
/// process only (the in-process executor refuses it).
pub struct RobotLink {
    pub link: Link,
    pub first: Heard,
}

impl protocol::task::Resources for RobotLink {
    fn open(scenario: &protocol::Validated) -> Result<RobotLink, protocol::task::TaskError> {
        let error = |e: RobotError| protocol::task::TaskError::setup(protocol::Role::Plant, e);
        let security = net::Security::from_env();
        let link =
            Link::open(&scenario.ros2, &security, scenario.lidar.is_some()).map_err(error)?;
        let first = link
            .first_odometry(&AtomicBool::new(false))
            .map_err(error)?;
        Ok(RobotLink { link, first })
    }
}

/// An odometry message as the pipeline heard it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heard {
    /// `[x_m, y_m, yaw_rad]` in the odometry's frame.
    pub pose: [f64; 3],
    /// The robot's forward speed (m/s) and turn rate (rad/s) as the odometry says.
    pub twist: [f64; 2],
    /// When it arrived, on this host's monotonic clock, ns.
    pub arrived_ns: u64,
    /// How old it was at arrival: the wall clock then less its header's stamp, ns (0 when
    /// the robot's clock is ahead).
    pub age_at_arrival_ns: u64,
}

/// The yaw of the unit quaternion `[x, y, z, w]`, rad in (-pi, pi].
pub fn yaw(q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// The wall clock, ns since the UNIX epoch.
pub(crate) fn wall_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// `ns` since the UNIX epoch as a ROS 2 time.
fn ros_time(ns: i64) -> cdr::Time {
    cdr::Time {
        sec: ns.div_euclid(1_000_000_000) as i32,
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

/// What an odometry payload says, heard at `arrived_ns` (monotonic) and `now_wall_ns`,
/// and the frame of its pose.
fn hear_odometry(payload: &[u8], arrived_ns: u64, now_wall_ns: i64) -> Option<(Heard, String)> {
    let odometry = cdr::Odometry::from_cdr(payload).ok()?;
    let p = odometry.pose;
    let stamp = odometry.header.stamp;
    let stamp_ns = i64::from(stamp.sec) * 1_000_000_000 + i64::from(stamp.nanosec);
    let pose = [p.position[0], p.position[1], yaw(p.orientation)];
    let twist = [odometry.twist.linear[0], odometry.twist.angular[2]];
    let heard = Heard {
        pose,
        twist,
        arrived_ns,
        age_at_arrival_ns: now_wall_ns.saturating_sub(stamp_ns).max(0) as u64,
    };
    pose.iter()
        .chain(&twist)
        .all(|v| v.is_finite())
        .then_some((heard, odometry.header.frame_id))
}

/// The robot's names, resolved: the node, its topics fully qualified, and their keys.
#[derive(Debug, Clone)]
pub(crate) struct Names {
    pub(crate) domain_id: u32,
    pub(crate) wire: Ros2Wire,
    pub(crate) distro: Distro,
    cmd_vel: String,
    command_type: MessageType,
    odom: String,
    goal: String,
    plan: String,
    route: String,
    obstacles: String,
    pub(crate) scan: String,
}

impl Names {
    /// The key of `topic`'s samples of type `message` on the robot's wire.
    pub(crate) fn key(&self, topic: &str, message: MessageType) -> String {
        match self.wire {
            Ros2Wire::RmwZenoh => ros2::keys::data_key(self.domain_id, topic, message, self.distro),
            Ros2Wire::Bridge => ros2::keys::bridge_key(topic),
        }
    }
}

/// Where the pipeline shows its plan, its route and the obstacles (relative: under the
/// node's namespace).
pub const VIEW_TOPICS: [&str; 3] = ["scmpc/plan", "scmpc/route", "scmpc/obstacles"];

impl Names {
    pub(crate) fn of(config: &Ros2Config) -> Result<Names, RobotError> {
        let invalid = |key: &str, e: ros2::NameError| RobotError::Key {
            key: key.into(),
            reason: e.to_string(),
        };
        let namespace =
            ros2::keys::namespace(&config.namespace).map_err(|e| invalid("ros2.namespace", e))?;
        let topic = |key: &str, name: &str| {
            ros2::keys::qualified_topic(&namespace, name).map_err(|e| invalid(key, e))
        };
        Ok(Names {
            domain_id: config.domain_id,
            wire: config.wire,
            distro: Distro::parse(&config.distro).ok_or_else(|| RobotError::Key {
                key: "ros2.distro".into(),
                reason: format!("`{}` is not a distribution this build knows", config.distro),
            })?,
            cmd_vel: topic("ros2.cmd_vel", &config.cmd_vel)?,
            command_type: if config.stamped {
                MessageType::TwistStamped
            } else {
                MessageType::Twist
            },
            odom: topic("ros2.odom", &config.odom)?,
            goal: topic("ros2.goal_topic", &config.goal_topic)?,
            plan: topic("ros2", VIEW_TOPICS[0])?,
            route: topic("ros2", VIEW_TOPICS[1])?,
            obstacles: topic("ros2", VIEW_TOPICS[2])?,
            scan: topic("ros2.scan", &config.scan)?,
        })
    }
}

/// The key the odometry of `config` is taken from.
pub fn odometry_key(config: &Ros2Config) -> Result<String, RobotError> {
    let names = Names::of(config)?;
    Ok(names.key(&names.odom, MessageType::Odometry))
}

/// The key the scans of `config` are taken from.
pub fn scan_key(config: &Ros2Config) -> Result<String, RobotError> {
    let names = Names::of(config)?;
    Ok(names.key(&names.scan, MessageType::LaserScan))
}

/// The keys of what a run cannot drive a ROS 2 robot without, by
/// [`protocol::task::Task::lost_input`]'s index: its odometry, and its scans with a lidar
/// (none with the simulated plant).
pub fn watched_keys(scenario: &protocol::Scenario) -> Vec<String> {
    if scenario.plant.kind != protocol::PlantKind::Ros2 {
        return Vec::new();
    }
    let scan = scenario.lidar.is_some().then(|| scan_key(&scenario.ros2));
    [Some(odometry_key(&scenario.ros2))]
        .into_iter()
        .chain([scan])
        .flatten()
        .filter_map(Result::ok)
        .collect()
}

/// Whether a sample carries what rmw_zenoh requires of one (its attachment), when
/// `attachment` is required (zenoh-bridge-ros2dds sends none).
pub(crate) fn is_attached(sample: &zenoh::sample::Sample, attachment: bool) -> bool {
    !attachment
        || sample
            .attachment()
            .is_some_and(|a| Attachment::from_bytes(&a.to_bytes()).is_ok())
}

/// The robot's names, and a client session to its router.
pub(crate) fn connect(
    config: &Ros2Config,
    security: &net::Security,
) -> Result<(Names, zenoh::Session), RobotError> {
    let names = Names::of(config)?;
    let router = |reason: String| RobotError::Router {
        endpoint: config.endpoint.clone(),
        reason,
    };
    let endpoint = Endpoint::parse(&config.endpoint).map_err(router)?;
    let zenoh_config =
        net::client_config(&endpoint, security).map_err(|e| router(e.to_string()))?;
    let session = net::open(zenoh_config).map_err(|e| match e {
        net::NetError::Unreachable(_) => router(format!(
            "{e}: start the robot's router there (`ros2 run rmw_zenoh_cpp rmw_zenohd`, which \
             listens on tcp/[::]:7447), or set `ros2.endpoint` to where it listens"
        )),
        _ => router(e.to_string()),
    })?;
    Ok((names, session))
}

/// A publisher as rmw_zenoh's: its samples carry its sequence number, the time and its
/// GID.
struct RosPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: [u8; ros2::attachment::GID_LEN],
    sequence_number: i64,
}

/// A publisher of `key` as rmw_zenoh's: a command or a view is dropped rather than
/// blocking the loop when the network is congested.
fn declare(session: &zenoh::Session, key: String) -> zenoh::Result<RosPublisher> {
    Ok(RosPublisher {
        publisher: session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .wait()?,
        gid: rand::random(),
        sequence_number: 0,
    })
}

impl RosPublisher {
    fn put(&mut self, payload: Vec<u8>) -> Result<(), String> {
        self.sequence_number += 1;
        let attachment = Attachment {
            sequence_number: self.sequence_number,
            source_timestamp_ns: wall_ns(),
            gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(attachment.to_bytes().to_vec())
            .wait()
            .map_err(|e| e.to_string())
    }
}

/// The pipeline's node on the robot's graph.
pub struct Link {
    session: zenoh::Session,
    endpoint: String,
    names: Names,
    command: RosPublisher,
    odometry_key: String,
    /// `ros2.first_message_timeout_s`: how long the first odometry and scan are waited for.
    first_message_timeout: Duration,
    newest_odometry: Newest<Heard>,
    /// The odometry's frame, the first odometry's.
    frame: Arc<OnceLock<String>>,
    newest_goal: Newest<protocol::Goal>,
    /// With a lidar: the key of its scans, and when the newest arrived (monotonic ns;
    /// before the first, when the link opened).
    scan: Option<(String, Arc<AtomicU64>)>,
    views: Views,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    _tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

/// The newest value heard, shared with a subscriber's callback.
type Newest<T> = Arc<Mutex<Option<T>>>;

/// A subscriber to `key` that keeps the newest sample `parse` makes of a payload.
fn keep_newest<T: Send + 'static>(
    session: &zenoh::Session,
    key: String,
    parse: impl Fn(&zenoh::sample::Sample) -> Option<T> + Send + Sync + 'static,
) -> zenoh::Result<(zenoh::pubsub::Subscriber<()>, Newest<T>)> {
    let newest = Arc::new(Mutex::new(None));
    let kept = newest.clone();
    let subscriber = session
        .declare_subscriber(key)
        .callback(move |sample| {
            if let (Some(value), Ok(mut kept)) = (parse(&sample), kept.lock()) {
                *kept = Some(value);
            }
        })
        .wait()?;
    Ok((subscriber, newest))
}

/// A subscriber to the scans on `key` that keeps when the newest arrived (monotonic ns;
/// when it was declared, before the first).
fn watch_scans(
    session: &zenoh::Session,
    key: String,
    attachment: bool,
) -> zenoh::Result<(zenoh::pubsub::Subscriber<()>, Arc<AtomicU64>)> {
    let arrived = Arc::new(AtomicU64::new(runtime::clock::monotonic_ns()));
    let stamp = arrived.clone();
    let subscriber = session
        .declare_subscriber(key)
        .callback(move |sample| {
            let scan = cdr::LaserScan::from_cdr(&sample.payload().to_bytes());
            if scan.is_ok() && is_attached(&sample, attachment) {
                stamp.store(runtime::clock::monotonic_ns(), Ordering::Relaxed);
            }
        })
        .wait()?;
    Ok((subscriber, arrived))
}

/// The odometry of a sample and its frame; rmw_zenoh drops a sample without its
/// attachment, and so does the pipeline when `attachment` is required (zenoh-bridge-ros2dds
/// sends none).
fn odometry_of(sample: &zenoh::sample::Sample, attachment: bool) -> Option<(Heard, String)> {
    let attached = is_attached(sample, attachment);
    let heard = hear_odometry(
        &sample.payload().to_bytes(),
        runtime::clock::monotonic_ns(),
        wall_ns(),
    );
    heard.filter(|_| attached)
}

/// The position and heading of a `geometry_msgs/msg/PoseStamped` sample (RViz's "2D Goal
/// Pose" sets both).
fn goal_of(sample: &zenoh::sample::Sample) -> Option<protocol::Goal> {
    let pose = cdr::PoseStamped::from_cdr(&sample.payload().to_bytes())
        .ok()?
        .pose;
    let goal = protocol::Goal {
        position: [pose.position[0], pose.position[1]],
        yaw_rad: Some(yaw(pose.orientation)),
    };
    let finite = goal
        .position
        .iter()
        .chain(&goal.yaw_rad)
        .all(|v| v.is_finite());
    finite.then_some(goal)
}

impl Link {
    /// Connects to the router of `config` with `security` and announces the node, its
    /// command publisher and its odometry and goal subscriptions; with `watch_scan`, also
    /// when each scan arrives (the scans themselves are the lidar role's,
    /// [`crate::ScanTask`]).
    pub fn open(
        config: &Ros2Config,
        security: &net::Security,
        watch_scan: bool,
    ) -> Result<Link, RobotError> {
        let (names, session) = connect(config, security)?;
        let router = |reason: String| RobotError::Router {
            endpoint: config.endpoint.clone(),
            reason,
        };
        let node = Node::new(
            config.domain_id,
            &session.zid().to_string(),
            &config.namespace,
            &config.node,
        )
        .map_err(|e| RobotError::Key {
            key: "ros2.node".into(),
            reason: e.to_string(),
        })?;
        let key = |topic: &str, message| names.key(topic, message);
        let zenoh_error = |e: zenoh::Error| router(e.to_string());
        let command =
            declare(&session, key(&names.cmd_vel, names.command_type)).map_err(zenoh_error)?;
        let odometry_key = odometry_key(config)?;
        let frame = Arc::new(OnceLock::new());
        let first_frame = frame.clone();
        let attached = names.wire == Ros2Wire::RmwZenoh;
        let (odometry, newest_odometry) = keep_newest(&session, odometry_key.clone(), move |s| {
            odometry_of(s, attached).map(|(heard, frame)| {
                first_frame.get_or_init(|| frame);
                heard
            })
        })
        .map_err(zenoh_error)?;
        let view = |topic: &str, message| declare(&session, key(topic, message));
        let views = Views {
            plan: view(&names.plan, MessageType::Path).map_err(zenoh_error)?,
            route: view(&names.route, MessageType::Path).map_err(zenoh_error)?,
            obstacles: view(&names.obstacles, MessageType::MarkerArray).map_err(zenoh_error)?,
        };
        let goal_key = key(&names.goal, MessageType::PoseStamped);
        let (goal, newest_goal) = keep_newest(&session, goal_key, goal_of).map_err(zenoh_error)?;
        let mut subscribers = vec![odometry, goal];
        let scan = if watch_scan {
            let key = key(&names.scan, MessageType::LaserScan);
            let (subscriber, arrived) =
                watch_scans(&session, key.clone(), attached).map_err(zenoh_error)?;
            subscribers.push(subscriber);
            Some((key, arrived))
        } else {
            None
        };
        let tokens = announce(&session, &node, &names, watch_scan).map_err(zenoh_error)?;
        Ok(Link {
            session,
            endpoint: config.endpoint.clone(),
            names,
            command,
            odometry_key,
            first_message_timeout: protocol::wait_of_s(config.first_message_timeout_s),
            newest_odometry,
            frame,
            newest_goal,
            scan,
            views,
            _subscribers: subscribers,
            _tokens: tokens,
        })
    }

    /// The key the odometry is taken from.
    pub fn odometry_key(&self) -> &str {
        &self.odometry_key
    }

    /// The newest odometry heard.
    pub fn newest_odometry(&self) -> Option<Heard> {
        self.newest_odometry.lock().ok().and_then(|n| *n)
    }

    /// With a lidar: the key of its scans and when the newest arrived (monotonic ns; when
    /// the link opened, before the first).
    pub fn newest_scan(&self) -> Option<(&str, u64)> {
        let (key, arrived) = self.scan.as_ref()?;
        Some((key, arrived.load(Ordering::Relaxed)))
    }

    /// The newest goal heard on the goal topic.
    pub fn newest_goal(&self) -> Option<protocol::Goal> {
        self.newest_goal.lock().ok().and_then(|n| *n)
    }

    /// Sends the command `forward_m_s`, `turn_rad_s` (a Twist or a TwistStamped).
    pub fn command(&mut self, forward_m_s: f64, turn_rad_s: f64) -> Result<(), RobotError> {
        let twist = cdr::Twist {
            linear: [forward_m_s, 0.0, 0.0],
            angular: [0.0, 0.0, turn_rad_s],
        };
        let payload = match self.names.command_type {
            MessageType::TwistStamped => cdr::TwistStamped {
                header: cdr::Header {
                    stamp: ros_time(wall_ns()),
                    frame_id: BASE_FRAME.into(),
                },
                twist,
            }
            .to_cdr(),
            _ => twist.to_cdr(),
        };
        self.command.put(payload).map_err(|reason| RobotError::Key {
            key: self.names.cmd_vel.clone(),
            reason,
        })
    }

    /// With a lidar: waits until a scan comes (at most `ros2.first_message_timeout_s`) or `stop`.
    pub fn first_scan(&self, stop: &AtomicBool) -> Result<(), RobotError> {
        let Some((key, opened_ns)) = self.newest_scan() else {
            return Ok(());
        };
        let since = Instant::now();
        while self
            .newest_scan()
            .is_some_and(|(_, arrived)| arrived == opened_ns)
        {
            if stop.load(Ordering::Relaxed) {
                return Err(RobotError::Stopped);
            }
            if since.elapsed() >= self.first_message_timeout {
                let awaited = Awaited {
                    topic: &self.names.scan,
                    message: MessageType::LaserScan,
                    key: "ros2.scan",
                };
                return Err(RobotError::NoScan {
                    waited_s: self.first_message_timeout.as_secs_f64(),
                    key: key.to_string(),
                    endpoint: self.endpoint.clone(),
                    graph: graph_text(&self.graph(), self.names.domain_id, &awaited),
                });
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// Waits until the first odometry comes (at most `ros2.first_message_timeout_s`) or `stop`.
    pub fn first_odometry(&self, stop: &AtomicBool) -> Result<Heard, RobotError> {
        let since = Instant::now();
        loop {
            if let Some(heard) = self.newest_odometry() {
                return Ok(heard);
            }
            if stop.load(Ordering::Relaxed) {
                return Err(RobotError::Stopped);
            }
            if since.elapsed() >= self.first_message_timeout {
                let awaited = Awaited {
                    topic: &self.names.odom,
                    message: MessageType::Odometry,
                    key: "ros2.odom",
                };
                return Err(RobotError::NoOdometry {
                    waited_s: self.first_message_timeout.as_secs_f64(),
                    key: self.odometry_key.clone(),
                    endpoint: self.endpoint.clone(),
                    graph: graph_text(&self.graph(), self.names.domain_id, &awaited),
                });
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The liveliness tokens the router knows of, on every domain (behind a bridge: the
    /// bridges'), without this session's own, each once, sorted.
    pub fn graph(&self) -> Vec<String> {
        let Ok(replies) = self
            .session
            .liveliness()
            .get(match self.names.wire {
                Ros2Wire::RmwZenoh => "@ros2_lv/**",
                // The bridges' own tokens: `@/<zid>/@ros2_lv/<kind>/<key>/<type>...`.
                Ros2Wire::Bridge => "@/*/@ros2_lv/**",
            })
            .timeout(GRAPH_QUERY)
            .wait()
        else {
            return Vec::new();
        };
        let own = format!("/{}/", self.session.zid());
        let mut tokens: Vec<String> = std::iter::from_fn(|| replies.recv().ok())
            .filter_map(|reply| reply.result().ok().map(|s| s.key_expr().to_string()))
            .filter(|token| !token.contains(&own))
            .collect();
        tokens.sort();
        tokens.dedup();
        tokens
    }

    /// Sends a zero twist and closes the session (what every end of a run does).
    pub fn stop_and_close(mut self) -> Result<(), RobotError> {
        let sent = self.command(0.0, 0.0);
        let closed = self.session.close().wait().map_err(|e| RobotError::Router {
            endpoint: self.endpoint.clone(),
            reason: e.to_string(),
        });
        sent.and(closed)
    }
}

/// The liveliness tokens of `node`, its publisher and its subscriptions, alive as long as
/// they are held (none behind zenoh-bridge-ros2dds: the DDS graph learns of the topics
/// from the bridge).
fn announce(
    session: &zenoh::Session,
    node: &Node,
    names: &Names,
    scan: bool,
) -> zenoh::Result<Vec<zenoh::liveliness::LivelinessToken>> {
    if names.wire == Ros2Wire::Bridge {
        return Ok(Vec::new());
    }
    let entities = [
        (1, EntityKind::Publisher, &names.cmd_vel, names.command_type),
        (
            2,
            EntityKind::Subscription,
            &names.odom,
            MessageType::Odometry,
        ),
        (
            3,
            EntityKind::Subscription,
            &names.goal,
            MessageType::PoseStamped,
        ),
    ];
    let mut tokens = vec![node.token()];
    tokens.extend(entities.iter().map(|(id, kind, topic, message)| {
        node.endpoint_token(*id, *kind, topic, *message, names.distro, QOS)
    }));
    if scan {
        let (kind, message) = (EntityKind::Subscription, MessageType::LaserScan);
        tokens.push(node.endpoint_token(4, kind, &names.scan, message, names.distro, SCAN_QOS));
    }
    tokens
        .into_iter()
        .map(|token| session.liveliness().declare_token(token).wait())
        .collect()
}

/// What the orchestrator learns before a run starts: where the robot is, and where it is
/// to go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    /// The first odometry's pose.
    pub pose: [f64; 3],
    /// The goal heard on the goal topic (`ros2.wait_for_goal`), `None`: `robot.goal`.
    pub goal: Option<protocol::Goal>,
}

/// Connects to the robot of `config`, waits for its first odometry (with `lidar`, and a
/// scan; with `ros2.wait_for_goal`, for a goal, as long as it takes) and disconnects.
/// Nothing is published.
pub fn first_contact(
    config: &Ros2Config,
    security: &net::Security,
    lidar: bool,
    stop: &AtomicBool,
) -> Result<Start, RobotError> {
    let link = Link::open(config, security, lidar)?;
    let first = link.first_odometry(stop)?;
    link.first_scan(stop)?;
    let goal = if config.wait_for_goal {
        loop {
            if let Some(goal) = link.newest_goal() {
                break Some(goal);
            }
            if stop.load(Ordering::Relaxed) {
                return Err(RobotError::Stopped);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    } else {
        None
    };
    let _ = link.session.close().wait();
    Ok(Start {
        pose: first.pose,
        goal,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_is_the_quaternions_turn_about_z() {
        for yaw_rad in [-3.0, -1.2, 0.0, 0.7, 2.356_194_490_192_345, 3.1] {
            let half: f64 = yaw_rad / 2.0;
            let q = [0.0, 0.0, half.sin(), half.cos()];
            assert!((yaw(q) - yaw_rad).abs() < 1e-12, "{yaw_rad}");
        }
    }

    #[test]
    fn odometry_is_heard_with_its_age_and_refused_when_not_finite() {
        let odometry = |x: f64| cdr::Odometry {
            header: cdr::Header {
                stamp: cdr::Time {
                    sec: 10,
                    nanosec: 500,
                },
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            pose: cdr::Pose {
                position: [x, 2.0, 0.0],
                orientation: [0.0, 0.0, 0.0, 1.0],
            },
            pose_covariance: [0.0; 36],
            twist: cdr::Twist {
                linear: [0.3, 0.0, 0.0],
                angular: [0.0, 0.0, -0.1],
            },
            twist_covariance: [0.0; 36],
        };
        let (heard, frame) = hear_odometry(&odometry(1.0).to_cdr(), 7, 10_000_002_500).unwrap();
        assert_eq!(frame, "odom");
        assert_eq!(heard.pose, [1.0, 2.0, 0.0]);
        assert_eq!(heard.twist, [0.3, -0.1]);
        assert_eq!((heard.arrived_ns, heard.age_at_arrival_ns), (7, 2000));
        // A robot clock ahead of this host's: no negative age.
        assert_eq!(
            hear_odometry(&odometry(1.0).to_cdr(), 7, 0)
                .unwrap()
                .0
                .age_at_arrival_ns,
            0
        );
        assert_eq!(hear_odometry(&odometry(f64::NAN).to_cdr(), 7, 0), None);
        assert_eq!(hear_odometry(&[0, 1, 0, 0, 9], 7, 0), None);
    }

    #[test]
    fn ros_time_splits_negative_and_positive_ns() {
        assert_eq!(
            ros_time(1_500_000_000),
            cdr::Time {
                sec: 1,
                nanosec: 500_000_000
            }
        );
        assert_eq!(
            ros_time(-1),
            cdr::Time {
                sec: -1,
                nanosec: 999_999_999
            }
        );
    }
}
