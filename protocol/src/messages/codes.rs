//! The codes the data messages carry: a plan's status, a route's status, why it was
//! planned and why it replaced the one before, the DFL's command mode and its safety
//! check's intervention.

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

/// Why a replan's route replaced the route before it (a periodic replan keeps the route
/// otherwise; docs/planner.md, "Replanning").
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RouteSwitch {
    /// Always taken: the first route, and the replans on a stall or a stray.
    Replanned = 0,
    /// Round the obstacles the same way as the route before, and shorter than what is
    /// left of it.
    SameWay = 1,
    /// Another way round, shorter than what is left of the route before by
    /// `planner.switch_margin` of it.
    Shorter = 2,
    /// The route before is blocked now.
    Blocked = 3,
}

impl RouteSwitch {
    pub const ALL: [RouteSwitch; 4] = [
        RouteSwitch::Replanned,
        RouteSwitch::SameWay,
        RouteSwitch::Shorter,
        RouteSwitch::Blocked,
    ];
    pub fn from_code(code: u32) -> Option<RouteSwitch> {
        RouteSwitch::ALL.into_iter().find(|r| *r as u32 == code)
    }
    pub fn as_str(self) -> &'static str {
        match self {
            RouteSwitch::Replanned => "replanned",
            RouteSwitch::SameWay => "same_way",
            RouteSwitch::Shorter => "shorter",
            RouteSwitch::Blocked => "blocked",
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
    /// from the current estimate (docs/safety.md), until a new plan passes it.
    SafetyBrake = 4,
    /// Held at the goal (`robot.final_approach = "settle"`, docs/reach.md): `U2 = 0`, `U1`
    /// brakes zeta to zero and the robot stays at rest; plans are checked, not flown.
    Hold = 5,
    /// Stepping out of the way of an obstacle coming at the robot (`dfl::evasion`): along
    /// the heading, then braking, until a plan passes the check.
    Evasion = 6,
    /// No command came: the simulated base's watchdog brakes it straight to rest
    /// (`plant.command_timeout_s`). Not the DFL's: the orchestrator records the ticks the
    /// plant was driven so ([`crate::GroundTruth::watchdog`]).
    Watchdog = 7,
}

impl CommandMode {
    pub fn from_code(code: u32) -> Option<CommandMode> {
        Some(match code {
            0 => CommandMode::Nominal,
            1 => CommandMode::Shifted,
            2 => CommandMode::Brake,
            3 => CommandMode::ZetaGuard,
            4 => CommandMode::SafetyBrake,
            5 => CommandMode::Hold,
            6 => CommandMode::Evasion,
            7 => CommandMode::Watchdog,
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
            CommandMode::Hold => "hold",
            CommandMode::Evasion => "evasion",
            CommandMode::Watchdog => "watchdog",
        }
    }
}

/// What the DFL's safety check did at a tick (docs/safety.md).
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
    /// Every choice would enter an inflated obstacle (a moving one coming at the robot,
    /// say): the new plan, the committed trajectory and the brake, each flown from the
    /// current estimate. The DFL takes one that comes to rest before its first predicted
    /// contact, the one that keeps the most clearance among those (the command's mode says
    /// which); reported once per plan flown on.
    LeastUnsafe = 3,
    /// As [`Intervention::LeastUnsafe`], but no choice comes to rest before its first
    /// predicted contact: the DFL takes the one that keeps the most clearance, and the
    /// robot is predicted to be still moving at the contact.
    MovingContact = 4,
    /// A return of the newest scan (off the map) lies on the robot's way ahead nearer than
    /// it needs to stop (`dfl::free_range`): the DFL brakes, whatever perception made of
    /// the scan.
    FreeRange = 5,
    /// The DFL would brake without a plan, or rest, where an obstacle coming at the robot
    /// is predicted to run into it (`dfl::evasion`): it drives along its heading out of
    /// the way instead, on an evasion the check finds clear.
    Evasion = 6,
}

impl Intervention {
    pub fn from_code(code: u32) -> Option<Intervention> {
        Some(match code {
            0 => Intervention::None,
            1 => Intervention::PlanRefused,
            2 => Intervention::CommittedUnsafe,
            3 => Intervention::LeastUnsafe,
            4 => Intervention::MovingContact,
            5 => Intervention::FreeRange,
            6 => Intervention::Evasion,
            _ => return None,
        })
    }
    pub fn as_str(self) -> &'static str {
        match self {
            Intervention::None => "none",
            Intervention::PlanRefused => "plan_refused",
            Intervention::CommittedUnsafe => "committed_unsafe",
            Intervention::LeastUnsafe => "least_unsafe",
            Intervention::MovingContact => "moving_contact",
            Intervention::FreeRange => "free_range",
            Intervention::Evasion => "evasion",
        }
    }
}
