//! Every message that crosses a process boundary: `#[repr(C)]`, fixed size, no heap, so
//! iceoryx2 can hand it over in shared memory without copying or serializing.
//!
//! Each carries a [`Header`] (DESIGN.md section 4). The in-process mode passes the very
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
/// `[t_k + i Ts, t_k + (i + 1) Ts)` (DESIGN.md section 3).
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
}

impl CommandMode {
    pub fn from_code(code: u32) -> Option<CommandMode> {
        Some(match code {
            0 => CommandMode::Nominal,
            1 => CommandMode::Shifted,
            2 => CommandMode::Brake,
            3 => CommandMode::ZetaGuard,
            _ => return None,
        })
    }
    pub fn as_str(self) -> &'static str {
        match self {
            CommandMode::Nominal => "nominal",
            CommandMode::Shifted => "shifted",
            CommandMode::Brake => "brake",
            CommandMode::ZetaGuard => "zeta_guard",
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
}

impl Actuation {
    pub fn mode(&self) -> Option<CommandMode> {
        CommandMode::from_code(self.mode)
    }
}

/// [`DeadlineVerdict::status`] of a plan that never reached the DFL.
pub const PLAN_MISSING: u32 = u32::MAX;

/// The DFL's judgement of one sample's deadline: plan(k) must be in its hands, solved, by
/// `t_k + Ts` (DESIGN.md section 3). Published for every sample, met or missed.
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
    /// Only the active epochs changed (a replacement process was started).
    Epochs = 3,
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
    /// Active producer epoch of each [`Role`] (by its code): consumers take only these.
    pub epochs: [u32; 4],
}

impl Control {
    pub fn command(&self) -> Option<ControlCommand> {
        Some(match self.command {
            0 => ControlCommand::Grant,
            1 => ControlCommand::Start,
            2 => ControlCommand::Stop,
            3 => ControlCommand::Epochs,
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
}

impl Role {
    pub const ALL: [Role; 4] = [Role::Plant, Role::Estimator, Role::Mpc, Role::Dfl];
    pub fn from_code(code: u32) -> Option<Role> {
        Role::ALL.into_iter().find(|r| *r as u32 == code)
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Plant => "plant",
            Role::Estimator => "estimator",
            Role::Mpc => "mpc",
            Role::Dfl => "dfl",
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

/// Why a consumer refused a sample (DESIGN.md section 4).
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    NonFinite = 0,
    TickBackwards = 1,
    WrongRun = 2,
    WrongEpoch = 3,
}

impl Rejection {
    pub const ALL: [Rejection; 4] = [
        Rejection::NonFinite,
        Rejection::TickBackwards,
        Rejection::WrongRun,
        Rejection::WrongEpoch,
    ];
    pub fn as_str(self) -> &'static str {
        match self {
            Rejection::NonFinite => "non_finite",
            Rejection::TickBackwards => "tick_backwards",
            Rejection::WrongRun => "wrong_run",
            Rejection::WrongEpoch => "wrong_epoch",
        }
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
}

/// Every message type: access to its [`Header`].
pub trait Message: Copy + core::fmt::Debug + ZeroCopySend + 'static {
    fn header(&self) -> &Header;
    fn header_mut(&mut self) -> &mut Header;
    /// Whether every floating-point value of the message is finite.
    fn all_finite(&self) -> bool;
}

fn finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

macro_rules! impl_message {
    ($($t:ty => |$m:ident| $finite:expr),* $(,)?) => {$(
        impl Message for $t {
            fn header(&self) -> &Header {
                &self.header
            }
            fn header_mut(&mut self) -> &mut Header {
                &mut self.header
            }
            fn all_finite(&self) -> bool {
                let $m = self;
                $m.header.time_s.is_finite() && $finite
            }
        }
    )*};
}

impl_message!(
    Measurement => |m| finite(&m.y),
    GroundTruth => |m| finite(&m.pose),
    Estimate => |m| finite(&m.state) && finite(&m.covariance),
    Plan => |m| {
        let n = (m.horizon as usize).min(MAX_HORIZON);
        m.v[..n].iter().all(|v| finite(v)) && m.z[..=n].iter().all(|z| finite(z))
    },
    Actuation => |m| finite(&[m.u1, m.u2, m.zeta]) && finite(&m.wheels) && finite(&m.linearizing_input) && finite(&m.v),
    DeadlineVerdict => |_m| true,
    Control => |_m| true,
    Status => |_m| true,
);
