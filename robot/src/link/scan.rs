//! The robot's lidar as the lidar role's resource ([`crate::ScanTask`] is the task): a
//! second node on the robot's graph takes the robot's `sensor_msgs/msg/LaserScan` (best
//! effort, as lidar drivers publish) and where the lidar sits on the base from
//! `tf_static`, and keeps the newest of each.

use super::{Names, SCAN_QOS, is_attached};
use crate::RobotError;
use protocol::task::TaskError;
use protocol::{MAX_BEAMS, Role, Ros2Config, Ros2Wire, Scan, Validated};
use ros2::cdr::{self, Message};
use ros2::{EntityKind, MessageType, Node, Qos};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use zenoh::Wait;
use zenoh::query::{ConsolidationMode, QueryTarget, ReplyKeyExpr};

mod frames;
pub use frames::{Mount, mount_of};

/// The frame the lidar's pose is asked in: the base's, the one commands are stamped in.
pub const BASE_FRAME: &str = "base_link";

/// `tf_static`'s QoS as tf2's static listener asks it: reliable, transient local.
const TF_STATIC_QOS: Qos = Qos {
    reliable: true,
    transient_local: true,
    depth: 100,
};

/// The newest scan heard: as the pipeline's sample (its header left for the task), its
/// frame, and when it arrived (monotonic ns).
#[derive(Debug)]
struct Heard {
    scan: Box<Scan>,
    frame_id: String,
    arrived_ns: u64,
}

/// The lidar's side of the robot: a session to its router, the newest scan and the
/// static transforms heard.
pub struct ScanLink {
    session: zenoh::Session,
    scan_key: String,
    newest: Arc<Mutex<Option<Heard>>>,
    /// `tf_static`: each child frame's mount on its parent.
    mounts: Arc<Mutex<BTreeMap<String, Mount>>>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    _tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

/// The pipeline's scan of `ros`: at most [`MAX_BEAMS`] beams (a denser scan's beams taken
/// k at a time, each group its nearest return, so a thin pole between kept beams is not
/// lost), REP 117's ranges kept, a finite range outside `[range_min, range_max]` (which
/// `sensor_msgs` says to discard) a NaN; `None` for a scan without beams or with angles
/// that are not numbers.
pub fn scan_of(ros: &cdr::LaserScan) -> Option<Scan> {
    let n = ros.ranges.len();
    let angles = [ros.angle_min, ros.angle_increment];
    if n == 0 || !angles.iter().all(|a| a.is_finite()) {
        return None;
    }
    let stride = n.div_ceil(MAX_BEAMS);
    let (min, max) = (ros.range_min, ros.range_max);
    let mut scan = Scan {
        beams: n.div_ceil(stride) as u32,
        angle_min_rad: f64::from(ros.angle_min),
        angle_increment_rad: f64::from(ros.angle_increment) * stride as f64,
        range_min_m: f64::from(min),
        range_max_m: f64::from(max),
        ..Scan::default()
    };
    let valid = |r: f32| {
        if r.is_finite() && !(min..=max).contains(&r) {
            f32::NAN
        } else {
            r
        }
    };
    for (kept, group) in scan.ranges_m.iter_mut().zip(ros.ranges.chunks(stride)) {
        // The nearest return, else +inf (nothing in range) before NaN (no return).
        let nearest = group.iter().map(|&r| valid(r)).filter(|r| !r.is_nan());
        *kept = nearest.fold(f32::NAN, |a, r| if a.is_nan() { r } else { a.min(r) });
    }
    Some(scan)
}

impl ScanLink {
    /// Connects to the router of `config` and announces the lidar's node (the run's node
    /// name with `_lidar`) with its scan and `tf_static` subscriptions; asks the
    /// transforms published before (rmw_zenoh's transient local: a publication cache on
    /// the topic's key, or, from rmw_zenoh 0.2.2 on, an advanced publisher's cache under
    /// `<key>/@adv/pub/**`).
    pub fn open(config: &Ros2Config, security: &net::Security) -> Result<ScanLink, RobotError> {
        let (names, session) = super::connect(config, security)?;
        let router = |reason: String| RobotError::Router {
            endpoint: config.endpoint.clone(),
            reason,
        };
        let zenoh_error = |e: zenoh::Error| router(e.to_string());
        let attached = names.wire == Ros2Wire::RmwZenoh;
        let scan_key = names.key(&names.scan, MessageType::LaserScan);
        let newest = Arc::new(Mutex::new(None));
        let kept = newest.clone();
        let scans = session
            .declare_subscriber(scan_key.clone())
            .callback(move |sample| {
                let ros = cdr::LaserScan::from_cdr(&sample.payload().to_bytes());
                let heard = (ros.ok())
                    .filter(|_| is_attached(&sample, attached))
                    .and_then(|ros| {
                        Some(Heard {
                            scan: Box::new(scan_of(&ros)?),
                            frame_id: ros.header.frame_id,
                            arrived_ns: runtime::clock::monotonic_ns(),
                        })
                    });
                if let (Some(heard), Ok(mut kept)) = (heard, kept.lock()) {
                    *kept = Some(heard);
                }
            })
            .wait()
            .map_err(zenoh_error)?;
        let tf_topic = ros2::keys::qualified_topic("/", "/tf_static").unwrap_or_default();
        let tf_key = names.key(&tf_topic, MessageType::TfMessage);
        let mounts = Arc::new(Mutex::new(BTreeMap::new()));
        let keep = |mounts: &Arc<Mutex<BTreeMap<String, Mount>>>| {
            let mounts = mounts.clone();
            move |sample: &zenoh::sample::Sample| {
                let Ok(tf) = cdr::TfMessage::from_cdr(&sample.payload().to_bytes()) else {
                    return;
                };
                if let Ok(mut mounts) = mounts.lock() {
                    for t in &tf.transforms {
                        mounts.insert(t.child_frame_id.clone(), Mount::of(t));
                    }
                }
            }
        };
        let live = keep(&mounts);
        let tf = session
            .declare_subscriber(tf_key.clone())
            .callback(move |sample| live(&sample))
            .wait()
            .map_err(zenoh_error)?;
        for selector in [tf_key.clone(), format!("{tf_key}/@adv/pub/**")] {
            let cached = keep(&mounts);
            // Every publisher's cache (robot_state_publisher's and a
            // static_transform_publisher's share the key), every reply.
            session
                .get(selector)
                .target(QueryTarget::All)
                .consolidation(ConsolidationMode::None)
                .accept_replies(ReplyKeyExpr::Any)
                .callback(move |reply| {
                    if let Ok(sample) = reply.result() {
                        cached(sample);
                    }
                })
                .wait()
                .map_err(zenoh_error)?;
        }
        let tokens = announce(&session, config, &names, &tf_topic).map_err(zenoh_error)?;
        Ok(ScanLink {
            session,
            scan_key,
            newest,
            mounts,
            _subscribers: vec![scans, tf],
            _tokens: tokens,
        })
    }

    /// The key the scans are taken from.
    pub fn scan_key(&self) -> &str {
        &self.scan_key
    }

    /// The newest scan copied into `into`, if it arrived after `after_ns` (monotonic),
    /// with when it arrived and the lidar's mount on the base from `tf_static` (`None`:
    /// not published).
    pub(crate) fn newest_after(
        &self,
        after_ns: u64,
        into: &mut Scan,
    ) -> Option<(u64, Option<[f64; 3]>)> {
        let newest = self.newest.lock().ok()?;
        let heard = newest.as_ref().filter(|h| h.arrived_ns > after_ns)?;
        *into = *heard.scan;
        let mounts = self.mounts.lock().ok()?;
        Some((
            heard.arrived_ns,
            mount_of(&mounts, &heard.frame_id, BASE_FRAME),
        ))
    }
}

/// The lidar node's tokens: the node and its two subscriptions.
fn announce(
    session: &zenoh::Session,
    config: &Ros2Config,
    names: &Names,
    tf_topic: &str,
) -> zenoh::Result<Vec<zenoh::liveliness::LivelinessToken>> {
    if names.wire == Ros2Wire::Bridge {
        return Ok(Vec::new());
    }
    let node_name = format!("{}_lidar", config.node);
    let node = Node::new(
        config.domain_id,
        &session.zid().to_string(),
        &config.namespace,
        &node_name,
    )?;
    let kind = EntityKind::Subscription;
    let tokens = [
        node.token(),
        node.endpoint_token(
            1,
            kind,
            &names.scan,
            MessageType::LaserScan,
            names.distro,
            SCAN_QOS,
        ),
        node.endpoint_token(
            2,
            kind,
            tf_topic,
            MessageType::TfMessage,
            names.distro,
            TF_STATIC_QOS,
        ),
    ];
    tokens
        .into_iter()
        .map(|token| session.liveliness().declare_token(token).wait())
        .collect()
}

impl protocol::task::Resources for ScanLink {
    fn open(scenario: &Validated) -> Result<ScanLink, TaskError> {
        let link = ScanLink::open(&scenario.ros2, &net::Security::from_env());
        link.map_err(|e| TaskError::setup(Role::Lidar, e))
    }
}

impl Drop for ScanLink {
    fn drop(&mut self) {
        let _ = self.session.close().wait();
    }
}

#[cfg(test)]
mod tests;
