//! The loop every role process runs, whatever its role.
//!
//! A process joins its run as a [`Member`] and hands [`Member::run`] its step
//! ([`crate::serve`] builds it from the role's task): a closure that takes what its inputs
//! hold, computes, publishes, and says what it waits for next ([`Next`]). The loop owns the
//! rest, in one place:
//!
//! 1. **sync**: control messages are taken straight from shared memory and a changed epoch
//!    schedule is applied to every input before the step judges a sample by it;
//! 2. **step**: the role's own work: it hands what its inputs hold to its task
//!    ([`protocol::task`]) and publishes what the task makes (every input sample it takes has
//!    passed the border check of [`Receiver`](crate::ipc::Receiver): run, epoch, finite,
//!    tick order); in real time the process then yields its core once, to a consumer
//!    spinning there for what it published;
//! 3. **housekeeping**, after the first step of a wake-up: the inputs' wake-ups are
//!    consumed, the control topic drained (stop, grants, start, replay), refused samples
//!    reported to the orchestrator, and every output replayed if the orchestrator asked.
//!    The step runs once more after it, since a sample may have come just before its
//!    wake-up was consumed;
//! 4. **wait**: until what the step named ([`Next`], in run time): block in the WaitSet
//!    (control and every input attached), or in real time poll an input around the time
//!    it has been coming ([`spin_wait`](crate::wait::spin_wait), [`next_arrival_lag_ns`](crate::wait::next_arrival_lag_ns)) or sleep to a
//!    deadline; in lockstep first poll shared memory for a while ([`lockstep_poll`](crate::wait::lockstep_poll)); a process that hears nothing for [`INPUT_TIMEOUT`] reports
//!    [`StatusEvent::InputLost`] and exits. A role that asks for it
//!    ([`Member::run_warming`]) is warmed up in real time shortly before an input it
//!    expects.
//!
//! The runtime owns time: a step never knows which clock runs. It asks the run's clock
//! ([`RunClock`], through [`ProcessContext`]) and names times; the runtime turns them into
//! waits (in lockstep time moves with the orchestrator's grants, so a wait for a time is a
//! wait for the next control message or input; in real time, for the wall clock).

use crate::alloc_count::{ENV_COUNT_ALLOCATIONS, allocations};
use crate::clock::{RunClock, RunMode, monotonic_ns, sleep_until_ns};
use crate::ipc::{
    CONTROL, Input, IpcError, Output, Receiver, STATUS, Sender, TickLimit, Wake, Wire, create_node,
    open_topic, output_slot, process_alive, waitset,
};
use crate::realtime::{self, Policy, Tier};
use crate::wait::{Heard, lockstep_poll, silent_since};
use crate::wakes::Wakes;
use crate::warm_up::{WarmUpPass, WarmUps};
use iceoryx2::prelude::*;
use protocol::messages::EpochSchedule;
use protocol::task::Context;
use protocol::{Control, ControlCommand, NO_PRODUCER, Rejection, Role, Status, StatusEvent};
use std::cell::Cell;
use std::rc::Rc;
use std::time::{Duration, Instant};

/// How long a process waits without any input before it reports [`StatusEvent::InputLost`]
/// and exits (the orchestrator is gone, or a producer died and was not replaced).
pub const INPUT_TIMEOUT: Duration = Duration::from_secs(5);

/// What a role process is started with.
#[derive(Debug, Clone)]
pub struct ProcessArgs {
    pub scenario: protocol::Validated,
    pub prefix: String,
    pub mode: RunMode,
    pub epoch: u32,
    /// The robot whose pipeline the process is part of: its topics' services and the
    /// robot id stamped on and checked in every sample ([`protocol::FIRST_ROBOT`] in every
    /// run today).
    pub robot: u32,
    /// The orchestrator's pid, watched (docs/design.md, "Supervision"); `None`: not watched.
    pub supervisor_pid: Option<u32>,
    /// The iceoryx2 id of the orchestrator's control publisher: control messages from
    /// any other publisher are refused. `None`: not checked.
    pub control_publisher: Option<u128>,
}

/// How often a role process looks whether its orchestrator still lives.
pub const SUPERVISOR_CHECK: Duration = Duration::from_millis(100);
/// Real time: how long a role process runs on once its orchestrator is gone, so the DFL
/// brakes the robot to rest ([`ProcessContext::orphaned`]), before it exits. In lockstep
/// nothing moves without the orchestrator's grants and a process exits at once.
pub const ORPHAN_GRACE: Duration = Duration::from_millis(1500);

/// Why a role process stopped other than by a stop command or a signal.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error("no input for {0:?}: giving up")]
    InputLost(Duration),
    /// The task could not be made, or gave up
    /// ([`Task::gave_up`](protocol::task::Task::gave_up)): its input is as good as lost.
    #[error(transparent)]
    Task(#[from] protocol::task::TaskError),
    /// The task gave a message on a topic that is not among its outputs (a defect of the
    /// task).
    #[error("the task gave a message on `{topic}`, which is not among its outputs")]
    Undeclared { topic: &'static str },
}

impl ProcessError {
    /// Whether the process lost its input (none came in time, or its task gave up), and
    /// which ([`protocol::task::Task::lost_input`]; 0 for a timeout).
    fn input_lost(&self) -> Option<u32> {
        match self {
            ProcessError::InputLost(_) => Some(0),
            ProcessError::Task(protocol::task::TaskError::GaveUp { input, .. }) => Some(*input),
            _ => None,
        }
    }
}

/// What the orchestrator has said so far, and what a step is told ([`Context`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProcessContext {
    role: Role,
    epoch: u32,
    /// The run's clock, as the grants and the start command set it.
    pub clock: RunClock,
    /// Publish-to-receipt latency of the newest grant, ns.
    pub grant_latency_ns: u64,
    /// Lockstep: the newest tick granted, as every control message carries it (a process
    /// that joins a running loop hears it before any grant of its own).
    pub heard_tick: Option<u64>,
    pub stopped: bool,
    /// A replay was asked for and not yet done (see [`ProcessContext::take_replay`]).
    pub replay: bool,
    /// The newest epoch schedule (`None` before the first control message).
    pub schedule: Option<EpochSchedule>,
    /// The orchestrator is gone: the DFL brakes, and the process exits after
    /// [`ORPHAN_GRACE`].
    pub orphaned: bool,
    /// The goals set while the run drives ([`Context::goals`]).
    pub goals: protocol::task::Goals,
}

impl ProcessContext {
    fn new(role: Role, epoch: u32, clock: RunClock) -> ProcessContext {
        ProcessContext {
            role,
            epoch,
            clock,
            grant_latency_ns: 0,
            heard_tick: None,
            stopped: false,
            replay: false,
            schedule: None,
            orphaned: false,
            goals: protocol::task::Goals::default(),
        }
    }

    /// Takes one control message.
    fn apply(&mut self, c: &Control, latency_ns: u64) {
        self.schedule = Some(c.epochs);
        self.goals = c.goals();
        self.heard_tick = self.heard_tick.max(Some(c.header.tick));
        match c.command() {
            Some(ControlCommand::Grant) => {
                self.clock.grant(c.header.tick);
                self.grant_latency_ns = latency_ns;
            }
            Some(ControlCommand::Start) => self.clock.start(c.start_ns),
            Some(ControlCommand::Stop) => self.stopped = true,
            Some(ControlCommand::Replay) => self.replay = true,
            Some(ControlCommand::Epochs | ControlCommand::Goal) | None => {}
        }
    }

    /// Whether to replay every output now (once per request).
    pub fn take_replay(&mut self) -> bool {
        std::mem::take(&mut self.replay)
    }
}

impl Context for ProcessContext {
    /// The run's monotonic clock ([`crate::clock::monotonic_ns`]: this host's, with the
    /// correction to the orchestrator's): what the resources of a task stamp their own
    /// arrivals with (the robot's odometry).
    fn monotonic_ns(&self) -> u64 {
        crate::clock::monotonic_ns()
    }

    fn goals(&self) -> protocol::task::Goals {
        self.goals
    }

    fn has_reached(&self, t_s: f64) -> bool {
        self.clock.has_reached(t_s)
    }

    fn is_past(&self, t_s: f64) -> bool {
        self.clock.is_past(t_s)
    }

    fn now_tick(&self) -> Option<u64> {
        self.clock.now_tick()
    }

    fn arrival_after_ns(&self, t_s: f64, production_ns: u64, period_s: f64) -> u64 {
        self.clock.arrival_after_ns(t_s, production_ns, period_s)
    }

    /// Whether this process's samples of `tick` are the ones taken (false before the
    /// orchestrator has said, and while warming up as a replacement).
    fn is_active(&self, tick: u64) -> bool {
        self.schedule
            .is_some_and(|s| s.producer_at(self.role, tick) == self.epoch)
    }

    fn orphaned(&self) -> bool {
        self.orphaned
    }

    fn clock_latency_ns(&self) -> u64 {
        self.grant_latency_ns
    }
}

/// What a role's step waits for before it is called again; times are run times, s
/// ([`RunClock`]).
pub enum Next<'a> {
    /// An input or a control message, and in real time at most until the time given
    /// (`None`: [`INPUT_TIMEOUT`]).
    Wait(Option<f64>),
    /// `input` is due at `at_s`: in real time poll for it around then ([`spin_wait`](crate::wait::spin_wait))
    /// rather than wake on its event, and block if it does not come; in lockstep wait.
    Expect { input: &'a dyn Input, at_s: f64 },
    /// The step is due again at `at_s`: in real time sleep until then; in lockstep wait
    /// (the time comes with a grant).
    At(f64),
}

impl<'a> Next<'a> {
    /// For a role that acts on a sample of `input` due at `at_s` (`None`: not known yet).
    pub fn expect(input: &'a dyn Input, at_s: Option<f64>) -> Self {
        match at_s {
            Some(at_s) => Next::Expect { input, at_s },
            None => Next::Wait(None),
        }
    }
}

/// Lockstep: how many ticks a sample may be ahead of the newest grant this process has
/// heard. A grant is written into each subscriber's queue in turn, so the plant can act
/// on it and the estimator and the DFL hear of the result before the orchestrator's send
/// reaches their own queue (seen once in about 40 swap runs on one core: an estimate
/// refused, the run stalled). Only one grant is ever in flight, so one tick covers it.
pub const GRANT_IN_FLIGHT: u64 = 1;

/// A role process's clock: the control topic and what it has said. Every input is bound
/// by it ([`Receiver::bound_by`]): in lockstep a sample may be as new as the newest grant
/// heard plus [`GRANT_IN_FLIGHT`], in real time as the wall clock's tick plus
/// [`TICK_SLACK`] ([`RunClock::newest_publishable`]).
struct RoleClock {
    control: Receiver<Control>,
    state: Cell<ProcessContext>,
}

impl RoleClock {
    /// Takes pending control messages straight from shared memory (no system call).
    fn take(&self) -> Result<(), IpcError> {
        let mut state = self.state.get();
        self.control.take(|c, latency| state.apply(&c, latency))?;
        self.state.set(state);
        Ok(())
    }
}

impl TickLimit for RoleClock {
    fn newest_tick(&self, refresh: bool) -> Option<u64> {
        if refresh {
            let _ = self.take();
        }
        let state = self.state.get();
        state
            .clock
            .newest_publishable(state.heard_tick.map(|t| t + GRANT_IN_FLIGHT))
    }

    fn dt_s(&self) -> f64 {
        self.state.get().clock.dt_s()
    }
}

/// When the orchestrator was last looked for, and when it was found gone
/// ([`Member::supervisor_watch`]).
struct SupervisorWatch {
    checked: Instant,
    orphaned_at: Option<Instant>,
}

/// A role process's connection to the orchestrator: its node, the control topic it
/// obeys (its clock) and the status topic it reports on.
pub struct Member {
    role: Role,
    epoch: u32,
    robot: u32,
    supervisor_pid: Option<u32>,
    /// Ticks before allocations are counted ([`ENV_COUNT_ALLOCATIONS`]): 20 samples.
    warm_up_ticks: u64,
    clock: Rc<RoleClock>,
    status: Sender<Status>,
    /// Real time: the scheduling put in force once the process is set up (`None` in
    /// lockstep).
    policy: Option<Policy>,
    /// Lockstep: whether it polls shared memory before it blocks ([`Member::poll`]).
    polls: bool,
    /// The inputs that do not wake it: in lockstep, those it takes from the tick before
    /// ([`protocol::graph::RoleDecl::from_the_tick_before`]).
    quiet_inputs: &'static [&'static str],
    lockstep: bool,
    /// `M`, which its outputs announce their sample starts by ([`Sender::with_ticks_per_sample`]).
    ticks_per_sample: u64,
    /// Declared last: dropped after the ports above.
    node: Node<ipc::Service>,
}

impl Member {
    pub fn open(args: &ProcessArgs, role: Role) -> Result<Member, IpcError> {
        crate::ipc::admit_robots(args.scenario.robot_count());
        let node = create_node(
            &args.prefix,
            &crate::ipc::node_name(args.robot, role, args.epoch),
            true,
        )?;
        let control = open_topic::<Control>(&node, args.robot, CONTROL)?;
        let declared = protocol::graph::declaration(role, args.scenario.plant.kind);
        let lockstep = args.mode == RunMode::Lockstep;
        let control = if lockstep && !declared.woken_by_grants {
            control.receiver()?.quiet() // its inputs wake it, and it takes the grant then
        } else {
            control.receiver()?
        };
        if let Some(id) = args.control_publisher {
            control.pin_to(id);
        }
        let clock = Rc::new(RoleClock {
            control,
            state: Cell::new(ProcessContext::new(
                role,
                args.epoch,
                RunClock::new(args.mode, args.scenario.timing.dt_s()),
            )),
        });
        let status = open_topic::<Status>(&node, args.robot, STATUS)?.sender(args.epoch)?;
        Ok(Member {
            node,
            role,
            epoch: args.epoch,
            robot: args.robot,
            supervisor_pid: args.supervisor_pid,
            warm_up_ticks: args.scenario.timing.first_tick(20),
            clock,
            status,
            polls: args.scenario.robot_count() == 1,
            quiet_inputs: if lockstep {
                declared.from_the_tick_before
            } else {
                &[]
            },
            lockstep,
            ticks_per_sample: args.scenario.timing.ticks_per_sample(),
            policy: (args.mode == RunMode::Realtime)
                .then(|| Policy::for_this_process(&args.scenario.realtime, Tier::of(role)).0),
        })
    }

    /// An input taking samples of topic `name` from the active process of `producer`;
    /// in lockstep woken only by the samples at sample starts if `at_sample_starts`
    /// ([`protocol::task::Task::woken_at_sample_starts`]).
    pub fn input<T: Wire>(
        &self,
        name: &'static str,
        producer: Role,
        at_sample_starts: bool,
    ) -> Result<Receiver<T>, IpcError> {
        let topic = open_topic::<T>(&self.node, self.robot, name)?;
        let mut input = if self.lockstep && at_sample_starts {
            topic.receiver_at_sample_starts(producer)?
        } else {
            topic.receiver_from(producer)?
        };
        if self.quiet_inputs.contains(&name) {
            input = input.quiet();
        }
        input.bound_by(self.clock.clone());
        Ok(input)
    }

    /// An input taking samples of topic `name` of another robot `robot` of a fleet, from
    /// whichever process publishes them: the sample's run, robot and content are checked
    /// (its producer's epochs are that robot's orchestrator session's to announce, which
    /// this process does not hear), its tick against this process's clock, in lockstep
    /// with the lead another robot may have ([`crate::ipc::MAX_TICKS_APART`]).
    pub fn peer_input<T: Wire>(
        &self,
        robot: u32,
        name: &'static str,
    ) -> Result<Receiver<T>, IpcError> {
        let input = open_topic::<T>(&self.node, robot, name)?.receiver()?;
        input.bound_by(Rc::new(crate::ipc::Ahead {
            clock: self.clock.clone(),
            ticks: if self.lockstep {
                crate::ipc::MAX_TICKS_APART
            } else {
                0
            },
        }));
        Ok(input)
    }

    /// An output publishing on topic `name` with this process's epoch.
    pub fn output<T: Wire>(&self, name: &'static str) -> Result<Sender<T>, IpcError> {
        Ok(open_topic::<T>(&self.node, self.robot, name)?
            .sender(self.epoch)?
            .with_ticks_per_sample(self.ticks_per_sample))
    }

    /// Tells the orchestrator about this process.
    pub fn report(&self, event: StatusEvent) -> Result<(), IpcError> {
        self.status.send(self.status_of(event))
    }

    fn status_of(&self, event: StatusEvent) -> Status {
        Status {
            role: self.role as u32,
            event: event as u32,
            pid: std::process::id(),
            ..Status::default()
        }
    }

    /// Ready, with the publisher of each of `outputs` its consumers are to pin
    /// ([`EpochSchedule::pin`](protocol::EpochSchedule::pin)).
    fn report_ready(&self, outputs: &[&dyn Output]) -> Result<(), IpcError> {
        let mut status = self.status_of(StatusEvent::Ready);
        for output in outputs {
            if let Some(slot) = output_slot(self.role, output.topic()) {
                status.publishers[slot] = output.publisher_id();
            }
        }
        self.status.send(status)
    }

    /// Runs the role until the orchestrator stops it or a signal comes (`Ok`), or until it
    /// fails (module docs). `step` is called on every wake-up with what the orchestrator
    /// has said; it takes from `inputs` and publishes on `outputs`, which the runtime
    /// attaches to its WaitSet, keeps in step with the epoch schedule and replays.
    pub(crate) fn run<'i>(
        &self,
        inputs: &[&'i dyn Input],
        outputs: &[&dyn Output],
        step: impl FnMut(&ProcessContext) -> Result<Next<'i>, ProcessError>,
    ) -> Result<(), ProcessError> {
        self.run_warming(inputs, outputs, step, None::<fn(u64)>)
    }

    /// [`Member::run`] for a role that idles between periodic inputs and whose step would
    /// start with cold caches after sleeping (the MPC, asleep for most of `Ts`).
    ///
    /// In real time, for each input it expects ([`Next::Expect`]), the runtime sleeps until
    /// shortly before the input comes and from there calls `warm_up` again and again, a pass
    /// of the step between two (which takes the input once it has come), until the input
    /// comes or the window ends ([`warm_up_window_ns`](crate::warm_up)). `warm_up` is given the window's end
    /// (monotonic ns) and must stop by then, and should stop as soon as the input comes
    /// (the MPC's stops its solves): what it warms fades within a millisecond, so the step
    /// is to follow it at once. Lockstep never calls it: its processes never sleep for a
    /// time, and `warm_up` may not change what the step computes.
    pub(crate) fn run_warming<'i>(
        &self,
        inputs: &[&'i dyn Input],
        outputs: &[&dyn Output],
        mut step: impl FnMut(&ProcessContext) -> Result<Next<'i>, ProcessError>,
        mut warm_up: Option<impl FnMut(u64)>,
    ) -> Result<(), ProcessError> {
        let waitset = waitset(true)?;
        let control = (self.clock.control.listener())
            .map(|listener| crate::ipc::attach(&waitset, listener))
            .transpose()?;
        let inputs_attached = inputs
            .iter()
            .filter(|input| input.listener().is_some())
            .map(|input| crate::ipc::attach_input(&waitset, *input))
            .collect::<Result<Vec<_>, _>>()?;
        // Listener 0 is the control topic's, if the process listens to it, then each
        // input's that does, in order (`housekeeping`).
        let mut wakes = Wakes::new(control.iter().chain(&inputs_attached));
        // Set up: the real-time policy before the first step (the orchestrator warned once
        // of what the machine refuses, and reads what each process runs under).
        let applied = match self.policy.as_ref().map(Policy::apply) {
            Some(Err(e)) => {
                eprintln!(
                    "scmpc {}: real-time policy not in force: {e}",
                    self.role.as_str()
                );
                None
            }
            applied => applied.and(self.policy.as_ref()),
        };
        // A task that talks Zenoh (the ROS 2 robot): the threads that bring its inputs
        // and take its outputs at the loop's priority while it runs.
        let _carriers = applied.and_then(|p| p.fifo_priority).and_then(|priority| {
            realtime::raise_threads(&realtime::ZENOH_CARRIER_THREADS, priority)
                .inspect_err(|e| {
                    eprintln!(
                        "scmpc {}: Zenoh's threads not raised: {e}",
                        self.role.as_str()
                    )
                })
                .ok()
        });
        self.report_ready(outputs)?;
        let mut warmed_up = None;
        let counting = std::env::var_os(ENV_COUNT_ALLOCATIONS).is_some();
        let result = self.drive(
            (&waitset, &mut wakes),
            inputs,
            outputs,
            &mut step,
            warm_up.as_mut(),
            || {
                if counting && warmed_up.is_none() {
                    let now = self.clock.newest_tick(false);
                    if now.is_some_and(|t| t >= self.warm_up_ticks) {
                        warmed_up = Some(allocations());
                    }
                }
            },
        );
        if let Some(before) = warmed_up {
            eprintln!(
                "scmpc {}: {} heap allocations after warm-up",
                self.role.as_str(),
                allocations() - before
            );
        }
        result
    }

    /// The loop of [`Member::run_warming`]; `each_pass` is called once per pass, after the
    /// step.
    fn drive<'i>(
        &self,
        (waitset, wakes): (&WaitSet<ipc::Service>, &mut Wakes),
        inputs: &[&'i dyn Input],
        outputs: &[&dyn Output],
        step: &mut impl FnMut(&ProcessContext) -> Result<Next<'i>, ProcessError>,
        mut warm_up: Option<&mut impl FnMut(u64)>,
        mut each_pass: impl FnMut(),
    ) -> Result<(), ProcessError> {
        let mut warm_ups = WarmUps::default();
        let mut heard = Heard {
            last_input: Instant::now(),
            taken_before: 0,
            arrival_lag_ns: 0,
            polled: None,
        };
        let mut followed = None;
        let mut cleared = false;
        let mut watch = SupervisorWatch {
            checked: Instant::now(),
            orphaned_at: None,
        };
        loop {
            self.sync(&mut followed, inputs)?;
            let next = step(&self.clock.state.get()).inspect_err(|e| {
                if let Some(input) = e.input_lost() {
                    let _ = self.status.send(Status {
                        detail: input,
                        ..self.status_of(StatusEvent::InputLost)
                    });
                }
            })?;
            each_pass();
            heard.count(inputs);
            // Real time, after a wake-up's first step (the one that publishes; the step
            // after housekeeping rarely does): give the core to whatever waits there for
            // the output (a consumer spinning for it on this core runs now, not when this
            // process next sleeps: the estimate → MPC hop p50 fell from 47-67 to 17-41 µs,
            // docs/performance.md, "Hops: where the spin starts").
            if !cleared && self.clock.state.get().clock.mode() == RunMode::Realtime {
                std::thread::yield_now();
            }
            heard.learn_lag(self.clock.state.get().clock.dt_s());
            // Off the hot path (the step has published): is the orchestrator still there?
            if !self.supervisor_watch(&mut watch) {
                return Ok(());
            }
            // In real time a step due at a time is slept to, and so is a warm-up before an
            // expected input; in lockstep a time comes with a grant, like any input.
            // Before an expected input a role warming up sleeps to its window and then,
            // pass after pass of the step (which takes the input if it has come), warms up.
            // (The pass that takes the input learns its arrival lag from it.)
            let clock = self.clock.state.get().clock;
            let (due_ns, warming) = match next {
                Next::At(at_s) => (clock.at_ns(at_s), None),
                Next::Expect { at_s, input } if warm_up.is_some() => {
                    heard.polled = clock.at_ns(at_s).map(|at_ns| (input, at_ns));
                    match warm_ups.next(&clock, at_s, heard.arrival_lag_ns, monotonic_ns()) {
                        WarmUpPass::SleepTo(from_ns) => (Some(from_ns), None),
                        WarmUpPass::WarmUp => (None, Some(input)),
                        WarmUpPass::Wait => (None, None),
                    }
                }
                _ => (None, None),
            };
            let again = due_ns.is_some() || warming.is_some();
            if !cleared || again {
                if !self.between_passes((inputs, &mut *wakes), outputs, again, due_ns)? {
                    return Ok(());
                }
                if let (Some(input), Some(warm_up)) = (warming, warm_up.as_mut()) {
                    let started_ns = monotonic_ns();
                    warm_up(warm_ups.until_ns);
                    warm_ups.warmed(started_ns, monotonic_ns(), input.has_samples());
                }
                cleared = !again;
                continue;
            }
            cleared = false;
            let Some(timeout) = heard.spin_or_timeout(&next, &clock) else {
                continue; // the expected input came
            };
            // Lockstep: the next input comes as soon as the process before this one in the
            // tick's chain has stepped, tens of µs from now; polling for it costs less than
            // a wake-up from an event (docs/performance.md, "Lockstep").
            if clock.mode() == RunMode::Lockstep && self.poll(inputs) {
                heard.last_input = Instant::now();
                continue;
            }
            if !self.wait((waitset, &mut *wakes), timeout, &mut heard.last_input)? {
                return Ok(());
            }
        }
    }

    /// Between two passes of the step: housekeeping, the replay of every output if asked,
    /// and, before a pass `again` at a time, a look for a signal and the sleep to `due_ns`
    /// (monotonic ns). `Ok(false)`: stop.
    fn between_passes(
        &self,
        (inputs, wakes): (&[&dyn Input], &mut Wakes),
        outputs: &[&dyn Output],
        again: bool,
        due_ns: Option<u64>,
    ) -> Result<bool, ProcessError> {
        let lockstep = self.clock.state.get().clock.mode() == RunMode::Lockstep;
        if !self.housekeeping(inputs, wakes, lockstep)? {
            return Ok(false);
        }
        if self.take_replay() {
            for output in outputs {
                output.replay()?;
            }
        }
        if again && self.node.wait(Duration::ZERO).is_err() {
            return Ok(false); // a signal
        }
        if let Some(at_ns) = due_ns {
            sleep_until_ns(at_ns);
        }
        Ok(true)
    }

    /// Whether the process goes on: every [`SUPERVISOR_CHECK`] it looks whether its
    /// orchestrator lives. Once it is gone, a lockstep process stops at once (nothing moves
    /// without grants); a real-time one is orphaned (the DFL brakes to rest) and stops
    /// after [`ORPHAN_GRACE`].
    fn supervisor_watch(&self, watch: &mut SupervisorWatch) -> bool {
        if let Some(since) = watch.orphaned_at {
            return since.elapsed() < ORPHAN_GRACE;
        }
        if watch.checked.elapsed() < SUPERVISOR_CHECK {
            return true;
        }
        watch.checked = Instant::now();
        if self.supervisor_pid.is_some_and(|pid| !process_alive(pid)) {
            if self.clock.state.get().clock.mode() == RunMode::Lockstep {
                return false;
            }
            watch.orphaned_at = Some(Instant::now());
            let mut state = self.clock.state.get();
            state.orphaned = true;
            self.clock.state.set(state);
        }
        true
    }

    /// Lockstep: whether a control message or an input came while polling shared memory
    /// for one ([`lockstep_poll`]).
    fn poll(&self, inputs: &[&dyn Input]) -> bool {
        self.polls
            && lockstep_poll(|| {
                self.clock.control.has_samples() || inputs.iter().any(|i| i.has_samples())
            })
    }

    /// Whether to replay every output now (once per request).
    fn take_replay(&self) -> bool {
        let mut state = self.clock.state.get();
        let replay = state.take_replay();
        self.clock.state.set(state);
        replay
    }

    /// Before the step: takes pending control messages straight from shared memory (no
    /// system call) and applies a changed epoch schedule to `inputs` (`followed`: the one
    /// applied last), so no sample is judged by a schedule older than the newest one sent
    /// before it.
    fn sync(
        &self,
        followed: &mut Option<EpochSchedule>,
        inputs: &[&dyn Input],
    ) -> Result<(), IpcError> {
        self.clock.take()?;
        let schedule = self.clock.state.get().schedule;
        if let Some(schedule) = schedule.filter(|s| Some(*s) != *followed) {
            for input in inputs {
                input.follow(schedule);
            }
            *followed = Some(schedule);
        }
        Ok(())
    }

    /// After the step: consumes the wake-ups of `inputs` and of the control topic, takes
    /// the control messages, applies the epoch schedule and reports refused samples.
    /// `Ok(false)`: stop.
    fn housekeeping(
        &self,
        inputs: &[&dyn Input],
        wakes: &mut Wakes,
        lockstep: bool,
    ) -> Result<bool, IpcError> {
        let control = self.clock.control.listener().is_some();
        let listening = inputs.iter().filter(|input| input.listener().is_some());
        for (i, input) in listening.enumerate() {
            if wakes.to_clear(lockstep, usize::from(control) + i) {
                input.clear_wakeups();
            }
        }
        if control && wakes.to_clear(lockstep, 0) {
            self.clock.control.clear_wakeups();
        }
        wakes.cleared();
        self.clock.take()?;
        let ctl = self.clock.state.get();
        for input in inputs {
            if let Some(schedule) = ctl.schedule {
                input.follow(schedule);
            }
            self.report_rejections(input.take_rejections(), input.producer())?;
        }
        // Control messages refused (another publisher than the orchestrator's, malformed).
        self.report_rejections(Input::take_rejections(&self.clock.control), None)?;
        Ok(!ctl.stopped)
    }

    /// Tells the orchestrator how many samples of `producer` (`None`: the control topic)
    /// were refused, by reason.
    fn report_rejections(
        &self,
        counts: [u64; Rejection::COUNT],
        producer: Option<Role>,
    ) -> Result<(), IpcError> {
        for (code, count) in counts.into_iter().enumerate() {
            if count > 0 {
                self.status.send(Status {
                    detail: code as u32,
                    count,
                    producer: producer.map_or(NO_PRODUCER, |r| r as u32),
                    ..self.status_of(StatusEvent::Rejected)
                })?;
            }
        }
        Ok(())
    }

    /// Waits for input, at most `timeout` and [`SUPERVISOR_CHECK`] (the orchestrator is
    /// looked at between waits); `Ok(false)` means stop (a signal). Fails after
    /// [`INPUT_TIMEOUT`] without input since `last_input` ([`silent_since`]).
    fn wait(
        &self,
        (waitset, wakes): (&WaitSet<ipc::Service>, &mut Wakes),
        timeout: Option<Duration>,
        last_input: &mut Instant,
    ) -> Result<bool, ProcessError> {
        let mut timeout = timeout.unwrap_or(INPUT_TIMEOUT).min(INPUT_TIMEOUT);
        // A process the control topic does not wake looks at it between waits too.
        if self.supervisor_pid.is_some() || self.clock.control.listener().is_none() {
            timeout = timeout.min(SUPERVISOR_CHECK);
        }
        match wakes.wait(waitset, timeout)? {
            Wake::Input => {
                *last_input = Instant::now();
                Ok(true)
            }
            Wake::Terminate => Ok(false),
            Wake::Timeout => {
                let supervised_before_start =
                    self.supervisor_pid.is_some() && !self.clock.state.get().clock.started();
                match silent_since(*last_input, Instant::now(), supervised_before_start) {
                    Some(since) => {
                        *last_input = since;
                        Ok(true)
                    }
                    None => Err(ProcessError::InputLost(INPUT_TIMEOUT)),
                }
            }
        }
    }
}
