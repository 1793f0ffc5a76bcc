//! What crosses process boundaries in scmpc: the message types, the scenario schema, and
//! the few conventions every role must agree on (angle wrapping, the wheel transform).

pub mod clock;
pub mod ipc;
pub mod messages;
pub mod scenario;

pub use messages::*;
pub use scenario::*;

/// Wraps an angle to (-pi, pi], rad.
pub fn wrap_angle(theta_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = (theta_rad + PI).rem_euclid(TAU) - PI;
    if w <= -PI { w + TAU } else { w }
}

/// `z = Phi(x_bar) = [x, zeta cos theta, y, zeta sin theta]` (paper eq. mobile37): the
/// map from the extended state to the linear equivalent model, shared by the MPC (which
/// plans in `z`) and the DFL (which realizes it).
pub fn phi(x_bar: [f64; 4]) -> [f64; 4] {
    let [x, y, theta, zeta] = x_bar;
    [x, zeta * theta.cos(), y, zeta * theta.sin()]
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
