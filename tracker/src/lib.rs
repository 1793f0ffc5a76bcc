//! The tracker: each obstacle it tracks is measured with noise every perception period
//! and filtered by a constant-velocity Kalman filter, one per axis (the axes move, and
//! are measured, independently). Math only: the role's task is in [`task`].

use protocol::{Obstacle, Track, Tracks, Validated};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

mod lidar;
pub use lidar::{Group, Perception};
mod peers;
pub use peers::{Peers, SILENT_SAMPLES};
mod task;
pub use task::{TrackerInput, TrackerTask};

/// Standard deviation of an obstacle's velocity before its first measurement, m/s: a
/// person running (the filter learns the velocity from the second measurement on).
pub const INITIAL_SPEED_STD_M_S: f64 = 2.0;

/// A constant-velocity Kalman filter of one axis: state `[position m, velocity m/s]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisFilter {
    pub state: [f64; 2],
    /// `[var p, cov p v, var v]`.
    pub covariance: [f64; 3],
}

impl AxisFilter {
    /// The filter after its first measurement `z` (variance `r`), velocity unknown.
    pub fn start(z: f64, r: f64) -> AxisFilter {
        AxisFilter {
            state: [z, 0.0],
            covariance: [r, 0.0, INITIAL_SPEED_STD_M_S.powi(2)],
        }
    }

    /// Predicts `dt_s` ahead under a white acceleration of standard deviation
    /// `accel_std` (the discrete white-noise-acceleration model).
    pub fn predict(&mut self, dt_s: f64, accel_std: f64) {
        let [p, v] = self.state;
        let [pp, pv, vv] = self.covariance;
        let q = accel_std * accel_std;
        self.state = [p + dt_s * v, v];
        self.covariance = [
            pp + 2.0 * dt_s * pv + dt_s * dt_s * vv + q * dt_s.powi(4) / 4.0,
            pv + dt_s * vv + q * dt_s.powi(3) / 2.0,
            vv + q * dt_s * dt_s,
        ];
    }

    /// Takes in a measurement `z` of the position with variance `r`.
    pub fn update(&mut self, z: f64, r: f64) {
        let [pp, pv, vv] = self.covariance;
        let s = pp + r;
        if s <= 0.0 {
            return;
        }
        let (k_p, k_v) = (pp / s, pv / s);
        let innovation = z - self.state[0];
        self.state = [
            self.state[0] + k_p * innovation,
            self.state[1] + k_v * innovation,
        ];
        self.covariance = [(1.0 - k_p) * pp, (1.0 - k_p) * pv, vv - k_v * pv];
    }
}

/// Every tracked obstacle's filters, and the noise of its measurements.
pub struct Tracker {
    /// `(index in obstacles, obstacle)` of each tracked obstacle.
    obstacles: Vec<(usize, Obstacle)>,
    filters: Vec<Option<[AxisFilter; 2]>>,
    noise: Option<Normal<f64>>,
    rng: ChaCha8Rng,
    variance: f64,
    accel_max: f64,
    /// Time of the newest measurement taken in, s.
    time_s: Option<f64>,
}

impl Tracker {
    pub fn new(scenario: &Validated) -> Tracker {
        let std = scenario.perception.noise_std;
        let obstacles: Vec<(usize, Obstacle)> =
            scenario.tracked().map(|(i, o)| (i, o.clone())).collect();
        Tracker {
            filters: vec![None; obstacles.len()],
            obstacles,
            noise: (std > 0.0).then(|| Normal::new(0.0, std).ok()).flatten(),
            // Its own stream: the plant's noise stays what it was without a tracker.
            rng: ChaCha8Rng::seed_from_u64(scenario.seed ^ 0x0074_7261_636b_6572),
            variance: std * std,
            accel_max: scenario.perception.accel_max,
            time_s: None,
        }
    }

    /// Measures every tracked obstacle at run time `t_s` (its true centre plus noise) and
    /// takes the measurements in.
    pub fn measure(&mut self, t_s: f64) {
        self.predict_to(t_s);
        for ((_, obstacle), filter) in self.obstacles.iter().zip(&mut self.filters) {
            let truth = obstacle.center_at(t_s);
            let mut z = [0.0; 2];
            for (axis, z) in z.iter_mut().enumerate() {
                let noise = self.noise.map_or(0.0, |n| n.sample(&mut self.rng));
                *z = truth[axis] + noise;
            }
            match filter {
                None => {
                    *filter = Some(z.map(|z| AxisFilter::start(z, self.variance)));
                }
                Some(axes) => {
                    for (f, z) in axes.iter_mut().zip(z) {
                        f.update(z, self.variance);
                    }
                }
            }
        }
    }

    /// Predicts every track to `t_s` without a measurement (a dropped one).
    pub fn predict_to(&mut self, t_s: f64) {
        let dt = self.time_s.map_or(0.0, |last| t_s - last);
        if dt > 0.0 {
            for axes in self.filters.iter_mut().flatten() {
                for f in axes {
                    f.predict(dt, self.accel_max);
                }
            }
        }
        self.time_s = Some(t_s);
    }

    /// The tracks (of the obstacles measured at least once).
    pub fn tracks(&self, tracks: &mut Tracks) {
        let mut count = 0;
        for ((index, obstacle), filter) in self.obstacles.iter().zip(&self.filters) {
            let Some(axes) = filter else { continue };
            tracks.tracks[count] = track(*index as u32, obstacle.radius, axes);
            count += 1;
        }
        tracks.count = count as u32;
    }
}

/// The track `obstacle` of radius `radius_m` whose axes are filtered by `axes`.
pub fn track(obstacle: u32, radius_m: f64, axes: &[AxisFilter; 2]) -> Track {
    let [x, y] = axes;
    Track {
        obstacle,
        reserved: 0,
        radius_m,
        center: [x.state[0], y.state[0]],
        velocity: [x.state[1], y.state[1]],
        covariance: [
            x.covariance[0],
            x.covariance[1],
            x.covariance[2],
            y.covariance[0],
            y.covariance[1],
            y.covariance[2],
        ],
    }
}

#[cfg(test)]
mod tests;
