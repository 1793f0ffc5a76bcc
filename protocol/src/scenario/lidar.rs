//! The robot's 2D lidar (docs/running.md, "A lidar"): a simulated one ray-cast against the
//! world's true discs by the `lidar` role.

use serde::{Deserialize, Serialize};

/// The most beams a scan carries ([`crate::Scan`]).
pub const MAX_BEAMS: usize = 1440;

/// `[lidar]`: the sensor. Its scans are the perception ticks' (`perception.period_s` is
/// `1 / rate_hz` with a lidar).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    /// Beams per scan, 1 to [`MAX_BEAMS`].
    pub beams: u32,
    /// Field of view, degrees, centred on the lidar's heading (360: all around).
    pub fov_deg: f64,
    /// Nearest range measured, m.
    pub range_min_m: f64,
    /// Farthest range measured, m.
    pub range_max_m: f64,
    /// Scans per second; the period is a whole number of inner ticks (rounded).
    pub rate_hz: f64,
    /// Standard deviation of a range, m.
    pub noise_std: f64,
    /// Probability that a beam returns nothing, in [0, 1].
    pub dropout: f64,
    /// The lidar's pose on the robot, `[x_m, y_m, yaw_rad]`, x forward.
    pub offset: [f64; 3],
}

impl Default for LidarConfig {
    fn default() -> Self {
        LidarConfig {
            beams: 360,
            fov_deg: 360.0,
            range_min_m: 0.1,
            range_max_m: 8.0,
            rate_hz: 10.0,
            noise_std: 0.01,
            dropout: 0.0,
            offset: [0.0; 3],
        }
    }
}

impl LidarConfig {
    /// Every problem of the table, with its dotted key.
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        if !(1..=MAX_BEAMS as u32).contains(&self.beams) {
            problems.push((
                "lidar.beams",
                format!("must be 1 to {MAX_BEAMS}, got {}", self.beams),
            ));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg <= 360.0) {
            problems.push((
                "lidar.fov_deg",
                format!("must be in (0, 360], got {}", self.fov_deg),
            ));
        }
        if !(self.range_min_m.is_finite() && self.range_min_m >= 0.0) {
            problems.push((
                "lidar.range_min_m",
                format!("must be a distance, m, got {}", self.range_min_m),
            ));
        }
        if !(self.range_max_m.is_finite() && self.range_max_m > self.range_min_m) {
            problems.push((
                "lidar.range_max_m",
                format!(
                    "must be finite and beyond lidar.range_min_m = {}, got {}",
                    self.range_min_m, self.range_max_m
                ),
            ));
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            problems.push((
                "lidar.rate_hz",
                format!("must be positive, got {}", self.rate_hz),
            ));
        }
        if !(self.noise_std.is_finite() && self.noise_std >= 0.0) {
            problems.push((
                "lidar.noise_std",
                format!("must not be negative, got {}", self.noise_std),
            ));
        }
        if !(0.0..=1.0).contains(&self.dropout) {
            problems.push((
                "lidar.dropout",
                format!("must be a probability in [0, 1], got {}", self.dropout),
            ));
        }
        if self.offset.iter().any(|x| !x.is_finite()) {
            problems.push((
                "lidar.offset",
                format!("must be finite, got {:?}", self.offset),
            ));
        }
        problems
    }

    /// The field of view, rad.
    pub fn fov_rad(&self) -> f64 {
        self.fov_deg.to_radians()
    }
}
