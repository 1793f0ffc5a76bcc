//! The one shape every role has: a [`Task`] (docs/design.md, "Roles and tasks").
//!
//! A task is a value holding a role's whole behaviour: what it takes from its inputs
//! ([`Task::hear`]), when it has what a step needs and the step itself ([`Task::step`]),
//! when it is due next ([`Task::next`]), its injected faults (a slow step is a
//! [`Publish::hold_ns`]), and the headers of its outputs. It does no I/O and reads no clock:
//! it asks the [`Context`] it is handed. Executors own the rest and are generic over the
//! trait: the in-process loop of the orchestrator, the role runtime of a process (crate
//! `runtime`, lockstep and real time) and, through the same runtime, a process on
//! another host.

use crate::messages::{Data, Message};
use crate::{Role, Validated};
use std::rc::Rc;

/// What a task is told when it is stepped: the run's time, as the executor's clock tells
/// it (times are seconds since tick 0, `t_j = j Ts / M`), and the executor's state.
pub trait Context {
    /// Whether the run's time has reached `t_s` (lockstep: the tick of `t_s` or a later
    /// one is granted).
    fn has_reached(&self, t_s: f64) -> bool;

    /// Whether the run's time is past `t_s`: an input still missing for `t_s` is not
    /// coming in time. In lockstep the time of the tick being computed is never past.
    fn is_past(&self, t_s: f64) -> bool;

    /// The inner tick the run is in (`None` before the clock has started).
    fn now_tick(&self) -> Option<u64>;

    /// How long after run time `t_s` a sample that took `production_ns` to make reaches
    /// its consumer now, ns, for a producer of period `period_s` (real time: measured;
    /// lockstep: at once within the period, else whole periods late).
    fn arrival_after_ns(&self, t_s: f64, production_ns: u64, period_s: f64) -> u64;

    /// Whether this task's outputs for `tick` are the ones its consumers take (not while
    /// it warms up as a replacement).
    fn is_active(&self, _tick: u64) -> bool {
        true
    }

    /// Whether the executor's supervisor is gone: the robot is to be brought to rest.
    fn orphaned(&self) -> bool {
        false
    }

    /// How late the newest clock event (a lockstep grant) reached the task, ns.
    fn clock_latency_ns(&self) -> u64 {
        0
    }

    /// The executor's monotonic clock, ns since an origin of its own: the one clock a task
    /// reads, to time its own computation (a plan's `solve_ns`, a route's `plan_ns`), in
    /// every executor the machine's (a computation takes the time it takes, in lockstep
    /// too: [`Context::arrival_after_ns`]).
    fn monotonic_ns(&self) -> u64 {
        monotonic_ns()
    }

    /// The goals the executor set while the run drives (a live view's client's,
    /// docs/foxglove.md): [`Goals::at`] a tick, the one in force (`None`: `robot.goal`).
    fn goals(&self) -> Goals {
        Goals::default()
    }
}

/// The newest goal set while the run drives and the one before it: since goals are set
/// at least two samples apart, the one in force at any tick is one of them, even for a
/// process that joins while the newest waits for its first tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Goals {
    pub prior: Option<GoalChange>,
    pub newest: Option<GoalChange>,
}

impl Goals {
    /// `change` set: the newest before it becomes the prior.
    pub fn set(&mut self, change: GoalChange) {
        self.prior = self.newest;
        self.newest = Some(change);
    }

    /// The goal in force at `tick` (`None`: the scenario's).
    pub fn at(&self, tick: u64) -> Option<GoalChange> {
        [self.newest, self.prior]
            .into_iter()
            .flatten()
            .find(|c| tick >= c.from_tick)
    }

    /// The goal in force at `tick`, if it is not the one `seen` (a task's serial of the
    /// goal it drives to, 0 for the scenario's): what a task retargets to, once.
    pub fn due(&self, tick: u64, seen: u32) -> Option<GoalChange> {
        self.at(tick).filter(|c| c.serial != seen)
    }
}

/// A goal set while the run drives: it replaces the goal from inner tick `from_tick` on (a
/// sample's first tick, after every process has heard of it). `serial` counts the goals
/// set, from 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalChange {
    pub serial: u32,
    pub from_tick: u64,
    pub goal: crate::Goal,
}

impl GoalChange {
    /// The `serial`th goal set while the run drives, set at inner tick `now_tick`: in force
    /// from the first tick of the sample after the next (of `inner_steps` ticks), when every
    /// role has heard of it.
    pub fn set_at(serial: u32, goal: crate::Goal, now_tick: u64, inner_steps: usize) -> GoalChange {
        let m = inner_steps.max(1) as u64;
        GoalChange {
            serial,
            from_tick: (now_tick / m + 2) * m,
            goal,
        }
    }
}

/// The machine's monotonic clock, ns since its first reading in this process
/// ([`Context::monotonic_ns`]).
pub fn monotonic_ns() -> u64 {
    static ORIGIN: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    let origin = *ORIGIN.get_or_init(std::time::Instant::now);
    u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

/// Simulated time standing at an inner tick: the lockstep clock's answers, and the
/// context of a task stepped in process ([`Context`]; every task active, never orphaned,
/// the clock heard at once). While a tick is computed its time stands at `t_j`, so no time
/// is ever *past* before every input of the tick has come, and a computation takes no
/// time unless it overruns its period ([`SimulatedTime::arrival_after_ns`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimulatedTime {
    tick: u64,
    dt_s: f64,
    goals: Goals,
}

impl SimulatedTime {
    /// The time of inner tick `tick` of `dt_s` seconds.
    pub fn at(tick: u64, dt_s: f64) -> SimulatedTime {
        SimulatedTime {
            tick,
            dt_s,
            goals: Goals::default(),
        }
    }

    /// The same time, telling of `goals` ([`Context::goals`]).
    pub fn with_goals(self, goals: Goals) -> SimulatedTime {
        SimulatedTime { goals, ..self }
    }

    fn now_s(&self) -> f64 {
        self.tick as f64 * self.dt_s
    }
}

impl Context for SimulatedTime {
    fn has_reached(&self, t_s: f64) -> bool {
        self.now_s() >= t_s
    }

    fn is_past(&self, t_s: f64) -> bool {
        self.now_s() > t_s
    }

    fn now_tick(&self) -> Option<u64> {
        Some(self.tick)
    }

    /// At once if the sample was made within its period, else `ceil(production /
    /// period)` whole periods late, so that timing violations behave as they would in
    /// real time (docs/design.md, "Deadlines and fallback").
    fn arrival_after_ns(&self, _t_s: f64, production_ns: u64, period_s: f64) -> u64 {
        let production_s = production_ns as f64 * 1e-9;
        let late_periods = if production_s <= period_s {
            0
        } else {
            (production_s / period_s).ceil() as u64
        };
        late_periods * crate::period_ns(period_s)
    }

    fn goals(&self) -> Goals {
        self.goals
    }
}

/// What a step gives, and how long its producer holds it before publishing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Publish<O> {
    pub output: O,
    /// An injected slow step (`fault.*_delay_ms`), ns: in real time the output is
    /// published this long after the step. In lockstep, where time stands still until the
    /// output comes, and in process it is published at once: a consumer that judges
    /// lateness reads the production time from the message (a plan's `injected_delay_ns`).
    pub hold_ns: u64,
}

impl<O> Publish<O> {
    /// `output`, published at once.
    pub fn now(output: O) -> Publish<O> {
        Publish { output, hold_ns: 0 }
    }
}

/// When a task is due again without being told, in run time, s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Due {
    /// When an input or a control message comes, and at the latest at the time given
    /// (`None`: only then).
    Wait(Option<f64>),
    /// The task's periodic input (the first it takes, [`RoleDecl::inputs`](crate::graph::RoleDecl::inputs)) is due at the time given
    /// (`None`: not known yet); in real time the runtime polls for it around then.
    Expect(Option<f64>),
    /// The step is due at the time given: in real time the runtime sleeps until then; in
    /// lockstep the time comes with a grant.
    At(f64),
}

/// What a warm-up asks to know whether it is to stop now (its time is over, or what it
/// warms up for has come): set once by the runtime, cloned without allocating.
pub type Cancel = Rc<dyn Fn() -> bool>;

/// Messages a step gives, in the order they are published.
pub trait Outputs: Copy {
    /// Hands every message to `publish`, in order.
    fn each(self, publish: impl FnMut(Data));
}

impl<M: Message + Into<Data>> Outputs for M {
    fn each(self, mut publish: impl FnMut(Data)) {
        publish(self.into());
    }
}

/// What a step of the plant role gives, whichever task plays it (the simulated plant, a
/// ROS 2 robot): the truth (for the record) and the measurement of one tick.
#[derive(Debug, Clone, Copy)]
pub struct PlantOutput {
    pub truth: crate::GroundTruth,
    pub measurement: crate::Measurement,
}

impl Outputs for PlantOutput {
    fn each(self, mut publish: impl FnMut(Data)) {
        publish(self.truth.into());
        publish(self.measurement.into());
    }
}

/// A role's own error (an `MpcError`, a `RobotError`), kept with its type: a caller
/// downcasts it, and the exit message prints it at the end of its chain.
pub type RoleError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Why a task could not be made, or could not go on: its role, and the role's own error as
/// the source (no reason turned into text on the way to the exit message).
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    /// [`Task::new`] failed.
    #[error("setting up the {}", .role.as_str())]
    Setup {
        role: Role,
        #[source]
        source: RoleError,
    },
    /// The task gave up ([`Task::gave_up`]): its input is as good as lost.
    #[error("the {} gave up", .role.as_str())]
    GaveUp {
        role: Role,
        /// Which of its inputs from outside the pipeline ([`Task::lost_input`]).
        input: u32,
        #[source]
        source: RoleError,
    },
}

impl TaskError {
    /// The task of `role` could not be made, for `source`.
    pub fn setup(role: Role, source: impl Into<RoleError>) -> TaskError {
        TaskError::Setup {
            role,
            source: source.into(),
        }
    }

    /// The role whose task failed.
    pub fn role(&self) -> Role {
        match self {
            TaskError::Setup { role, .. } | TaskError::GaveUp { role, .. } => *role,
        }
    }
}

/// What an executor opens and hands a task before making it: I/O outside the pipeline
/// (the robot's ROS 2 link), which may do what a task may not (block, read a clock).
/// `()` for a task that needs none.
pub trait Resources: Sized {
    /// The resources of a task of `scenario` (it may wait: the robot's first odometry).
    fn open(scenario: &Validated) -> Result<Self, TaskError>;
}

impl Resources for () {
    fn open(_scenario: &Validated) -> Result<(), TaskError> {
        Ok(())
    }
}

/// A role: a value the executor hands inputs to and steps (module docs).
pub trait Task: Sized {
    /// The role the task plays: its inputs and outputs are the role's declaration's
    /// ([`crate::graph`]).
    const ROLE: Role;
    /// What it takes: one variant per input topic its role declares.
    type Input: TryFrom<Data>;
    /// What one step gives.
    type Output: Outputs;
    /// What the executor opens for it ([`Resources`]).
    type Resources: Resources;

    /// The task of `scenario` for the process of producer epoch `epoch` (0: the first),
    /// with the `resources` the executor opened for it.
    fn new(scenario: &Validated, epoch: u32, resources: Self::Resources)
    -> Result<Self, TaskError>;

    /// Whether it takes `topic`, one of its role's declared inputs whose producer runs
    /// (all of them, unless a task leaves one out: the DFL the tracks without its
    /// gatekeeper).
    fn takes(&self, _topic: &str) -> bool {
        true
    }

    /// Whether, of `topic` (a tick topic: [`crate::graph::SAMPLE_START_TOPICS`]), it
    /// needs only the samples at sample starts to step: in lockstep those alone wake its
    /// process, and the others are taken then (the MPC's and the planner's estimates; the
    /// tracker's truths when every perception tick starts a sample).
    fn woken_at_sample_starts(&self, _topic: &str) -> bool {
        false
    }

    /// An input sample, received `latency_ns` after it was published.
    fn hear(&mut self, input: Self::Input, latency_ns: u64, context: &impl Context);

    /// The topics it takes from the other robots of a fleet (docs/fleet.md): its role's
    /// declared [`crate::graph::RoleDecl::peer_inputs`] (the tracker's and the lidar's).
    /// The executor hands their samples to [`Task::hear_peer`], each stamped with its
    /// robot's id ([`crate::Header::robot`]); a task keeps what it hears in a [`Recent`].
    fn peer_topics(&self) -> &'static [&'static str] {
        crate::graph::peer_inputs_of(Self::ROLE)
    }

    /// A sample of another robot of the fleet, of one of [`Task::peer_topics`].
    fn hear_peer(&mut self, _data: &crate::Data) {}

    /// The next output, once the task has what it needs; `None`: nothing to do now. The
    /// executor steps the task again until it says `None`.
    fn step(&mut self, context: &impl Context) -> Option<Publish<Self::Output>>;

    /// When the task is due again without being told.
    fn next(&self) -> Due;

    /// Why the task cannot go on, once it cannot (a robot whose odometry stopped): the
    /// process then reports its input lost and exits with this error
    /// ([`TaskError::GaveUp`]).
    fn gave_up(&self) -> Option<RoleError> {
        None
    }

    /// Once it gave up: which of its inputs from outside the pipeline was lost, by index
    /// (the robot: 0 its odometry, 1 its scans), for the orchestrator's `input_lost` event.
    fn lost_input(&self) -> u32 {
        0
    }

    /// Whether it warms up before its periodic input in real time ([`Task::warm_up`]).
    fn warms_up(&self) -> bool {
        false
    }

    /// A warm-up for the next step: what a process that slept finds cold (caches) is
    /// touched again, changing nothing a step computes. It stops as soon as `cancel`
    /// holds. The runtime calls it in real time only, again and again before the periodic
    /// input comes (docs/design.md, "Clocks").
    fn warm_up(&mut self, _cancel: &Cancel) {}
}

/// The perception ticks a task takes (the lidar's scans, the tracker's measurements):
/// every [`crate::Scenario::perception_ticks`]-th inner tick, each once and in order.
#[derive(Debug, Clone, Copy)]
pub struct PerceptionTicks {
    every: u64,
    dt_s: f64,
    /// The newest taken.
    last: Option<u64>,
}

impl PerceptionTicks {
    pub fn of(scenario: &crate::Scenario) -> PerceptionTicks {
        PerceptionTicks {
            every: scenario.perception_ticks(),
            dt_s: scenario.timing.dt_s(),
            last: None,
        }
    }

    /// Whether `tick` is a perception tick newer than every one taken: it is taken then.
    pub fn take(&mut self, tick: u64) -> bool {
        let new = tick.is_multiple_of(self.every) && !self.is_past(tick);
        if new {
            self.last = Some(tick);
        }
        new
    }

    /// Whether `tick` is no newer than the last taken.
    pub fn is_past(&self, tick: u64) -> bool {
        self.last.is_some_and(|last| tick <= last)
    }

    /// When the next perception tick is, s.
    pub fn next_s(&self) -> f64 {
        self.last.map_or(0, |last| last + self.every) as f64 * self.dt_s
    }
}

/// Keeps in `newest` the sample with the highest tick offered so far (a replay or a late
/// sample of an older tick does not replace a newer one).
pub fn keep_newest<T: Message>(newest: &mut Option<T>, sample: T) {
    if newest.is_none_or(|n| sample.header().tick >= n.header().tick) {
        *newest = Some(sample);
    }
}

/// A latency in the `u32` of a header, ns (saturating).
pub fn header_latency(latency_ns: u64) -> u32 {
    latency_ns.min(u64::from(u32::MAX)) as u32
}

/// Implements `TryFrom<Data>` for a task's input enum whose variants are named as
/// [`Data`]'s: `task_input!(MpcInput: Estimate, Route);`.
#[macro_export]
macro_rules! task_input {
    ($input:ident: $($variant:ident),+ $(,)?) => {
        impl TryFrom<$crate::Data> for $input {
            type Error = $crate::Data;
            fn try_from(data: $crate::Data) -> Result<Self, $crate::Data> {
                match data {
                    $($crate::Data::$variant(m) => Ok($input::$variant(m)),)+
                    other => Err(other),
                }
            }
        }
    };
}

/// A value of a tick.
pub type Stamped<T> = (u64, T);

/// The newest samples of one kind heard from another robot of a fleet, with their ticks,
/// oldest first ([`Task::hear_peer`]): as many as the robot publishes in two samples, so
/// that the newest before the taker's tick is kept however far the other robot's process
/// has run ahead (in lockstep a robot runs ahead less than a sample of the ticks at which
/// the robots start together, and a taker stepping such a tick may lag to its next
/// sample start: `2 M + 1` kept is the least that holds; in real time a role may lag by
/// a few inner ticks).
#[derive(Debug, Clone)]
pub struct Recent<T> {
    kept: std::collections::VecDeque<Stamped<T>>,
    capacity: usize,
    /// Whether one was dropped to make room.
    dropped: bool,
}

impl<T: Copy> Recent<T> {
    /// None kept yet, at most `capacity` (at least 1).
    pub fn new(capacity: usize) -> Recent<T> {
        let capacity = capacity.max(1);
        Recent {
            kept: std::collections::VecDeque::with_capacity(capacity),
            capacity,
            dropped: false,
        }
    }

    /// None kept yet, room for a sample a tick over two samples of `ticks_per_sample`.
    pub fn of_two_samples(ticks_per_sample: usize) -> Recent<T> {
        Recent::new(2 * ticks_per_sample + 2)
    }

    /// Keeps `value` of tick `tick` if it is newer than every one kept.
    pub fn push(&mut self, tick: u64, value: T) {
        if self.kept.back().is_none_or(|(newest, _)| tick > *newest) {
            if self.kept.len() == self.capacity {
                self.kept.pop_front();
                self.dropped = true;
            }
            self.kept.push_back((tick, value));
        }
    }

    /// The newest kept of a tick before `tick`; when none is, but the robot ran so far
    /// past `tick` that those before it were dropped (in real time), the oldest kept.
    /// (In lockstep a robot runs less far ahead of the tick a role steps than it keeps,
    /// so what the role takes never depends on how far the others have come: before a
    /// robot's first samples, nothing.)
    pub fn newest_before(&self, tick: u64) -> Option<Stamped<T>> {
        self.newest_two_before(tick).map(|(newest, _)| newest)
    }

    /// [`Recent::newest_before`], and the one kept before it, if any.
    pub fn newest_two_before(&self, tick: u64) -> Option<(Stamped<T>, Option<Stamped<T>>)> {
        let ran_past = self.dropped && self.kept.back().is_some_and(|(t, _)| *t > tick);
        let index = (self.kept.iter().rposition(|(t, _)| *t < tick))
            .or((ran_past && !self.kept.is_empty()).then_some(0))?;
        let before = index.checked_sub(1).map(|i| self.kept[i]);
        Some((self.kept[index], before))
    }
}

impl Recent<[f64; 2]> {
    /// Where the positions kept (m) put a robot at tick `tick` (time `time_s`, ticks of
    /// `dt_s`): the newest before it, moved on at the velocity from the one before it for
    /// at most a tick (a robot whose positions stopped coming is where it was last); `None`
    /// before any.
    pub fn position_at(&self, tick: u64, time_s: f64, dt_s: f64) -> Option<[f64; 2]> {
        let ((now, position), before) = self.newest_two_before(tick)?;
        let ahead_s = (time_s - now as f64 * dt_s).clamp(0.0, dt_s);
        Some(match before {
            Some((then, earlier)) if now > then => {
                let elapsed_s = (now - then) as f64 * dt_s;
                [0, 1].map(|a| position[a] + (position[a] - earlier[a]) / elapsed_s * ahead_s)
            }
            _ => position,
        })
    }
}

#[cfg(test)]
mod goal_tests {
    use super::*;

    #[test]
    fn the_goal_in_force_is_the_newest_whose_first_tick_has_come_and_a_task_takes_it_once() {
        let at = |x: f64| crate::Goal::at([x, 0.0]);
        let mut goals = Goals::default();
        assert_eq!(goals.at(100), None);
        goals.set(GoalChange::set_at(1, at(1.0), 15, 10));
        assert_eq!(goals.newest.unwrap().from_tick, 30);
        assert_eq!(goals.at(29), None);
        assert_eq!(goals.at(30).unwrap().serial, 1);
        goals.set(GoalChange::set_at(2, at(2.0), 45, 10));
        // A process that joins while goal 2 waits drives to goal 1 until goal 2's tick.
        assert_eq!(goals.due(50, 0).unwrap().serial, 1);
        assert_eq!(goals.due(59, 1), None);
        assert_eq!(goals.due(60, 1).unwrap().goal, at(2.0));
        assert_eq!(goals.due(61, 2), None);
    }
}

#[cfg(test)]
mod recent_tests {
    use super::Recent;

    #[test]
    fn recent_gives_the_newest_before_a_tick_and_the_oldest_when_all_are_later() {
        let mut recent = Recent::new(3);
        for tick in [3, 4, 5, 6] {
            recent.push(tick, tick);
        }
        recent.push(5, 50); // older than the newest: ignored
        assert_eq!(recent.newest_before(6), Some((5, 5)));
        assert_eq!(recent.newest_two_before(6), Some(((5, 5), Some((4, 4)))));
        assert_eq!(recent.newest_before(7), Some((6, 6)));
        assert_eq!(
            recent.newest_two_before(4),
            Some(((4, 4), None)),
            "3 was dropped: the oldest"
        );
        assert_eq!(Recent::<u64>::new(2).newest_before(9), None);
        // A robot that has run ahead from its start: nothing was before the tick.
        let mut ahead = Recent::new(3);
        ahead.push(0, 0);
        ahead.push(1, 1);
        assert_eq!(ahead.newest_before(0), None);
        assert_eq!(ahead.newest_before(1), Some((0, 0)));
    }

    #[test]
    fn a_position_is_moved_on_at_its_velocity_for_a_tick_at_most() {
        let dt = 0.005;
        let mut positions = Recent::of_two_samples(10);
        assert_eq!(positions.position_at(0, 0.0, dt), None);
        positions.push(4, [1.0, 2.0]);
        assert_eq!(positions.position_at(6, 6.0 * dt, dt), Some([1.0, 2.0]));
        positions.push(5, [1.01, 2.0]); // 2 m/s along x
        let at_6 = positions.position_at(6, 6.0 * dt, dt).unwrap();
        assert!((at_6[0] - 1.02).abs() < 1e-12 && at_6[1] == 2.0, "{at_6:?}");
        // Nothing since tick 5: a tick on, and no farther.
        assert_eq!(positions.position_at(40, 40.0 * dt, dt), Some(at_6));
    }
}
