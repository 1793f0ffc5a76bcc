//! The linear equivalent model and its LQR terminal ingredients.
//!
//! With `z = [x, xdot, y, ydot]` and `v = [xddot, yddot]` the DFL-linearized robot is two
//! double integrators (paper eq. mobile46-1). Their zero-order-hold discretization is exact
//! and closed-form.

use nalgebra::{Matrix2, Matrix2x4, Matrix4, Matrix4x2, Vector4};
use protocol::Scenario;

/// Error of the discrete algebraic Riccati equation solver.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DareError {
    #[error("the Riccati iteration met a singular matrix (is (A, B) stabilizable and R > 0?)")]
    Singular,
    #[error("the Riccati iteration did not converge in {0} doublings")]
    NoConvergence(usize),
}

/// Exact zero-order-hold discretization `(A_d, B_d)` at `ts_s` of
/// `z1' = z2, z2' = v1, z3' = z4, z4' = v2`.
pub fn discretize(ts_s: f64) -> (Matrix4<f64>, Matrix4x2<f64>) {
    let t = ts_s;
    #[rustfmt::skip]
    let a = Matrix4::new(
        1.0, t,   0.0, 0.0,
        0.0, 1.0, 0.0, 0.0,
        0.0, 0.0, 1.0, t,
        0.0, 0.0, 0.0, 1.0,
    );
    #[rustfmt::skip]
    let b = Matrix4x2::new(
        0.5 * t * t, 0.0,
        t,           0.0,
        0.0,         0.5 * t * t,
        0.0,         t,
    );
    (a, b)
}

/// Solves the DARE `P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q` by the structured doubling
/// algorithm (quadratic convergence). `P` is the terminal weight `Q_bar` of eq. (56).
pub fn dare(
    a: &Matrix4<f64>,
    b: &Matrix4x2<f64>,
    q: &Matrix4<f64>,
    r: &Matrix2<f64>,
) -> Result<Matrix4<f64>, DareError> {
    const MAX_DOUBLINGS: usize = 100;
    let r_inv = r.try_inverse().ok_or(DareError::Singular)?;
    let (mut ak, mut gk, mut hk) = (*a, b * r_inv * b.transpose(), *q);
    for _ in 0..MAX_DOUBLINGS {
        let w = (Matrix4::identity() + gk * hk)
            .try_inverse()
            .ok_or(DareError::Singular)?;
        let a_next = ak * w * ak;
        let g_next = gk + ak * w * gk * ak.transpose();
        let h_next = hk + ak.transpose() * hk * w * ak;
        let change = (h_next - hk).norm();
        (ak, gk, hk) = (a_next, g_next, h_next);
        if change <= 1e-12 * hk.norm().max(1.0) {
            return Ok(0.5 * (hk + hk.transpose()));
        }
    }
    Err(DareError::NoConvergence(MAX_DOUBLINGS))
}

/// Discrete LQR gain `K` for `v = K z` (so `A + B K` is the closed loop), given the DARE
/// solution `p`: `K = -(R + B'PB)^-1 B'PA`.
pub fn lqr_gain(
    a: &Matrix4<f64>,
    b: &Matrix4x2<f64>,
    r: &Matrix2<f64>,
    p: &Matrix4<f64>,
) -> Result<Matrix2x4<f64>, DareError> {
    let s = (r + b.transpose() * p * b)
        .try_inverse()
        .ok_or(DareError::Singular)?;
    Ok(-s * b.transpose() * p * a)
}

/// `Q` and `R` of the scenario (eq. 51).
pub fn q_matrix(scenario: &Scenario) -> Matrix4<f64> {
    Matrix4::from_diagonal(&Vector4::from(scenario.mpc.q_diag))
}
pub fn r_matrix(scenario: &Scenario) -> Matrix2<f64> {
    Matrix2::from_diagonal(&nalgebra::Vector2::from(scenario.mpc.r_diag))
}

/// `Q_bar`, the DARE solution of the scenario's linearized model (eq. 56).
pub fn terminal_weight(scenario: &Scenario) -> Result<Matrix4<f64>, DareError> {
    let (a, b) = discretize(scenario.timing.ts_s);
    dare(&a, &b, &q_matrix(scenario), &r_matrix(scenario))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zoh_discretization_is_exact_for_the_double_integrator() {
        // Constant v over ts: x(ts) = x0 + xdot0 ts + v ts^2 / 2, xdot(ts) = xdot0 + v ts.
        let (a, b) = discretize(0.05);
        let z0 = nalgebra::Vector4::new(1.0, -0.5, 2.0, 0.25);
        let v = nalgebra::Vector2::new(0.3, -1.2);
        let z1 = a * z0 + b * v;
        let t = 0.05;
        let expected = [
            1.0 - 0.5 * t + 0.15 * t * t,
            -0.5 + 0.3 * t,
            2.0 + 0.25 * t - 0.6 * t * t,
            0.25 - 1.2 * t,
        ];
        for i in 0..4 {
            assert!((z1[i] - expected[i]).abs() < 1e-15);
        }
    }

    #[test]
    fn dare_solution_satisfies_the_lyapunov_identity_of_eq_56() {
        let (a, b) = discretize(0.05);
        let q = Matrix4::identity();
        let r = Matrix2::identity() * 100.0;
        let p = dare(&a, &b, &q, &r).unwrap();
        let k = lqr_gain(&a, &b, &r, &p).unwrap();
        let acl = a + b * k;
        // Q_bar - (A + BK)' Q_bar (A + BK) = Q + K' R K
        let residual = p - acl.transpose() * p * acl - (q + k.transpose() * r * k);
        assert!(
            residual.norm() < 1e-8 * p.norm(),
            "residual {:e}",
            residual.norm()
        );
        // and the closed loop is stable.
        let spectral_radius = acl
            .complex_eigenvalues()
            .iter()
            .map(|l| l.norm())
            .fold(0.0, f64::max);
        assert!(
            spectral_radius < 1.0,
            "closed loop not stable: {spectral_radius}"
        );
    }
}
