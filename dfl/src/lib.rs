//! The inner loop: dynamic feedback linearization (DFL) of the unicycle.
//!
//! The dynamic extension `zeta_dot = U1, u1 = zeta, u2 = U2` turns the unicycle into
//! `x_bar = [x, y, theta, zeta]`, and the linearizing law (paper eq. 1101) makes
//! `z = Phi(x_bar) = [x, zeta cos theta, y, zeta sin theta]` two double integrators
//! `z1'' = v1`, `z3'' = v2`. The [`Dfl`] applies the element of the newest plan that covers
//! the current time, falls back to braking when none does, and integrates zeta. With
//! `dfl.gatekeeper` it flies only plans its safety check has passed ([`gatekeeper`]).

use protocol::{
    Actuation, CommandMode, Estimate, Header, Intervention, Plan, Scenario, Timing, WheelGeometry,
};

pub mod gatekeeper;
pub mod process;
pub mod task;

pub use gatekeeper::Gatekeeper;
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

/// Which element of `plan` covers sample `current_sample`, if any (README, "Deadlines":
/// element `i` is valid on `[t_k + i Ts, t_k + (i + 1) Ts)`). A plan from the future
/// covers nothing yet; a plan older than its horizon is exhausted.
pub fn covering_element(plan: &Plan, current_sample: u64) -> Option<usize> {
    let age = current_sample.checked_sub(plan.sample)?;
    (age < u64::from(plan.horizon)).then_some(age as usize)
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
    geometry: WheelGeometry,
    /// The plan flown: with the safety check on, the committed one.
    active: Option<Plan>,
    /// The safety check (`dfl.gatekeeper`).
    gatekeeper: Option<Gatekeeper>,
    /// A plan offered and not yet checked (the check needs the estimate of the tick).
    offered: Option<Plan>,
    /// Braking because the committed trajectory was found unsafe, until a plan passes.
    safety_braking: bool,
    /// The committed plan found unsafe but flown on (braking would be worse), reported.
    flown_unsafe: Option<u64>,
    /// Sample of the newest plan taken (offered, committed or given up).
    newest: Option<u64>,
    interventions: u32,
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

impl Dfl {
    pub fn new(scenario: &Scenario) -> Dfl {
        Dfl {
            zeta: scenario.robot.zeta0,
            zeta_threshold: scenario.dfl.zeta_threshold,
            brake_decel: scenario.brake_decel(),
            timing: scenario.timing.clone(),
            dt_s: scenario.timing.dt_s(),
            geometry: WheelGeometry {
                wheel_radius_m: scenario.plant.wheel_radius_m,
                wheel_base_m: scenario.plant.wheel_base_m,
            },
            active: None,
            gatekeeper: scenario.dfl.gatekeeper.then(|| Gatekeeper::new(scenario)),
            offered: None,
            safety_braking: false,
            flown_unsafe: None,
            newest: None,
            interventions: 0,
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
        let mut outcome = CheckOutcome::default();
        let Some(gatekeeper) = &self.gatekeeper else {
            return outcome;
        };
        let sample = self.timing.sample_of(tick);
        let into_sample_s = self.timing.time_into_sample_s(tick);
        let [x, y, theta, _] = estimate.state;
        let z = protocol::phi([x, y, theta, self.zeta]);
        let sigma = estimate.position_sigma();
        let (commit_growth, keep_growth) = (
            gatekeeper.commit_growth(sigma),
            gatekeeper.keep_growth(sigma),
        );
        let mut note = |intervention, plan_sample, clearance_m| {
            outcome = CheckOutcome {
                intervention,
                plan_sample,
                clearance_m,
                count: outcome.count + 1,
            };
        };
        let mut committed = false;
        if let Some(plan) = self.offered.take() {
            match gatekeeper.check(&plan, sample, into_sample_s, z, commit_growth) {
                None => {
                    self.active = Some(plan);
                    self.safety_braking = false;
                    committed = true;
                }
                Some(clearance) => note(Intervention::PlanRefused, plan.sample, clearance),
            }
        }
        // The committed trajectory, flown from this estimate (not needed when it was just
        // checked, nor once its plan is exhausted and the DFL brakes anyway).
        let unsafe_committed = match &self.active {
            Some(plan) if !committed && covering_element(plan, sample).is_some() => gatekeeper
                .check(plan, sample, into_sample_s, z, keep_growth)
                .map(|clearance| (plan.sample, clearance)),
            _ => None,
        };
        if let Some((plan_sample, clearance)) = unsafe_committed {
            // Brake at once, unless braking from here would enter an obstacle deeper than
            // the committed trajectory does (a plan turning away from it, say): then fly it
            // on, reported once.
            let braking = gatekeeper.brake_check(z, keep_growth);
            if braking.is_none_or(|b| b >= clearance) {
                note(Intervention::CommittedUnsafe, plan_sample, clearance);
                self.active = None;
                self.safety_braking = true;
            } else if self.flown_unsafe != Some(plan_sample) {
                note(Intervention::CommittedUnsafe, plan_sample, clearance);
                self.flown_unsafe = Some(plan_sample);
            }
        }
        self.interventions += outcome.count;
        outcome
    }

    /// One inner tick: the command for `[t_j, t_j + Ts/M)` from `estimate` and the active
    /// plan; integrates zeta over the tick. The header's publish time and epoch are the
    /// caller's to fill.
    pub fn step(&mut self, estimate: &Estimate, tick: u64) -> Actuation {
        let checked = self.check(estimate, tick);
        let sample = self.timing.sample_of(tick);
        let theta = estimate.state[2];
        let chosen = self
            .active
            .as_ref()
            .and_then(|p| covering_element(p, sample).map(|i| (p.v[i], p.sample)));
        let braking = if self.safety_braking {
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
                let mode = if plan_sample != sample {
                    CommandMode::Shifted
                } else if guarded {
                    CommandMode::ZetaGuard
                } else {
                    CommandMode::Nominal
                };
                (u, v, mode, plan_sample)
            }
            None => (self.braking_input(), [0.0; 2], braking, 0),
        };
        let mut act = self.command(tick, u, v, mode, plan_sample);
        act.intervention = checked.intervention as u32;
        act.intervention_plan = checked.plan_sample;
        act.intervention_clearance_m = checked.clearance_m;
        act
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
        let u1 = 0.5 * (zeta_start + self.zeta);
        let u2 = u[1];
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
mod tests {
    use super::*;
    use protocol::{PLAN_MISSING, PlanStatus};

    #[test]
    fn phi_and_its_inverse_round_trip() {
        for x_bar in [
            [1.0, -2.0, 0.3, 0.8],
            [0.0, 4.0, -2.9, 1.5],
            [-3.0, 0.5, 3.1, 0.01],
        ] {
            let back = phi_inverse(phi(x_bar), 0.0);
            for i in 0..4 {
                assert!((back[i] - x_bar[i]).abs() < 1e-12, "{x_bar:?} -> {back:?}");
            }
        }
        let at_rest = phi_inverse(phi([2.0, 3.0, 1.2, 0.0]), 1.2);
        assert_eq!(at_rest, [2.0, 3.0, 1.2, 0.0]);
    }

    #[test]
    fn zeta_guard_zeroes_steering_below_threshold_in_both_directions() {
        // v within 45 degrees of the robot's axis (forwards, then backwards).
        for v in [[1.0, 0.5], [-1.0, -0.5]] {
            for zeta in [0.0, 0.005, -0.01, 0.01] {
                let (u, guarded) = linearizing_input(0.7, zeta, v, 0.01);
                assert!(guarded && u[1] == 0.0, "zeta {zeta}: {u:?}");
            }
        }
        let (u, guarded) = linearizing_input(0.7, -0.5, [1.0, -2.0], 0.01);
        assert!(!guarded && u[1] != 0.0);
    }

    #[test]
    fn under_the_guard_a_plan_across_the_axis_turns_the_robot_in_place_towards_it() {
        let theta = 0.7;
        for v in [[1.0, -2.0], [-1.5, 1.0], [0.0, 1.0]] {
            let ([u1, u2], guarded) = linearizing_input(theta, 0.0, v, 0.01);
            assert!(guarded);
            // Turning at u2 for TURN_IN_PLACE_S puts v on the robot's axis.
            let aligned = theta + u2 * TURN_IN_PLACE_S;
            let across = -v[0] * aligned.sin() + v[1] * aligned.cos();
            assert!(across.abs() < 1e-12, "{v:?}: {across}");
            assert!(u2.abs() <= std::f64::consts::FRAC_PI_2 / TURN_IN_PLACE_S);
            assert_eq!(u1, v[0] * theta.cos() + v[1] * theta.sin());
        }
        // No turning for a plan that asks for (almost) nothing.
        let (u, _) = linearizing_input(theta, 0.0, [0.0, 1e-4], 0.01);
        assert_eq!(u[1], 0.0);
    }

    #[test]
    fn z_follows_the_double_integrator_under_the_linearizing_law() {
        // Continuous DFL with constant v: z1'' = v1 and z3'' = v2 exactly, so after T
        // seconds z matches the double integrator up to RK4's error.
        let v = [0.4, -0.7];
        let x0 = [1.0, 2.0, 0.5, 1.2];
        let (t, steps) = (1.0, 1000);
        let mut x = x0;
        for _ in 0..steps {
            x = plant::rk4_step(&x, t / steps as f64, |s| extended_dynamics(s, v, 0.01));
        }
        let z0 = phi(x0);
        let expected = [
            z0[0] + z0[1] * t + 0.5 * v[0] * t * t,
            z0[1] + v[0] * t,
            z0[2] + z0[3] * t + 0.5 * v[1] * t * t,
            z0[3] + v[1] * t,
        ];
        let z = phi(x);
        for i in 0..4 {
            assert!(
                (z[i] - expected[i]).abs() < 1e-9,
                "z{i}: {} vs {}",
                z[i],
                expected[i]
            );
        }
    }

    #[test]
    fn the_mid_tick_law_follows_the_double_integrator_ten_times_closer() {
        // A second of hard turning (about 1.7 rad/s) in 10 ms ticks, the commands held over
        // each tick as the plant holds them: u1 the mean of zeta, u2 = U2.
        let (dt, ticks, v) = (0.01, 100, [0.8, -1.5]);
        let x0 = [0.0, 0.0, 0.3, 1.0];
        let z0 = phi(x0);
        let t = dt * f64::from(ticks);
        let expected = [
            z0[0] + z0[1] * t + 0.5 * v[0] * t * t,
            z0[1] + v[0] * t,
            z0[2] + z0[3] * t + 0.5 * v[1] * t * t,
            z0[3] + v[1] * t,
        ];
        let error = |mid_tick: bool| {
            let (mut pose, mut zeta) = ([x0[0], x0[1], x0[2]], x0[3]);
            for _ in 0..ticks {
                let (u, _) = if mid_tick {
                    mid_tick_linearizing_input(pose[2], zeta, v, 0.01, dt)
                } else {
                    linearizing_input(pose[2], zeta, v, 0.01)
                };
                let u1 = zeta + 0.5 * u[0] * dt;
                zeta += u[0] * dt;
                for _ in 0..20 {
                    pose = plant::rk4_step(&pose, dt / 20.0, |x| plant::unicycle(x, u1, u[1]));
                }
            }
            let z = phi([pose[0], pose[1], pose[2], zeta]);
            (0..4)
                .map(|i| (z[i] - expected[i]).abs())
                .fold(0.0, f64::max)
        };
        let (start, mid) = (error(false), error(true));
        assert!(
            mid < start / 10.0,
            "start of tick {start:e}, mid-tick {mid:e}"
        );
    }

    fn plan(sample: u64, horizon: u32, status: PlanStatus) -> Plan {
        let mut p = Plan {
            sample,
            horizon,
            status: status as u32,
            ..Plan::default()
        };
        for i in 0..horizon as usize {
            p.v[i] = [i as f64, 0.0];
        }
        p
    }

    #[test]
    fn covering_element_is_the_age_of_the_plan_within_its_horizon() {
        let p = plan(10, 8, PlanStatus::Solved);
        assert_eq!(
            covering_element(&p, 9),
            None,
            "a plan covers nothing before its sample"
        );
        assert_eq!(covering_element(&p, 10), Some(0));
        assert_eq!(covering_element(&p, 17), Some(7));
        assert_eq!(covering_element(&p, 18), None, "exhausted after N samples");
    }

    #[test]
    fn a_late_plan_is_held_until_the_sample_it_arrived_in() {
        let mut dfl = Dfl::new(&Scenario::default());
        let mut inbox = PlanInbox::new(0.05);
        let mut p = plan(100, 8, PlanStatus::Solved);
        // Lockstep: a solve of 2.5 Ts arrives 3 whole samples late.
        p.solve_ns = 125_000_000;
        let lockstep = protocol::clock::RunClock::simulated_at(1000, 0.005);
        let arrival_ns = lockstep.arrival_after_ns(5.0, p.solve_ns, 0.05);
        assert_eq!(inbox.receive(&p, arrival_ns), 103);
        assert!(inbox.has_received(100));
        let est = Estimate::default();
        inbox.release(102, &mut dfl);
        assert_eq!(dfl.step(&est, 1020).mode(), Some(CommandMode::Brake));
        inbox.release(103, &mut dfl);
        let a = dfl.step(&est, 1030);
        assert_eq!(
            (a.mode(), a.v),
            (Some(CommandMode::Shifted), [3.0, 0.0]),
            "element 3 of plan 100"
        );
        // Real time: received 1.2 Ts after its sample started, usable at once (sample 101).
        let mut inbox = PlanInbox::new(0.05);
        assert_eq!(
            inbox.receive(&plan(100, 8, PlanStatus::Solved), 60_000_000),
            101
        );
    }

    #[test]
    fn the_dfl_waits_for_every_plan_unless_it_joined_after_the_previous_one() {
        let mut inbox = PlanInbox::new(0.05);
        assert!(inbox.waits_for(0), "from the start, plan 0 is waited for");
        assert!(
            !inbox.waits_for(40),
            "joined at sample 40: plan 39 never came"
        );
        inbox.receive(&plan(40, 8, PlanStatus::Solved), 0);
        assert!(!inbox.waits_for(40), "plan 40 is here");
        assert!(inbox.waits_for(41));
    }

    #[test]
    fn a_joining_dfl_adopts_the_zeta_the_plant_is_driven_with() {
        let mut dfl = Dfl::new(&Scenario::default());
        dfl.adopt_zeta(0.8);
        assert_eq!(dfl.zeta(), 0.8);
        dfl.adopt_zeta(f64::NAN);
        assert_eq!(dfl.zeta(), 0.8);
    }

    #[test]
    fn a_plan_arriving_exactly_at_the_deadline_meets_it_and_one_later_misses() {
        let mut m = DeadlineMonitor::new(0.05);
        m.sample_started(10, CommandMode::Nominal);
        m.on_plan(&plan(10, 8, PlanStatus::Solved), 50_000_000);
        let v = m.sample_started(11, CommandMode::Shifted).unwrap();
        assert_eq!((v.sample, v.met, v.misses_total), (10, 1, 0));
        m.on_plan(&plan(11, 8, PlanStatus::Solved), 50_000_001);
        let v = m.sample_started(12, CommandMode::Nominal).unwrap();
        assert_eq!(
            (v.sample, v.met, v.misses_total, v.fallback),
            (11, 0, 1, CommandMode::Shifted as u32)
        );
    }

    #[test]
    fn a_missing_or_failed_plan_is_a_miss_with_its_status() {
        let mut m = DeadlineMonitor::new(0.05);
        m.sample_started(0, CommandMode::Brake);
        let v = m.sample_started(1, CommandMode::Brake).unwrap();
        assert_eq!((v.met, v.status), (0, PLAN_MISSING));
        m.on_plan(&plan(1, 8, PlanStatus::NumericalError), 1_000_000);
        let v = m.sample_started(2, CommandMode::Brake).unwrap();
        assert_eq!(
            (v.met, v.status, v.misses_total),
            (0, PlanStatus::NumericalError as u32, 2)
        );
    }

    #[test]
    fn a_plan_older_than_its_horizon_is_exhausted_and_the_dfl_brakes() {
        let mut dfl = Dfl::new(&Scenario::default());
        assert!(dfl.offer(&plan(10, 8, PlanStatus::Solved)));
        let est = Estimate::default();
        assert_eq!(
            dfl.step(&est, 170).mode(),
            Some(CommandMode::Shifted),
            "element 7 still covers sample 17"
        );
        assert_eq!(
            dfl.step(&est, 180).mode(),
            Some(CommandMode::Brake),
            "nothing covers sample 18"
        );
    }

    #[test]
    fn older_or_failed_plans_never_replace_the_active_one() {
        let mut dfl = Dfl::new(&Scenario::default());
        assert!(dfl.offer(&plan(5, 8, PlanStatus::Solved)));
        assert!(!dfl.offer(&plan(4, 8, PlanStatus::Solved)));
        assert!(!dfl.offer(&plan(6, 8, PlanStatus::Infeasible)));
        let est = Estimate {
            state: [7.0, 7.0, 0.0, 0.0],
            ..Estimate::default()
        };
        let a = dfl.step(&est, 6 * 10);
        assert_eq!(a.mode(), Some(CommandMode::Shifted));
        assert_eq!((a.plan_sample, a.v), (5, [1.0, 0.0]));
    }

    /// A robot at the origin heading along x at 1 m/s, an obstacle whose edge is 1 m
    /// ahead; the safety check on or off.
    fn approaching(gatekeeper: bool) -> (Dfl, Estimate) {
        let mut s = Scenario {
            obstacles: vec![protocol::Obstacle {
                x: 1.5,
                y: 0.0,
                radius: 0.5,
            }],
            ..Scenario::default()
        };
        s.robot.zeta0 = 1.0;
        s.dfl.gatekeeper = gatekeeper;
        let estimate = Estimate {
            state: [0.0, 0.0, 0.0, 1.0],
            ..Estimate::default()
        };
        (Dfl::new(&s), estimate)
    }

    /// Plan `sample` accelerating at `ax` along x for 8 samples (0.4 s).
    fn along_x(sample: u64, ax: f64) -> Plan {
        let mut p = plan(sample, 8, PlanStatus::Solved);
        p.v = [[ax, 0.0]; protocol::MAX_HORIZON];
        p
    }

    #[test]
    fn a_plan_into_an_obstacle_is_refused_and_the_committed_one_goes_on() {
        // Braking at 2 m/s^2 for 0.4 s, then the brake: 0.25 m. Speeding up at 2 m/s^2:
        // 0.56 m, then 0.54 m to stop, into the obstacle 1 m ahead.
        let (mut dfl, estimate) = approaching(true);
        assert!(dfl.offer(&along_x(0, -2.0)));
        let a = dfl.step(&estimate, 0);
        assert_eq!(
            (a.mode(), a.intervention()),
            (Some(CommandMode::Nominal), Some(Intervention::None))
        );
        assert!(dfl.offer(&along_x(1, 2.0)));
        let a = dfl.step(&estimate, 10);
        assert_eq!(a.intervention(), Some(Intervention::PlanRefused));
        assert_eq!(
            (a.mode(), a.plan_sample, a.v),
            (Some(CommandMode::Shifted), 0, [-2.0, 0.0])
        );
        assert!(a.intervention_clearance_m < 0.0);
        assert_eq!((a.safety_interventions, dfl.interventions()), (1, 1));
    }

    #[test]
    fn without_a_committed_plan_an_unsafe_one_leaves_the_robot_braking() {
        let (mut dfl, estimate) = approaching(true);
        dfl.offer(&along_x(0, 2.0));
        let a = dfl.step(&estimate, 0);
        assert_eq!(
            (a.mode(), a.intervention()),
            (Some(CommandMode::Brake), Some(Intervention::PlanRefused))
        );
        assert_eq!(
            a.linearizing_input,
            [-3.0, 0.0],
            "the brake at its deceleration"
        );
    }

    #[test]
    fn an_estimate_that_shows_the_committed_trajectory_unsafe_brings_the_brake_until_a_plan_passes()
    {
        let (mut dfl, estimate) = approaching(true);
        dfl.offer(&along_x(0, -2.0));
        dfl.step(&estimate, 0);
        // The estimate jumps 0.8 m ahead: the rest of the plan and the brake now run 1.04 m.
        let jumped = Estimate {
            state: [0.8, 0.0, 0.0, 1.0],
            ..Estimate::default()
        };
        let a = dfl.step(&jumped, 1);
        assert_eq!(
            (a.mode(), a.intervention()),
            (
                Some(CommandMode::SafetyBrake),
                Some(Intervention::CommittedUnsafe)
            )
        );
        assert_eq!(a.plan_sample, 0);
        let a = dfl.step(&jumped, 2);
        assert_eq!(
            (a.mode(), a.intervention()),
            (Some(CommandMode::SafetyBrake), Some(Intervention::None))
        );
        // A plan that stops in time from there (in 1/6 m) is committed and flown.
        dfl.offer(&along_x(1, -3.0));
        let a = dfl.step(&jumped, 10);
        assert_eq!(
            (a.mode(), a.intervention()),
            (Some(CommandMode::Nominal), Some(Intervention::None))
        );
        assert_eq!(dfl.interventions(), 1);
    }

    #[test]
    fn a_committed_plan_swerving_away_flies_on_when_braking_would_go_in_deeper() {
        // A small obstacle straight ahead: braking along the heading runs through it (5 cm
        // deep), the committed plan's swerve clips it by 1.6 cm.
        let mut s = Scenario {
            obstacles: vec![protocol::Obstacle {
                x: 0.15,
                y: 0.0,
                radius: 0.05,
            }],
            ..Scenario::default()
        };
        s.robot.zeta0 = 1.0;
        let mut dfl = Dfl::new(&s);
        let mut swerve = plan(0, 8, PlanStatus::Solved);
        swerve.v = [[0.0, 3.0]; protocol::MAX_HORIZON];
        dfl.offer(&swerve);
        let far = Estimate {
            state: [-5.0, 0.0, 0.0, 1.0],
            ..Estimate::default()
        };
        assert_eq!(dfl.step(&far, 0).intervention(), Some(Intervention::None));
        let close = Estimate {
            state: [0.0, 0.0, 0.0, 1.0],
            ..Estimate::default()
        };
        let a = dfl.step(&close, 1);
        assert_eq!(
            (a.mode(), a.intervention()),
            (
                Some(CommandMode::Nominal),
                Some(Intervention::CommittedUnsafe)
            )
        );
        assert!((-0.02..-0.01).contains(&a.intervention_clearance_m));
        // Flown on, reported once.
        let a = dfl.step(&close, 2);
        assert_eq!(
            (a.mode(), a.intervention()),
            (Some(CommandMode::Nominal), Some(Intervention::None))
        );
        assert_eq!(dfl.interventions(), 1);
    }

    #[test]
    fn an_older_plan_never_replaces_a_newer_one_given_up() {
        let (mut dfl, estimate) = approaching(true);
        dfl.offer(&along_x(5, -2.0));
        dfl.step(&estimate, 50);
        let jumped = Estimate {
            state: [0.8, 0.0, 0.0, 1.0],
            ..Estimate::default()
        };
        assert_eq!(dfl.step(&jumped, 51).mode(), Some(CommandMode::SafetyBrake));
        assert!(!dfl.offer(&along_x(4, -3.0)), "plan 4 is older than plan 5");
    }

    #[test]
    fn without_the_safety_check_the_unsafe_plan_is_flown() {
        let (mut dfl, estimate) = approaching(false);
        dfl.offer(&along_x(0, 2.0));
        let a = dfl.step(&estimate, 0);
        assert_eq!(
            (a.mode(), a.v, a.intervention()),
            (
                Some(CommandMode::Nominal),
                [2.0, 0.0],
                Some(Intervention::None)
            )
        );
    }

    #[test]
    fn without_a_covering_plan_the_dfl_brakes_zeta_to_zero_without_steering() {
        let mut s = Scenario::default();
        s.robot.zeta0 = 1.0;
        let mut dfl = Dfl::new(&s);
        let est = Estimate {
            state: [7.0, 7.0, 0.0, 1.0],
            ..Estimate::default()
        };
        let mut last = dfl.zeta();
        // The speed falls at the braking deceleration, to exactly zero.
        let per_tick = s.brake_decel() * s.timing.dt_s();
        for tick in 0..200 {
            let a = dfl.step(&est, tick);
            assert_eq!(a.mode(), Some(CommandMode::Brake));
            assert_eq!(a.u2, 0.0);
            let expected = (last - per_tick).max(0.0);
            assert!(
                (a.zeta - expected).abs() < 1e-9,
                "tick {tick}: zeta {} not {expected}",
                a.zeta
            );
            last = a.zeta;
        }
        assert_eq!(dfl.zeta(), 0.0);
    }
}
