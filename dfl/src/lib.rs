//! The inner loop: dynamic feedback linearization (DFL) of the unicycle.
//!
//! The dynamic extension `zeta_dot = U1, u1 = zeta, u2 = U2` turns the unicycle into
//! `x_bar = [x, y, theta, zeta]`, and the linearizing law (paper eq. 1101) makes
//! `z = Phi(x_bar) = [x, zeta cos theta, y, zeta sin theta]` two double integrators
//! `z1'' = v1`, `z3'' = v2`. The [`Dfl`] applies the element of the newest plan that covers
//! the current time, falls back to braking when none does, and integrates zeta. With
//! `dfl.gatekeeper` it flies only plans its safety check has passed ([`gatekeeper`]).

use protocol::actuator::BaseModel;
use protocol::{
    Actuation, CommandMode, Estimate, Header, Intervention, Plan, Scenario, Timing, WheelGeometry,
};

mod choice;
pub mod evasion;
pub mod free_range;
pub mod gatekeeper;
pub mod task;

pub use choice::{Candidate, least_unsafe};
use choice::{Choice, choose, touching};
pub use gatekeeper::{Foresight, Gatekeeper, Moment, Verdict};
pub use task::{
    DeadlineMonitor, DflTask, PLAN_WAIT_FRACTION, PlanInbox, SILENT_TICKS, SilenceWatch,
};

pub use protocol::{phi, phi_inverse};

/// The linearizing input `U = [U1, U2]` for the virtual input `v` (paper eq. 1101):
/// `U1 = v1 cos theta + v2 sin theta`, `U2 = (-v1 sin theta + v2 cos theta) / zeta`.
///
/// The zeta guard takes over when `|zeta| <= zeta_th` (the paper writes `zeta <=
/// zeta_th`; the absolute value lets the robot steer while reversing too): `U2` is zero
/// (the paper's guard), unless `v` points more than 45 degrees off the robot's axis
/// (forwards or backwards). Then no `U1` realizes it, and a robot standing still with `v`
/// across its axis would stay so (the stall of a robot that reaches the goal's
/// neighbourhood sideways); instead it turns in place towards the nearer of the two
/// directions of `v`, at the rate that would align it in [`TURN_IN_PLACE_S`]. Turning in
/// place leaves `z` as it is (`zeta` is ~0), so the linear model the MPC plans on and the
/// safety check flies still holds. Returns `U` and whether the guard acted.
pub fn linearizing_input(
    theta_rad: f64,
    zeta: f64,
    v: [f64; 2],
    zeta_threshold: f64,
) -> ([f64; 2], bool) {
    let (s, c) = theta_rad.sin_cos();
    let u1 = v[0] * c + v[1] * s;
    if zeta.abs() <= zeta_threshold {
        let across = -v[0] * s + v[1] * c;
        let turn = if across.abs() > u1.abs() && across.hypot(u1) >= TURN_IN_PLACE_MIN_ACCEL {
            // Angle from the nearer end of the robot's axis to v, in (-pi/2, pi/2).
            (across / u1).atan() / TURN_IN_PLACE_S
        } else {
            0.0
        };
        ([u1, turn], true)
    } else {
        ([u1, (-v[0] * s + v[1] * c) / zeta], false)
    }
}

/// Under the zeta guard, a robot whose plan points across its axis turns in place to
/// align with it in this long, s ([`linearizing_input`]).
pub const TURN_IN_PLACE_S: f64 = 0.25;
/// Plans asking for less acceleration than this, m/s^2, are not turned towards (a robot at
/// rest at its goal does not spin on rounding).
pub const TURN_IN_PLACE_MIN_ACCEL: f64 = 1e-3;

/// The linearizing input for the middle of an inner tick of `dt_s`: [`linearizing_input`]
/// evaluated again at the heading and zeta half a tick on, as its first evaluation moves
/// them. Held over the tick, `U` makes the tick's mean z-acceleration `v` to second order
/// in `U2 dt`; evaluated at the tick's start it is off by a rotation of `U2 dt / 2`, an
/// error that adds up over a plan (a millimetre over a second of hard turning, measured
/// on random worlds). The DFL uses it with the safety check on, whose model must hold.
pub fn mid_tick_linearizing_input(
    theta_rad: f64,
    zeta: f64,
    v: [f64; 2],
    zeta_threshold: f64,
    dt_s: f64,
) -> ([f64; 2], bool) {
    let (u, guarded) = linearizing_input(theta_rad, zeta, v, zeta_threshold);
    if guarded {
        return (u, guarded);
    }
    let (theta_mid, zeta_mid) = (theta_rad + 0.5 * u[1] * dt_s, zeta + 0.5 * u[0] * dt_s);
    linearizing_input(theta_mid, zeta_mid, v, zeta_threshold)
}

/// Extended unicycle under the DFL law with a constant `v` (used to check eq. 1101).
pub fn extended_dynamics(x_bar: &[f64; 4], v: [f64; 2], zeta_threshold: f64) -> [f64; 4] {
    let [_, _, theta, zeta] = *x_bar;
    let ([u1, u2], _) = linearizing_input(theta, zeta, v, zeta_threshold);
    [zeta * theta.cos(), zeta * theta.sin(), u2, u1]
}

/// Which element of `plan` covers sample `current_sample`, if any (docs/design.md, "Deadlines and fallback":
/// element `i` is valid on `[t_k + i Ts, t_k + (i + 1) Ts)`). A plan from the future
/// covers nothing yet; a plan older than its horizon is exhausted.
pub fn covering_element(plan: &Plan, current_sample: u64) -> Option<usize> {
    let age = current_sample.checked_sub(plan.sample)?;
    (age < u64::from(plan.horizon)).then_some(age as usize)
}

/// Whether `plan` (an evasion: one acceleration along the heading) slows a robot heading
/// `theta_rad` that moves at `zeta` (m/s).
fn braking_along(plan: &Plan, theta_rad: f64, zeta: f64) -> bool {
    let (sin, cos) = theta_rad.sin_cos();
    (plan.v[0][0] * cos + plan.v[0][1] * sin) * zeta < 0.0
}

/// The DFL role: owns zeta and the newest usable plan (with the safety check on, the
/// committed one).
pub struct Dfl {
    zeta: f64,
    zeta_threshold: f64,
    brake_decel: f64,
    timing: Timing,
    /// The inner tick, s.
    dt_s: f64,
    /// The MPC's horizon `N`, samples.
    horizon: u32,
    geometry: WheelGeometry,
    /// The wheels' limits (`plant.max_wheel_speed_rad_s`): the robot knows its actuators.
    wheels: protocol::PlantConfig,
    /// The plan flown: with the safety check on, the committed one.
    active: Option<Plan>,
    /// The safety check (`dfl.gatekeeper`).
    gatekeeper: Option<Gatekeeper>,
    /// With the safety check and a lidar: the free range of the newest scan.
    free_range: Option<free_range::FreeRange>,
    /// A plan offered and not yet checked (the check needs the estimate of the tick).
    offered: Option<Plan>,
    /// Braking because the committed trajectory was found unsafe, until a plan passes.
    safety_braking: bool,
    /// Whether the robot steps out of the way (`dfl.evasion`, [`evasion`]).
    evades: bool,
    /// The plan flown is an evasion ([`evasion`]), not one of the MPC's (until the first
    /// tick it no longer covers).
    evading: bool,
    /// The plan flown on though it touches (every other choice is worse), and how that was
    /// reported: once per plan, and again if it comes to touch while moving.
    flown_unsafe: Option<(u64, Intervention)>,
    /// Sample of the newest plan taken (offered, committed or given up).
    newest: Option<u64>,
    interventions: u32,
    /// Where the robot is held once it arrives (`robot.final_approach = "settle"`).
    goal_hold: Option<GoalHold>,
    /// Holding the robot at its goal ([`GoalHold`]).
    holding: bool,
    /// A base with a lag or a delay (`robot.actuator_lag_s`, `robot.command_delay_s`): its
    /// commands in flight and its speeds ([`Dfl::step`]).
    base: Option<BaseModel>,
}

/// Holding the robot at its goal (`robot.final_approach = "settle"`, docs/reach.md): a
/// robot whose estimate is within the goal tolerance and whose speed is below
/// [`protocol::HOLD_SPEED_M_S`] is braked to rest and held, unless the plan flown would
/// take it out of the tolerance or the safety check finds that staying would be run into
/// (a person walking at it): then it flies its plans, out of the way, as any robot does.
/// An estimate beyond twice the tolerance (the robot pushed away) lets it go too.
/// With a goal heading (`robot.goal = [x, y, theta]`) the held robot turns in place to it
/// ([`GoalHold::turn`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GoalHold {
    pub goal: protocol::Goal,
    pub tolerance_m: f64,
    pub yaw_tolerance_rad: f64,
}

/// How fast a held robot turns to its goal heading per radian it is off, 1/s.
pub const TURN_GAIN_PER_S: f64 = 2.0;
/// The fastest a held robot turns, rad/s.
pub const TURN_RATE_RAD_S: f64 = 1.0;

impl GoalHold {
    /// The turn rate `U2` (rad/s) of a held robot heading `theta_rad`: towards the goal
    /// heading, proportional to how far off it is up to [`TURN_RATE_RAD_S`], until within
    /// half the yaw tolerance (so that it ends within the tolerance, not at its edge);
    /// none without a goal heading.
    pub fn turn(&self, theta_rad: f64) -> f64 {
        let Some(yaw) = self.goal.yaw_rad else {
            return 0.0;
        };
        let off = protocol::wrap_angle(yaw - theta_rad);
        if off.abs() <= 0.5 * self.yaw_tolerance_rad {
            return 0.0;
        }
        (TURN_GAIN_PER_S * off).clamp(-TURN_RATE_RAD_S, TURN_RATE_RAD_S)
    }

    /// Whether `plan` takes the robot out of the goal tolerance: the MPC, which sees the
    /// obstacles' predicted discs, moves a robot at its goal away only to keep clear of
    /// one (near its goal it drives towards it).
    pub fn leaves(&self, plan: &Plan) -> bool {
        plan.z[..=plan.horizon as usize]
            .iter()
            .any(|z| protocol::distance([z[0], z[2]], self.goal.position) > self.tolerance_m)
    }

    /// Whether a robot at `position` moving at `zeta` (m/s) is held, if it `was`.
    pub fn holds(&self, was: bool, position: [f64; 2], zeta: f64) -> bool {
        let distance_m = protocol::distance(position, self.goal.position);
        if was {
            distance_m <= 2.0 * self.tolerance_m
        } else {
            distance_m <= self.tolerance_m && zeta.abs() < protocol::HOLD_SPEED_M_S
        }
    }
}

/// What the safety check did at one tick.
#[derive(Debug, Clone, Copy, Default)]
struct CheckOutcome {
    intervention: Intervention,
    plan_sample: u64,
    clearance_m: f64,
    /// Interventions at this tick (a refused plan and an unsafe committed one: two).
    count: u32,
}

impl CheckOutcome {
    /// Notes one intervention (the newest is the one reported).
    fn note(&mut self, intervention: Intervention, plan_sample: u64, clearance_m: f64) {
        *self = CheckOutcome {
            intervention,
            plan_sample,
            clearance_m,
            count: self.count + 1,
        };
    }
}

impl Dfl {
    pub fn new(scenario: &Scenario) -> Dfl {
        Dfl {
            zeta: scenario.robot.zeta0,
            zeta_threshold: scenario.dfl.zeta_threshold,
            brake_decel: scenario.brake_decel(),
            timing: scenario.timing.clone(),
            dt_s: scenario.timing.dt_s(),
            horizon: scenario.mpc.horizon as u32,
            geometry: WheelGeometry {
                wheel_radius_m: scenario.plant.wheel_radius_m,
                wheel_base_m: scenario.plant.wheel_base_m,
            },
            wheels: scenario.plant.clone(),
            active: None,
            gatekeeper: scenario.dfl.gatekeeper.then(|| Gatekeeper::new(scenario)),
            free_range: (scenario.dfl.gatekeeper && scenario.sees_with_lidar())
                .then(|| free_range::FreeRange::new(scenario)),
            offered: None,
            safety_braking: false,
            evades: scenario.dfl.evasion,
            evading: false,
            flown_unsafe: None,
            newest: None,
            interventions: 0,
            goal_hold: (scenario.robot.final_approach == protocol::FinalApproach::Settle)
                .then_some(GoalHold {
                    goal: scenario.robot.goal,
                    tolerance_m: scenario.robot.goal_tolerance_m,
                    yaw_tolerance_rad: scenario.robot.goal_yaw_tolerance_rad,
                }),
            holding: false,
            base: BaseModel::of(scenario.actuator(), scenario),
        }
    }

    /// Safety interventions so far: plans refused and committed trajectories given up.
    pub fn interventions(&self) -> u32 {
        self.interventions
    }

    /// The DFL's integrator state zeta, m/s.
    pub fn zeta(&self) -> f64 {
        self.zeta
    }

    /// Takes zeta from outside (m/s): a DFL that joins a running loop (a restart, or a
    /// replacement warming up) continues from the zeta the plant is actually driven with,
    /// which every estimate carries.
    pub fn adopt_zeta(&mut self, zeta: f64) {
        if zeta.is_finite() {
            self.zeta = zeta;
        }
    }

    /// [`Dfl::adopt_zeta`] from `estimate`: with a model of the base, the speed it will
    /// have when the DFL's command acts ([`Estimate::ahead`]).
    pub fn adopt_zeta_of(&mut self, estimate: &Estimate) {
        let x_bar = if self.base.is_some() {
            estimate.ahead
        } else {
            estimate.state
        };
        self.adopt_zeta(x_bar[3]);
    }

    /// Takes the tracker's tracks into the safety check (without one, nothing).
    pub fn set_tracks(&mut self, tracks: &protocol::Tracks) {
        if let Some(gatekeeper) = &mut self.gatekeeper {
            gatekeeper.set_tracks(tracks);
        }
    }

    /// Takes the newest scan, taken with the lidar at `lidar` (`[x_m, y_m, yaw_rad]` in the
    /// world), into the free-range check (without one, nothing).
    pub fn set_scan(&mut self, scan: &protocol::Scan, lidar: [f64; 3]) {
        if let Some(free_range) = &mut self.free_range {
            free_range.take(scan, lidar);
        }
    }

    /// Offers a received plan. It becomes active if it is solved and newer than the active
    /// one; a failed plan is ignored, like a missed one, and an older one (out of order)
    /// never replaces a newer one. With the safety check on, it is only a candidate until
    /// the next [`Dfl::step`] has checked it. Returns whether it was taken.
    pub fn offer(&mut self, plan: &Plan) -> bool {
        let take = plan.is_solved() && self.newest.is_none_or(|newest| plan.sample > newest);
        if take {
            self.newest = Some(plan.sample);
            if self.gatekeeper.is_some() {
                self.offered = Some(*plan);
            } else {
                self.active = Some(*plan);
            }
        }
        take
    }

    /// The safety check of a tick: commits an offered plan whose trajectory (the plan, then
    /// the brake) is safe from `estimate`, and gives up the committed one when it is not.
    fn check(&mut self, estimate: &Estimate, tick: u64) -> CheckOutcome {
        let Some(gatekeeper) = &self.gatekeeper else {
            return CheckOutcome::default();
        };
        let (now, z) = self.checked_at(estimate, tick);
        let sigma = estimate.position_sigma();
        let (commit_growth, keep_growth) = (
            gatekeeper.commit_growth(sigma),
            gatekeeper.keep_growth(sigma),
        );
        let mut refused = None;
        if let Some(plan) = self.offered.take() {
            match gatekeeper.check(&plan, now, z, commit_growth) {
                None => {
                    self.active = Some(plan);
                    self.safety_braking = false;
                    self.evading = false;
                    return CheckOutcome::default();
                }
                Some(clearance) => refused = Some((plan, clearance)),
            }
        }
        // The committed trajectory, flown from this estimate (not needed once its plan is
        // exhausted and the DFL brakes anyway).
        let flying = self
            .active
            .filter(|plan| covering_element(plan, now.sample).is_some());
        let choice = choose(
            gatekeeper,
            (now, z, keep_growth),
            flying.as_ref(),
            refused.as_ref().map(|(plan, _)| plan),
        );
        let outcome = self.take(choice, refused);
        self.interventions += outcome.count;
        outcome
    }

    /// Flies `choice`, made with the plan `refused` (and its clearance at the commit
    /// check), if any; what it did.
    fn take(&mut self, choice: Choice, refused: Option<(Plan, f64)>) -> CheckOutcome {
        let mut outcome = CheckOutcome::default();
        match (choice, refused) {
            (Choice::Refused(verdict, stages), Some((mut plan, _))) => {
                let clearance = verdict.deepest().unwrap_or(0.0);
                let intervention = touching(verdict);
                outcome.note(intervention, plan.sample, clearance);
                plan.horizon = stages;
                self.active = Some(plan);
                self.safety_braking = false;
                self.evading = false;
                self.flown_unsafe = Some((plan.sample, intervention));
            }
            (_, Some((plan, clearance))) => {
                outcome.note(Intervention::PlanRefused, plan.sample, clearance)
            }
            _ => {}
        }
        match choice {
            Choice::Brake(Some(plan_sample), brake, clearance) => {
                let intervention = if brake.clear() {
                    Intervention::CommittedUnsafe
                } else {
                    touching(brake)
                };
                let clearance = brake.deepest().unwrap_or(clearance);
                outcome.note(intervention, plan_sample, clearance);
                self.active = None;
                self.safety_braking = true;
                self.evading = false;
            }
            Choice::Brake(None, brake, _) if !brake.rests_before_contact() => {
                let plan_sample = refused.map_or(0, |(plan, _)| plan.sample);
                let clearance = brake.deepest().unwrap_or(0.0);
                outcome.note(Intervention::MovingContact, plan_sample, clearance);
            }
            Choice::Fly(plan_sample, verdict, stages, whole_clearance) => {
                // A cut of the committed plan that clears: the whole one is given up.
                let (intervention, clearance) = match verdict.deepest() {
                    None => (Intervention::CommittedUnsafe, whole_clearance),
                    Some(clearance) => (touching(verdict), clearance),
                };
                let reported = self
                    .flown_unsafe
                    .filter(|(sample, _)| *sample == plan_sample);
                let escalates = intervention == Intervention::MovingContact
                    && reported.is_some_and(|(_, i)| i != Intervention::MovingContact);
                if reported.is_none() || escalates {
                    outcome.note(intervention, plan_sample, clearance);
                    self.flown_unsafe = Some((plan_sample, intervention));
                }
                if let Some(plan) = &mut self.active {
                    plan.horizon = plan.horizon.min(stages);
                }
            }
            // The committed trajectory goes on, or the robot brakes already; a refused
            // plan is reported above.
            _ => {}
        }
        outcome
    }

    /// Holds the robot at `goal` from now on (a goal set while the run drives): a robot
    /// held at the old one is let go, to the plans that lead to the new one.
    pub fn set_goal(&mut self, goal: protocol::Goal) {
        if let Some(hold) = &mut self.goal_hold {
            hold.goal = goal;
        }
        self.holding = false;
    }

    /// One inner tick: the command for `[t_j, t_j + Ts/M)` from `estimate` and the active
    /// plan; integrates zeta over the tick. The header's publish time and epoch are the
    /// caller's to fill.
    ///
    /// With a command delay the command sent at tick `j` takes effect `q` whole ticks later
    /// (`q = floor(delay / dt)`; the rest of the delay, under a tick, is not compensated).
    /// A plan's timeline then runs `q` ticks behind the clock
    /// ([`protocol::Scenario::command_lead_s`]): the estimator predicts, over its model of
    /// the base, the state the commands already in flight take the robot to by `t_j + q dt`
    /// ([`Estimate::ahead`], a Smith predictor); the MPC plans sample `k` from that of
    /// `t_k`, and the DFL flies the element of tick `j` from that of `t_j`. Its safety
    /// check, the hold and the evasion see that state too.
    pub fn step(&mut self, estimate: &Estimate, tick: u64) -> Actuation {
        if self.base.is_none() {
            return self.step_from(estimate, tick);
        }
        let ahead = Estimate {
            state: estimate.ahead,
            ..*estimate
        };
        self.step_from(&ahead, tick)
    }

    /// [`Dfl::step`] from `estimate`, predicted over the delay.
    fn step_from(&mut self, estimate: &Estimate, tick: u64) -> Actuation {
        let checked = self.check(estimate, tick);
        let checked = self.check_free_range(estimate, checked);
        let sample = self.timing.sample_of(tick);
        let [x, y, theta, _] = estimate.state;
        if let Some(hold) = self.goal_hold {
            // Checked in order of cost, and only near the goal.
            self.holding = !self.evading
                && hold.holds(self.holding, [x, y], self.zeta)
                && !self.active.as_ref().is_some_and(|plan| hold.leaves(plan))
                && !self.staying_touches(estimate, tick);
        }
        let checked = if self.holding {
            checked
        } else {
            self.evade(estimate, tick, checked)
        };
        let chosen = self
            .active
            .as_ref()
            .filter(|_| !self.holding)
            .and_then(|p| covering_element(p, sample).map(|i| (p.v[i], p.sample)));
        let braking = if self.holding {
            CommandMode::Hold
        } else if self.safety_braking {
            CommandMode::SafetyBrake
        } else {
            CommandMode::Brake
        };
        let (u, v, mode, plan_sample) = match chosen {
            Some((v, plan_sample)) => {
                let (u, guarded) = if self.gatekeeper.is_some() {
                    mid_tick_linearizing_input(theta, self.zeta, v, self.zeta_threshold, self.dt_s)
                } else {
                    linearizing_input(theta, self.zeta, v, self.zeta_threshold)
                };
                let mode = if self.evading {
                    CommandMode::Evasion
                } else if plan_sample != sample {
                    CommandMode::Shifted
                } else if guarded {
                    CommandMode::ZetaGuard
                } else {
                    CommandMode::Nominal
                };
                (u, v, mode, plan_sample)
            }
            None => {
                let [u1, _] = self.braking_input();
                let turn = self
                    .goal_hold
                    .filter(|_| self.holding)
                    .map(|h| h.turn(theta));
                ([u1, turn.unwrap_or(0.0)], [0.0; 2], braking, 0)
            }
        };
        let mut act = self.command(tick, u, v, mode, plan_sample);
        act.intervention = checked.intervention as u32;
        act.intervention_plan = checked.plan_sample;
        act.intervention_clearance_m = checked.clearance_m;
        act
    }

    /// The free-range check of a tick, after the safety check's `outcome`: a robot driving
    /// faster than it can stop short of a point of the newest scan on its way brakes
    /// ([`free_range::FreeRange::shortfall_m`]), until a plan passes the check again.
    fn check_free_range(&mut self, estimate: &Estimate, mut outcome: CheckOutcome) -> CheckOutcome {
        let Some(free_range) = self.free_range.as_ref().filter(|_| !self.safety_braking) else {
            return outcome;
        };
        let [x, y, theta, _] = estimate.state;
        if self.evading
            && self
                .active
                .is_some_and(|plan| braking_along(&plan, theta, self.zeta))
        {
            // An evasion against the robot's motion brakes as the brake would, and the
            // free range held its way back when it was taken (`dfl::evasion`).
            return outcome;
        }
        if let Some(short_m) = free_range.shortfall_m([x, y, theta], self.zeta) {
            let plan_sample = self.active.map_or(0, |plan| plan.sample);
            outcome.note(Intervention::FreeRange, plan_sample, -short_m);
            self.interventions += 1;
            self.active = None;
            self.safety_braking = true;
            self.evading = false;
        }
        outcome
    }

    /// Steps out of the way ([`evasion`]) when the DFL would brake, or rest, at `tick`
    /// without a plan and the brake is predicted to be run into within
    /// [`evasion::EVASION_WINDOW_S`]: flies the shortest evasion the commit check finds
    /// clear, if any, as its committed trajectory.
    fn evade(&mut self, estimate: &Estimate, tick: u64, mut outcome: CheckOutcome) -> CheckOutcome {
        let (now, z) = self.checked_at(estimate, tick);
        if (self.active.as_ref()).is_some_and(|plan| covering_element(plan, now.sample).is_some()) {
            return outcome;
        }
        // An evasion that no longer covers the tick is over: the robot brakes.
        self.evading = false;
        let Some(gatekeeper) = self.gatekeeper.as_ref().filter(|_| self.evades) else {
            return outcome;
        };
        let [x, y, theta, _] = estimate.state;
        let sigma = estimate.position_sigma();
        let start = evasion::Start {
            now,
            z,
            heading_rad: theta,
            zeta_m_s: self.zeta,
        };
        let limits = evasion::Limits {
            accel_m_s2: self.brake_decel,
            most_speed_m_s: evasion::most_forward_speed_m_s(&self.wheels),
            ts_s: self.timing.ts_s,
        };
        // The way an evasion drives the way it evades, to its stop, is at most twice the
        // stopping distance of its end speed (it accelerates and brakes at one rate): the
        // free range must hold the stop from sqrt(2) times that speed.
        let free_range = self.free_range.as_ref();
        let may_reach = |end: f64| {
            free_range.is_none_or(|f| {
                f.shortfall_m([x, y, theta], end * std::f64::consts::SQRT_2)
                    .is_none()
            })
        };
        let checks = evasion::Checks {
            keep_growth_m: gatekeeper.keep_growth(sigma),
            commit_growth_m: gatekeeper.commit_growth(sigma),
            horizon: self.horizon,
        };
        if let Some((plan, run_into)) =
            evasion::evasion(gatekeeper, start, checks, limits, may_reach)
        {
            outcome.note(Intervention::Evasion, plan.sample, run_into);
            self.interventions += 1;
            self.active = Some(plan);
            self.safety_braking = false;
            self.evading = true;
        }
        outcome
    }

    /// Whether the safety check finds that braking to rest from `estimate` at `tick` would
    /// be run into (a person walking at the robot): a held robot then flies its plans.
    fn staying_touches(&self, estimate: &Estimate, tick: u64) -> bool {
        let Some(gatekeeper) = &self.gatekeeper else {
            return false;
        };
        let (now, z) = self.checked_at(estimate, tick);
        let grow = gatekeeper.keep_growth(estimate.position_sigma());
        gatekeeper.brake_check(z, now, grow).is_some()
    }

    /// When and from what the safety check of `tick` checks: the moment, and the state
    /// `z = Phi(x_bar)` of `estimate` with the DFL's zeta.
    fn checked_at(&self, estimate: &Estimate, tick: u64) -> (Moment, [f64; 4]) {
        let now = Moment {
            sample: self.timing.sample_of(tick),
            into_sample_s: self.timing.time_into_sample_s(tick),
        };
        let [x, y, theta, _] = estimate.state;
        (now, protocol::phi([x, y, theta, self.zeta]))
    }

    /// A braking command for `tick` without an estimate (the estimator is silent): braking
    /// needs only zeta, which the DFL owns.
    pub fn brake(&mut self, tick: u64) -> Actuation {
        self.command(tick, self.braking_input(), [0.0; 2], CommandMode::Brake, 0)
    }

    /// The actuation for `[t_tick, t_tick+1)` from `U`; integrates zeta over the tick.
    fn command(
        &mut self,
        tick: u64,
        u: [f64; 2],
        v: [f64; 2],
        mode: CommandMode,
        plan_sample: u64,
    ) -> Actuation {
        // zeta is linear over the tick; its mean is the forward speed held by the plant.
        let zeta_start = self.zeta;
        self.zeta += u[0] * self.dt_s;
        let [u1, u2] = match &mut self.base {
            None => {
                let u1 = 0.5 * (zeta_start + self.zeta);
                // Anti-windup: where the wheels saturate, zeta is held at the forward speed
                // they realize, so the estimate (which carries zeta), the MPC's `z_0` and
                // the brake start from the speed the robot has, not from one it was asked
                // for and never reached (a robot believed 0.7 m/s faster brakes that much
                // later). Without a wheel limit the realized inputs are the commanded ones
                // and nothing changes.
                let realized = self.wheels.realized_inputs([u1, u[1]])[0];
                if realized.abs() < u1.abs() {
                    self.zeta = realized;
                }
                [u1, u[1]]
            }
            Some(base) => {
                // The command that brings the base, when it takes effect, to zeta and the
                // turn rate U2 by the end of its tick: the lag inverted over one tick
                // (`Actuator::command_reaching`). Anti-windup as above, on the speed the
                // wheels' limit lets the base reach.
                let actuator = base.actuator();
                let speeds = base.predict(base.ticks_decided(), |_, _| {});
                // Rounding leaves a base the inversion brought to rest a speed of 1e-17 m/s
                // or so: a command that small is none (a robot braked to rest is sent 0).
                let command = (actuator.command_reaching(speeds, [self.zeta, u[1]], self.dt_s))
                    .map(|c| if c.abs() < 1e-12 { 0.0 } else { c });
                let realized = self.wheels.realized_inputs(command);
                if realized[0].abs() < command[0].abs() {
                    self.zeta = actuator.follow(speeds, realized, self.dt_s).end[0];
                }
                base.advance(realized, |_, _| {});
                command
            }
        };
        Actuation {
            header: Header {
                tick,
                time_s: self.timing.tick_time_s(tick),
                ..Header::default()
            },
            u1,
            u2,
            wheels: self.geometry.wheel_speeds([u1, u2]),
            linearizing_input: u,
            zeta: self.zeta,
            v,
            mode: mode as u32,
            deadline_misses: 0,
            plan_sample,
            safety_interventions: self.interventions,
            ..Actuation::default()
        }
    }

    /// Braking without a plan: `U2 = 0` (the zeta-threshold branch) and `U1` takes zeta to
    /// zero at the braking limit without overshooting it.
    fn braking_input(&self) -> [f64; 2] {
        let u1 = (-self.zeta / self.dt_s).clamp(-self.brake_decel, self.brake_decel);
        [u1, 0.0]
    }
}

#[cfg(test)]
mod tests;
