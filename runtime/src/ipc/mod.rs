//! The iceoryx2 side of the protocol: per-run configuration, service names, and the one
//! function that opens every topic with identical settings in every process.
//!
//! A topic is a publish-subscribe service paired with an event service of the same name:
//! a [`Sender`] publishes a sample and then notifies, so a [`Receiver`]'s process can
//! block in a WaitSet on the listener instead of spinning. A tick topic of
//! [`protocol::graph::SAMPLE_START_TOPICS`] has a second event service, notified only of
//! the samples at sample starts, for the receivers that need no others to step
//! ([`Topic::receiver_at_sample_starts`]).

use crate::clock::monotonic_ns;
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use iceoryx2::waitset::WaitSetRunResult;
use protocol::messages::{EpochSchedule, EpochVerdict, Message, Rejection};
use std::cell::{Cell, OnceCell};
use std::fmt::Display;
use std::marker::PhantomData;
use std::rc::Rc;

pub use protocol::topics::*;

/// A message iceoryx2 can carry: every [`Message`] of `protocol` (whose feature
/// `iceoryx2` this crate turns on).
pub trait Wire: Message + ZeroCopySend {}

impl<T: Message + ZeroCopySend> Wire for T {}

/// Publishers a data topic admits: the producer, its replacement, the process it replaces
/// while retiring, and one spare. Every receive looks at each publisher slot, so this is
/// kept small (8 made the real-time loop measurably slower).
pub const MAX_PUBLISHERS: usize = 4;
/// Publishers of the status topic: a process of each role, a replacement per swappable
/// role, and a retiring one.
pub const MAX_STATUS_PUBLISHERS: usize = 8;
/// Subscribers a topic admits in a run of one robot. In a fleet the roles of every other
/// robot that take a topic from it take it too ([`admit_robots`]).
pub const MAX_SUBSCRIBERS: usize = 8;

/// The robots of the run this process takes part in ([`admit_robots`]).
static ROBOTS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(1);

/// Makes the topics this process opens from now on admit the subscribers (and their
/// nodes and listeners) of a run of `robots` robots: for each other robot, one more for
/// each of its roles that takes the topic from the others
/// ([`protocol::graph::RoleDecl::peer_inputs`]). Every process of a fleet's run calls it before it opens a topic, so whichever
/// creates a topic makes room for all (a process that does not, such as `scmpc echo`,
/// asks for less, which opens).
pub fn admit_robots(robots: usize) {
    ROBOTS.store(robots.max(1), std::sync::atomic::Ordering::Relaxed);
}

/// The subscribers, nodes and listeners the other robots of the run ([`admit_robots`])
/// may add to topic `name`.
fn peer_takers(name: &str) -> usize {
    let others = ROBOTS.load(std::sync::atomic::Ordering::Relaxed) - 1;
    protocol::graph::peer_takers_of(name) * others
}

/// iceoryx2's defaults for the nodes of a publish-subscribe service and for the nodes and
/// the listeners of an event service, raised by one for each other robot of a fleet.
const MAX_PUBSUB_NODES: usize = 20;
const MAX_EVENT_NODES: usize = 36;
const MAX_LISTENERS: usize = 16;

/// The largest event id a topic's event service carries. Every notifier wakes with the
/// default id 0; iceoryx2's default of 255 gives each listener 256 counters, and every
/// `try_wait` (each wake-up cleared, [`Receiver::clear_wakeups`]) swaps all of them: 2 KB
/// of shared memory per call, 13 % of a lockstep `swap8`'s CPU time (`perf record -a`,
/// 2026-12-03). Opening a service made by another client with a larger bound still works:
/// iceoryx2 checks only that it is at least this.
const EVENT_ID_MAX: usize = 7;

/// Samples a subscriber can hold before the oldest is overwritten (safe overflow).
pub const SUBSCRIBER_BUFFER: usize = 64;
/// Every run's resource prefix starts with this.
pub const PREFIX_STEM: &str = "scmpc";

/// An iceoryx2 operation that failed, with what was being done.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("iceoryx2: {0}")]
pub struct IpcError(pub String);

fn ctx<E: Display>(what: impl Display) -> impl FnOnce(E) -> IpcError {
    move |e| IpcError(format!("{what}: {e}"))
}

/// A fresh resource prefix for one run: `scmpc<pid>x<nanos>_`.
pub fn new_prefix() -> String {
    format!(
        "{PREFIX_STEM}{}x{}_",
        std::process::id(),
        monotonic_ns() % 1_000_000_000_000
    )
}

/// Environment: the run's id (hexadecimal) for a process on another host, whose iceoryx2
/// prefix is its agent's, not the run's (docs/hosts.md).
pub const ENV_RUN_ID: &str = "SCMPC_RUN_ID";

/// The run id this process's topics stamp and check: [`ENV_RUN_ID`] if it is set, else
/// that of `prefix`.
fn topic_run_id(prefix: &str) -> u32 {
    static OVERRIDE: std::sync::OnceLock<Option<u32>> = std::sync::OnceLock::new();
    let from_env = *OVERRIDE.get_or_init(|| {
        std::env::var(ENV_RUN_ID)
            .ok()
            .and_then(|text| u32::from_str_radix(text.trim(), 16).ok())
    });
    from_env.unwrap_or_else(|| run_id(prefix.as_bytes()))
}

/// The run's identity stamped on every sample: FNV-1a of its prefix.
pub fn run_id(prefix: &[u8]) -> u32 {
    prefix.iter().fold(0x811c_9dc5u32, |h, b| {
        (h ^ u32::from(*b)).wrapping_mul(0x0100_0193)
    })
}

/// The iceoryx2 configuration of a run: iceoryx2's built-in defaults (no config file is
/// read, so every process of every machine agrees) with the run's prefix, so runs never
/// share a resource. One change: nodes do not clean up after dead nodes when they are
/// created or dropped or open a service; the orchestrator alone does
/// ([`cleanup_dead_nodes`]), so it sees every death (another process cleaning first would
/// hide it).
pub fn run_config(prefix: &str) -> Result<Config, IpcError> {
    // Only iceoryx2's errors are worth showing next to ours.
    set_log_level(LogLevel::Error);
    let mut config = Config::default();
    config.global.prefix =
        FileName::new(prefix.as_bytes()).map_err(ctx(format!("prefix `{prefix}`")))?;
    config.global.node.cleanup_dead_nodes_on_creation = false;
    config.global.node.cleanup_dead_nodes_on_destruction = false;
    config.global.service.cleanup_dead_nodes_on_open = false;
    Ok(config)
}

/// A node of the run. Processes handle SIGINT/SIGTERM through iceoryx2 (their waits
/// return); the orchestrator installs its own handler and passes `handle_signals = false`.
pub fn create_node(
    prefix: &str,
    name: &str,
    handle_signals: bool,
) -> Result<Node<ipc::Service>, IpcError> {
    let config = run_config(prefix)?;
    let mode = signal_mode(handle_signals);
    let node_name = NodeName::new(name).map_err(ctx(format!("node name `{name}`")))?;
    NodeBuilder::new()
        .config(&config)
        .name(&node_name)
        .signal_handling_mode(mode)
        .create::<ipc::Service>()
        .map_err(ctx(format!("creating node `{name}`")))
}

/// A publisher and the notifier that wakes its subscribers.
pub(crate) type PublishingPorts<T> = (Publisher<ipc::Service, T, ()>, Notifier<ipc::Service>);
/// A subscriber and the listener its publishers wake.
pub(crate) type SubscribingPorts<T> = (Subscriber<ipc::Service, T, ()>, Listener<ipc::Service>);

/// A publish-subscribe service and its event service, opened with the settings every
/// process uses.
pub struct Topic<T: Wire> {
    name: &'static str,
    run_id: u32,
    /// The robot whose samples it carries.
    robot: u32,
    pubsub: publish_subscribe::PortFactory<ipc::Service, T, ()>,
    event: event::PortFactory<ipc::Service>,
    /// The event service of its samples at sample starts (a topic of
    /// [`protocol::graph::SAMPLE_START_TOPICS`]).
    sample_starts: Option<event::PortFactory<ipc::Service>>,
}

/// Opens (or creates) topic `name` of robot `robot`'s pipeline, carrying `T`: its service
/// is [`protocol::topics::service_name`], and its samples are stamped with and checked for
/// `robot` ([`Header::robot`](protocol::Header)).
pub fn open_topic<T: Wire>(
    node: &Node<ipc::Service>,
    robot: u32,
    name: &'static str,
) -> Result<Topic<T>, IpcError> {
    let service = protocol::topics::service_name(robot, name);
    open_service(node, &service, name, robot, true)
}

/// Opens topic `name` of robot `robot`'s pipeline if the run has it, never creating it:
/// a tool watching a run (`scmpc echo`) leaves nothing behind.
pub fn open_existing_topic<T: Wire>(
    node: &Node<ipc::Service>,
    robot: u32,
    name: &'static str,
) -> Result<Topic<T>, IpcError> {
    let service = protocol::topics::service_name(robot, name);
    open_service(node, &service, name, robot, false)
}

/// Opens (or creates) topic `name` of the run itself (one of [`RUN_TOPICS`]), carrying
/// `T`.
pub fn open_run_topic<T: Wire>(
    node: &Node<ipc::Service>,
    name: &'static str,
) -> Result<Topic<T>, IpcError> {
    open_service(node, name, name, protocol::FIRST_ROBOT, true)
}

/// The topic's services, opened with the settings every process uses; created too when
/// `create`.
fn open_service<T: Wire>(
    node: &Node<ipc::Service>,
    service: &str,
    name: &'static str,
    robot: u32,
    create: bool,
) -> Result<Topic<T>, IpcError> {
    let service_name: ServiceName = service
        .try_into()
        .map_err(ctx(format!("service name `{service}`")))?;
    let pubsub = node
        .service_builder(&service_name)
        .publish_subscribe::<T>()
        .max_publishers(if name == STATUS {
            MAX_STATUS_PUBLISHERS
        } else {
            MAX_PUBLISHERS
        })
        .max_subscribers(MAX_SUBSCRIBERS + peer_takers(name))
        .max_nodes(MAX_PUBSUB_NODES + peer_takers(name))
        .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
        .history_size(0)
        .enable_safe_overflow(true);
    let pubsub = if create {
        pubsub.open_or_create().map_err(|e| e.to_string())
    } else {
        pubsub.open().map_err(|e| e.to_string())
    }
    .map_err(|e| IpcError(format!("opening service `{service}`: {e}")))?;
    let event = open_event_service(node, service, name, create)?;
    let sample_starts = if protocol::graph::SAMPLE_START_TOPICS.contains(&name) {
        Some(open_event_service(
            node,
            &format!("{service}/sample_starts"),
            name,
            create,
        )?)
    } else {
        None
    };
    let run_id = topic_run_id(node.config().global.prefix.as_str());
    Ok(Topic {
        name,
        run_id,
        robot,
        pubsub,
        event,
        sample_starts,
    })
}

/// The event service `service` of topic `name`, opened with the settings every process
/// uses; created too when `create`.
fn open_event_service(
    node: &Node<ipc::Service>,
    service: &str,
    name: &str,
    create: bool,
) -> Result<event::PortFactory<ipc::Service>, IpcError> {
    let service_name: ServiceName = service
        .try_into()
        .map_err(ctx(format!("service name `{service}`")))?;
    let event = (node.service_builder(&service_name).event())
        .max_nodes(MAX_EVENT_NODES + peer_takers(name))
        .max_listeners(MAX_LISTENERS + peer_takers(name))
        .event_id_max_value(EVENT_ID_MAX);
    if create {
        event.open_or_create().map_err(|e| e.to_string())
    } else {
        event.open().map_err(|e| e.to_string())
    }
    .map_err(|e| IpcError(format!("opening event service `{service}`: {e}")))
}

impl<T: Wire> Topic<T> {
    /// A publisher on the topic and the notifier that wakes its subscribers.
    pub(crate) fn publishing_ports(&self) -> Result<PublishingPorts<T>, IpcError> {
        let publisher = self
            .pubsub
            .publisher_builder()
            .create()
            .map_err(ctx(format!("publisher on `{}`", self.name)))?;
        let notifier = self.notifier(&self.event)?;
        Ok((publisher, notifier))
    }

    /// A notifier on `event`, one of this topic's event services.
    fn notifier(
        &self,
        event: &event::PortFactory<ipc::Service>,
    ) -> Result<Notifier<ipc::Service>, IpcError> {
        (event.notifier_builder().create()).map_err(ctx(format!("notifier on `{}`", self.name)))
    }

    /// The notifier of the samples at sample starts, if the topic announces them.
    pub(crate) fn sample_start_notifier(&self) -> Result<Option<Notifier<ipc::Service>>, IpcError> {
        self.sample_starts
            .as_ref()
            .map(|event| self.notifier(event))
            .transpose()
    }

    /// A subscriber on the topic and the listener its publishers wake.
    pub(crate) fn subscribing_ports(&self) -> Result<SubscribingPorts<T>, IpcError> {
        self.subscribing_ports_on(&self.event)
    }

    /// A subscriber on the topic and a listener on `event`, one of its event services.
    fn subscribing_ports_on(
        &self,
        event: &event::PortFactory<ipc::Service>,
    ) -> Result<SubscribingPorts<T>, IpcError> {
        let subscriber = self
            .pubsub
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(ctx(format!("subscriber on `{}`", self.name)))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(ctx(format!("listener on `{}`", self.name)))?;
        Ok((subscriber, listener))
    }

    /// A publisher stamping every sample with `epoch` and its publish time. On a topic
    /// that announces its samples at sample starts it announces every sample as one
    /// until told how many ticks a sample has ([`Sender::with_ticks_per_sample`]).
    pub fn sender(&self, epoch: u32) -> Result<Sender<T>, IpcError> {
        let (publisher, notifier) = self.publishing_ports()?;
        Ok(Sender {
            name: self.name,
            publisher,
            notifier,
            sample_starts: self.sample_start_notifier()?,
            ticks_per_sample: 1,
            epoch,
            run_id: self.run_id,
            robot: self.robot,
            last: Cell::new(None),
        })
    }

    /// A receiver of samples from any producer epoch (for topics without a single
    /// producer role, such as status).
    pub fn receiver(&self) -> Result<Receiver<T>, IpcError> {
        self.receiver_inner(None)
    }

    /// A receiver that takes only samples of this run, from the active epoch of
    /// `producer`, finite, and in tick order; it counts every sample it refuses.
    pub fn receiver_from(&self, producer: protocol::Role) -> Result<Receiver<T>, IpcError> {
        self.receiver_inner(Some(producer))
    }

    /// [`Topic::receiver_from`] whose process only the samples at sample starts wake (of a
    /// topic of [`protocol::graph::SAMPLE_START_TOPICS`]; of another, every sample).
    pub fn receiver_at_sample_starts(
        &self,
        producer: protocol::Role,
    ) -> Result<Receiver<T>, IpcError> {
        let event = self.sample_starts.as_ref().unwrap_or(&self.event);
        self.receiver_on(Some(producer), event)
    }

    fn receiver_inner(&self, producer: Option<protocol::Role>) -> Result<Receiver<T>, IpcError> {
        self.receiver_on(producer, &self.event)
    }

    fn receiver_on(
        &self,
        producer: Option<protocol::Role>,
        event: &event::PortFactory<ipc::Service>,
    ) -> Result<Receiver<T>, IpcError> {
        let (subscriber, listener) = self.subscribing_ports_on(event)?;
        Ok(Receiver {
            subscriber,
            listener: Some(listener),
            run_id: self.run_id,
            robot: self.robot,
            producer,
            slot: producer.and_then(|role| output_slot(role, self.name)),
            pinned: Cell::new(None),
            schedule: Cell::new(None),
            last_tick: Cell::new(None),
            rejected: Cell::new([0; Rejection::COUNT]),
            taken: Cell::new(0),
            newest_publish_ns: Cell::new(None),
            limit: OnceCell::new(),
            clock_known: Cell::new(false),
            standby_newest: Cell::new(None),
            _payload: PhantomData,
        })
    }
}

/// Publishes `T` and wakes the topic's listeners.
pub struct Sender<T: Wire> {
    name: &'static str,
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    /// The notifier of the samples at sample starts, if the topic announces them.
    sample_starts: Option<Notifier<ipc::Service>>,
    /// `M`: a sample whose tick is a multiple of it starts a sample.
    ticks_per_sample: u64,
    epoch: u32,
    run_id: u32,
    robot: u32,
    /// The newest sample sent, for [`Sender::replay`].
    last: Cell<Option<T>>,
}

impl<T: Wire> Sender<T> {
    /// Stamps the publish time and the epoch, publishes a copy and notifies.
    pub fn send(&self, mut message: T) -> Result<(), IpcError> {
        let header = message.header_mut();
        header.epoch = self.epoch;
        header.run_id = self.run_id;
        header.robot = self.robot;
        header.publish_ns = monotonic_ns();
        self.last.set(Some(message));
        self.publisher
            .send_copy(message)
            .map_err(ctx("publishing"))?;
        self.notifier.notify().map_err(ctx("notifying"))?;
        if let Some(sample_starts) = &self.sample_starts
            && message.header().tick.is_multiple_of(self.ticks_per_sample)
        {
            sample_starts.notify().map_err(ctx("notifying"))?;
        }
        Ok(())
    }

    /// Announces as sample starts only the samples whose tick is a multiple of
    /// `ticks_per_sample` (`M`, at least 1).
    pub fn with_ticks_per_sample(mut self, ticks_per_sample: u64) -> Sender<T> {
        self.ticks_per_sample = ticks_per_sample.max(1);
        self
    }

    /// The iceoryx2 id of this sender's publisher: what its consumers pin it to.
    pub fn publisher_id(&self) -> u128 {
        self.publisher.id().value()
    }

    /// Publishes the newest sample again (same tick, fresh publish time), if there is one:
    /// the answer to [`ControlCommand::Replay`](protocol::ControlCommand::Replay).
    pub fn replay(&self) -> Result<(), IpcError> {
        match self.last.get() {
            Some(message) => self.send(message),
            None => Ok(()),
        }
    }
}

/// Receives `T`; its listener is what a WaitSet blocks on.
pub struct Receiver<T: Wire> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    /// `None`: a quiet receiver ([`Receiver::quiet`]).
    listener: Option<Listener<ipc::Service>>,
    run_id: u32,
    robot: u32,
    /// Role whose producer epoch is checked (`None`: any epoch, no tick order).
    producer: Option<protocol::Role>,
    /// Which of the producer's outputs this topic is ([`output_slot`]).
    slot: Option<usize>,
    /// The only publisher taken from, when set ([`Receiver::pin_to`]).
    pinned: Cell<Option<u128>>,
    /// Which epoch of `producer` to take; `None` until the orchestrator has said (a
    /// process that joins a running run takes nothing before that).
    schedule: Cell<Option<EpochSchedule>>,
    last_tick: Cell<Option<u64>>,
    /// Refused samples by [`Rejection`] code, since last taken.
    rejected: Cell<[u64; Rejection::COUNT]>,
    /// Samples taken so far.
    taken: Cell<u64>,
    /// When the newest sample taken was published, monotonic ns.
    newest_publish_ns: Cell<Option<u64>>,
    /// The clock a sample's tick is judged against ([`Receiver::bound_by`]).
    limit: OnceCell<Rc<dyn TickLimit>>,
    /// Whether that clock has known "now" ([`Receiver::clock_known`]).
    clock_known: Cell<bool>,
    /// Newest tick heard from a producer being swapped in or out (not taken).
    standby_newest: Cell<Option<u64>>,
    _payload: PhantomData<T>,
}

impl<T: Wire> Receiver<T> {
    /// The receiver without its listener: no publisher wakes it, so a sample costs its
    /// publisher no system call for it; its samples are taken when the process wakes for
    /// something else (in lockstep: a role's control topic, `process::Member`; the
    /// orchestrator's inputs that come before a tick's command, `run::multiproc`).
    pub fn quiet(mut self) -> Receiver<T> {
        self.listener = None;
        self
    }

    /// The listener its publishers wake (`None`: a quiet receiver).
    pub fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }

    /// The next acceptable sample, if any, with its publish-to-receipt latency in ns.
    /// Refused samples are counted and skipped.
    pub fn receive(&self) -> Result<Option<(T, u64)>, IpcError> {
        Ok(self
            .receive_with_origin()?
            .map(|(m, latency, _)| (m, latency)))
    }

    /// [`Receiver::receive`], with the iceoryx2 id of the sample's publisher.
    pub fn receive_with_origin(&self) -> Result<Option<(T, u64, u128)>, IpcError> {
        // Nothing is judged before the orchestrator has named the producers and, for a
        // bound receiver, before its clock knows "now" (a process that joins a real-time
        // run may hear the schedule before the clock's start).
        if self.producer.is_some() && (self.schedule.get().is_none() || !self.clock_known()) {
            return Ok(None);
        }
        loop {
            let Some(sample) = self.subscriber.receive().map_err(ctx("receiving"))? else {
                return Ok(None);
            };
            let message = *sample.payload();
            let origin = sample.origin().value();
            let latency = monotonic_ns().saturating_sub(message.header().publish_ns);
            match self.check(&message, origin) {
                Ok(EpochVerdict::Take) => {
                    self.taken.set(self.taken.get() + 1);
                    self.newest_publish_ns
                        .set(Some(message.header().publish_ns));
                    return Ok(Some((message, latency, origin)));
                }
                Ok(_) => {
                    let tick = message.header().tick;
                    self.standby_newest
                        .set(self.standby_newest.get().max(Some(tick)));
                }
                Err(reason) => {
                    let mut counts = self.rejected.get();
                    counts[reason as usize] += 1;
                    self.rejected.set(counts);
                }
            }
        }
    }

    /// The border check (docs/design.md, "Supervision"), in one place. A sample of a producer
    /// being swapped in or out is [`EpochVerdict::Standby`]: skipped, not an error.
    /// Whether the bound clock (if any) knows "now". A clock once known stays known, so
    /// it is asked only until then (in real time asking reads the wall clock).
    fn clock_known(&self) -> bool {
        if self.clock_known.get() {
            return true;
        }
        let known = self.limit.get().is_none_or(|l| {
            l.newest_tick(false)
                .or_else(|| l.newest_tick(true))
                .is_some()
        });
        self.clock_known.set(known);
        known
    }

    /// The order matters: who sent it (run, epoch, publisher) before what it says, so a
    /// stranger's sample is never blamed on the producer ([`Rejection::blames_producer`]).
    fn check(&self, message: &T, origin: u128) -> Result<EpochVerdict, Rejection> {
        let h = message.header();
        if h.run_id != self.run_id {
            return Err(Rejection::WrongRun);
        }
        if h.robot != self.robot {
            return Err(Rejection::WrongRobot);
        }
        if self.pinned.get().is_some_and(|id| id != origin) {
            return Err(Rejection::UnknownPublisher);
        }
        let content = || message.content_rejection().map_or(Ok(()), Err);
        let (Some(role), Some(schedule)) = (self.producer, self.schedule.get()) else {
            // Any producer (a fleet's other robot, `Member::peer_input`): what it says,
            // and its tick against the clock when bound to one.
            content()?;
            return self.against_clock(h).map(|()| EpochVerdict::Take);
        };
        let verdict = schedule.judge(role, h.epoch, h.tick);
        if verdict == EpochVerdict::Reject {
            return Err(Rejection::WrongEpoch);
        }
        // Until the producer's announcement is known here (a moment after it joins),
        // its epoch alone vouches for it.
        let pin = self
            .slot
            .and_then(|slot| schedule.publisher(role, h.epoch, slot));
        if pin.is_some_and(|id| id != origin) {
            return Err(Rejection::UnknownPublisher);
        }
        if verdict == EpochVerdict::Standby {
            return Ok(EpochVerdict::Standby);
        }
        content()?;
        self.against_clock(h)?;
        if self.last_tick.get().is_some_and(|last| h.tick < last) {
            return Err(Rejection::TickBackwards);
        }
        self.last_tick.set(Some(h.tick));
        Ok(EpochVerdict::Take)
    }

    /// A sample's tick and time judged against the clock it is bound to, if any
    /// ([`Receiver::bound_by`]), refreshed once before a sample is refused: a sample may
    /// overtake the control message that let its producer make it.
    fn against_clock(&self, h: &protocol::Header) -> Result<(), Rejection> {
        let Some(limit) = self.limit.get() else {
            return Ok(());
        };
        let ahead = |refresh| limit.newest_tick(refresh).is_none_or(|n| h.tick > n);
        if ahead(false) && ahead(true) {
            return Err(Rejection::TickAhead);
        }
        let tick_time_s = h.tick as f64 * limit.dt_s();
        if (h.time_s - tick_time_s).abs() > TIME_TOLERANCE_S {
            return Err(Rejection::TimeMismatch);
        }
        Ok(())
    }

    /// Takes samples only from the iceoryx2 publisher `id` from now on (the control topic:
    /// the orchestrator's); others are refused as [`Rejection::UnknownPublisher`].
    pub fn pin_to(&self, id: u128) {
        self.pinned.set(Some(id));
    }

    /// Judges every sample's tick and time against `limit` from now on (once; later calls
    /// change nothing): a sample ahead of what its producer can have made by now is
    /// refused as [`Rejection::TickAhead`] and changes nothing.
    pub fn bound_by(&self, limit: Rc<dyn TickLimit>) {
        let _ = self.limit.set(limit);
    }

    /// Takes samples by `schedule` from now on. When the producers of the role change,
    /// ticks are checked afresh.
    pub fn follow(&self, schedule: EpochSchedule) {
        let Some(role) = self.producer else {
            return;
        };
        let r = role as usize;
        let changed = self.schedule.replace(Some(schedule)).is_none_or(|old| {
            (old.active[r], old.next[r], old.switch_tick[r])
                != (
                    schedule.active[r],
                    schedule.next[r],
                    schedule.switch_tick[r],
                )
        });
        if changed {
            self.last_tick.set(None);
        }
    }

    /// Whether a sample is waiting (without taking it).
    pub fn has_samples(&self) -> bool {
        self.subscriber.has_samples().unwrap_or(false)
    }

    /// Consumes the pending wake-ups, so a WaitSet does not fire again for them.
    pub fn clear_wakeups(&self) {
        if let Some(listener) = &self.listener {
            let _ = listener.try_wait(|_| {});
        }
    }
}

impl<T: Wire> Receiver<T> {
    /// Attaches this receiver's listener to `waitset`; keep the guard while waiting.
    pub fn attach<'w>(
        &'w self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<WaitSetGuard<'w, 'w, ipc::Service>, IpcError> {
        attach_input(waitset, self)
    }

    /// Every pending sample, after clearing the wake-ups (so none is missed).
    pub fn drain(&self, each: impl FnMut(T, u64)) -> Result<(), IpcError> {
        self.clear_wakeups();
        self.take(each)
    }

    /// Every pending sample, straight from shared memory (no system call). The caller
    /// must [`clear_wakeups`](Self::clear_wakeups) and take once more before it blocks.
    pub fn take(&self, mut each: impl FnMut(T, u64)) -> Result<(), IpcError> {
        while let Some((message, latency)) = self.receive()? {
            each(message, latency);
        }
        Ok(())
    }
}

/// Attaches the listener of `input` to `waitset`; keep the guard while waiting. A quiet
/// receiver ([`Receiver::quiet`]) has none to attach.
pub fn attach_input<'w>(
    waitset: &'w WaitSet<ipc::Service>,
    input: &'w dyn Input,
) -> Result<WaitSetGuard<'w, 'w, ipc::Service>, IpcError> {
    let listener = input
        .listener()
        .ok_or_else(|| IpcError("a quiet receiver has no listener to wait on".into()))?;
    attach(waitset, listener)
}

/// Attaches `listener` to `waitset`; keep the guard while waiting.
pub fn attach<'w>(
    waitset: &'w WaitSet<ipc::Service>,
    listener: &'w Listener<ipc::Service>,
) -> Result<WaitSetGuard<'w, 'w, ipc::Service>, IpcError> {
    waitset
        .attach_notification(listener)
        .map_err(ctx("attaching a listener"))
}

/// Real time: how many ticks a sample may be ahead of the consumer's clock (the producer's
/// clock is the same `CLOCK_MONOTONIC`; the slack covers rounding at a tick's edge).
pub const TICK_SLACK: u64 = 2;
/// Largest difference between a sample's time and its tick's, s (both are `tick * dt`).
pub const TIME_TOLERANCE_S: f64 = 1e-6;

/// What a consumer knows of "now", so that no sample can move it: the newest tick any
/// producer can have published (docs/design.md, "Supervision").
pub trait TickLimit {
    /// The newest tick a producer can have published by now (`None`: none yet). With
    /// `refresh`, after taking what the clock's source has pending.
    fn newest_tick(&self, refresh: bool) -> Option<u64>;
    /// The inner tick, s.
    fn dt_s(&self) -> f64;
}

/// What the role runtime needs of an input, whatever it carries (every [`Receiver`]).
pub trait Input {
    /// The listener a WaitSet blocks on (`None`: a quiet receiver, which nothing wakes).
    fn listener(&self) -> Option<&Listener<ipc::Service>>;
    /// Whether a sample is waiting (without taking it).
    fn has_samples(&self) -> bool;
    fn clear_wakeups(&self);
    fn follow(&self, schedule: EpochSchedule);
    /// See [`Receiver::bound_by`].
    fn bound_by(&self, limit: Rc<dyn TickLimit>);
    /// Refused samples by [`Rejection`] code since the last call.
    fn take_rejections(&self) -> [u64; Rejection::COUNT];
    /// The role whose samples this input takes (`None`: any sender).
    fn producer(&self) -> Option<protocol::Role>;
    /// How many samples it has taken so far.
    fn taken(&self) -> u64;
    /// When the newest sample taken was published, monotonic ns (`None`: none taken).
    fn newest_publish_ns(&self) -> Option<u64>;
    /// Newest tick published by the replacement (or the retiring producer) of the role and
    /// not taken, since the last call: how the orchestrator sees a replacement warm up.
    fn take_standby_newest(&self) -> Option<u64>;
}

impl<T: Wire> Input for Receiver<T> {
    fn listener(&self) -> Option<&Listener<ipc::Service>> {
        self.listener.as_ref()
    }
    fn has_samples(&self) -> bool {
        Receiver::has_samples(self)
    }
    fn clear_wakeups(&self) {
        Receiver::clear_wakeups(self);
    }
    fn follow(&self, schedule: EpochSchedule) {
        Receiver::follow(self, schedule);
    }
    fn bound_by(&self, limit: Rc<dyn TickLimit>) {
        Receiver::bound_by(self, limit);
    }
    fn take_rejections(&self) -> [u64; Rejection::COUNT] {
        self.rejected.replace([0; Rejection::COUNT])
    }
    fn producer(&self) -> Option<protocol::Role> {
        self.producer
    }
    fn taken(&self) -> u64 {
        self.taken.get()
    }
    fn newest_publish_ns(&self) -> Option<u64> {
        self.newest_publish_ns.get()
    }
    fn take_standby_newest(&self) -> Option<u64> {
        self.standby_newest.take()
    }
}

/// What the role runtime needs of an output, whatever it carries (every [`Sender`]).
pub trait Output {
    /// See [`Sender::replay`].
    fn replay(&self) -> Result<(), IpcError>;
    /// The topic's name.
    fn topic(&self) -> &'static str;
    /// See [`Sender::publisher_id`].
    fn publisher_id(&self) -> u128;
}

impl<T: Wire> Output for Sender<T> {
    fn replay(&self) -> Result<(), IpcError> {
        Sender::replay(self)
    }
    fn topic(&self) -> &'static str {
        self.name
    }
    fn publisher_id(&self) -> u128 {
        Sender::publisher_id(self)
    }
}

/// How a wait ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// At least one attached listener fired.
    Input,
    Timeout,
    /// SIGINT or SIGTERM: the process should exit.
    Terminate,
}

/// Blocks on the WaitSet until an input arrives or `timeout` passes.
pub fn wait(
    waitset: &WaitSet<ipc::Service>,
    timeout: std::time::Duration,
) -> Result<Wake, IpcError> {
    wait_fired(waitset, timeout, |_| {})
}

/// [`wait`], handing `on_fired` the attachment of every listener that fired, so that the
/// caller can clear those alone.
pub fn wait_fired(
    waitset: &WaitSet<ipc::Service>,
    timeout: std::time::Duration,
    mut on_fired: impl FnMut(WaitSetAttachmentId<ipc::Service>),
) -> Result<Wake, IpcError> {
    let mut fired = false;
    let result = waitset
        .wait_and_process_once_with_timeout(
            |id| {
                fired = true;
                on_fired(id);
                CallbackProgression::Continue
            },
            timeout,
        )
        .map_err(ctx("waiting"))?;
    Ok(match result {
        WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt => Wake::Terminate,
        _ if fired => Wake::Input,
        _ => Wake::Timeout,
    })
}

/// A WaitSet; with `handle_signals` its waits return [`Wake::Terminate`] on SIGINT and
/// SIGTERM (role processes), without it the caller's own handler stays in charge.
pub fn waitset(handle_signals: bool) -> Result<WaitSet<ipc::Service>, IpcError> {
    WaitSetBuilder::new()
        .signal_handling_mode(signal_mode(handle_signals))
        .create::<ipc::Service>()
        .map_err(ctx("creating a WaitSet"))
}

fn signal_mode(handle_signals: bool) -> SignalHandlingMode {
    if handle_signals {
        SignalHandlingMode::HandleTerminationRequests
    } else {
        SignalHandlingMode::Disabled
    }
}

mod resources;
pub mod wire;
pub use resources::*;

#[cfg(test)]
mod tests;
