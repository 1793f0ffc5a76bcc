//! Stepping out of the way (docs/safety.md, "Stepping out of the way"): a robot that
//! brakes without a plan, or rests, where an obstacle coming at it is predicted to walk
//! into it, drives straight along its heading, forwards or backwards, and brakes again, if
//! that keeps clear of every disc the safety check knows.
//!
//! The MPC plans `N Ts` ahead (a quarter of a second in some configurations): a person
//! who walks at a robot at rest is in its program only when they are about to touch it,
//! and then no plan within the horizon gets out of their way, so every solve fails and the
//! robot waits to be walked into. An evasion is checked [`EVASION_WINDOW_S`] ahead. Along
//! its heading is the only way a robot at rest can move at once (a differential drive
//! turns in place before it goes sideways; under the linearizing law the path is then a
//! straight line, exactly the arc the check models). Evasions accelerate at the brake's
//! deceleration for [`EVASION_STAGES`] samples (no faster than the wheels turn, nor than
//! the robot can stop short of the newest scan's points the way it evades; a robot that
//! evades against its motion first brakes along the way it had, as the brake would) and
//! brake; the shortest one that
//! the check finds clear of every disc (moving ones until the window's end, phantoms and
//! the map as for any plan) is flown, as a committed trajectory: checked again on every
//! tick, and replaced by the first plan of the MPC's that passes.

use crate::gatekeeper::{Foresight, Gatekeeper, Moment};
use protocol::{Plan, PlanStatus};

/// How long after now an evasion, and the brake it replaces, are checked against the
/// obstacles coming at the robot, s: a person at 1.5 m/s comes 1.5 m nearer in it.
pub const EVASION_WINDOW_S: f64 = 1.0;

/// The samples an evasion accelerates for, shortest first (those longer than
/// [`protocol::MAX_HORIZON`] or than the window are left out).
pub const EVASION_STAGES: [u32; 10] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32];

/// The robot as an evasion starts from it: the state `z = [x, xdot, y, ydot]` (absolute),
/// its heading (rad) and its forward speed `zeta` (m/s), `now`.
#[derive(Debug, Clone, Copy)]
pub struct Start {
    pub now: Moment,
    pub z: [f64; 4],
    pub heading_rad: f64,
    pub zeta_m_s: f64,
}

/// How an evasion may drive: at `accel_m_s2`, no faster than `most_speed_m_s` (m/s), with
/// samples of `ts_s`.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub accel_m_s2: f64,
    pub most_speed_m_s: f64,
    pub ts_s: f64,
}

/// The fastest forward speed the wheels of `plant` drive the robot at (both at
/// `plant.max_wheel_speed_rad_s`), m/s; unbounded without a wheel limit.
pub fn most_forward_speed_m_s(plant: &protocol::PlantConfig) -> f64 {
    if plant.max_wheel_speed_rad_s > 0.0 {
        plant.max_wheel_speed_rad_s * plant.wheel_radius_m
    } else {
        f64::INFINITY
    }
}

/// The evasion that accelerates along the heading (`sign` 1: forwards, -1: backwards)
/// for `stages` samples from `start`: a plan for `start.now`'s sample whose first element
/// is flown for the rest of that sample. Its states are where the robot is predicted at
/// each sample's start (the first one: where it is now).
pub fn evasion_plan(start: Start, sign: f64, stages: u32, limits: Limits) -> Plan {
    let (sin, cos) = start.heading_rad.sin_cos();
    let v = [
        sign * limits.accel_m_s2 * cos,
        sign * limits.accel_m_s2 * sin,
    ];
    let mut plan = Plan {
        sample: start.now.sample,
        status: PlanStatus::Solved as u32,
        horizon: stages,
        ..Plan::default()
    };
    let mut z = start.z;
    plan.z[0] = z;
    for i in 0..stages as usize {
        plan.v[i] = v;
        let duration = if i == 0 {
            (limits.ts_s - start.now.into_sample_s).max(0.0)
        } else {
            limits.ts_s
        };
        for (p, w, a) in [(0, 1, v[0]), (2, 3, v[1])] {
            z[p] += z[w] * duration + 0.5 * a * duration * duration;
            z[w] += a * duration;
        }
        plan.z[i + 1] = z;
    }
    plan
}

/// The forward speed (signed, m/s) an evasion along `sign` has at the end of its
/// acceleration: its fastest the way it evades (against the robot's motion, it first
/// brakes, from a speed the free range already holds).
pub fn end_speed_m_s(start: Start, sign: f64, stages: u32, limits: Limits) -> f64 {
    let duration = stages as f64 * limits.ts_s - start.now.into_sample_s;
    start.zeta_m_s + sign * limits.accel_m_s2 * duration.max(0.0)
}

/// What an evasion is checked with: the growth of every disc for the look ahead and for
/// the commit check (m, [`Gatekeeper::keep_growth`], [`Gatekeeper::commit_growth`]), the
/// MPC's horizon `N` (samples).
#[derive(Debug, Clone, Copy)]
pub struct Checks {
    pub keep_growth_m: f64,
    pub commit_growth_m: f64,
    pub horizon: u32,
}

/// How an evasion, and the brake it replaces, look ahead: [`EVASION_WINDOW_S`] (at least
/// the safety check's window), each tracked obstacle going on as it goes.
fn look_ahead(gatekeeper: &Gatekeeper) -> Foresight {
    Foresight {
        window_s: EVASION_WINDOW_S.max(gatekeeper.foresight().window_s),
        prediction: protocol::Prediction::ConstantVelocity,
    }
}

/// The evasion to fly from `start`, if braking there is run into looked ahead
/// ([`look_ahead`]), with the brake's deepest contact so looked ahead (negative, m): the
/// shortest evasion (forwards before backwards) that, looked ahead to its stop and rest,
/// enters no disc, among those whose end speed is within the limits and
/// `may_reach(end_speed_m_s)` allows; flown for its first `N` samples at most (then, if
/// it is still needed, the next evasion goes on from there), which the commit check must
/// find clear as it finds an MPC plan.
pub fn evasion(
    gatekeeper: &Gatekeeper,
    start: Start,
    checks: Checks,
    limits: Limits,
    may_reach: impl Fn(f64) -> bool,
) -> Option<(Plan, f64)> {
    let ahead = look_ahead(gatekeeper);
    let brake = gatekeeper.brake_verdict_within(start.z, start.now, checks.keep_growth_m, ahead);
    let run_into = brake.deepest()?;
    let longest = protocol::MAX_HORIZON.min((ahead.window_s / limits.ts_s) as usize) as u32;
    for stages in EVASION_STAGES.into_iter().filter(|&k| k <= longest) {
        for sign in [1.0, -1.0] {
            let end = end_speed_m_s(start, sign, stages, limits);
            if end.abs() > limits.most_speed_m_s || !may_reach(end) {
                continue;
            }
            let (now, z) = (start.now, start.z);
            let mut plan = evasion_plan(start, sign, stages, limits);
            let gets_away = gatekeeper.verdict_within(&plan, now, z, checks.keep_growth_m, ahead);
            if !gets_away.clear() {
                continue;
            }
            plan.horizon = stages.min(checks.horizon);
            if gatekeeper
                .check(&plan, now, z, checks.commit_growth_m)
                .is_none()
            {
                return Some((plan, run_into));
            }
        }
    }
    None
}
