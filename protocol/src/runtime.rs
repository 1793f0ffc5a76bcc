//! The role runtime: the loop every role process runs, whatever its role.
//!
//! A role opens its inputs and outputs on a [`Link`] and hands [`Link::run`] its step: a
//! closure that takes what its inputs hold, computes, publishes, and says what it waits
//! for next ([`Next`]). The runtime owns the rest, in one place:
//!
//! 1. **sync**: control messages are taken straight from shared memory and a changed epoch
//!    schedule is applied to every input before the step judges a sample by it;
//! 2. **step**: the role's own work (every input sample it takes has passed the border
//!    check of [`Receiver`](crate::ipc::Receiver): run, epoch, finite, tick order);
//! 3. **housekeeping**, after the first step of a wake-up: the inputs' wake-ups are
//!    consumed, the control topic drained (stop, grants, start, replay), refused samples
//!    reported to the orchestrator, and every output replayed if the orchestrator asked.
//!    The step runs once more after it, since a sample may have come just before its
//!    wake-up was consumed;
//! 4. **wait**: block in the WaitSet (control and every input attached), or in real time
//!    poll an input around the time it is due ([`spin_wait`]); a process that hears
//!    nothing for [`INPUT_TIMEOUT`] reports [`StatusEvent::InputLost`] and exits.
//!
//! The two clocks differ only in what the step returns: in lockstep a role waits for its
//! inputs of the tick (the plant for the orchestrator's grant); in real time it is paced
//! by the run's start time ([`ControlState::at_ns`]).

use crate::clock::monotonic_ns;
use crate::ipc::{
    CONTROL, Input, IpcError, Output, Receiver, STATUS, Sender, Wake, create_node, open_topic,
    wait, waitset,
};
use crate::messages::{EpochSchedule, Message};
use crate::{Control, ControlCommand, Role, Status, StatusEvent};
use iceoryx2::prelude::*;
use std::time::Duration;

/// How long a process waits without any input before it reports [`StatusEvent::InputLost`]
/// and exits (the orchestrator is gone, or a producer died and was not replaced).
pub const INPUT_TIMEOUT: Duration = Duration::from_secs(5);

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
    pub scenario: crate::Validated,
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
    InputLost(Duration),
    #[error("setting up: {0}")]
    Setup(String),
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
    pub fn producing(&self, role: Role, epoch: u32, tick: u64) -> bool {
        self.schedule
            .is_some_and(|s| s.producer_at(role, tick) == epoch)
    }

    /// Real time: the monotonic time, ns, `offset_s` after the run's start (`None` before
    /// the orchestrator has started the clock).
    pub fn at_ns(&self, offset_s: f64) -> Option<u64> {
        self.start_ns.map(|start| start + (offset_s * 1e9) as u64)
    }

    /// Takes one control message.
    fn apply(&mut self, c: &Control, latency_ns: u64) {
        self.schedule = Some(c.epochs);
        match c.command() {
            Some(ControlCommand::Grant) => self.granted = Some((c.header.tick, latency_ns)),
            Some(ControlCommand::Start) => self.start_ns = Some(c.start_ns),
            Some(ControlCommand::Stop) => self.stopped = true,
            Some(ControlCommand::Replay) => self.replay = true,
            Some(ControlCommand::Epochs) | None => {}
        }
    }

    /// Whether to replay every output now (once per request).
    pub fn take_replay(&mut self) -> bool {
        std::mem::take(&mut self.replay)
    }
}

/// What a role's step waits for before it is called again.
pub enum Next<'a> {
    /// An input or a control message, or `timeout` (`None`: [`INPUT_TIMEOUT`]).
    Wait(Option<Duration>),
    /// Real time: `input` is due at monotonic `at_ns`; poll for it around then
    /// ([`spin_wait`]) rather than wake on its event, and block if it does not come.
    Expect { input: &'a dyn Input, at_ns: u64 },
    /// Nothing: the step paces itself (the real-time plant sleeps to its deadlines).
    Again,
}

/// A role process's connection to the orchestrator: its node, the control topic it
/// obeys and the status topic it reports on.
pub struct Link {
    role: Role,
    epoch: u32,
    control: Receiver<Control>,
    status: Sender<Status>,
    /// Declared last: dropped after the ports above.
    node: Node<ipc::Service>,
}

impl Link {
    pub fn open(args: &ProcessArgs, role: Role) -> Result<Link, IpcError> {
        let node = create_node(
            &args.prefix,
            &format!("{}-{}", role.as_str(), args.epoch),
            true,
        )?;
        let control = open_topic::<Control>(&node, CONTROL)?.receiver()?;
        let status = open_topic::<Status>(&node, STATUS)?.sender(args.epoch)?;
        Ok(Link {
            node,
            role,
            epoch: args.epoch,
            control,
            status,
        })
    }

    /// An input taking samples of topic `name` from the active process of `producer`.
    pub fn input<T: Message>(
        &self,
        name: &'static str,
        producer: Role,
    ) -> Result<Receiver<T>, IpcError> {
        open_topic::<T>(&self.node, name)?.receiver_from(producer)
    }

    /// An output publishing on topic `name` with this process's epoch.
    pub fn output<T: Message>(&self, name: &'static str) -> Result<Sender<T>, IpcError> {
        open_topic::<T>(&self.node, name)?.sender(self.epoch)
    }

    /// Tells the orchestrator about this process.
    pub fn report(&self, event: StatusEvent) -> Result<(), IpcError> {
        self.status.send(Status {
            role: self.role as u32,
            event: event as u32,
            pid: std::process::id(),
            ..Status::default()
        })
    }

    /// Runs the role until the orchestrator stops it or a signal comes (`Ok`), or until it
    /// fails (module docs). `step` is called on every wake-up with what the orchestrator
    /// has said; it takes from `inputs` and publishes on `outputs`, which the runtime
    /// attaches to its WaitSet, keeps in step with the epoch schedule and replays.
    pub fn run<'i>(
        &self,
        inputs: &[&'i dyn Input],
        outputs: &[&dyn Output],
        mut step: impl FnMut(&ControlState) -> Result<Next<'i>, ProcessError>,
    ) -> Result<(), ProcessError> {
        let waitset = waitset(true)?;
        let attach = |listener| {
            waitset
                .attach_notification(listener)
                .map_err(|e| IpcError(format!("attaching a listener: {e}")))
        };
        let _control = attach(self.control.listener())?;
        let _inputs = inputs
            .iter()
            .map(|input| attach(input.listener()))
            .collect::<Result<Vec<_>, _>>()?;
        self.report(StatusEvent::Ready)?;

        let mut ctl = ControlState::default();
        let mut cleared = false;
        loop {
            self.sync(&mut ctl, inputs)?;
            let next = step(&ctl).inspect_err(|e| {
                if matches!(e, ProcessError::InputLost(_)) {
                    let _ = self.report(StatusEvent::InputLost);
                }
            })?;
            let again = matches!(next, Next::Again);
            if !cleared || again {
                if !self.housekeeping(&mut ctl, inputs)? {
                    return Ok(());
                }
                if ctl.take_replay() {
                    for output in outputs {
                        output.replay()?;
                    }
                }
                if again && self.node.wait(Duration::ZERO).is_err() {
                    return Ok(()); // a signal
                }
                cleared = !again;
                continue;
            }
            cleared = false;
            let timeout = match next {
                Next::Wait(timeout) => timeout,
                Next::Expect { input, at_ns } => {
                    if spin_wait(at_ns, || input.has_samples()) {
                        continue;
                    }
                    None
                }
                Next::Again => unreachable!("handled above"),
            };
            if !self.wait(&waitset, timeout)? {
                return Ok(());
            }
        }
    }

    /// Takes every pending control message into `state`.
    fn poll_control(&self, state: &mut ControlState) -> Result<(), IpcError> {
        self.control.drain(|c, latency| state.apply(&c, latency))
    }

    /// Before the step: takes pending control messages straight from shared memory (no
    /// system call) and applies a changed epoch schedule to `inputs`, so no sample is
    /// judged by a schedule older than the newest one sent before it.
    fn sync(&self, ctl: &mut ControlState, inputs: &[&dyn Input]) -> Result<(), IpcError> {
        let before = ctl.schedule;
        self.control.take(|c, latency| ctl.apply(&c, latency))?;
        if let Some(schedule) = ctl.schedule.filter(|s| Some(*s) != before) {
            for input in inputs {
                input.follow(schedule);
            }
        }
        Ok(())
    }

    /// After the step: consumes the wake-ups of `inputs`, drains the control topic,
    /// applies the epoch schedule and reports refused samples. `Ok(false)`: stop.
    fn housekeeping(
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
                    self.status.send(Status {
                        role: self.role as u32,
                        event: StatusEvent::Rejected as u32,
                        pid: std::process::id(),
                        detail: code as u32,
                        count,
                        ..Status::default()
                    })?;
                }
            }
        }
        Ok(!ctl.stopped)
    }

    /// Waits for input; `Ok(false)` means stop (a signal). Reports and fails after
    /// [`INPUT_TIMEOUT`] without input.
    fn wait(
        &self,
        waitset: &WaitSet<ipc::Service>,
        timeout: Option<Duration>,
    ) -> Result<bool, ProcessError> {
        let timeout = timeout.unwrap_or(INPUT_TIMEOUT).min(INPUT_TIMEOUT);
        match wait(waitset, timeout)? {
            Wake::Input => Ok(true),
            Wake::Terminate => Ok(false),
            Wake::Timeout if timeout < INPUT_TIMEOUT => Ok(true),
            Wake::Timeout => Err(ProcessError::InputLost(INPUT_TIMEOUT)),
        }
    }
}

/// Keeps in `newest` the sample with the highest tick offered so far (a replay or a late
/// sample of an older tick does not replace a newer one).
pub fn keep_newest<T: Message>(newest: &mut Option<T>, sample: T) {
    if newest.is_none_or(|n| sample.header().tick >= n.header().tick) {
        *newest = Some(sample);
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
