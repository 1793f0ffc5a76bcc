//! Every message that crosses a process boundary: `#[repr(C)]`, fixed size, no heap, so
//! iceoryx2 can hand it over in shared memory without copying or serializing.
//!
//! Each carries a [`Header`] (docs/design.md, "Supervision"). The in-process mode passes the very
//! same values between the roles, so both modes share one set of semantics.

#[cfg(feature = "iceoryx2")]
use iceoryx2::prelude::ZeroCopySend;

/// Compile-time maximum prediction horizon `N` a plan can carry.
pub const MAX_HORIZON: usize = 64;

/// Common to every message.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Header"))]
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
    /// The robot the sample is of: a role instance is a role and a robot id, and a
    /// consumer refuses a sample of another robot ([`Rejection::WrongRobot`]). Every run
    /// has one robot today, [`FIRST_ROBOT`].
    pub robot: u32,
}

/// The robot id of a run's one robot ([`Header::robot`]): its samples, names and records
/// are those of a run before robot ids were carried.
pub const FIRST_ROBOT: u32 = 0;

/// Noisy output `y = [x, y, theta] + noise` of the plant.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::Measurement")
)]
pub struct Measurement {
    pub header: Header,
    /// `[x_m, y_m, theta_rad]`, theta wrapped to (-pi, pi].
    pub y: [f64; 3],
    /// The base's speeds at the tick as its odometry reports them, `[u1 m/s, u2 rad/s]`:
    /// the simulated base's exactly, a ROS 2 base's odometry twist. An estimator that
    /// starts mid-run takes zeta from it.
    pub odometry: [f64; 2],
}

/// The plant's true state; read only by the recorder.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::GroundTruth")
)]
pub struct GroundTruth {
    pub header: Header,
    /// `[x_m, y_m, theta_rad]`, theta wrapped to (-pi, pi].
    pub pose: [f64; 3],
    /// The command the base applied over the tick before, `[t_(j-1), t_j)`, after
    /// saturation: `[u1 m/s, u2 rad/s]` (the simulated base's; 0 from a ROS 2 base).
    pub applied: [f64; 2],
    /// 1 when the base drove that tick on its own watchdog, no command having come for
    /// `plant.command_timeout_s` ([`CommandMode::Watchdog`]); 2 when, after that, it
    /// ramped its forward speed to the commands that came again (at the watchdog's
    /// deceleration, `plant::task::resumed_command`); else 0.
    pub watchdog: u32,
    /// Zero: the struct's size a whole number of its 8-byte fields, with no padding.
    pub reserved: u32,
}

/// The estimator's output: the extended state and the covariance of the pose.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::Estimate")
)]
pub struct Estimate {
    pub header: Header,
    /// `x_bar = [x_m, y_m, theta_rad, zeta_m_s]`; zeta is the DFL's integrator state.
    pub state: [f64; 4],
    /// Covariance of `[x, y, theta]`, row-major 3x3.
    pub covariance: [f64; 9],
    /// `x_bar` predicted to when the commands already sent have all taken effect, `t +
    /// command_lead_s` (`robot.command_delay_s`, docs/robot.md), zeta being the base's
    /// forward speed then: what the MPC plans from and the DFL commands for. Without a
    /// command delay, `state`.
    pub ahead: [f64; 4],
}

impl Estimate {
    /// Largest standard deviation of the position, m (`sigma` of the uncertainty margin).
    pub fn position_sigma(&self) -> f64 {
        self.covariance[0].max(self.covariance[4]).max(0.0).sqrt()
    }
}

/// plan(k): a time-indexed input sequence. Element `i` is valid on
/// `[t_k + i Ts, t_k + (i + 1) Ts)` (docs/design.md, "Deadlines and fallback").
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Plan"))]
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
    /// In a fleet: `1 +` the id of the robot this plan gives way to, breaking a deadlock
    /// (docs/fleet.md, "Deadlocks"); 0 when it gives way to none.
    pub gives_way: u32,
    pub reserved: u32,
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
            gives_way: 0,
            reserved: 0,
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

/// The planner's route to the goal (docs/planner.md), published every sample:
/// the waypoints of the newest plan, from the position it was planned at to the goal.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Route"))]
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
    /// [`RouteSwitch`] code: why the newest plan taken replaced the route before it.
    pub switch: u32,
    pub reserved: u32,
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
            switch: RouteSwitch::Replanned as u32,
            reserved: 0,
            length_m: 0.0,
            plan_ns: 0,
            waypoints: [[0.0; 2]; ROUTE_CAPACITY],
        }
    }
}

impl Route {
    /// A route through `points` (the last the goal; followable with two or more), or none
    /// when they are more than [`ROUTE_CAPACITY`].
    pub fn through(points: &[[f64; 2]]) -> Option<Route> {
        let mut route = Route {
            status: RouteStatus::Ok as u32,
            count: u32::try_from(points.len()).ok()?,
            ..Route::default()
        };
        route
            .waypoints
            .get_mut(..points.len())?
            .copy_from_slice(points);
        Some(route)
    }

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

/// Most obstacles the tracker tracks.
pub const MAX_TRACKS: usize = 32;

/// The first [`Track::obstacle`] of a phantom: an obstacle assumed where the lidar cannot
/// see (docs/safety.md, "What the lidar cannot see").
pub const FIRST_PHANTOM: u32 = 1 << 31;

/// One obstacle as the tracker sees it: its constant-velocity Kalman filter's state.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Track"))]
pub struct Track {
    /// Index of the obstacle in the scenario's `obstacles`; with a lidar the track's number,
    /// from [`FIRST_PHANTOM`] on a phantom's.
    pub obstacle: u32,
    pub reserved: u32,
    /// Its true radius, m (the tracker measures centres only).
    pub radius_m: f64,
    /// Estimated centre at the track's time, m.
    pub center: [f64; 2],
    /// Estimated velocity, m/s.
    pub velocity: [f64; 2],
    /// Covariance of `[position, velocity]` along x then along y (the axes are filtered
    /// apart): `[var x, cov x vx, var vx, var y, cov y vy, var vy]`, m^2, m^2/s, m^2/s^2.
    pub covariance: [f64; 6],
}

/// A track whose speed plus its velocity's standard deviation is below this stands
/// still, m/s ([`Track::stands_still`]).
pub const STANDING_SPEED_M_S: f64 = 0.3;

impl Track {
    /// Whether it stands still: not a phantom, its speed plus its velocity's standard
    /// deviation below [`STANDING_SPEED_M_S`]: a box or a person waiting. To the route
    /// planner it is an obstacle at rest; the MPC's terminal rows sweep its disc over the
    /// plan's own stop rather than the fastest one (`mpc::terminal`); until it is overdue
    /// its disc grows only until the next tracks are due, and is held after
    /// ([`crate::DiscMotion::held`]).
    pub fn stands_still(&self) -> bool {
        let speed = self.velocity[0].hypot(self.velocity[1]);
        !self.is_phantom() && speed + self.sigmas().1 < STANDING_SPEED_M_S
    }

    /// Whether it is another robot of a fleet ([`crate::FIRST_PEER`]), predicted from the
    /// plans it publishes ([`crate::PeerPrediction`]).
    pub fn is_peer(&self) -> bool {
        (crate::FIRST_PEER..FIRST_PHANTOM).contains(&self.obstacle)
    }

    /// Whether it is a phantom ([`FIRST_PHANTOM`]).
    pub fn is_phantom(&self) -> bool {
        self.obstacle >= FIRST_PHANTOM
    }

    /// Standard deviations of the position and of the velocity along the worse axis,
    /// m and m/s. The predicted position's `sigma(t) = sqrt(var p + 2 t cov + t^2 var v)`
    /// is at most `sigma_p + t sigma_v` (the covariance is at most `sigma_p sigma_v`).
    pub fn sigmas(&self) -> (f64, f64) {
        let c = &self.covariance;
        (
            c[0].max(c[3]).max(0.0).sqrt(),
            c[2].max(c[5]).max(0.0).sqrt(),
        )
    }
}

/// The tracker's tracks, published after each measurement of the obstacles.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Tracks"))]
pub struct Tracks {
    /// The tick of the newest measurement taken in (the tracks' time).
    pub header: Header,
    /// Valid tracks.
    pub count: u32,
    /// Measurements dropped so far (`fault.tracker_drop_samples`).
    pub dropped: u32,
    /// The tracks, for `i < count`, in the order of the scenario's obstacles.
    pub tracks: [Track; MAX_TRACKS],
}

impl Default for Tracks {
    fn default() -> Self {
        Tracks {
            header: Header::default(),
            count: 0,
            dropped: 0,
            tracks: [Track::default(); MAX_TRACKS],
        }
    }
}

impl Tracks {
    /// The valid tracks.
    pub fn tracks(&self) -> &[Track] {
        &self.tracks[..(self.count as usize).min(MAX_TRACKS)]
    }
}

/// The DFL's command for one inner tick, held by the plant until the next one.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::Actuation")
)]
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

/// [`DeadlineVerdict::status`] of a plan that never reached the DFL.
pub const PLAN_MISSING: u32 = u32::MAX;

/// The DFL's judgement of one sample's deadline: plan(k) must be in its hands, solved, by
/// `t_k + Ts` (docs/design.md, "Deadlines and fallback"). Published for every sample, met or missed.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::DeadlineVerdict")
)]
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

/// Every message type: access to its [`Header`]. (With the feature `iceoryx2`, which the
/// runtime turns on, every message is also iceoryx2's `ZeroCopySend`; the role crates build
/// without it.)
pub trait Message: Copy + core::fmt::Debug + 'static {
    fn header(&self) -> &Header;
    fn header_mut(&mut self) -> &mut Header;
    /// Whether every floating-point value of the message is finite.
    fn all_finite(&self) -> bool;
    /// Whether every code, count and length is one the type allows.
    fn well_formed(&self) -> bool;

    /// The names of the values a sample is recorded with when the record has no place of
    /// its own for its topic (`<topic>.csv` and a `run.mcap` channel, after its time),
    /// units in the names; empty (the default): the record has one, or records nothing.
    const RECORDED: &'static [&'static str] = &[];

    /// Appends the values [`Message::RECORDED`] names, in its order.
    fn recorded(&self, _values: &mut Vec<f64>) {}

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

/// Implements [`Message`] for each type: `Type => |m| all finite, well formed`, and for a
/// message the record has no place of its own for, `, record [names] => [values]`
/// ([`Message::RECORDED`]).
macro_rules! impl_message {
    ($($t:ty => |$m:ident| $finite:expr, $formed:expr $(, record $names:expr => $values:expr)?);* $(;)?) => {$(
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
            $(
                const RECORDED: &'static [&'static str] = &$names;
                fn recorded(&self, values: &mut Vec<f64>) {
                    let $m = self;
                    values.extend($values);
                }
            )?
        }
    )*};
}

impl_message!(
    Measurement => |m| finite(&m.y) && finite(&m.odometry), true;
    GroundTruth => |m| finite(&m.pose) && finite(&m.applied), m.watchdog <= 2;
    Estimate => |m| finite(&m.state) && finite(&m.covariance) && finite(&m.ahead), true;
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
            && RouteSwitch::from_code(m.switch).is_some()
            && match m.status() {
                Some(RouteStatus::Ok) => m.count >= 2,
                Some(RouteStatus::NoRoute) => m.count == 0,
                None => false,
            };
    Tracks => |m| m.tracks().iter().all(|t| {
        finite(&t.center) && finite(&t.velocity) && finite(&t.covariance) && t.radius_m.is_finite()
    }), m.count as usize <= MAX_TRACKS;
    Scan => |m| finite(&[m.angle_min_rad, m.angle_increment_rad, m.range_min_m, m.range_max_m])
        && finite(&m.offset), m.beams as usize <= crate::MAX_BEAMS,
        record ["beams", "returns", "nearest_m"] => [m.beams.into(), m.returns() as f64, m.nearest_m()];
    Odometry => |m| m.distance_m.is_finite(), true, record ["distance_m"] => [m.distance_m];
    Control => |m| (m.goal_serial == 0 || finite(&m.goal[..2]))
        && (m.prior_goal_serial == 0 || finite(&m.prior_goal[..2])), m.command().is_some();
    Status => |m| true, Role::from_code(m.role).is_some()
        && StatusEvent::from_code(m.event).is_some()
        && (m.event != StatusEvent::Rejected as u32
            || (m.detail as usize) < Rejection::COUNT
                && (m.producer == NO_PRODUCER || Role::from_code(m.producer).is_some()));
    SwapRequest => |m| true, Role::from_code(m.role).is_some() && m.command_is_well_formed();
    SwapReply => |m| true, m.done <= 1 && m.message_len as usize <= MAX_REPLY_BYTES;
);

/// The odometer's reading (the example role, examples/roles/odometer).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::Odometry")
)]
pub struct Odometry {
    pub header: Header,
    /// The length of the path the estimate has driven since the run started, m.
    pub distance_m: f64,
}

// The fields of the header and of every data message (`scmpc schema`'s `types`).
crate::layouts! {
    Odometry {
        header: Header,
        distance_m: f64,
    }
    Track {
        obstacle: u32,
        reserved: u32,
        radius_m: f64,
        center: [f64; 2],
        velocity: [f64; 2],
        covariance: [f64; 6],
    }
    Tracks {
        header: Header,
        count: u32,
        dropped: u32,
        tracks: [Track; MAX_TRACKS],
    }
    Header {
        tick: u64,
        time_s: f64,
        publish_ns: u64,
        epoch: u32,
        input_latency_ns: u32,
        run_id: u32,
        robot: u32,
    }
    Measurement {
        header: Header,
        y: [f64; 3],
        odometry: [f64; 2],
    }
    GroundTruth {
        header: Header,
        pose: [f64; 3],
        applied: [f64; 2],
        watchdog: u32,
        reserved: u32,
    }
    Estimate {
        header: Header,
        state: [f64; 4],
        covariance: [f64; 9],
        ahead: [f64; 4],
    }
    Plan {
        header: Header,
        sample: u64,
        status: u32,
        horizon: u32,
        solve_ns: u64,
        iterations: u32,
        solves: u32,
        gives_way: u32,
        reserved: u32,
        injected_delay_ns: u64,
        v: [[f64; 2]; MAX_HORIZON],
        z: [[f64; 4]; MAX_HORIZON + 1],
    }
    Route {
        header: Header,
        sample: u64,
        planned_sample: u64,
        status: u32,
        count: u32,
        plans: u32,
        reason: u32,
        switch: u32,
        reserved: u32,
        length_m: f64,
        plan_ns: u64,
        waypoints: [[f64; 2]; ROUTE_CAPACITY],
    }
    Actuation {
        header: Header,
        u1: f64,
        u2: f64,
        wheels: [f64; 2],
        linearizing_input: [f64; 2],
        zeta: f64,
        v: [f64; 2],
        mode: u32,
        deadline_misses: u32,
        plan_sample: u64,
        intervention: u32,
        safety_interventions: u32,
        intervention_plan: u64,
        intervention_clearance_m: f64,
    }
    DeadlineVerdict {
        header: Header,
        sample: u64,
        met: u32,
        status: u32,
        production_ns: u64,
        arrival_ns: u64,
        fallback: u32,
        misses_total: u32,
    }
}

mod codes;
mod control;
mod scan;
pub use codes::*;
pub use control::*;
pub use scan::Scan;

macro_rules! data_variants {
    ($($(#[$doc:meta])* $variant:ident($t:ty) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
        /// Every data message of a run, one variant per data topic
        /// ([`crate::data_topics!`]): what executors hand from a task's outputs to the
        /// tasks that take them, whatever the roles ([`crate::task`]).
        ///
        /// A plan is large (about 3 KiB) and carried by value, as over shared memory:
        /// boxing it would allocate per plan, and the steady state allocates nothing.
        #[allow(clippy::large_enum_variant)]
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub enum Data {
            $($variant($t),)*
        }

        impl Data {
            /// The topic the message is published on.
            pub fn topic(&self) -> &'static str {
                match self {
                    $(Data::$variant(_) => crate::topics::$topic,)*
                }
            }

            /// What a consumer refuses in the message's content, if anything
            /// ([`Message::content_rejection`]).
            pub fn content_rejection(&self) -> Option<Rejection> {
                match self {
                    $(Data::$variant(m) => m.content_rejection(),)*
                }
            }

            /// The message's header.
            pub fn header(&self) -> &Header {
                match self {
                    $(Data::$variant(m) => m.header(),)*
                }
            }

            pub fn header_mut(&mut self) -> &mut Header {
                match self {
                    $(Data::$variant(m) => m.header_mut(),)*
                }
            }

            /// What the record writes of a sample of `topic` when it has no place of its
            /// own for it ([`Message::RECORDED`]; empty: nothing).
            pub fn recorded_names(topic: &str) -> &'static [&'static str] {
                match topic {
                    $($name => <$t as Message>::RECORDED,)*
                    _ => &[],
                }
            }

            /// The values [`Data::recorded_names`] names, appended to `values`.
            pub fn recorded(&self, values: &mut Vec<f64>) {
                match self {
                    $(Data::$variant(m) => m.recorded(values),)*
                }
            }

            /// A message of every data topic, each its type's default (for tests of what a
            /// task takes).
            pub fn one_of_each() -> Vec<Data> {
                vec![$(Data::$variant(<$t>::default()),)*]
            }
        }
        $(
            impl From<$t> for Data {
                fn from(m: $t) -> Data {
                    Data::$variant(m)
                }
            }
        )*
    };
}

crate::data_topics!(data_variants);

#[cfg(test)]
mod tests;
