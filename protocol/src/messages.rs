//! Every message that crosses a process boundary: `#[repr(C)]`, fixed size, no heap, so
//! iceoryx2 can hand it over in shared memory without copying or serializing.
//!
//! Each carries a [`Header`] (README, "Supervision"). The in-process mode passes the very
//! same values between the roles, so both modes share one set of semantics.

use iceoryx2::prelude::ZeroCopySend;

/// Compile-time maximum prediction horizon `N` a plan can carry.
pub const MAX_HORIZON: usize = 64;

/// Common to every message.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Header")]
pub struct Header {
    /// Inner tick `j` the message belongs to (time `j * Ts / M`).
    pub tick: u64,
    /// Simulated time of that tick, s.
    pub time_s: f64,
    /// Monotonic clock when published, ns (for per-hop latency).
    pub publish_ns: u64,
    /// Epoch of the producer: only samples of the active epoch of a role are used.
    pub epoch: u32,
    /// Publish-to-receipt latency of the input that triggered this message, ns
    /// (saturating; 0 when there was none).
    pub input_latency_ns: u32,
    /// Identifies the run (a hash of its iceoryx2 prefix): a process left over from
    /// another run on the same prefix is rejected.
    pub run_id: u32,
    pub reserved: u32,
}

/// Noisy output `y = [x, y, theta] + noise` of the plant.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Measurement")]
pub struct Measurement {
    pub header: Header,
    /// `[x_m, y_m, theta_rad]`, theta wrapped to (-pi, pi].
    pub y: [f64; 3],
}

/// The plant's true state; read only by the recorder.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::GroundTruth")]
pub struct GroundTruth {
    pub header: Header,
    /// `[x_m, y_m, theta_rad]`, theta wrapped to (-pi, pi].
    pub pose: [f64; 3],
}

/// The estimator's output: the extended state and the covariance of the pose.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Estimate")]
pub struct Estimate {
    pub header: Header,
    /// `x_bar = [x_m, y_m, theta_rad, zeta_m_s]`; zeta is the DFL's integrator state.
    pub state: [f64; 4],
    /// Covariance of `[x, y, theta]`, row-major 3x3.
    pub covariance: [f64; 9],
}

impl Estimate {
    /// Largest standard deviation of the position, m (`sigma` of the uncertainty margin).
    pub fn position_sigma(&self) -> f64 {
        self.covariance[0].max(self.covariance[4]).max(0.0).sqrt()
    }
}

/// Outcome of one MPC solve.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlanStatus {
    #[default]
    Solved = 0,
    Infeasible = 1,
    MaxIterations = 2,
    NumericalError = 3,
}

impl PlanStatus {
    pub fn from_code(code: u32) -> Option<PlanStatus> {
        Some(match code {
            0 => PlanStatus::Solved,
            1 => PlanStatus::Infeasible,
            2 => PlanStatus::MaxIterations,
            3 => PlanStatus::NumericalError,
            _ => return None,
        })
    }
    pub fn as_str(self) -> &'static str {
        match self {
            PlanStatus::Solved => "solved",
            PlanStatus::Infeasible => "infeasible",
            PlanStatus::MaxIterations => "max_iterations",
            PlanStatus::NumericalError => "numerical_error",
        }
    }
}

/// plan(k): a time-indexed input sequence. Element `i` is valid on
/// `[t_k + i Ts, t_k + (i + 1) Ts)` (README, "Deadlines").
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Plan")]
pub struct Plan {
    pub header: Header,
    /// Sample index `k` the plan was computed for.
    pub sample: u64,
    /// [`PlanStatus`] code.
    pub status: u32,
    /// Number of valid elements (the horizon `N`).
    pub horizon: u32,
    /// Wall time of the whole step (problem update, every solve), ns.
    pub solve_ns: u64,
    /// Interior-point iterations summed over the solves of this step.
    pub iterations: u32,
    /// Convex solves of this step (1 + refinements).
    pub solves: u32,
    /// Delay injected before publishing (fault injection), ns; in lockstep it counts as
    /// production time like `solve_ns`.
    pub injected_delay_ns: u64,
    /// `v_i = [xddot, yddot]`, m/s^2, for `i < horizon`.
    pub v: [[f64; 2]; MAX_HORIZON],
    /// Predicted `z_i = [x, xdot, y, ydot]` for `i <= horizon`.
    pub z: [[f64; 4]; MAX_HORIZON + 1],
}

impl Default for Plan {
    fn default() -> Self {
        Plan {
            header: Header::default(),
            sample: 0,
            status: PlanStatus::Infeasible as u32,
            horizon: 0,
            solve_ns: 0,
            iterations: 0,
            solves: 0,
            injected_delay_ns: 0,
            v: [[0.0; 2]; MAX_HORIZON],
            z: [[0.0; 4]; MAX_HORIZON + 1],
        }
    }
}

impl Plan {
    pub fn status(&self) -> Option<PlanStatus> {
        PlanStatus::from_code(self.status)
    }
    pub fn is_solved(&self) -> bool {
        self.status() == Some(PlanStatus::Solved)
    }
}

/// Most waypoints a [`Route`] carries.
pub const ROUTE_CAPACITY: usize = 64;

/// The planner's route to the goal (README, "Route planner"), published every sample:
/// the waypoints of the newest plan, from the position it was planned at to the goal.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Route")]
pub struct Route {
    pub header: Header,
    /// Sample `k` whose estimate this publication answers.
    pub sample: u64,
    /// Sample whose estimate the route was planned from (older than `sample` between
    /// replans).
    pub planned_sample: u64,
    /// [`RouteStatus`] code.
    pub status: u32,
    /// Valid waypoints (`0` with [`RouteStatus::NoRoute`]).
    pub count: u32,
    /// Plans made so far by this process (1 after the first).
    pub plans: u32,
    /// [`ReplanReason`] code of the newest plan.
    pub reason: u32,
    /// Length of the polyline through the waypoints, m.
    pub length_m: f64,
    /// Wall time of the newest plan, ns.
    pub plan_ns: u64,
    /// `[x_m, y_m]` of each waypoint, for `i < count`; the last is the goal.
    pub waypoints: [[f64; 2]; ROUTE_CAPACITY],
}

impl Default for Route {
    fn default() -> Self {
        Route {
            header: Header::default(),
            sample: 0,
            planned_sample: 0,
            status: RouteStatus::NoRoute as u32,
            count: 0,
            plans: 0,
            reason: ReplanReason::Start as u32,
            length_m: 0.0,
            plan_ns: 0,
            waypoints: [[0.0; 2]; ROUTE_CAPACITY],
        }
    }
}

impl Route {
    /// The valid waypoints.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.waypoints[..(self.count as usize).min(ROUTE_CAPACITY)]
    }
    pub fn status(&self) -> Option<RouteStatus> {
        RouteStatus::from_code(self.status)
    }
    /// Whether the route can be followed (a route of at least one segment).
    pub fn is_ok(&self) -> bool {
        self.status() == Some(RouteStatus::Ok) && self.count >= 2
    }
}

/// Whether a route was found.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RouteStatus {
    Ok = 0,
    /// The start and the goal are not connected around the grown obstacles.
    NoRoute = 1,
}

impl RouteStatus {
    pub fn from_code(code: u32) -> Option<RouteStatus> {
        [RouteStatus::Ok, RouteStatus::NoRoute]
            .into_iter()
            .find(|s| *s as u32 == code)
    }
}

/// Why the planner planned.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplanReason {
    /// The first estimate.
    Start = 0,
    /// `planner.period_s` has passed since the last plan.
    Period = 1,
    /// The robot has not moved for a while away from the goal.
    Stall = 2,
    /// The robot is farther than `planner.stray_m` from the route.
    Stray = 3,
}

impl ReplanReason {
    pub const ALL: [ReplanReason; 4] = [
        ReplanReason::Start,
        ReplanReason::Period,
        ReplanReason::Stall,
        ReplanReason::Stray,
    ];
    pub fn from_code(code: u32) -> Option<ReplanReason> {
        ReplanReason::ALL.into_iter().find(|r| *r as u32 == code)
    }
    pub fn as_str(self) -> &'static str {
        match self {
            ReplanReason::Start => "start",
            ReplanReason::Period => "period",
            ReplanReason::Stall => "stall",
            ReplanReason::Stray => "stray",
        }
    }
}

/// Where an applied command came from.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CommandMode {
    /// The element of the current sample's plan.
    #[default]
    Nominal = 0,
    /// An element of an older plan (the current one is late or failed).
    Shifted = 1,
    /// No plan covers the current time: `U2 = 0`, `U1` brakes zeta to zero.
    Brake = 2,
    /// A nominal command whose steering was zeroed by the zeta guard.
    ZetaGuard = 3,
    /// Braking because the safety check found the trajectory being flown no longer safe
    /// from the current estimate (README, "Safety"), until a new plan passes it.
    SafetyBrake = 4,
}

impl CommandMode {
    pub fn from_code(code: u32) -> Option<CommandMode> {
        Some(match code {
            0 => CommandMode::Nominal,
            1 => CommandMode::Shifted,
            2 => CommandMode::Brake,
            3 => CommandMode::ZetaGuard,
            4 => CommandMode::SafetyBrake,
            _ => return None,
        })
    }
    pub fn as_str(self) -> &'static str {
        match self {
            CommandMode::Nominal => "nominal",
            CommandMode::Shifted => "shifted",
            CommandMode::Brake => "brake",
            CommandMode::ZetaGuard => "zeta_guard",
            CommandMode::SafetyBrake => "safety_brake",
        }
    }
}

/// The DFL's command for one inner tick, held by the plant until the next one.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Actuation")]
pub struct Actuation {
    pub header: Header,
    /// Forward speed applied over the tick, m/s (the mean of zeta over the tick).
    pub u1: f64,
    /// Turn rate applied over the tick, rad/s.
    pub u2: f64,
    /// `[omega_r, omega_l]` for `(u1, u2)` through `T^-1`, rad/s.
    pub wheels: [f64; 2],
    /// `U = [U1, U2]` of the linearizing law (eq. 1101), after the guard.
    pub linearizing_input: [f64; 2],
    /// The DFL's zeta at the end of the tick, m/s.
    pub zeta: f64,
    /// `v` in use, m/s^2 (zero while braking).
    pub v: [f64; 2],
    /// [`CommandMode`] code.
    pub mode: u32,
    /// The DFL's live count of deadline misses so far.
    pub deadline_misses: u32,
    /// Sample of the plan the command came from (meaningless while braking).
    pub plan_sample: u64,
    /// [`Intervention`] code of what the safety check did at this tick.
    pub intervention: u32,
    /// The DFL's live count of safety interventions so far.
    pub safety_interventions: u32,
    /// With an intervention: the plan it concerns (refused, or the one given up).
    pub intervention_plan: u64,
    /// With an intervention: how far the trajectory checked entered an inflated obstacle,
    /// m (negative clearance).
    pub intervention_clearance_m: f64,
}

impl Actuation {
    pub fn mode(&self) -> Option<CommandMode> {
        CommandMode::from_code(self.mode)
    }
    pub fn intervention(&self) -> Option<Intervention> {
        Intervention::from_code(self.intervention)
    }
}

/// What the DFL's safety check did at a tick (README, "Safety").
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Intervention {
    #[default]
    None = 0,
    /// A solved plan was not committed: flown from the current estimate and followed by
    /// the brake, it would enter an inflated obstacle. The trajectory already committed
    /// goes on.
    PlanRefused = 1,
    /// The committed trajectory, flown from the current estimate, would enter an inflated
    /// obstacle: the DFL brakes at once (or, should braking from there enter one deeper,
    /// flies the trajectory on; reported once per plan).
    CommittedUnsafe = 2,
}

impl Intervention {
    pub fn from_code(code: u32) -> Option<Intervention> {
        Some(match code {
            0 => Intervention::None,
            1 => Intervention::PlanRefused,
            2 => Intervention::CommittedUnsafe,
            _ => return None,
        })
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Intervention::None => "none",
            Intervention::PlanRefused => "plan_refused",
            Intervention::CommittedUnsafe => "committed_unsafe",
        }
    }
}

/// [`DeadlineVerdict::status`] of a plan that never reached the DFL.
pub const PLAN_MISSING: u32 = u32::MAX;

/// The DFL's judgement of one sample's deadline: plan(k) must be in its hands, solved, by
/// `t_k + Ts` (README, "Deadlines"). Published for every sample, met or missed.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::DeadlineVerdict")]
pub struct DeadlineVerdict {
    pub header: Header,
    /// The sample `k` judged.
    pub sample: u64,
    /// 1 if the deadline was met.
    pub met: u32,
    /// [`PlanStatus`] code of plan(k), or [`PLAN_MISSING`].
    pub status: u32,
    /// The plan's solve time plus injected delay, ns (0 if missing).
    pub production_ns: u64,
    /// When plan(k) reached the DFL after `t_k`, ns (`u64::MAX` if missing).
    pub arrival_ns: u64,
    /// [`CommandMode`] of the first command of sample k: the fallback used on a miss.
    pub fallback: u32,
    /// Misses so far, this one included.
    pub misses_total: u32,
}

/// What the orchestrator tells every process.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlCommand {
    /// Lockstep: the plant may publish tick `header.tick`.
    Grant = 0,
    /// Real time: tick 0 is at monotonic time `start_ns`.
    Start = 1,
    /// The run is over: exit cleanly.
    Stop = 2,
    /// Only the epoch schedule changed (a process was restarted or is being swapped).
    Epochs = 3,
    /// Every producer publishes its newest sample of each output again, so a process that
    /// joined a running loop (a restart, a replacement) gets what it missed; consumers
    /// skip ticks they have already handled.
    Replay = 4,
}

/// The orchestrator's clock and commands.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Control")]
pub struct Control {
    pub header: Header,
    /// [`ControlCommand`] code.
    pub command: u32,
    pub reserved: u32,
    /// Monotonic time of tick 0 (real time), ns.
    pub start_ns: u64,
    /// Which producer of each role consumers take, tick by tick.
    pub epochs: EpochSchedule,
}

/// Which producer epoch of each [`Role`] (indexed by its code) consumers take, tick by
/// tick (README, "Supervision"). A swap-in replacement is announced as `next` while it warms
/// up: its samples are neither used nor counted as rejected. Once `switch_tick` is set,
/// samples of ticks before it are taken from `active` and from it on from `next`, so the
/// hand-over happens at one sample boundary in every process alike. The schedule stays so
/// after the swap: the old producer's late samples are skipped, not rejected.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("scmpc::EpochSchedule")]
pub struct EpochSchedule {
    pub active: [u32; Role::COUNT],
    /// The replacement being started, or the same as `active` when there is none.
    pub next: [u32; Role::COUNT],
    /// First tick taken from `next`; [`SWITCH_UNSCHEDULED`] while it warms up.
    pub switch_tick: [u64; Role::COUNT],
    /// The iceoryx2 publisher of each output of `active` (by role, then by the output's
    /// slot, [`output_slot`](crate::ipc::output_slot)), as the process announced it when it
    /// joined; 0 while not known. A sample from another publisher is refused.
    pub active_publishers: [[u128; 2]; Role::COUNT],
    /// The same for `next`.
    pub next_publishers: [[u128; 2]; Role::COUNT],
}

/// `switch_tick` of a replacement that is still warming up.
pub const SWITCH_UNSCHEDULED: u64 = u64::MAX;

/// What a consumer does with a sample of a given producer epoch and tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpochVerdict {
    Take,
    /// From a producer being swapped in (before its switch) or out (after it): not used,
    /// not an error.
    Standby,
    Reject,
}

impl Default for EpochSchedule {
    /// Epoch 0 of every role, no replacement.
    fn default() -> Self {
        EpochSchedule {
            active: [0; Role::COUNT],
            next: [0; Role::COUNT],
            switch_tick: [SWITCH_UNSCHEDULED; Role::COUNT],
            active_publishers: [[0; 2]; Role::COUNT],
            next_publishers: [[0; 2]; Role::COUNT],
        }
    }
}

impl EpochSchedule {
    /// The producer epoch whose samples of `tick` are taken.
    pub fn producer_at(&self, role: Role, tick: u64) -> u32 {
        let r = role as usize;
        if tick >= self.switch_tick[r] {
            self.next[r]
        } else {
            self.active[r]
        }
    }

    /// How a consumer treats a sample of `role` from `epoch` for `tick`.
    pub fn judge(&self, role: Role, epoch: u32, tick: u64) -> EpochVerdict {
        let r = role as usize;
        if epoch == self.producer_at(role, tick) {
            EpochVerdict::Take
        } else if epoch == self.active[r] || epoch == self.next[r] {
            EpochVerdict::Standby
        } else {
            EpochVerdict::Reject
        }
    }

    /// Makes `epoch` the only producer of `role`, for every tick (a restart, or a
    /// replacement that takes over at once because the process it replaces died).
    pub fn activate(&mut self, role: Role, epoch: u32) {
        let r = role as usize;
        let pins = self.pins(role, epoch).unwrap_or_default();
        self.active_publishers[r] = pins;
        self.next_publishers[r] = pins;
        self.active[r] = epoch;
        self.next[r] = epoch;
        self.switch_tick[r] = SWITCH_UNSCHEDULED;
    }

    /// The epoch producing the newest ticks of `role`.
    pub fn current(&self, role: Role) -> u32 {
        let r = role as usize;
        if self.switch_tick[r] == SWITCH_UNSCHEDULED {
            self.active[r]
        } else {
            self.next[r]
        }
    }

    /// Announces `epoch` as the replacement of the current producer of `role`, warming up.
    /// (The producer an earlier swap replaced is forgotten: its samples are rejected.)
    pub fn announce(&mut self, role: Role, epoch: u32) {
        let r = role as usize;
        let current = self.current(role);
        self.active_publishers[r] = self.pins(role, current).unwrap_or_default();
        self.next_publishers[r] = [0; 2];
        self.active[r] = current;
        self.next[r] = epoch;
        self.switch_tick[r] = SWITCH_UNSCHEDULED;
    }

    /// The publishers of `epoch` of `role` by output slot (0: not known yet), if `epoch` is
    /// named for the role.
    fn pins(&self, role: Role, epoch: u32) -> Option<[u128; 2]> {
        let r = role as usize;
        if epoch == self.next[r] {
            Some(self.next_publishers[r])
        } else if epoch == self.active[r] {
            Some(self.active_publishers[r])
        } else {
            None
        }
    }

    /// Pins the outputs of `epoch` of `role` to the publishers it announced, once: an
    /// epoch already pinned keeps its publishers (a second announcement is someone else's).
    /// Whether anything changed.
    pub fn pin(&mut self, role: Role, epoch: u32, publishers: [u128; 2]) -> bool {
        let r = role as usize;
        if self.pins(role, epoch) != Some([0; 2]) || publishers == [0; 2] {
            return false;
        }
        if epoch == self.active[r] {
            self.active_publishers[r] = publishers;
        }
        if epoch == self.next[r] {
            self.next_publishers[r] = publishers;
        }
        true
    }

    /// The publisher that output `slot` of `epoch` of `role` was pinned to, if known.
    pub fn publisher(&self, role: Role, epoch: u32, slot: usize) -> Option<u128> {
        let id = self.pins(role, epoch)?.get(slot).copied()?;
        (id != 0).then_some(id)
    }

    /// Takes the replacement of `role` from `tick` on.
    pub fn schedule_switch(&mut self, role: Role, tick: u64) {
        self.switch_tick[role as usize] = tick;
    }

    /// Calls off the switch of `role`: the active producer stays; the replacement's
    /// samples are still skipped, not rejected, as it may have some in flight.
    pub fn unschedule(&mut self, role: Role) {
        self.switch_tick[role as usize] = SWITCH_UNSCHEDULED;
    }
}

impl Control {
    pub fn command(&self) -> Option<ControlCommand> {
        Some(match self.command {
            0 => ControlCommand::Grant,
            1 => ControlCommand::Start,
            2 => ControlCommand::Stop,
            3 => ControlCommand::Epochs,
            4 => ControlCommand::Replay,
            _ => return None,
        })
    }
}

/// The four roles of a run.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Role {
    Plant = 0,
    Estimator = 1,
    Mpc = 2,
    Dfl = 3,
    /// The route planner (README, "Route planner"): only in runs with `planner.kind =
    /// "route"`.
    Planner = 4,
}

impl Role {
    /// How many roles there are (the length of per-role arrays).
    pub const COUNT: usize = 5;
    pub const ALL: [Role; Role::COUNT] = [
        Role::Plant,
        Role::Estimator,
        Role::Mpc,
        Role::Dfl,
        Role::Planner,
    ];
    pub fn from_code(code: u32) -> Option<Role> {
        Role::ALL.into_iter().find(|r| *r as u32 == code)
    }
    pub fn from_name(name: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.as_str() == name)
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Plant => "plant",
            Role::Estimator => "estimator",
            Role::Mpc => "mpc",
            Role::Dfl => "dfl",
            Role::Planner => "planner",
        }
    }
}

/// What a process reports to the orchestrator.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusEvent {
    /// Every port is open: the process can take part in the run.
    Ready = 0,
    /// No input arrived within the input timeout; the process exits.
    InputLost = 1,
    /// Samples were rejected: `detail` is the [`Rejection`] code, `count` how many.
    Rejected = 2,
}

impl StatusEvent {
    pub fn from_code(code: u32) -> Option<StatusEvent> {
        [
            StatusEvent::Ready,
            StatusEvent::InputLost,
            StatusEvent::Rejected,
        ]
        .into_iter()
        .find(|e| *e as u32 == code)
    }
}

/// Why a consumer refused a sample (README, "Supervision").
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    NonFinite = 0,
    TickBackwards = 1,
    WrongRun = 2,
    WrongEpoch = 3,
    /// A tick its producer cannot have reached yet: ahead of the clock (the lockstep grant,
    /// or the real-time clock's tick plus [`TICK_SLACK`](crate::ipc::TICK_SLACK)).
    TickAhead = 4,
    /// A time that is not its tick's (`tick Ts / M`).
    TimeMismatch = 5,
    /// From an iceoryx2 publisher other than the one the producer announced when it joined
    /// (or, on the control topic, than the orchestrator's).
    UnknownPublisher = 6,
    /// A code, count or length outside what the message type allows
    /// ([`Message::well_formed`]).
    Malformed = 7,
}

impl Rejection {
    pub const COUNT: usize = 8;
    pub const ALL: [Rejection; Rejection::COUNT] = [
        Rejection::NonFinite,
        Rejection::TickBackwards,
        Rejection::WrongRun,
        Rejection::WrongEpoch,
        Rejection::TickAhead,
        Rejection::TimeMismatch,
        Rejection::UnknownPublisher,
        Rejection::Malformed,
    ];
    pub fn as_str(self) -> &'static str {
        match self {
            Rejection::NonFinite => "non_finite",
            Rejection::TickBackwards => "tick_backwards",
            Rejection::WrongRun => "wrong_run",
            Rejection::WrongEpoch => "wrong_epoch",
            Rejection::TickAhead => "tick_ahead",
            Rejection::TimeMismatch => "time_mismatch",
            Rejection::UnknownPublisher => "unknown_publisher",
            Rejection::Malformed => "malformed",
        }
    }

    /// Whether the refusal is the fault of the sample's own producer (its run, epoch and
    /// publisher were right): what counts towards its failure
    /// (README, "Supervision"). A stranger's samples never do.
    pub fn blames_producer(self) -> bool {
        !matches!(
            self,
            Rejection::WrongRun | Rejection::WrongEpoch | Rejection::UnknownPublisher
        )
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("scmpc::Status")]
pub struct Status {
    pub header: Header,
    /// [`Role`] code.
    pub role: u32,
    /// [`StatusEvent`] code.
    pub event: u32,
    pub pid: u32,
    /// [`Rejection`] code for [`StatusEvent::Rejected`].
    pub detail: u32,
    pub count: u64,
    /// [`StatusEvent::Rejected`]: the [`Role`] code of the producer refused, or
    /// [`NO_PRODUCER`] (the control topic).
    pub producer: u32,
    pub reserved: u32,
    /// [`StatusEvent::Ready`]: the iceoryx2 publisher of each of the role's outputs, by
    /// [`output_slot`](crate::ipc::output_slot) (0: none).
    pub publishers: [u128; 2],
}

/// [`Status::producer`] of refused samples of a topic without a producer role (control).
pub const NO_PRODUCER: u32 = u32::MAX;

/// Longest command line a live swap request carries, bytes (arguments NUL-terminated).
pub const MAX_COMMAND_BYTES: usize = 1024;
/// Longest message of a swap reply, bytes.
pub const MAX_REPLY_BYTES: usize = 256;

/// `scmpc swap` to the orchestrator: replace `role` by a process started with `command`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("scmpc::SwapRequest")]
pub struct SwapRequest {
    pub header: Header,
    /// Chosen by the requester; the reply carries it back.
    pub request_id: u64,
    /// [`Role`] code.
    pub role: u32,
    /// Bytes of `command` used.
    pub command_len: u32,
    /// Program and arguments, each NUL-terminated; empty: the built-in process of the role.
    pub command: [u8; MAX_COMMAND_BYTES],
}

impl Default for SwapRequest {
    fn default() -> Self {
        SwapRequest {
            header: Header::default(),
            request_id: 0,
            role: 0,
            command_len: 0,
            command: [0; MAX_COMMAND_BYTES],
        }
    }
}

impl SwapRequest {
    /// A request; `None` if the command line does not fit in [`MAX_COMMAND_BYTES`] or an
    /// argument holds a NUL byte.
    pub fn new(request_id: u64, role: Role, command: &[String]) -> Option<SwapRequest> {
        let mut request = SwapRequest {
            request_id,
            role: role as u32,
            ..SwapRequest::default()
        };
        let mut at = 0;
        for arg in command {
            let bytes = arg.as_bytes();
            if bytes.contains(&0) || at + bytes.len() + 1 > MAX_COMMAND_BYTES {
                return None;
            }
            request.command[at..at + bytes.len()].copy_from_slice(bytes);
            at += bytes.len() + 1;
        }
        request.command_len = at as u32;
        Some(request)
    }

    /// Whether the command fits and is empty or UTF-8 arguments, each NUL-terminated.
    fn command_is_well_formed(&self) -> bool {
        let len = self.command_len as usize;
        len <= MAX_COMMAND_BYTES
            && (len == 0 || self.command[len - 1] == 0)
            && std::str::from_utf8(&self.command[..len]).is_ok()
    }

    /// The command's program and arguments.
    pub fn command(&self) -> Vec<String> {
        let len = (self.command_len as usize).min(MAX_COMMAND_BYTES);
        self.command[..len]
            .strip_suffix(&[0])
            .map_or_else(Vec::new, |args| {
                args.split(|b| *b == 0)
                    .map(|arg| String::from_utf8_lossy(arg).into_owned())
                    .collect()
            })
    }
}

/// The orchestrator's answer to a [`SwapRequest`], once the swap is done or has failed.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("scmpc::SwapReply")]
pub struct SwapReply {
    pub header: Header,
    pub request_id: u64,
    /// 1: the replacement is active; 0: the swap failed, the old process still runs.
    pub done: u32,
    /// Epoch of the replacement.
    pub epoch: u32,
    /// First tick taken from the replacement.
    pub switch_tick: u64,
    /// The iceoryx2 publisher of the request answered: the client that asked takes only
    /// the replies addressed to it.
    pub requester: u128,
    pub message_len: u32,
    pub reserved: u32,
    /// What happened, UTF-8.
    pub message: [u8; MAX_REPLY_BYTES],
}

impl Default for SwapReply {
    fn default() -> Self {
        SwapReply {
            header: Header::default(),
            request_id: 0,
            done: 0,
            epoch: 0,
            switch_tick: 0,
            requester: 0,
            message_len: 0,
            reserved: 0,
            message: [0; MAX_REPLY_BYTES],
        }
    }
}

impl SwapReply {
    /// Sets the message, cut to [`MAX_REPLY_BYTES`] at a character boundary.
    pub fn with_message(mut self, text: &str) -> SwapReply {
        let mut end = text.len().min(MAX_REPLY_BYTES);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        self.message[..end].copy_from_slice(&text.as_bytes()[..end]);
        self.message_len = end as u32;
        self
    }

    pub fn message(&self) -> String {
        let len = (self.message_len as usize).min(MAX_REPLY_BYTES);
        String::from_utf8_lossy(&self.message[..len]).into_owned()
    }
}

/// Every message type: access to its [`Header`].
pub trait Message: Copy + core::fmt::Debug + ZeroCopySend + 'static {
    fn header(&self) -> &Header;
    fn header_mut(&mut self) -> &mut Header;
    /// Whether every floating-point value of the message is finite.
    fn all_finite(&self) -> bool;
    /// Whether every code, count and length is one the type allows.
    fn well_formed(&self) -> bool;

    /// What a consumer refuses in the message's content, if anything (the border check's
    /// content rule, applied by every executor).
    fn content_rejection(&self) -> Option<crate::Rejection> {
        if !self.all_finite() {
            Some(crate::Rejection::NonFinite)
        } else if !self.well_formed() {
            Some(crate::Rejection::Malformed)
        } else {
            None
        }
    }
}

fn finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

macro_rules! impl_message {
    ($($t:ty => |$m:ident| $finite:expr, $formed:expr);* $(;)?) => {$(
        impl Message for $t {
            fn header(&self) -> &Header {
                &self.header
            }
            fn header_mut(&mut self) -> &mut Header {
                &mut self.header
            }
            fn all_finite(&self) -> bool {
                #[allow(unused_variables)]
                let $m = self;
                $m.header.time_s.is_finite() && $finite
            }
            fn well_formed(&self) -> bool {
                #[allow(unused_variables)]
                let $m = self;
                $formed
            }
        }
    )*};
}

impl_message!(
    Measurement => |m| finite(&m.y), true;
    GroundTruth => |m| finite(&m.pose), true;
    Estimate => |m| finite(&m.state) && finite(&m.covariance), true;
    Plan => |m| {
        let n = (m.horizon as usize).min(MAX_HORIZON);
        m.v[..n].iter().all(|v| finite(v)) && m.z[..=n].iter().all(|z| finite(z))
    }, m.horizon as usize <= MAX_HORIZON && PlanStatus::from_code(m.status).is_some();
    Actuation => |m| {
        finite(&[m.u1, m.u2, m.zeta]) && finite(&m.wheels) && finite(&m.linearizing_input) && finite(&m.v)
    }, CommandMode::from_code(m.mode).is_some() && Intervention::from_code(m.intervention).is_some();
    DeadlineVerdict => |m| true, m.met <= 1
        && (m.status == PLAN_MISSING || PlanStatus::from_code(m.status).is_some())
        && CommandMode::from_code(m.fallback).is_some();
    Route => |m| m.length_m.is_finite() && m.points().iter().all(|p| finite(p)),
        m.count as usize <= ROUTE_CAPACITY && ReplanReason::from_code(m.reason).is_some()
            && match m.status() {
                Some(RouteStatus::Ok) => m.count >= 2,
                Some(RouteStatus::NoRoute) => m.count == 0,
                None => false,
            };
    Control => |m| true, m.command().is_some();
    Status => |m| true, Role::from_code(m.role).is_some()
        && StatusEvent::from_code(m.event).is_some()
        && (m.event != StatusEvent::Rejected as u32
            || (m.detail as usize) < Rejection::COUNT
                && (m.producer == NO_PRODUCER || Role::from_code(m.producer).is_some()));
    SwapRequest => |m| true, Role::from_code(m.role).is_some() && m.command_is_well_formed();
    SwapReply => |m| true, m.done <= 1 && m.message_len as usize <= MAX_REPLY_BYTES;
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replacement_is_standby_while_warming_and_takes_over_at_its_switch_tick() {
        let mut s = EpochSchedule::default();
        assert_eq!(s.judge(Role::Mpc, 0, 100), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 7, 100), EpochVerdict::Reject);
        s.announce(Role::Mpc, 1);
        assert_eq!(s.judge(Role::Mpc, 0, 100), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 1, 100), EpochVerdict::Standby);
        s.schedule_switch(Role::Mpc, 200);
        assert_eq!(s.judge(Role::Mpc, 0, 199), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 1, 199), EpochVerdict::Standby);
        assert_eq!(s.judge(Role::Mpc, 1, 200), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 0, 200), EpochVerdict::Standby);
        // Other roles are untouched.
        assert_eq!(s.judge(Role::Estimator, 1, 200), EpochVerdict::Reject);
        // The next swap replaces the producer of the newest ticks.
        assert_eq!(s.current(Role::Mpc), 1);
        s.announce(Role::Mpc, 2);
        assert_eq!(s.judge(Role::Mpc, 1, 500), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 0, 500), EpochVerdict::Reject);
        s.schedule_switch(Role::Mpc, 600);
        s.unschedule(Role::Mpc);
        assert_eq!(s.judge(Role::Mpc, 1, 700), EpochVerdict::Take);
        assert_eq!(s.judge(Role::Mpc, 2, 700), EpochVerdict::Standby);
        s.activate(Role::Mpc, 3);
        assert_eq!(s.judge(Role::Mpc, 1, 700), EpochVerdict::Reject);
        assert_eq!(s.judge(Role::Mpc, 3, 0), EpochVerdict::Take);
    }

    #[test]
    fn codes_counts_and_lengths_outside_their_type_are_malformed() {
        let verdict = DeadlineVerdict {
            status: PLAN_MISSING,
            ..DeadlineVerdict::default()
        };
        assert!(verdict.well_formed());
        for bad in [
            DeadlineVerdict { met: 2, ..verdict },
            DeadlineVerdict {
                status: 17,
                ..verdict
            },
            DeadlineVerdict {
                fallback: 99,
                ..verdict
            },
        ] {
            assert!(!bad.well_formed(), "{bad:?}");
        }
        let plan = Plan {
            status: PlanStatus::Solved as u32,
            horizon: 8,
            ..Plan::default()
        };
        assert!(plan.well_formed());
        assert!(
            !Plan {
                horizon: MAX_HORIZON as u32 + 1,
                ..plan
            }
            .well_formed()
        );
        assert!(!Plan { status: 9, ..plan }.well_formed());
        let request = SwapRequest::new(1, Role::Mpc, &["scmpc".into(), "mpc".into()]).unwrap();
        assert!(request.well_formed());
        assert!(!SwapRequest { role: 9, ..request }.well_formed());
        // A command that does not end in NUL, or runs past the buffer.
        assert!(
            !SwapRequest {
                command_len: 4,
                ..request
            }
            .well_formed()
        );
        assert!(
            !SwapRequest {
                command_len: MAX_COMMAND_BYTES as u32 + 1,
                ..request
            }
            .well_formed()
        );
        let status = Status {
            event: StatusEvent::Rejected as u32,
            detail: Rejection::Malformed as u32,
            producer: NO_PRODUCER,
            ..Status::default()
        };
        assert!(status.well_formed());
        assert!(
            !Status {
                detail: Rejection::COUNT as u32,
                ..status
            }
            .well_formed()
        );
        assert!(!Status { event: 7, ..status }.well_formed());
        assert!(
            !Control {
                command: 5,
                ..Control::default()
            }
            .well_formed()
        );
    }

    #[test]
    fn a_swap_request_carries_its_command_line_exactly() {
        let command: Vec<String> = ["scmpc", "mpc", "--set", "mpc.horizon=10", ""]
            .map(String::from)
            .to_vec();
        let request = SwapRequest::new(7, Role::Mpc, &command).unwrap();
        assert_eq!(request.command(), command);
        assert!(
            SwapRequest::new(7, Role::Mpc, &[])
                .unwrap()
                .command()
                .is_empty()
        );
        assert!(SwapRequest::new(7, Role::Mpc, &["a\0b".into()]).is_none());
        let long = vec!["x".repeat(MAX_COMMAND_BYTES)];
        assert!(SwapRequest::new(7, Role::Mpc, &long).is_none());
    }

    #[test]
    fn a_swap_reply_message_is_cut_at_a_character_boundary() {
        let text = "é".repeat(MAX_REPLY_BYTES);
        let reply = SwapReply::default().with_message(&text);
        assert_eq!(reply.message(), "é".repeat(MAX_REPLY_BYTES / 2));
    }
}
