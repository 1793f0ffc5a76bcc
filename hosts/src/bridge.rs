//! The bridge of one host (docs/hosts.md): it forwards every topic with a producer on this
//! host and a consumer on another from iceoryx2 to Zenoh, and the topics its roles take
//! from other hosts from Zenoh to iceoryx2, byte for byte in the `#[repr(C)]` layouts
//! (`runtime::ipc::wire`).
//!
//! Two threads: the sender blocks in an iceoryx2 WaitSet on the taps of the topics it
//! sends, the receiver on the Zenoh subscriber of the keys addressed to this host. What
//! they check:
//! - **sending**: a sample goes out only from the publisher its producer announced (the
//!   epoch schedule of the host's control topic pins it, as it pins every consumer's
//!   input); the orchestrator's control only from its control publisher. Every sample
//!   carries a tag of the run's key ([`crate::auth`]).
//! - **receiving**: a sample whose tag does not verify is refused and counted. On a host
//!   of its own (an agent's bridge) the control topic's publisher pins are rewritten for
//!   the host: a producer on another host is pinned to this bridge's relay, which carries
//!   it; one on this host to the publisher it announced when it joined. So a bridged
//!   producer is pinned to the bridge that carries it on every host.
//! - **link faults** (`fault.link_*`, real time): the sender holds data samples for the
//!   link's delay, drops them with the link's loss probability and while the link is down
//!   (by the samples' run time). Control and status are not dropped: a lost grant would
//!   stop a lockstep clock, a lost report hide a crash.

use crate::auth::RunKey;
use crate::keys;
use crate::{HostError, LinkCounters};
use protocol::{Control, EpochSchedule, Role, Status, StatusEvent};
use rand::{Rng, RngExt, SeedableRng};
use runtime::ipc::wire::{self, WireRelay, WireTap};
use runtime::ipc::{self, CONTROL, STATUS, output_slot, output_topic, producer_of};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;
use zenoh::Wait;
use zenoh::qos::CongestionControl;

/// How often the threads look at the stop flag when nothing comes.
const IDLE: Duration = Duration::from_millis(20);

/// The faults a bridge applies to the data samples it sends.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LinkFaults {
    pub delay_ns: u64,
    pub loss: f64,
    /// Run times `[from, to)` the link is down, s.
    pub down_s: [f64; 2],
    /// Seed of the loss draws.
    pub seed: u64,
}

impl LinkFaults {
    /// The link faults of a scenario.
    pub fn of(scenario: &protocol::Scenario, seed: u64) -> LinkFaults {
        LinkFaults {
            delay_ns: (scenario.fault.link_delay_ms * 1e6) as u64,
            loss: scenario.fault.link_loss,
            down_s: scenario.fault.link_down_s,
            seed,
        }
    }
}

/// What one host's bridge carries.
#[derive(Debug, Clone)]
pub struct BridgeSpec {
    /// The run (its keys' prefix).
    pub run: String,
    /// This host's name ([`keys::ORCHESTRATOR`] on the orchestrator's).
    pub host: String,
    /// This host's iceoryx2 prefix for the run.
    pub prefix: String,
    /// The robot whose pipeline's topics it carries (every run of one robot:
    /// [`protocol::FIRST_ROBOT`]).
    pub robot: u32,
    pub key: RunKey,
    /// Topics sent, each to the hosts named.
    pub send: BTreeMap<String, Vec<String>>,
    /// Topics received and published on this host.
    pub receive: Vec<String>,
    /// The other robots' topics a fleet's robot on another host takes (docs/fleet.md,
    /// "Across hosts"), by robot and topic, sent to the hosts named. Not checked against
    /// their producers here, as a tracker does not check them.
    pub peer_send: BTreeMap<(u32, String), Vec<String>>,
    /// The other robots' topics received and published on this host.
    pub peer_receive: Vec<(u32, String)>,
    /// The roles on this host, when it is not the orchestrator's: its control is rewritten.
    pub local_roles: Option<Vec<Role>>,
    /// The orchestrator's control publisher, on the orchestrator's host: the only one
    /// whose control messages go out.
    pub control_publisher: Option<u128>,
    pub faults: LinkFaults,
    /// The `SCHED_FIFO` priority of the threads that carry samples, the bridge's and
    /// Zenoh's (`None`: the normal policy). A real-time run's control tier: the bridge is
    /// part of the control loop's data path, and at a lower priority the loop's processes
    /// hold back the samples they wait for (docs/running.md, "Real-time scheduling").
    pub carrier_priority: Option<u8>,
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    lost: AtomicU64,
    down: AtomicU64,
    refused_tag: AtomicU64,
    refused_origin: AtomicU64,
}

/// A running bridge; stopped when dropped.
pub struct Bridge {
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    relay_ids: HashMap<String, u128>,
    threads: Vec<JoinHandle<()>>,
    /// Zenoh's runtime threads at the carriers' priority while the bridge runs.
    _zenoh_raised: Option<runtime::realtime::RaisedThreads>,
}

/// The publisher ids of this host's processes, as their ready reports announced them.
type ReadyPins = Arc<Mutex<HashMap<(Role, u32), [u128; 2]>>>;

impl Bridge {
    /// Starts both threads on `session`; returns once they carry samples.
    pub fn start(session: &zenoh::Session, spec: BridgeSpec) -> Result<Bridge, HostError> {
        let stop = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(Counters::default());
        let ready_pins: ReadyPins = Arc::default();
        let (receiver_ready, receiver_up) = mpsc::channel();
        let receiver = {
            let (session, spec, stop, counters, pins) = (
                session.clone(),
                spec.clone(),
                stop.clone(),
                counters.clone(),
                ready_pins.clone(),
            );
            std::thread::Builder::new()
                .name(format!("bridge-in-{}", spec.host))
                .spawn(move || receive(session, spec, stop, counters, pins, receiver_ready))
                .map_err(|e| HostError::Bridge(format!("starting a thread: {e}")))?
        };
        let relay_ids = receiver_up
            .recv()
            .map_err(|_| HostError::Bridge("the receiving thread ended".into()))??;
        let zenoh_raised = spec.carrier_priority.and_then(|priority| {
            runtime::realtime::raise_threads(&runtime::realtime::ZENOH_CARRIER_THREADS, priority)
                .inspect_err(|e| not_raised(&spec.host, "Zenoh's threads", e))
                .ok()
        });
        let (sender_ready, sender_up) = mpsc::channel();
        let sender = {
            let (session, stop, counters) = (session.clone(), stop.clone(), counters.clone());
            std::thread::Builder::new()
                .name(format!("bridge-out-{}", spec.host))
                .spawn(move || send(session, spec, stop, counters, ready_pins, sender_ready))
                .map_err(|e| HostError::Bridge(format!("starting a thread: {e}")))?
        };
        let bridge = Bridge {
            stop,
            counters,
            relay_ids,
            threads: vec![receiver, sender],
            _zenoh_raised: zenoh_raised,
        };
        sender_up
            .recv()
            .map_err(|_| HostError::Bridge("the sending thread ended".into()))??;
        Ok(bridge)
    }

    /// The iceoryx2 id of the relay publishing `topic` on this host: the publisher local
    /// consumers pin the topic's producer on another host to.
    pub fn relay_id(&self, topic: &str) -> Option<u128> {
        self.relay_ids.get(topic).copied()
    }

    /// What the bridge has carried and refused so far.
    pub fn counters(&self) -> LinkCounters {
        let c = &self.counters;
        LinkCounters {
            sent: c.sent.load(Ordering::Relaxed),
            received: c.received.load(Ordering::Relaxed),
            lost: c.lost.load(Ordering::Relaxed),
            down: c.down.load(Ordering::Relaxed),
            refused_tag: c.refused_tag.load(Ordering::Relaxed),
            refused_origin: c.refused_origin.load(Ordering::Relaxed),
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

/// The receiving thread: Zenoh to iceoryx2.
fn receive(
    session: zenoh::Session,
    spec: BridgeSpec,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    ready_pins: ReadyPins,
    ready: mpsc::Sender<Result<HashMap<String, u128>, HostError>>,
) {
    let setup = || -> Result<_, HostError> {
        let node = ipc::create_node(&spec.prefix, &format!("bridge-in-{}", spec.host), false)?;
        let mut relays: HashMap<(u32, String), Box<dyn WireRelay>> = HashMap::new();
        let own = spec.receive.iter().map(|topic| (spec.robot, topic.clone()));
        for (robot, topic) in own.chain(spec.peer_receive.iter().cloned()) {
            let relay = wire::relay(&node, robot, &topic)?;
            relays.insert((robot, topic), relay);
        }
        let subscriber = session
            .declare_subscriber(keys::to_host_all(&spec.run, &spec.host))
            .wait()
            .map_err(|e| HostError::Zenoh(format!("subscribing: {e}")))?;
        Ok((node, relays, subscriber))
    };
    let (_node, relays, subscriber) = match setup() {
        Ok(parts) => parts,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    raise(&spec);
    let relay_ids: HashMap<String, u128> = relays
        .iter()
        .filter(|((robot, _), _)| *robot == spec.robot)
        .map(|((_, topic), relay)| (topic.clone(), relay.publisher_id()))
        .collect();
    let _ = ready.send(Ok(relay_ids.clone()));
    while !stop.load(Ordering::Relaxed) {
        let Ok(Some(sample)) = subscriber.recv_timeout(IDLE) else {
            continue;
        };
        let key_expr = sample.key_expr().as_str();
        let payload = sample.payload().to_bytes();
        let tag = sample.attachment().map(|a| a.to_bytes());
        if !tag.is_some_and(|tag| spec.key.verify(key_expr, &payload, &tag)) {
            counters.refused_tag.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        let Some(relay) = keys::robot_topic_of(key_expr)
            .and_then(|(robot, topic)| relays.get(&(robot, topic.to_string())))
        else {
            continue;
        };
        let mut edit = |value: &mut dyn std::any::Any| {
            if let (Some(control), Some(local)) =
                (value.downcast_mut::<Control>(), &spec.local_roles)
            {
                let pins = ready_pins.lock().map(|p| p.clone()).unwrap_or_default();
                pin_for_host(&mut control.epochs, local, &pins, &relay_ids);
            }
        };
        match relay.relay(&payload, &mut edit) {
            Ok(true) => {
                counters.received.fetch_add(1, Ordering::Relaxed);
            }
            Ok(false) => {
                counters.refused_tag.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::warn!("bridge {}: relaying: {e}", spec.host),
        }
    }
}

/// The calling thread at the carriers' priority, if any; the bridge carries on at the
/// normal policy if the kernel refuses it.
fn raise(spec: &BridgeSpec) {
    if let Some(priority) = spec.carrier_priority
        && let Err(e) = runtime::realtime::raise_this_thread(priority)
    {
        not_raised(&spec.host, "a thread", &e);
    }
}

fn not_raised(host: &str, what: &str, e: &std::io::Error) {
    tracing::warn!("bridge {host}: {what} not at the real-time priority: {e}");
}

/// The publisher pins of `schedule` as they hold on a host running `local` roles: a local
/// producer's as it announced them (`ready_pins`), another host's the relays of this host
/// carrying its outputs (0, unpinned, for an output this host does not take).
fn pin_for_host(
    schedule: &mut EpochSchedule,
    local: &[Role],
    ready_pins: &HashMap<(Role, u32), [u128; 2]>,
    relay_ids: &HashMap<String, u128>,
) {
    for role in Role::ALL {
        let r = role as usize;
        let pins = |epoch: u32| -> [u128; 2] {
            if local.contains(&role) {
                ready_pins.get(&(role, epoch)).copied().unwrap_or([0; 2])
            } else {
                std::array::from_fn(|slot| {
                    output_topic(role, slot)
                        .and_then(|t| relay_ids.get(t).copied())
                        .unwrap_or(0)
                })
            }
        };
        schedule.active_publishers[r] = pins(schedule.active[r]);
        schedule.next_publishers[r] = pins(schedule.next[r]);
    }
}

/// A sample the sender holds for the link's delay.
struct Held {
    due_ns: u64,
    key: String,
    bytes: Vec<u8>,
}

type IpcService = iceoryx2::service::ipc::Service;

/// A topic a bridge sends: its robot, its name and the tap it is taken from.
type Tapped = (u32, String, Box<dyn WireTap>);

/// What [`send_ports`] opens: the node, the taps, the publishers by key, the WaitSet.
type SendPorts = (
    iceoryx2::node::Node<IpcService>,
    Vec<Tapped>,
    HashMap<String, zenoh::pubsub::Publisher<'static>>,
    iceoryx2::waitset::WaitSet<IpcService>,
);

/// The ports of the sending side of a bridge: a tap of every topic it sends (and of the
/// control topic, whose schedule pins what goes out), a Zenoh publisher per topic and
/// host, and the WaitSet it waits in.
fn send_ports(session: &zenoh::Session, spec: &BridgeSpec) -> Result<SendPorts, HostError> {
    let node = ipc::create_node(&spec.prefix, &format!("bridge-out-{}", spec.host), false)?;
    let mut taps: Vec<Tapped> = Vec::new();
    let mut sent: Vec<(u32, &str)> = spec.send.keys().map(|t| (spec.robot, t.as_str())).collect();
    if !spec.send.contains_key(CONTROL) {
        // The schedule pins what goes out.
        sent.push((spec.robot, CONTROL));
    }
    sent.extend(spec.peer_send.keys().map(|(r, t)| (*r, t.as_str())));
    for (robot, topic) in sent {
        taps.push((robot, topic.to_string(), wire::tap(&node, robot, topic)?));
    }
    let mut publishers = HashMap::new();
    let own = spec
        .send
        .iter()
        .map(|(topic, hosts)| ((spec.robot, topic), hosts));
    let peers = spec
        .peer_send
        .iter()
        .map(|((r, t), hosts)| ((*r, t), hosts));
    for ((robot, topic), hosts) in own.chain(peers) {
        for host in hosts {
            let key = keys::to_host(&spec.run, host, robot, topic);
            let publisher = session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Block)
                .express(true)
                .wait()
                .map_err(|e| HostError::Zenoh(format!("publisher {key}: {e}")))?;
            publishers.insert(key, publisher);
        }
    }
    let waitset = ipc::waitset(false)?;
    Ok((node, taps, publishers, waitset))
}

/// The sending thread: iceoryx2 to Zenoh.
fn send(
    session: zenoh::Session,
    spec: BridgeSpec,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    ready_pins: ReadyPins,
    ready: mpsc::Sender<Result<(), HostError>>,
) {
    let (_node, mut taps, publishers, waitset) = match send_ports(&session, &spec) {
        Ok(parts) => parts,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    // This robot's taps are taken first (below).
    taps.sort_by_key(|(robot, _, _)| *robot != spec.robot);
    let guards: Result<Vec<_>, _> = taps
        .iter()
        .map(|(_, _, tap)| waitset.attach_notification(tap.listener()))
        .collect();
    if guards.is_err() {
        let _ = ready.send(Err(HostError::Bridge("attaching a listener".into())));
        return;
    }
    raise(&spec);
    let _ = ready.send(Ok(()));
    let mut schedule: Option<EpochSchedule> = None;
    let mut outbox = Outbox {
        spec: &spec,
        publishers,
        counters: &counters,
        held: VecDeque::new(),
        rng: rand::rngs::StdRng::seed_from_u64(spec.faults.seed),
    };
    let is_plane = |topic: &str| topic == CONTROL || topic == STATUS;
    let mut data: Vec<(u32, &str, Vec<u8>, u128)> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let timeout = outbox.send_due();
        if ipc::wait(&waitset, timeout).is_err() {
            break;
        }
        // Each pass takes in the reverse of the order it sends, so that whatever was
        // published before a sample it sends is sent before it: it takes this robot's
        // data, then the other robots' data, then the control, and sends the control,
        // then the other robots' data, then this robot's. A grant published before a
        // sample then goes out before it, so no sample reaches another host ahead of its
        // clock. In lockstep every other robot's tick `j - 1` is published before this
        // robot's tick `j` is granted, so it reaches this robot's tracker before the truth
        // of tick `j` that steps it. (Taking the other robots' data first let a sample of
        // theirs published between the two takes go out after this robot's next truth: a
        // lockstep run across hosts differed from the fleet in process in the 10th digit of
        // a track's sigma, once in about 30 runs beside a busy machine, 2026-12-02.)
        for (robot, topic, tap) in taps.iter().filter(|(_, t, _)| !is_plane(t)) {
            tap.clear_wakeups();
            let taken = tap.take(&mut |bytes, origin| {
                data.push((*robot, topic, bytes.to_vec(), origin));
            });
            if let Err(e) = taken {
                tracing::warn!("bridge {}: {topic}: {e}", spec.host);
            }
        }
        for (robot, topic, tap) in taps.iter().filter(|(_, t, _)| is_plane(t)) {
            tap.clear_wakeups();
            let taken = tap.take(&mut |bytes, origin| {
                if topic == CONTROL
                    && let Some(c) = decode::<Control>(bytes)
                {
                    schedule = Some(c.epochs);
                }
                if topic == STATUS {
                    note_ready(bytes, &ready_pins);
                }
                outbox.forward(*robot, topic, bytes, origin, &schedule);
            });
            if let Err(e) = taken {
                tracing::warn!("bridge {}: {topic}: {e}", spec.host);
            }
        }
        data.sort_by_key(|(robot, ..)| *robot == spec.robot);
        for (robot, topic, bytes, origin) in data.drain(..) {
            outbox.forward(robot, topic, &bytes, origin, &schedule);
        }
    }
}

/// What the sender puts on the network, and holds for the link's delay.
struct Outbox<'a> {
    spec: &'a BridgeSpec,
    publishers: HashMap<String, zenoh::pubsub::Publisher<'static>>,
    counters: &'a Counters,
    held: VecDeque<Held>,
    rng: rand::rngs::StdRng,
}

impl Outbox<'_> {
    /// Sends a sample of robot `robot`'s `topic` to every host it goes to, if its
    /// producer sent it (the bridge's robot's topics) and the link does not drop it (held
    /// for the link's delay, if any).
    fn forward(
        &mut self,
        robot: u32,
        topic: &str,
        bytes: &[u8],
        origin: u128,
        schedule: &Option<EpochSchedule>,
    ) {
        let own = robot == self.spec.robot;
        let destinations = match own {
            true => self.spec.send.get(topic),
            // A few entries, looked up without a key of their own.
            false => (self.spec.peer_send.iter())
                .find(|((r, t), _)| *r == robot && t == topic)
                .map(|(_, hosts)| hosts),
        };
        let Some(destinations) = destinations else {
            return;
        };
        if own && !sent_by_its_producer(topic, bytes, origin, schedule, self.spec) {
            self.counters.refused_origin.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let data = topic != CONTROL && topic != STATUS;
        if data && dropped(bytes, &self.spec.faults, &mut self.rng, self.counters) {
            return;
        }
        for host in destinations {
            let key = keys::to_host(&self.spec.run, host, robot, topic);
            if data && self.spec.faults.delay_ns > 0 {
                self.held.push_back(Held {
                    due_ns: runtime::clock::monotonic_ns() + self.spec.faults.delay_ns,
                    key,
                    bytes: bytes.to_vec(),
                });
            } else {
                self.put(&key, bytes);
            }
        }
    }

    /// Sends the held samples that are due; returns how long to wait for the next.
    fn send_due(&mut self) -> Duration {
        let now = runtime::clock::monotonic_ns();
        while self.held.front().is_some_and(|h| h.due_ns <= now) {
            if let Some(h) = self.held.pop_front() {
                self.put(&h.key, &h.bytes);
            }
        }
        self.held.front().map_or(IDLE, |h| {
            Duration::from_nanos(h.due_ns.saturating_sub(now)).min(IDLE)
        })
    }

    fn put(&self, key: &str, bytes: &[u8]) {
        let Some(publisher) = self.publishers.get(key) else {
            return;
        };
        let tag = self.spec.key.tag(key, bytes);
        match publisher
            .put(bytes.to_vec())
            .attachment(tag.to_vec())
            .wait()
        {
            Ok(()) => {
                self.counters.sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::warn!("bridge {}: sending on {key}: {e}", self.spec.host),
        }
    }
}

/// A message from its bytes (`None`: too short).
fn decode<T: Copy>(bytes: &[u8]) -> Option<T> {
    (bytes.len() == std::mem::size_of::<T>())
        // SAFETY: the length is checked; every message type is integers and floats
        // (runtime::ipc::wire).
        .then(|| unsafe { std::ptr::read_unaligned(bytes.as_ptr() as *const T) })
}

/// Remembers the publishers a ready report of this host announces.
fn note_ready(bytes: &[u8], ready_pins: &ReadyPins) {
    let Some(status) = decode::<Status>(bytes) else {
        return;
    };
    if status.event != StatusEvent::Ready as u32 {
        return;
    }
    if let (Some(role), Ok(mut pins)) = (Role::from_code(status.role), ready_pins.lock()) {
        pins.insert((role, status.header.epoch), status.publishers);
    }
}

/// Whether a sample of `topic` came from the publisher its producer is pinned to (or one
/// not pinned yet: its epoch alone vouches for it, as at every consumer).
fn sent_by_its_producer(
    topic: &str,
    bytes: &[u8],
    origin: u128,
    schedule: &Option<EpochSchedule>,
    spec: &BridgeSpec,
) -> bool {
    if topic == CONTROL {
        return spec.control_publisher.is_none_or(|id| id == origin);
    }
    let (Some(role), Some(header), Some(schedule)) =
        (producer_of(topic), wire::header_of(bytes), schedule)
    else {
        return true;
    };
    output_slot(role, topic)
        .and_then(|slot| schedule.publisher(role, header.epoch, slot))
        .is_none_or(|pinned| pinned == origin)
}

/// Whether the link drops this data sample (loss, or the link down at its time).
fn dropped(bytes: &[u8], faults: &LinkFaults, rng: &mut impl Rng, counters: &Counters) -> bool {
    let down = wire::header_of(bytes)
        .is_some_and(|h| (faults.down_s[0]..faults.down_s[1]).contains(&h.time_s));
    if down {
        counters.down.fetch_add(1, Ordering::Relaxed);
        return true;
    }
    if faults.loss > 0.0 && rng.random::<f64>() < faults.loss {
        counters.lost.fetch_add(1, Ordering::Relaxed);
        return true;
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_a_host_a_producer_elsewhere_is_pinned_to_the_relay_and_a_local_one_to_itself() {
        let mut schedule = EpochSchedule::default();
        schedule.active[Role::Mpc as usize] = 3;
        schedule.active_publishers[Role::Estimator as usize] = [11, 0];
        schedule.active_publishers[Role::Mpc as usize] = [12, 0];
        let ready = HashMap::from([((Role::Mpc, 3), [99, 0])]);
        let relays = HashMap::from([(runtime::ipc::ESTIMATE.to_string(), 7u128)]);
        pin_for_host(&mut schedule, &[Role::Mpc], &ready, &relays);
        assert_eq!(schedule.active_publishers[Role::Estimator as usize], [7, 0]);
        assert_eq!(schedule.active_publishers[Role::Mpc as usize], [99, 0]);
        assert_eq!(
            schedule.active_publishers[Role::Plant as usize],
            [0, 0],
            "not carried here: unpinned"
        );
    }
}
