//! The orchestrator's ports on the run's iceoryx2 topics, the epoch schedule it announces
//! and the run's clock, which it keeps and which bounds what its inputs accept.

use protocol::graph::{Graph, declaration};
use protocol::{
    Actuation, Control, ControlCommand, DeadlineVerdict, EpochSchedule, Estimate, GroundTruth,
    Header, Measurement, Plan, Role, Route, Status, SwapReply, SwapRequest, Tracks,
};
use protocol::{Data, PlantKind, Scenario};
use runtime::clock::{RunClock, RunMode};
use runtime::ipc::wire::{self, DataInput};
use runtime::ipc::{
    self, Input, IpcError, Receiver, Sender, TickLimit, open_run_topic, open_topic,
};
use std::cell::Cell;
use std::rc::Rc;

/// The run's clock as the orchestrator keeps it. Its inputs are bound by it: in lockstep a
/// sample may be as new as the tick granted last, in real time as the wall clock's tick
/// plus [`ipc::TICK_SLACK`] ([`RunClock::newest_publishable`]).
struct Clock(Cell<RunClock>);

impl TickLimit for Clock {
    fn newest_tick(&self, _refresh: bool) -> Option<u64> {
        let clock = self.0.get();
        clock.newest_publishable(clock.now_tick())
    }

    fn dt_s(&self) -> f64 {
        self.0.get().dt_s()
    }
}

/// The robot a multi-process run drives: every run has one today.
const ROBOT: u32 = protocol::FIRST_ROBOT;

/// The orchestrator's ports.
pub(super) struct Session {
    pub control: Sender<Control>,
    pub status: Receiver<Status>,
    pub truth: Receiver<GroundTruth>,
    pub measurement: Receiver<Measurement>,
    pub estimate: Receiver<Estimate>,
    pub plan: Receiver<Plan>,
    pub actuation: Receiver<Actuation>,
    pub deadline: Receiver<DeadlineVerdict>,
    pub route: Receiver<Route>,
    pub tracks: Receiver<Tracks>,
    /// The topics of the run the record has no place of its own for, and that it records
    /// as [`protocol::Data`] ([`protocol::Message::RECORDED`]): a role added as
    /// docs/design.md says needs nothing here.
    pub recorded: Vec<(&'static str, Box<dyn DataInput>)>,
    /// Live requests of `scmpc swap`, and the answers.
    pub swap_requests: Receiver<SwapRequest>,
    pub swap_replies: Sender<SwapReply>,
    /// Which producer of each role is taken, announced with every control message.
    schedule: Cell<EpochSchedule>,
    clock: Rc<Clock>,
    /// The node of the ports above; declared last, so it is dropped after them.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Session {
    pub fn open(prefix: &str, scenario: &Scenario, mode: RunMode) -> Result<Session, IpcError> {
        let node = ipc::create_node(prefix, "orchestrator", false)?;
        let robot = ROBOT;
        let mut recorded = Vec::new();
        for (topic, producer) in Graph::of(scenario).topics() {
            if !Data::recorded_names(topic).is_empty() {
                recorded.push((topic, wire::data_input(&node, robot, topic, producer)?));
            }
        }
        let session = Session {
            control: open_topic(&node, robot, ipc::CONTROL)?.sender(0)?,
            status: open_topic(&node, robot, ipc::STATUS)?.receiver()?,
            truth: open_topic(&node, robot, ipc::TRUTH)?.receiver_from(Role::Plant)?,
            measurement: open_topic(&node, robot, ipc::MEASUREMENT)?.receiver_from(Role::Plant)?,
            estimate: open_topic(&node, robot, ipc::ESTIMATE)?.receiver_from(Role::Estimator)?,
            plan: open_topic(&node, robot, ipc::PLAN)?.receiver_from(Role::Mpc)?,
            actuation: open_topic(&node, robot, ipc::ACTUATION)?.receiver_from(Role::Dfl)?,
            deadline: open_topic(&node, robot, ipc::DEADLINE)?.receiver_from(Role::Dfl)?,
            route: open_topic(&node, robot, ipc::ROUTE)?.receiver_from(Role::Planner)?,
            tracks: open_topic(&node, robot, ipc::TRACKS)?.receiver_from(Role::Tracker)?,
            recorded,
            swap_requests: open_run_topic(&node, ipc::SWAP)?.receiver()?,
            swap_replies: open_run_topic(&node, ipc::SWAP_REPLY)?.sender(0)?,
            schedule: Cell::new(EpochSchedule::default()),
            clock: Rc::new(Clock(Cell::new(RunClock::new(
                mode,
                scenario.timing.dt_s(),
            )))),
            _node: node,
        };
        for input in session.inputs() {
            input.bound_by(session.clock.clone());
            input.follow(EpochSchedule::default());
        }
        Ok(session)
    }

    /// The robot whose pipeline the session runs.
    pub fn robot(&self) -> u32 {
        ROBOT
    }

    /// The run's clock.
    pub fn clock(&self) -> RunClock {
        self.clock.0.get()
    }

    /// The epoch schedule announced last.
    pub fn schedule(&self) -> EpochSchedule {
        self.schedule.get()
    }

    /// Lockstep: grants tick `tick`.
    pub fn grant(&self, tick: u64) -> Result<(), IpcError> {
        let mut clock = self.clock();
        clock.grant(tick);
        self.clock.0.set(clock);
        self.command(ControlCommand::Grant)
    }

    /// Real time: starts the clock, tick 0 at monotonic `start_ns`.
    pub fn start(&self, start_ns: u64) -> Result<(), IpcError> {
        let mut clock = self.clock();
        clock.start(start_ns);
        self.clock.0.set(clock);
        self.command(ControlCommand::Start)
    }

    /// Tells a process that joined the running loop the clock and the schedule.
    pub fn tell_the_clock(&self) -> Result<(), IpcError> {
        match self.clock().mode() {
            RunMode::Lockstep => self.command(ControlCommand::Epochs),
            RunMode::Realtime => self.command(ControlCommand::Start),
        }
    }

    /// Sends `command` with the schedule, the start time of the clock and, in its header,
    /// the tick granted last (a process's clock in lockstep).
    pub fn command(&self, command: ControlCommand) -> Result<(), IpcError> {
        let clock = self.clock();
        self.control.send(Control {
            header: Header {
                tick: clock
                    .now_tick()
                    .filter(|_| clock.mode() == RunMode::Lockstep)
                    .unwrap_or(0),
                ..Header::default()
            },
            command: command as u32,
            start_ns: clock.at_ns(0.0).unwrap_or(0),
            epochs: self.schedule.get(),
            ..Control::default()
        })
    }

    /// The orchestrator's inputs, for housekeeping.
    pub fn inputs(&self) -> impl Iterator<Item = &dyn Input> {
        let typed: [&dyn Input; 8] = [
            &self.truth,
            &self.measurement,
            &self.estimate,
            &self.plan,
            &self.actuation,
            &self.deadline,
            &self.route,
            &self.tracks,
        ];
        let recorded = self.recorded.iter().map(|(_, i)| i.as_ref() as &dyn Input);
        typed.into_iter().chain(recorded)
    }

    /// Changes the epoch schedule, for the orchestrator and every process.
    pub fn reschedule(&self, change: impl FnOnce(&mut EpochSchedule)) -> Result<(), IpcError> {
        let mut schedule = self.schedule.get();
        change(&mut schedule);
        self.schedule.set(schedule);
        for input in self.inputs() {
            input.follow(schedule);
        }
        self.command(ControlCommand::Epochs)
    }

    /// Pins the outputs of the process of `role` and `epoch` to `publishers` (those its
    /// ready report announced, or the relays carrying it from another host), once per
    /// epoch (docs/design.md, "Supervision"), and tells every process.
    pub fn pin(&self, role: Role, epoch: u32, publishers: [u128; 2]) -> Result<(), IpcError> {
        let mut schedule = self.schedule.get();
        if schedule.pin(role, epoch, publishers) {
            self.reschedule(|now| *now = schedule)?;
        }
        Ok(())
    }

    /// The orchestrator's input carrying the output of `role`: how it sees a replacement
    /// warm up.
    pub fn output_of(&self, role: Role) -> Option<&dyn Input> {
        let topic = *declaration(role, PlantKind::Sim).outputs.first()?;
        let typed: Option<&dyn Input> = match topic {
            ipc::TRUTH => Some(&self.truth),
            ipc::ESTIMATE => Some(&self.estimate),
            ipc::PLAN => Some(&self.plan),
            ipc::ACTUATION => Some(&self.actuation),
            ipc::ROUTE => Some(&self.route),
            ipc::TRACKS => Some(&self.tracks),
            _ => None,
        };
        typed.or_else(|| {
            (self.recorded.iter())
                .find(|(t, _)| *t == topic)
                .map(|(_, i)| i.as_ref() as &dyn Input)
        })
    }

    /// Samples the orchestrator itself refused since the last call: (producer, rejection
    /// code, count).
    pub fn take_rejections(&self) -> Vec<(Option<Role>, u32, u64)> {
        let mut refused = Vec::new();
        for input in self.inputs() {
            for (code, count) in input.take_rejections().into_iter().enumerate() {
                if count > 0 {
                    refused.push((input.producer(), code as u32, count));
                }
            }
        }
        refused
    }
}
