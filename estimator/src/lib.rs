//! The state estimator: an extended Kalman filter on the unicycle, driven by the commanded
//! inputs it hears, or a passthrough of the raw measurement (the paper's noisy feedback).
//!
//! Both publish `x_bar = [x, y, theta, zeta]`, where zeta is the DFL's own integrator state
//! as reported on the actuation service, and the covariance of `[x, y, theta]`.

use nalgebra::{Matrix3, Vector3};
use protocol::actuator::BaseModel;
use protocol::{Estimate, EstimatorKind, Header, Scenario, wrap_angle};

pub mod task;
pub use task::EstimatorTask;

/// Smallest measurement variance the EKF uses, so a noise-free run is exact state
/// feedback (to ~1e-8 relative) without a singular innovation covariance.
pub const MIN_MEASUREMENT_VARIANCE: f64 = 1e-12;

/// Unicycle motion over `dt_s` with `(u1, u2)` held: exact circular arc
/// ([`protocol::actuator::chord`]). Returns the new pose and the Jacobian of the new pose
/// with respect to the old one (only the heading moves the chord).
pub fn predict_pose(
    pose: &Vector3<f64>,
    u1: f64,
    u2: f64,
    dt_s: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    let [dx, dy] = protocol::actuator::chord(pose[2], [u1, u2], dt_s);
    let next = Vector3::new(pose[0] + dx, pose[1] + dy, pose[2] + u2 * dt_s);
    let mut jacobian = Matrix3::identity();
    jacobian[(0, 2)] = -dy;
    jacobian[(1, 2)] = dx;
    (next, jacobian)
}

/// Extended Kalman filter on `[x, y, theta]` with a full-state measurement.
#[derive(Debug, Clone)]
pub struct Ekf {
    mean: Vector3<f64>,
    covariance: Matrix3<f64>,
    process_noise_rate: Matrix3<f64>,
    measurement_noise: Matrix3<f64>,
}

impl Ekf {
    pub fn new(first_measurement: [f64; 3], scenario: &Scenario) -> Ekf {
        let e = &scenario.estimator;
        let r = scenario
            .plant
            .noise_variance
            .per_axis()
            .map(|v| v.max(MIN_MEASUREMENT_VARIANCE));
        Ekf {
            mean: Vector3::from(first_measurement),
            covariance: Matrix3::from_diagonal(&Vector3::from(e.initial_variance)),
            process_noise_rate: Matrix3::from_diagonal(&Vector3::from(e.process_noise)),
            measurement_noise: Matrix3::from_diagonal(&Vector3::from(r)),
        }
    }

    /// Time update with the inputs held over the last `dt_s`.
    pub fn predict(&mut self, u1: f64, u2: f64, dt_s: f64) {
        let (mean, f) = predict_pose(&self.mean, u1, u2, dt_s);
        self.mean = mean;
        self.covariance = f * self.covariance * f.transpose() + self.process_noise_rate * dt_s;
    }

    /// Measurement update with `y = [x, y, theta]`; the heading innovation is wrapped.
    pub fn update(&mut self, y: [f64; 3]) {
        let mut innovation = Vector3::from(y) - self.mean;
        innovation[2] = wrap_angle(innovation[2]);
        let s = self.covariance + self.measurement_noise;
        let Some(s_inv) = s.try_inverse() else { return };
        let gain = self.covariance * s_inv;
        self.mean += gain * innovation;
        self.mean[2] = wrap_angle(self.mean[2]);
        // Joseph form keeps the covariance symmetric and positive definite.
        let i_k = Matrix3::identity() - gain;
        self.covariance = i_k * self.covariance * i_k.transpose()
            + gain * self.measurement_noise * gain.transpose();
    }

    pub fn pose(&self) -> [f64; 3] {
        self.mean.into()
    }

    pub fn covariance(&self) -> [f64; 9] {
        // nalgebra stores column-major; the covariance is symmetric so the order agrees.
        self.covariance.as_slice().try_into().unwrap_or([0.0; 9])
    }
}

/// How the robot moved over the last tick, as the estimator models it: up to two stretches
/// (duration, s; speeds `[u1, u2]` held or, with a lag, their mean over it).
#[derive(Debug, Clone, Copy, Default)]
struct Moved {
    stretches: [(f64, [f64; 2]); 2],
    count: usize,
}

/// The estimator role: EKF or passthrough, as the scenario says.
pub struct Estimator {
    kind: EstimatorKind,
    ekf: Option<Ekf>,
    scenario: Scenario,
    /// The base's commands in flight and its speeds, for a base with a lag or a delay
    /// (`robot.actuator_lag_s`, `robot.command_delay_s`): the EKF predicts with the speeds
    /// the base has, not with the command it was just sent.
    base: Option<BaseModel>,
    /// Whether a measurement has been taken (the first starts the filter).
    started: bool,
}

impl Estimator {
    /// How the robot moved over the last `dt_s` under the command `applied` (as the
    /// wheels' speed limit, the robot's own, realizes it): held without a model of the
    /// base (nothing without a command), else as the base's model follows its commands
    /// (none heard: the base was sent none).
    fn moved(&mut self, applied: Option<[f64; 2]>, dt_s: f64) -> Moved {
        let realized = |c| self.scenario.plant.realized_inputs(c);
        let mut moved = Moved::default();
        match (&mut self.base, applied) {
            (Some(base), applied) => base.advance(
                realized(applied.unwrap_or([0.0; 2])),
                |duration_s, speeds| {
                    moved.stretches[moved.count] = (duration_s, speeds);
                    moved.count += 1;
                },
            ),
            (None, Some(command)) => {
                moved.stretches[0] = (dt_s, realized(command));
                moved.count = 1;
            }
            (None, None) => {}
        }
        moved
    }

    pub fn new(scenario: &Scenario) -> Estimator {
        Estimator {
            kind: scenario.estimator.kind,
            ekf: None,
            scenario: scenario.clone(),
            base: BaseModel::of(scenario.actuator(), scenario),
            started: false,
        }
    }

    /// A filter that starts mid-run, before its first step: its model of the base (with a
    /// lag or a delay) starts at the speeds `[u1 m/s, u2 rad/s]` the odometry reports, with
    /// no command in flight, rather than at `robot.zeta0`.
    pub fn start_base_at(&mut self, speeds: [f64; 2]) {
        if let (false, Some(base)) = (self.started, &self.base) {
            let dt_s = self.scenario.timing.dt_s();
            self.base = Some(BaseModel::new(base.actuator(), dt_s, speeds));
        }
    }

    /// One inner tick: `applied` are the inputs `(u1, u2)` heard on the actuation service
    /// for the previous tick (held for `dt_s`, the scenario's inner tick), `y` the
    /// measurement of this tick, `zeta` the DFL's zeta at this tick (with a lag or a
    /// delay, the base's modelled forward speed is published instead). The first call
    /// initializes the filter at `y`.
    pub fn step(
        &mut self,
        applied: Option<[f64; 2]>,
        dt_s: f64,
        y: [f64; 3],
        zeta: f64,
        header: Header,
    ) -> Estimate {
        let moved = if self.started {
            self.moved(applied, dt_s)
        } else {
            Moved::default()
        };
        let (pose, covariance) = match self.kind {
            EstimatorKind::Passthrough => {
                let var = self.scenario.plant.noise_variance.per_axis();
                let mut cov = [0.0; 9];
                (cov[0], cov[4], cov[8]) = (var[0], var[1], var[2]);
                (y, cov)
            }
            EstimatorKind::Ekf => {
                let ekf = match self.ekf.as_mut() {
                    Some(ekf) => {
                        for &(duration_s, [u1, u2]) in &moved.stretches[..moved.count] {
                            ekf.predict(u1, u2, duration_s);
                        }
                        ekf.update(y);
                        ekf
                    }
                    None => self.ekf.insert(Ekf::new(y, &self.scenario)),
                };
                (ekf.pose(), ekf.covariance())
            }
        };
        let state = [pose[0], pose[1], pose[2], zeta];
        let (state, ahead) = match &self.base {
            None => (state, state),
            Some(base) => {
                // The DFL's zeta is the speed the base will have when its newest command
                // acts; the state now has the speed the base has now.
                let mut ahead = [pose[0], pose[1], pose[2]];
                let [forward, _] = base.predict(base.ticks_decided(), |duration_s, speeds| {
                    ahead = protocol::actuator::arc(ahead, speeds, duration_s)
                });
                let now = [pose[0], pose[1], pose[2], base.speeds()[0]];
                (now, [ahead[0], ahead[1], ahead[2], forward])
            }
        };
        self.started = true;
        Estimate {
            header,
            state,
            ahead,
            covariance,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::NoiseVariance;
    use rand::SeedableRng;

    #[test]
    fn prediction_matches_the_exact_arc() {
        let pose = Vector3::new(1.0, 2.0, 0.3);
        let (u1, u2, dt) = (1.5, 0.8, 0.4);
        let (next, _) = predict_pose(&pose, u1, u2, dt);
        let th = pose[2] + u2 * dt;
        let exact_x = pose[0] + u1 / u2 * (th.sin() - pose[2].sin());
        let exact_y = pose[1] - u1 / u2 * (th.cos() - pose[2].cos());
        assert!((next[0] - exact_x).abs() < 1e-12 && (next[1] - exact_y).abs() < 1e-12);
    }

    #[test]
    fn prediction_jacobian_matches_finite_differences() {
        let pose = Vector3::new(0.0, 0.0, 1.1);
        let (_, f) = predict_pose(&pose, 2.0, -0.5, 0.1);
        let h = 1e-6;
        let (plus, _) = predict_pose(&(pose + Vector3::new(0.0, 0.0, h)), 2.0, -0.5, 0.1);
        let (minus, _) = predict_pose(&(pose - Vector3::new(0.0, 0.0, h)), 2.0, -0.5, 0.1);
        let numeric = (plus - minus) / (2.0 * h);
        for i in 0..3 {
            assert!((numeric[i] - f[(i, 2)]).abs() < 1e-8);
        }
    }

    #[test]
    fn the_ekf_predicts_with_the_inputs_the_wheels_realize() {
        // u2 = 10 rad/s asks the wheels for +-25 rad/s more than their mean; at 5 rad/s
        // they turn the robot at 2 rad/s and do not move it forward.
        let mut s = Scenario::default();
        s.plant.max_wheel_speed_rad_s = 5.0;
        s.plant.noise_variance = NoiseVariance::Uniform(1.0);
        assert_eq!(s.plant.realized_inputs([0.2, 10.0]), [0.0, 2.0]);
        let mut est = Estimator::new(&s);
        est.step(None, 0.1, [0.0, 0.0, 0.0], 0.0, Header::default());
        // The measurement (variance 1) barely moves the prediction.
        let e = est.step(
            Some([0.2, 10.0]),
            0.1,
            [0.0, 0.0, 0.2],
            0.0,
            Header::default(),
        );
        assert!((e.state[2] - 0.2).abs() < 1e-3, "heading {}", e.state[2]);
        assert!(e.state[0].abs() < 1e-3, "x {}", e.state[0]);
    }

    #[test]
    fn noise_free_ekf_is_exact_state_feedback() {
        let s = Scenario::default();
        let mut est = Estimator::new(&s);
        est.step(None, 0.005, [1.0, 2.0, 0.5], 0.0, Header::default());
        let e = est.step(
            Some([1.0, 0.3]),
            0.005,
            [1.01, 2.02, 0.6],
            0.0,
            Header::default(),
        );
        assert!(
            (e.state[0] - 1.01).abs() < 1e-8 && (e.state[2] - 0.6).abs() < 1e-8,
            "{:?}",
            e.state
        );
    }

    /// Drives the EKF in a circle through theta = pi (where the heading wraps) for `ticks`
    /// ticks, measured with noise of variance 0.05 on every axis (`seed`); calls `each`
    /// from tick 1000 on with the measurement, the estimate and the true pose.
    fn noisy_circle(seed: u64, ticks: usize, mut each: impl FnMut([f64; 3], &Estimate, [f64; 3])) {
        use rand_distr::{Distribution, Normal};
        let mut s = Scenario::default();
        s.plant.noise_variance = NoiseVariance::Uniform(0.05);
        let mut ekf = Estimator::new(&s);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = Normal::new(0.0, 0.05f64.sqrt()).unwrap();
        let (u1, u2, dt) = (1.0, 0.5, 0.005);
        let mut truth = Vector3::new(0.0, 0.0, 3.0);
        for k in 0..ticks {
            let y = [
                truth[0] + n.sample(&mut rng),
                truth[1] + n.sample(&mut rng),
                wrap_angle(truth[2] + n.sample(&mut rng)),
            ];
            let e = ekf.step((k > 0).then_some([u1, u2]), dt, y, u1, Header::default());
            if k >= 1000 {
                each(y, &e, [truth[0], truth[1], truth[2]]);
            }
            truth = predict_pose(&truth, u1, u2, dt).0;
        }
    }

    #[test]
    fn ekf_filters_noise_better_than_passthrough_and_wraps_the_heading() {
        let (mut err_ekf, mut err_raw) = (0.0, 0.0);
        noisy_circle(3, 2000, |y, e, truth| {
            err_ekf += (e.state[0] - truth[0]).powi(2) + wrap_angle(e.state[2] - truth[2]).powi(2);
            err_raw += (y[0] - truth[0]).powi(2) + wrap_angle(y[2] - truth[2]).powi(2);
        });
        assert!(
            err_ekf < 0.1 * err_raw,
            "EKF error {err_ekf} vs raw {err_raw}"
        );
    }

    #[test]
    fn the_reported_position_covariance_matches_the_actual_error() {
        // sigma drives the kappa-sigma margin of the barrier: an optimistic covariance
        // would shrink it below the true error. Pooled over eight noise seeds (each alone
        // measured 0.65-0.92 over twenty seeds), the error must not exceed sigma, nor be
        // so far below it that the margin is mostly waste.
        let (mut squared_error, mut reported) = (0.0, 0.0);
        for seed in 0..8 {
            noisy_circle(seed, 6000, |_, e, truth| {
                squared_error += (e.state[0] - truth[0]).powi(2) + (e.state[1] - truth[1]).powi(2);
                reported += e.covariance[0] + e.covariance[4];
            });
        }
        let ratio = (squared_error / reported).sqrt();
        assert!(
            (0.6..=1.0).contains(&ratio),
            "actual position error is {ratio:.2} times the reported sigma"
        );
    }
}
