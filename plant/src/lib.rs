//! The plant: a unicycle (differential-drive robot) integrated with RK4, with seeded
//! Gaussian output noise, optional wheel-speed saturation, process disturbance, and a base
//! that follows its commands with a lag after a delay ([`protocol::actuator`]).

use protocol::actuator::{Actuator, CommandLine};
use protocol::{PlantConfig, Scenario, wrap_angle};
pub mod task;
pub use task::PlantTask;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Unicycle pose `[x_m, y_m, theta_rad]`.
pub type Pose = [f64; 3];

/// Unicycle vector field `[u1 cos theta, u1 sin theta, u2]` (paper eqs. 001-003).
pub fn unicycle(pose: &Pose, u1: f64, u2: f64) -> Pose {
    [u1 * pose[2].cos(), u1 * pose[2].sin(), u2]
}

/// One classical fourth-order Runge-Kutta step of `xdot = f(x)` over `dt_s`.
pub fn rk4_step<const D: usize>(
    x: &[f64; D],
    dt_s: f64,
    f: impl Fn(&[f64; D]) -> [f64; D],
) -> [f64; D] {
    let add = |a: &[f64; D], b: &[f64; D], h: f64| std::array::from_fn(|i| a[i] + h * b[i]);
    let k1 = f(x);
    let k2 = f(&add(x, &k1, dt_s / 2.0));
    let k3 = f(&add(x, &k2, dt_s / 2.0));
    let k4 = f(&add(x, &k3, dt_s));
    std::array::from_fn(|i| x[i] + dt_s / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
}

/// The simulated robot.
pub struct Plant {
    pose: Pose,
    /// The wheels and their speed limit.
    config: PlantConfig,
    substeps: usize,
    noise: [Option<Normal<f64>>; 3],
    disturbance: Option<Normal<f64>>,
    rng: ChaCha8Rng,
    /// The base's lag and delay (`plant.actuator_lag_s`, `plant.command_delay_s`).
    actuator: Actuator,
    /// The commands in flight.
    line: CommandLine,
    /// The base's speeds `[u1 (m/s), u2 (rad/s)]`: with a lag, state of the plant.
    speeds: [f64; 2],
}

impl Plant {
    /// The plant at the scenario's start pose, its noise seeded by the scenario's seed.
    pub fn new(scenario: &Scenario) -> Plant {
        let p = &scenario.plant;
        let gaussian = |std: f64| {
            (std > 0.0)
                .then(|| Normal::new(0.0, std))
                .and_then(Result::ok)
        };
        let var = p.noise_variance.per_axis();
        let actuator = scenario.simulated_actuator();
        let speeds = [scenario.robot.zeta0, 0.0];
        Plant {
            pose: scenario.robot.start,
            config: p.clone(),
            substeps: p.rk4_substeps.max(1),
            noise: var.map(|v| gaussian(v.sqrt())),
            disturbance: gaussian(p.disturbance_std),
            rng: ChaCha8Rng::seed_from_u64(scenario.seed),
            actuator,
            line: CommandLine::new(actuator.delay_s, scenario.timing.dt_s(), speeds),
            speeds,
        }
    }

    /// The true pose, theta wrapped to (-pi, pi].
    pub fn pose(&self) -> Pose {
        [self.pose[0], self.pose[1], wrap_angle(self.pose[2])]
    }

    /// The output `y = pose + noise` (one draw per call).
    pub fn measure(&mut self) -> Pose {
        let truth = self.pose();
        let mut y = truth;
        for (axis, n) in self.noise.iter().enumerate() {
            if let Some(n) = n {
                y[axis] += n.sample(&mut self.rng);
            }
        }
        y[2] = wrap_angle(y[2]);
        y
    }

    /// Wheel saturation: `(u1, u2)` as the wheels can realize them.
    pub fn saturate(&self, u1: f64, u2: f64) -> [f64; 2] {
        self.config.realized_inputs([u1, u2])
    }

    /// The base's speeds `[u1 (m/s), u2 (rad/s)]` now.
    pub fn speeds(&self) -> [f64; 2] {
        self.speeds
    }

    /// Takes the command `(u1, u2)` (after saturation) for the coming `dt_s` and integrates
    /// over it: the base realizes it at once, or ([`protocol::actuator`]) after the delay
    /// and with the lag. Returns the command after saturation.
    pub fn step(&mut self, u1: f64, u2: f64, dt_s: f64) -> [f64; 2] {
        let command = self.saturate(u1, u2);
        let d = match self.disturbance {
            Some(n) => [
                n.sample(&mut self.rng),
                n.sample(&mut self.rng),
                n.sample(&mut self.rng),
            ],
            None => [0.0; 3],
        };
        if self.actuator.is_ideal() {
            self.integrate(command, d, dt_s);
            self.speeds = command;
        } else {
            for (duration_s, in_effect) in self.line.send(command) {
                if duration_s > 0.0 {
                    self.integrate_lagged(in_effect, d, duration_s);
                }
            }
        }
        command
    }

    /// The pose over `dt_s` with the speeds `u` held.
    fn integrate(&mut self, [u1, u2]: [f64; 2], d: [f64; 3], dt_s: f64) {
        let h = dt_s / self.substeps as f64;
        for _ in 0..self.substeps {
            self.pose = rk4_step(&self.pose, h, |x| {
                let f = unicycle(x, u1, u2);
                [f[0] + d[0], f[1] + d[1], f[2] + d[2]]
            });
        }
    }

    /// The pose and the speeds over `duration_s` with `command` in effect: the speeds
    /// follow it with the lag (exactly), the pose is integrated with RK4 in between.
    fn integrate_lagged(&mut self, command: [f64; 2], d: [f64; 3], duration_s: f64) {
        let h = duration_s / self.substeps as f64;
        for _ in 0..self.substeps {
            let start = self.speeds;
            let speeds_at = |t: f64| self.actuator.follow(start, command, t).end;
            // Without lag the speeds jump to the command at once.
            let [now, mid, end] = [speeds_at(0.0), speeds_at(0.5 * h), speeds_at(h)];
            // RK4 of the pose with its speeds given in time: start, middle (twice), end.
            let f = |x: &Pose, [u1, u2]: [f64; 2]| {
                let f = unicycle(x, u1, u2);
                [f[0] + d[0], f[1] + d[1], f[2] + d[2]]
            };
            let add = |a: &Pose, b: &Pose, s: f64| std::array::from_fn(|i| a[i] + s * b[i]);
            let x = self.pose;
            let k1 = f(&x, now);
            let k2 = f(&add(&x, &k1, 0.5 * h), mid);
            let k3 = f(&add(&x, &k2, 0.5 * h), mid);
            let k4 = f(&add(&x, &k3, h), end);
            self.pose = std::array::from_fn(|i| {
                x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
            self.speeds = end;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Exact unicycle motion on a circular arc under constant inputs.
    fn arc(pose: Pose, u1: f64, u2: f64, t: f64) -> Pose {
        let th = pose[2] + u2 * t;
        [
            pose[0] + u1 / u2 * (th.sin() - pose[2].sin()),
            pose[1] - u1 / u2 * (th.cos() - pose[2].cos()),
            th,
        ]
    }

    fn error_after(steps: usize) -> f64 {
        let (u1, u2, t) = (1.3, 0.9, 2.0);
        let start = [0.5, -0.2, 0.4];
        let mut x = start;
        for _ in 0..steps {
            x = rk4_step(&x, t / steps as f64, |p| unicycle(p, u1, u2));
        }
        let exact = arc(start, u1, u2, t);
        (0..3).map(|i| (x[i] - exact[i]).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn rk4_converges_at_fourth_order_on_the_unicycle() {
        let (e1, e2) = (error_after(10), error_after(20));
        let order = (e1 / e2).log2();
        assert!(
            (3.8..4.3).contains(&order),
            "observed order {order} (errors {e1:e}, {e2:e})"
        );
    }

    #[test]
    fn a_lagged_delayed_base_starts_moving_after_the_delay_and_follows_the_lag() {
        let mut s = Scenario::default();
        s.robot.start = [0.0, 0.0, 0.0];
        s.plant.actuator_lag_s = protocol::AutoOr::Value(0.05);
        s.plant.command_delay_s = protocol::AutoOr::Value(0.02);
        let mut p = Plant::new(&s);
        let dt = s.timing.dt_s();
        let mut x_at = Vec::new();
        for _ in 0..200 {
            p.step(1.0, 0.0, dt);
            x_at.push(p.pose()[0]);
        }
        // Nothing moves within the delay (4 ticks of 5 ms).
        assert_eq!(x_at[3], 0.0);
        assert!(x_at[4] > 0.0);
        // After the delay, x(t) = t - lag (1 - exp(-t / lag)) of a unit step.
        let t = 200.0 * dt - 0.02;
        let exact = t - 0.05 * (1.0 - (-t / 0.05f64).exp());
        // RK4 at one substep of 5 ms: a few nanometres.
        assert!((x_at[199] - exact).abs() < 1e-8, "{} vs {exact}", x_at[199]);
        assert!((p.speeds()[0] - (1.0 - (-t / 0.05f64).exp())).abs() < 1e-12);
    }

    #[test]
    fn noise_is_reproducible_for_a_seed_and_absent_when_off() {
        let mut s = Scenario::default();
        s.plant.noise_variance = protocol::NoiseVariance::Uniform(0.05);
        let (mut a, mut b) = (Plant::new(&s), Plant::new(&s));
        let (ya, yb) = (a.measure(), b.measure());
        assert_eq!(ya, yb);
        assert_ne!(ya, a.pose());
        let mut clean = Plant::new(&Scenario::default());
        assert_eq!(clean.measure(), clean.pose());
    }

    #[test]
    fn wheel_saturation_limits_both_wheels() {
        let mut s = Scenario::default();
        s.plant.max_wheel_speed_rad_s = 5.0;
        let p = Plant::new(&s);
        let [u1, u2] = p.saturate(10.0, 3.0);
        let w = s.plant.wheel_geometry().wheel_speeds([u1, u2]);
        assert!(w.iter().all(|x| x.abs() <= 5.0 + 1e-12), "{w:?}");
    }

    #[test]
    fn measurement_noise_has_the_configured_variance_on_every_axis() {
        let mut s = Scenario::default();
        s.plant.noise_variance = protocol::NoiseVariance::Uniform(0.05);
        let mut p = Plant::new(&s);
        let truth = p.pose();
        let n = 20_000;
        let mut sum_sq = [0.0; 3];
        for _ in 0..n {
            let y = p.measure();
            for axis in 0..3 {
                sum_sq[axis] += wrap_angle(y[axis] - truth[axis]).powi(2);
            }
        }
        for (axis, sq) in sum_sq.iter().enumerate() {
            let variance = sq / n as f64;
            // The sample variance of 20,000 draws is within 3 % of the true one (4 sigma).
            assert!(
                (variance / 0.05 - 1.0).abs() < 0.04,
                "axis {axis}: variance {variance}"
            );
        }
    }

    #[test]
    fn saturation_clamps_each_wheel_to_its_limit_and_changes_nothing_within_it() {
        let mut s = Scenario::default();
        s.plant.max_wheel_speed_rad_s = 5.0;
        let geometry = s.plant.wheel_geometry();
        let p = Plant::new(&s);
        for body in [[10.0, 3.0], [-10.0, 0.0], [0.5, 40.0]] {
            let wanted = geometry.wheel_speeds(body);
            let [u1, u2] = p.saturate(body[0], body[1]);
            let w = geometry.wheel_speeds([u1, u2]);
            for (got, want) in w.iter().zip(wanted) {
                assert!(
                    (got - want.clamp(-5.0, 5.0)).abs() < 1e-9,
                    "{body:?}: {w:?}"
                );
            }
        }
        let within = geometry.body_inputs([4.0, -3.0]);
        let [u1, u2] = p.saturate(within[0], within[1]);
        assert!((u1 - within[0]).abs() < 1e-12 && (u2 - within[1]).abs() < 1e-12);
    }
}
