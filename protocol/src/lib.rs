//! What every part of scmpc agrees on, and no transport: the message types and the data
//! flow between roles, the scenario schema with its one validator, the [`task::Task`]
//! every role implements, the geometry, and the few conventions every role must share
//! (angle wrapping, the wheel transform). The crate `runtime` carries these messages over
//! iceoryx2 (it turns on this crate's feature `iceoryx2`, which makes every message
//! iceoryx2's `ZeroCopySend`); the role crates build without it.

pub mod actuator;
pub mod endpoint;
pub mod geometry;
pub mod graph;
pub mod layout;
pub mod messages;
pub mod prediction;
pub mod samples;
pub mod scenario;
pub mod task;
pub mod topics;

pub use geometry::*;
pub use messages::*;
pub use prediction::*;
pub use scenario::*;

/// Wraps an angle to (-pi, pi], rad.
pub fn wrap_angle(theta_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = (theta_rad + PI).rem_euclid(TAU) - PI;
    if w <= -PI { w + TAU } else { w }
}

/// `z = Phi(x_bar) = [x, zeta cos theta, y, zeta sin theta]` (paper eq. mobile37-1): the
/// map from the extended state to the linear equivalent model, shared by the MPC (which
/// plans in `z`) and the DFL (which realizes it).
pub fn phi(x_bar: [f64; 4]) -> [f64; 4] {
    let [x, y, theta, zeta] = x_bar;
    [x, zeta * theta.cos(), y, zeta * theta.sin()]
}

/// Inverse of [`phi`] on the branch `zeta >= 0`; at rest (`zeta = 0`) theta is not
/// determined by `z` and `theta_at_rest_rad` is returned.
pub fn phi_inverse(z: [f64; 4], theta_at_rest_rad: f64) -> [f64; 4] {
    let zeta = z[1].hypot(z[3]);
    let theta = if zeta > 0.0 {
        z[3].atan2(z[1])
    } else {
        theta_at_rest_rad
    };
    [z[0], z[2], theta, zeta]
}

/// A wait of `seconds` (validated positive where it comes from a scenario; one that is
/// negative, not a number or beyond what a `Duration` holds waits the longest there is
/// rather than panicking).
pub fn wait_of_s(seconds: f64) -> std::time::Duration {
    std::time::Duration::try_from_secs_f64(seconds).unwrap_or(std::time::Duration::MAX)
}

/// A period in whole nanoseconds.
pub fn period_ns(period_s: f64) -> u64 {
    (period_s * 1e9).round() as u64
}

/// Distance the fallback brake covers from `speed_m_s` (either sign), m: `U2 = 0`, so
/// the robot moves straight along its heading, and `U1` takes zeta to zero at `decel`
/// (m/s^2), the command being held over steps of `hold_s` (the DFL's inner tick). The
/// continuous distance is `s^2 / (2 a)`; the last step, whose command only has the rest of
/// the speed `rho < a hold` to take away, adds `rho (hold / 2 - rho / (2 a))`, which is at
/// most `min(s hold / 2, a hold^2 / 8)`.
pub fn stopping_distance(speed_m_s: f64, decel: f64, hold_s: f64) -> f64 {
    let s = speed_m_s.abs();
    s * s / (2.0 * decel) + (0.5 * s * hold_s).min(0.125 * decel * hold_s * hold_s)
}

/// A robot whose commanded forward speed (the DFL's zeta) is below this is at rest, m/s:
/// a disturbance may still push it about, but it does not drive into anything. The judge
/// counts a contact that starts below it as one at rest, and the DFL's safety check
/// calls a contact predicted where the robot is this slow one at rest.
pub const REST_SPEED_M_S: f64 = 1e-3;

/// A fleet's robot slower than this holds still, m/s: to the rule by which it gives way
/// (`mpc::give_way`), and to the judge, for which a robot standing near another robot
/// faster than this waits for it rather than stalls (`record::judge`).
pub const ROBOT_STILL_SPEED_M_S: f64 = 0.05;

/// The DFL's safety check commits a trajectory only if it clears every obstacle, grown by
/// the robot's radius, `mpc.safety_margin_m` and `kappa sigma`, by a further
/// [`commit_margin_m`]; it gives a committed trajectory up only when, flown from the
/// current estimate, it would enter the obstacle grown by those alone. The gap between the
/// two takes the estimate's drift from tick to tick (a fraction of sigma) and the
/// difference between the robot and its linearized model (the zeta guard, the held
/// inner-tick commands: micrometres) without giving up safe trajectories (docs/safety.md). This is its fixed part, m.
pub const COMMIT_MARGIN_M: f64 = 1e-3;

/// The extra clearance of the commit check over the re-check (module docs of
/// `dfl::gatekeeper`): one standard deviation `sigma_m` of the position estimate and
/// [`COMMIT_MARGIN_M`], m. Measured on noisy random worlds (docs/safety.md), a margin of
/// [`COMMIT_MARGIN_M`] alone had the DFL give up trajectories several times a second and
/// halved the worlds that reached their goal.
pub fn commit_margin_m(position_sigma_m: f64) -> f64 {
    position_sigma_m + COMMIT_MARGIN_M
}

/// Differential-drive geometry: the transform `T` of paper eq. (5) between wheel speeds
/// `[omega_r, omega_l]` (rad/s) and body inputs `[u1, u2]` (m/s, rad/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelGeometry {
    pub wheel_radius_m: f64,
    pub wheel_base_m: f64,
}

impl WheelGeometry {
    /// `[u1, u2] = T [omega_r, omega_l]`.
    pub fn body_inputs(&self, wheels: [f64; 2]) -> [f64; 2] {
        let (r, d) = (self.wheel_radius_m, self.wheel_base_m);
        [
            r / 2.0 * (wheels[0] + wheels[1]),
            r / d * (wheels[0] - wheels[1]),
        ]
    }
    /// `[omega_r, omega_l] = T^-1 [u1, u2]`.
    pub fn wheel_speeds(&self, body: [f64; 2]) -> [f64; 2] {
        let (r, d) = (self.wheel_radius_m, self.wheel_base_m);
        let sum = 2.0 * body[0] / r;
        let diff = d * body[1] / r;
        [(sum + diff) / 2.0, (sum - diff) / 2.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_lands_in_half_open_interval() {
        use std::f64::consts::PI;
        for k in -5..=5 {
            let a = 0.3 + k as f64 * 2.0 * PI;
            assert!((wrap_angle(a) - 0.3).abs() < 1e-12);
        }
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
    }

    #[test]
    fn wheel_transform_round_trips() {
        let g = WheelGeometry {
            wheel_radius_m: 0.1,
            wheel_base_m: 0.5,
        };
        let body = [0.7, -1.3];
        let back = g.body_inputs(g.wheel_speeds(body));
        assert!((back[0] - body[0]).abs() < 1e-12 && (back[1] - body[1]).abs() < 1e-12);
    }
}
