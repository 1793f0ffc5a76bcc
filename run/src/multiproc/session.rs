//! The orchestrator's ports on the run's iceoryx2 topics, the epoch schedule it announces
//! and the run's clock, which it keeps and which bounds what its inputs accept.

use protocol::graph::{Graph, declaration};
use protocol::task::{GoalChange, Goals};
use protocol::{
    Control, ControlCommand, EpochSchedule, Header, PlantKind, Role, Scenario, Status, SwapReply,
    SwapRequest,
};
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

/// The orchestrator's ports.
pub(super) struct Session {
    pub control: Sender<Control>,
    pub status: Receiver<Status>,
    /// An input of every data topic of the run's graph, from its producer, taking its
    /// samples as [`protocol::Data`]: the orchestrator records them all.
    pub data: Vec<(&'static str, Box<dyn DataInput>)>,
    /// Live requests of `scmpc swap`, and the answers.
    pub swap_requests: Receiver<SwapRequest>,
    pub swap_replies: Sender<SwapReply>,
    /// Which producer of each role is taken, announced with every control message.
    schedule: Cell<EpochSchedule>,
    /// The goals set while the run drives, announced with every control message.
    goals: Cell<Goals>,
    clock: Rc<Clock>,
    robot: u32,
    /// The node of the ports above; declared last, so it is dropped after them.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Session {
    pub fn open(prefix: &str, scenario: &Scenario, mode: RunMode) -> Result<Session, IpcError> {
        Session::open_for(prefix, scenario, mode, protocol::FIRST_ROBOT)
    }

    /// The ports of robot `robot`'s pipeline (a fleet's: [`super::fleet`]). Only the first
    /// robot's session takes `scmpc swap`'s requests on the run's topics; the others' swap
    /// ports are their robot's own, which no tool uses (a fleet refuses swaps).
    pub fn open_for(
        prefix: &str,
        scenario: &Scenario,
        mode: RunMode,
        robot: u32,
    ) -> Result<Session, IpcError> {
        let node = ipc::create_node(prefix, "orchestrator", false)?;
        let (swap_requests, swap_replies) = match robot {
            protocol::FIRST_ROBOT => (
                open_run_topic(&node, ipc::SWAP)?.receiver()?,
                open_run_topic(&node, ipc::SWAP_REPLY)?.sender(0)?,
            ),
            _ => (
                open_topic(&node, robot, ipc::SWAP)?.receiver()?,
                open_topic(&node, robot, ipc::SWAP_REPLY)?.sender(0)?,
            ),
        };
        let mut data = Vec::new();
        for (topic, producer) in Graph::of(scenario).topics() {
            let quiet = mode == RunMode::Lockstep && comes_before_the_command(topic);
            data.push((
                topic,
                wire::data_input(&node, robot, topic, producer, quiet)?,
            ));
        }
        let session = Session {
            control: open_topic(&node, robot, ipc::CONTROL)?.sender(0)?,
            status: open_topic(&node, robot, ipc::STATUS)?.receiver()?,
            data,
            swap_requests,
            swap_replies,
            schedule: Cell::new(EpochSchedule::default()),
            goals: Cell::new(Goals::default()),
            clock: Rc::new(Clock(Cell::new(RunClock::new(
                mode,
                scenario.timing.dt_s(),
            )))),
            robot,
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
        self.robot
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

    /// Sets a new goal, for every process ([`Control::goal`]).
    pub fn set_goal(&self, change: GoalChange) -> Result<(), IpcError> {
        let mut goals = self.goals.get();
        goals.set(change);
        self.goals.set(goals);
        self.command(ControlCommand::Goal)
    }

    /// Sends `command` with the schedule, the start time of the clock, the newest goal set
    /// and, in its header, the tick granted last (a process's clock in lockstep).
    pub fn command(&self, command: ControlCommand) -> Result<(), IpcError> {
        let clock = self.clock();
        let mut control = Control {
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
        };
        control.set_goals(self.goals.get());
        self.control.send(control)
    }

    /// The orchestrator's inputs, for housekeeping.
    pub fn inputs(&self) -> impl Iterator<Item = &dyn Input> {
        self.data
            .iter()
            .map(|(_, input)| input.as_ref() as &dyn Input)
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
        (self.data.iter())
            .find(|(t, _)| *t == topic)
            .map(|(_, input)| input.as_ref() as &dyn Input)
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

/// Lockstep: whether a sample of `topic` always comes before the DFL's command of its
/// tick, which is computed from it: the truth and the measurement the plant's step gives,
/// and the estimate. The orchestrator takes those when the command, or anything else,
/// wakes it, so they need not wake it ([`Receiver::quiet`]): every notification costs its
/// publisher a system call, on the tick's path (docs/fleet.md, "Measured", "Speed").
fn comes_before_the_command(topic: &str) -> bool {
    use protocol::topics::{ESTIMATE, MEASUREMENT, TRUTH};
    [TRUTH, MEASUREMENT, ESTIMATE].contains(&topic)
}
