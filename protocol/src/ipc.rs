//! The iceoryx2 side of the protocol: per-run configuration, service names, and the one
//! function that opens every topic with identical settings in every process.
//!
//! A topic is a publish-subscribe service paired with an event service of the same name:
//! a [`Sender`] publishes a sample and then notifies, so a [`Receiver`]'s process can
//! block in a WaitSet on the listener instead of spinning.

use crate::clock::monotonic_ns;
use crate::messages::{EpochSchedule, EpochVerdict, Message, Rejection};
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use iceoryx2::waitset::WaitSetRunResult;
use std::cell::Cell;
use std::fmt::Display;
use std::marker::PhantomData;

/// Noisy output of the plant.
pub const MEASUREMENT: &str = "measurement";
/// True state of the plant (read by the recorder only).
pub const TRUTH: &str = "truth";
pub const ESTIMATE: &str = "estimate";
pub const PLAN: &str = "plan";
pub const ACTUATION: &str = "actuation";
/// The DFL's deadline verdict for every sample.
pub const DEADLINE: &str = "deadline";
/// Orchestrator to processes: clock grants, start, stop.
pub const CONTROL: &str = "control";
/// Processes to orchestrator: ready, input lost.
pub const STATUS: &str = "status";
/// `scmpc swap` to orchestrator: live swap requests.
pub const SWAP: &str = "swap";
/// Orchestrator to `scmpc swap`: how a requested swap ended.
pub const SWAP_REPLY: &str = "swap_reply";

/// Publishers a data topic admits: the producer, its replacement, the process it replaces
/// while retiring, and one spare. Every receive looks at each publisher slot, so this is
/// kept small (8 made the real-time loop measurably slower).
pub const MAX_PUBLISHERS: usize = 4;
/// Publishers of the status topic: a process of each role, a replacement per swappable
/// role, and a retiring one.
pub const MAX_STATUS_PUBLISHERS: usize = 8;
pub const MAX_SUBSCRIBERS: usize = 8;
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

/// A publish-subscribe service and its event service, opened with the settings every
/// process uses.
pub struct Topic<T: Message> {
    name: &'static str,
    run_id: u32,
    pubsub: publish_subscribe::PortFactory<ipc::Service, T, ()>,
    event: event::PortFactory<ipc::Service>,
}

/// Opens (or creates) topic `name` carrying `T`.
pub fn open_topic<T: Message>(
    node: &Node<ipc::Service>,
    name: &'static str,
) -> Result<Topic<T>, IpcError> {
    let service_name: ServiceName = name
        .try_into()
        .map_err(ctx(format!("service name `{name}`")))?;
    let pubsub = node
        .service_builder(&service_name)
        .publish_subscribe::<T>()
        .max_publishers(if name == STATUS {
            MAX_STATUS_PUBLISHERS
        } else {
            MAX_PUBLISHERS
        })
        .max_subscribers(MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(ctx(format!("opening service `{name}`")))?;
    let event = node
        .service_builder(&service_name)
        .event()
        .open_or_create()
        .map_err(ctx(format!("opening event service `{name}`")))?;
    let run_id = run_id(node.config().global.prefix.as_bytes());
    Ok(Topic {
        name,
        run_id,
        pubsub,
        event,
    })
}

impl<T: Message> Topic<T> {
    /// A publisher stamping every sample with `epoch` and its publish time.
    pub fn sender(&self, epoch: u32) -> Result<Sender<T>, IpcError> {
        Ok(Sender {
            publisher: self
                .pubsub
                .publisher_builder()
                .create()
                .map_err(ctx(format!("publisher on `{}`", self.name)))?,
            notifier: self
                .event
                .notifier_builder()
                .create()
                .map_err(ctx(format!("notifier on `{}`", self.name)))?,
            epoch,
            run_id: self.run_id,
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
    pub fn receiver_from(&self, producer: crate::Role) -> Result<Receiver<T>, IpcError> {
        self.receiver_inner(Some(producer))
    }

    fn receiver_inner(&self, producer: Option<crate::Role>) -> Result<Receiver<T>, IpcError> {
        Ok(Receiver {
            subscriber: self
                .pubsub
                .subscriber_builder()
                .buffer_size(SUBSCRIBER_BUFFER)
                .create()
                .map_err(ctx(format!("subscriber on `{}`", self.name)))?,
            listener: self
                .event
                .listener_builder()
                .create()
                .map_err(ctx(format!("listener on `{}`", self.name)))?,
            run_id: self.run_id,
            producer,
            schedule: Cell::new(None),
            last_tick: Cell::new(None),
            rejected: Cell::new([0; 4]),
            standby_newest: Cell::new(None),
            _payload: PhantomData,
        })
    }
}

/// Publishes `T` and wakes the topic's listeners.
pub struct Sender<T: Message> {
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    epoch: u32,
    run_id: u32,
    /// The newest sample sent, for [`Sender::replay`].
    last: Cell<Option<T>>,
}

impl<T: Message> Sender<T> {
    /// Stamps the publish time and the epoch, publishes a copy and notifies.
    pub fn send(&self, mut message: T) -> Result<(), IpcError> {
        let header = message.header_mut();
        header.epoch = self.epoch;
        header.run_id = self.run_id;
        header.publish_ns = monotonic_ns();
        self.last.set(Some(message));
        self.publisher
            .send_copy(message)
            .map_err(ctx("publishing"))?;
        self.notifier.notify().map_err(ctx("notifying"))?;
        Ok(())
    }

    /// Publishes the newest sample again (same tick, fresh publish time), if there is one:
    /// the answer to [`ControlCommand::Replay`](crate::ControlCommand::Replay).
    pub fn replay(&self) -> Result<(), IpcError> {
        match self.last.get() {
            Some(message) => self.send(message),
            None => Ok(()),
        }
    }
}

/// Receives `T`; its listener is what a WaitSet blocks on.
pub struct Receiver<T: Message> {
    subscriber: Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
    run_id: u32,
    /// Role whose producer epoch is checked (`None`: any epoch, no tick order).
    producer: Option<crate::Role>,
    /// Which epoch of `producer` to take; `None` until the orchestrator has said (a
    /// process that joins a running run takes nothing before that).
    schedule: Cell<Option<EpochSchedule>>,
    last_tick: Cell<Option<u64>>,
    /// Refused samples by [`Rejection`] code, since last taken.
    rejected: Cell<[u64; 4]>,
    /// Newest tick heard from a producer being swapped in or out (not taken).
    standby_newest: Cell<Option<u64>>,
    _payload: PhantomData<T>,
}

impl<T: Message> Receiver<T> {
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// The next acceptable sample, if any, with its publish-to-receipt latency in ns.
    /// Refused samples are counted and skipped.
    pub fn receive(&self) -> Result<Option<(T, u64)>, IpcError> {
        if self.producer.is_some() && self.schedule.get().is_none() {
            return Ok(None);
        }
        loop {
            let Some(sample) = self.subscriber.receive().map_err(ctx("receiving"))? else {
                return Ok(None);
            };
            let message = *sample.payload();
            let latency = monotonic_ns().saturating_sub(message.header().publish_ns);
            match self.check(&message) {
                Ok(EpochVerdict::Take) => return Ok(Some((message, latency))),
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

    /// The border check (README, "Supervision"), in one place. A sample of a producer
    /// being swapped in or out is [`EpochVerdict::Standby`]: skipped, not an error.
    fn check(&self, message: &T) -> Result<EpochVerdict, Rejection> {
        let h = message.header();
        if h.run_id != self.run_id {
            return Err(Rejection::WrongRun);
        }
        let (Some(role), Some(schedule)) = (self.producer, self.schedule.get()) else {
            return if message.all_finite() {
                Ok(EpochVerdict::Take)
            } else {
                Err(Rejection::NonFinite)
            };
        };
        match schedule.judge(role, h.epoch, h.tick) {
            EpochVerdict::Take => {}
            EpochVerdict::Standby => return Ok(EpochVerdict::Standby),
            EpochVerdict::Reject => return Err(Rejection::WrongEpoch),
        }
        if !message.all_finite() {
            return Err(Rejection::NonFinite);
        }
        if self.last_tick.get().is_some_and(|last| h.tick < last) {
            return Err(Rejection::TickBackwards);
        }
        self.last_tick.set(Some(h.tick));
        Ok(EpochVerdict::Take)
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
        let _ = self.listener.try_wait(|_| {});
    }
}

/// What housekeeping needs of an input (every [`Receiver`]).
pub trait Input {
    fn clear_wakeups(&self);
    fn follow(&self, schedule: EpochSchedule);
    /// Refused samples by [`Rejection`] code since the last call.
    fn take_rejections(&self) -> [u64; 4];
    /// Newest tick published by the replacement (or the retiring producer) of the role and
    /// not taken, since the last call: how the orchestrator sees a replacement warm up.
    fn take_standby_newest(&self) -> Option<u64>;
}

impl<T: Message> Input for Receiver<T> {
    fn clear_wakeups(&self) {
        Receiver::clear_wakeups(self);
    }
    fn follow(&self, schedule: EpochSchedule) {
        Receiver::follow(self, schedule);
    }
    fn take_rejections(&self) -> [u64; 4] {
        self.rejected.replace([0; 4])
    }
    fn take_standby_newest(&self) -> Option<u64> {
        self.standby_newest.take()
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
    let mut fired = false;
    let result = waitset
        .wait_and_process_once_with_timeout(
            |_| {
                fired = true;
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

/// Removes what dead nodes of the run left behind (their shared memory, their ports in
/// every service): iceoryx2's dead-node detection, which sees a process die whoever
/// started it. Returns the names of the nodes cleaned.
pub fn cleanup_dead_nodes(prefix: &str) -> Result<Vec<String>, IpcError> {
    let config = run_config(prefix)?;
    let mut dead = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        // Alive, or inaccessible or inconsistent: nothing this process can clean.
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    let mut names = Vec::with_capacity(dead.len());
    for view in dead {
        let name = view
            .details()
            .as_ref()
            .map_or_else(String::new, |d| d.name().as_str().to_string());
        if view.try_remove_stale_resources().is_ok() {
            names.push(name);
        }
    }
    Ok(names)
}

/// The process ids of the run's living nodes (iceoryx2's node listing, about 1 ms).
pub fn node_pids(prefix: &str) -> Result<Vec<u32>, IpcError> {
    let config = run_config(prefix)?;
    let mut pids = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        if let NodeState::Alive(view) = state
            && let Some(details) = view.details()
            && let Ok(pid) = u32::try_from(details.process_id().value())
        {
            pids.push(pid);
        }
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    Ok(pids)
}

/// The role and epoch of a role process's node, from its name (`<role>-<epoch>`).
pub fn role_of_node(name: &str) -> Option<(crate::Role, u32)> {
    let (role, epoch) = name.rsplit_once('-')?;
    Some((crate::Role::from_name(role)?, epoch.parse().ok()?))
}

/// Removes every resource of a finished run: dead nodes' leftovers and, once no node of
/// the run is alive, the run's global node-counter segment (iceoryx2 keeps it by design;
/// the prefix is unique to the run, so nobody else can use it).
pub fn remove_run_resources(prefix: &str) -> Result<(), IpcError> {
    cleanup_dead_nodes(prefix)?;
    let config = run_config(prefix)?;
    let mut alive = 0;
    Node::<ipc::Service>::list(&config, |_| {
        alive += 1;
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    if alive > 0 {
        return Err(IpcError(format!(
            "{alive} node(s) of the run are still alive"
        )));
    }
    for path in leftover_files(prefix) {
        if path.starts_with("/dev/shm") && path.to_string_lossy().ends_with(".global_mgmt") {
            std::fs::remove_file(&path).map_err(ctx(format!("removing {}", path.display())))?;
        }
    }
    Ok(())
}

/// Prefixes of earlier runs whose orchestrator is gone (killed, say, with SIGKILL) but
/// whose iceoryx2 files are still in `/dev/shm` or iceoryx2's directory. A run's prefix
/// names its orchestrator's pid (`scmpc<pid>x…_`), so a dead pid means a dead run.
pub fn stale_run_prefixes() -> Vec<String> {
    let mut prefixes: Vec<String> = leftover_files(PREFIX_STEM)
        .iter()
        .filter_map(|path| {
            let name = path.file_name()?.to_string_lossy().into_owned();
            let start = name.find(PREFIX_STEM)?;
            let rest = &name[start..];
            let end = rest.find('_')?;
            let prefix = &rest[..=end];
            let pid: u32 = prefix[PREFIX_STEM.len()..]
                .split('x')
                .next()?
                .parse()
                .ok()?;
            (!process_alive(pid)).then(|| prefix.to_string())
        })
        .collect();
    prefixes.sort();
    prefixes.dedup();
    prefixes
}

/// Whether process `pid` exists and is not a zombie (a killed process nobody reaped yet).
pub fn process_alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|stat| {
            stat.rsplit_once(") ")
                .map(|(_, rest)| !rest.starts_with('Z'))
        })
        .unwrap_or(false)
}

/// Paths in `/dev/shm` and iceoryx2's root directory whose names contain `prefix`: what
/// a run leaves behind (empty after a clean run).
pub fn leftover_files(prefix: &str) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![
        std::path::PathBuf::from("/dev/shm"),
        std::path::PathBuf::from("/tmp/iceoryx2"),
    ];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if entry.file_name().to_string_lossy().contains(prefix) {
                found.push(path.clone());
            }
            if entry.file_type().is_ok_and(|t| t.is_dir()) && !dir.starts_with("/dev/shm") {
                stack.push(path);
            }
        }
    }
    found
}

/// How long a process waits without any input before it reports [`StatusEvent::InputLost`]
/// and exits (the orchestrator is gone, or a producer died and was not replaced).
pub const INPUT_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(5);

/// How a run is clocked (README, "Deadlines").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunMode {
    /// Simulated time: every process waits for its inputs of the tick; deterministic.
    Lockstep,
    /// Every process paced by the monotonic wall clock with absolute deadlines.
    Realtime,
}

/// What a role process is started with.
#[derive(Debug, Clone)]
pub struct ProcessArgs {
    pub scenario: crate::Scenario,
    pub prefix: String,
    pub mode: RunMode,
    pub epoch: u32,
}

/// Why a role process stopped other than by a stop command or a signal.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error("no input for {0:?}: giving up")]
    InputLost(std::time::Duration),
    #[error("setting up: {0}")]
    Setup(String),
}

/// A role process's connection to the orchestrator: its node, the control topic it
/// obeys and the status topic it reports on.
pub struct Link {
    pub args: ProcessArgs,
    role: crate::Role,
    control: Receiver<crate::Control>,
    status: Sender<crate::Status>,
    /// Declared last: dropped after the ports above.
    pub node: Node<ipc::Service>,
}

/// What the orchestrator has said so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ControlState {
    /// Newest lockstep grant, and its publish-to-receipt latency, ns.
    pub granted: Option<(u64, u64)>,
    /// Real-time tick 0, monotonic ns.
    pub start_ns: Option<u64>,
    pub stopped: bool,
    /// A replay was asked for and not yet done (see [`ControlState::take_replay`]).
    pub replay: bool,
    /// The newest epoch schedule (`None` before the first control message).
    pub schedule: Option<EpochSchedule>,
}

impl ControlState {
    /// Whether a process of `role` with `epoch` is the one whose samples of `tick` are
    /// taken (false before the orchestrator has said, and while warming up as a
    /// replacement).
    pub fn producing(&self, role: crate::Role, epoch: u32, tick: u64) -> bool {
        self.schedule
            .is_some_and(|s| s.producer_at(role, tick) == epoch)
    }

    /// Takes one control message.
    fn apply(&mut self, c: &crate::Control, latency_ns: u64) {
        self.schedule = Some(c.epochs);
        match c.command() {
            Some(crate::ControlCommand::Grant) => self.granted = Some((c.header.tick, latency_ns)),
            Some(crate::ControlCommand::Start) => self.start_ns = Some(c.start_ns),
            Some(crate::ControlCommand::Stop) => self.stopped = true,
            Some(crate::ControlCommand::Replay) => self.replay = true,
            Some(crate::ControlCommand::Epochs) | None => {}
        }
    }

    /// Whether to replay every output now (once per request).
    pub fn take_replay(&mut self) -> bool {
        std::mem::take(&mut self.replay)
    }
}

impl Link {
    pub fn open(args: &ProcessArgs, role: crate::Role) -> Result<Link, IpcError> {
        let node = create_node(
            &args.prefix,
            &format!("{}-{}", role.as_str(), args.epoch),
            true,
        )?;
        let control = open_topic::<crate::Control>(&node, CONTROL)?.receiver()?;
        let status = open_topic::<crate::Status>(&node, STATUS)?.sender(args.epoch)?;
        Ok(Link {
            node,
            args: args.clone(),
            role,
            control,
            status,
        })
    }

    pub fn control(&self) -> &Receiver<crate::Control> {
        &self.control
    }

    /// Tells the orchestrator about this process.
    pub fn report(&self, event: crate::StatusEvent) -> Result<(), IpcError> {
        self.status.send(crate::Status {
            role: self.role as u32,
            event: event as u32,
            pid: std::process::id(),
            ..crate::Status::default()
        })
    }

    /// Takes every pending control message into `state`.
    pub fn poll_control(&self, state: &mut ControlState) -> Result<(), IpcError> {
        self.control.drain(|c, latency| state.apply(&c, latency))
    }

    /// Hot path, before taking inputs: takes pending control messages straight from
    /// shared memory (no system call) and applies a changed epoch schedule to `inputs`, so
    /// no sample is judged by a schedule older than the newest one sent before it.
    pub fn sync(&self, ctl: &mut ControlState, inputs: &[&dyn Input]) -> Result<(), IpcError> {
        let before = ctl.schedule;
        self.control.take(|c, latency| ctl.apply(&c, latency))?;
        if let Some(schedule) = ctl.schedule.filter(|s| Some(*s) != before) {
            for input in inputs {
                input.follow(schedule);
            }
        }
        Ok(())
    }

    /// After publishing: consumes the wake-ups of `inputs` and takes pending control
    /// messages. The caller must take its inputs once more before it blocks (a sample
    /// may have come just before the wake-ups were consumed). `Ok(false)`: stop.
    /// Also applies the epoch schedule and reports refused samples to the orchestrator.
    pub fn housekeeping(
        &self,
        ctl: &mut ControlState,
        inputs: &[&dyn Input],
    ) -> Result<bool, IpcError> {
        for input in inputs {
            input.clear_wakeups();
        }
        self.poll_control(ctl)?;
        for input in inputs {
            if let Some(schedule) = ctl.schedule {
                input.follow(schedule);
            }
            for (code, count) in input.take_rejections().into_iter().enumerate() {
                if count > 0 {
                    self.status.send(crate::Status {
                        role: self.role as u32,
                        event: crate::StatusEvent::Rejected as u32,
                        pid: std::process::id(),
                        detail: code as u32,
                        count,
                        ..crate::Status::default()
                    })?;
                }
            }
        }
        Ok(!ctl.stopped)
    }

    /// Waits for input; `Ok(false)` means stop (a signal). Reports and fails after
    /// [`INPUT_TIMEOUT`] without input.
    pub fn wait(
        &self,
        waitset: &WaitSet<ipc::Service>,
        timeout: Option<std::time::Duration>,
    ) -> Result<bool, ProcessError> {
        let timeout = timeout.unwrap_or(INPUT_TIMEOUT).min(INPUT_TIMEOUT);
        match wait(waitset, timeout)? {
            Wake::Input => Ok(true),
            Wake::Terminate => Ok(false),
            Wake::Timeout if timeout < INPUT_TIMEOUT => Ok(true),
            Wake::Timeout => {
                let _ = self.report(crate::StatusEvent::InputLost);
                Err(ProcessError::InputLost(INPUT_TIMEOUT))
            }
        }
    }
}

impl<T: Message> Receiver<T> {
    /// Attaches this receiver's listener to `waitset`; keep the guard while waiting.
    pub fn attach<'w>(
        &'w self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<WaitSetGuard<'w, 'w, ipc::Service>, IpcError> {
        waitset
            .attach_notification(&self.listener)
            .map_err(ctx("attaching a listener"))
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

/// Real time: how long before an expected sample a consumer starts polling for it, ns.
pub const SPIN_LEAD_NS: u64 = 50_000;
/// Real time: how long after the expected time a consumer keeps polling before it falls
/// back to blocking in its WaitSet, ns.
pub const SPIN_BUDGET_NS: u64 = 300_000;

/// Real time: sleeps until [`SPIN_LEAD_NS`] before `expected_ns`, then polls `ready` until it
/// holds or [`SPIN_BUDGET_NS`] past `expected_ns`. Waking from an event on an idle core
/// costs tens to hundreds of µs on a virtual machine; a short, scheduled spin around a
/// periodic input's known arrival time does not (measured: README, real-time latency).
pub fn spin_wait(expected_ns: u64, mut ready: impl FnMut() -> bool) -> bool {
    crate::clock::sleep_until_ns(expected_ns.saturating_sub(SPIN_LEAD_NS));
    let give_up = expected_ns + SPIN_BUDGET_NS;
    while monotonic_ns() < give_up {
        if ready() {
            return true;
        }
        std::hint::spin_loop();
    }
    ready()
}
