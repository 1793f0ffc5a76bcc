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

/// Lockstep, a fleet: the most ticks one robot's processes may run ahead of the newest
/// tick granted to another's (the orchestrator grants each robot its ticks apart between
/// the ticks at which all start together, `run::multiproc::fleet`). A robot's samples are
/// judged against another's clock with this allowance ([`Ahead`]). Its tracker, woken at
/// sample starts, may find a sample of ticks of a robot waiting and this many more, of
/// which it keeps the newest [`SUBSCRIBER_BUFFER`]: half of them leaves the other half for
/// a sample of up to 32 ticks.
pub const MAX_TICKS_APART: u64 = SUBSCRIBER_BUFFER as u64 / 2;

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

/// Where iceoryx2 keeps the files that describe a run's services and nodes (its default is
/// `/tmp/iceoryx2/`, on disk): on the tmpfs of the shared memory, so that creating and
/// removing a run's hundreds of them costs no file system's inode search. `swap8` across
/// processes for one tick took 0.95 s where it took 1.45 s (2026-12-04, docs/fleet.md,
/// "Speed").
pub const ROOT_PATH: &str = "/dev/shm/iceoryx2/";

/// The iceoryx2 configuration of a run: iceoryx2's built-in defaults (no config file is
/// read, so every process of every machine agrees) with the run's prefix, so runs never
/// share a resource. Two changes: its files are under [`ROOT_PATH`]; nodes do not clean up
/// after dead nodes when they are created or dropped or open a service; the orchestrator
/// alone does ([`cleanup_dead_nodes`]), so it sees every death (another process cleaning
/// first would hide it).
pub fn run_config(prefix: &str) -> Result<Config, IpcError> {
    // Only iceoryx2's errors are worth showing next to ours.
    set_log_level(LogLevel::Error);
    let mut config = Config::default();
    config.global.prefix =
        FileName::new(prefix.as_bytes()).map_err(ctx(format!("prefix `{prefix}`")))?;
    config
        .global
        .set_root_path(&Path::new(ROOT_PATH.as_bytes()).map_err(ctx("iceoryx2's root path"))?);
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
    // A watcher (`create` false) neither publishes nor waits for sample starts.
    let sample_starts = if create && protocol::graph::SAMPLE_START_TOPICS.contains(&name) {
        Some(open_event_service(
            node,
            &sample_starts_service(service),
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

/// The event service of the samples at sample starts of the topic of service `service`.
pub fn sample_starts_service(service: &str) -> String {
    format!("{service}/sample_starts")
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

mod receiver;
mod resources;
pub mod wire;

pub use receiver::*;
pub use resources::*;

#[cfg(test)]
mod tests;
