//! The scenario's world beyond the robot: its obstacles, at rest or moving, and the
//! tracker's perception of the moving ones (docs/running.md, "Moving obstacles").

use super::{Auto, AutoOr};
use serde::{Deserialize, Serialize};

/// The tracker (docs/running.md, "Moving obstacles"): it measures the obstacles it
/// tracks with noise and filters each with a constant-velocity Kalman filter; the MPC
/// keeps clear of the discs its tracks predict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionConfig {
    /// `auto`: with a `[lidar]`, `lidar`; else a tracker process tracks the obstacles not
    /// `known` when there is one (by default the moving ones; the obstacles at rest are
    /// known, as in the paper); `track`: it tracks every obstacle; `lidar`: the tracker
    /// sees the obstacles not `known` in the lidar's scans only.
    pub kind: PerceptionKind,
    /// Time between two measurements of the obstacles, s; `auto`: `timing.ts_s`. A whole
    /// number of inner ticks (rounded).
    pub period_s: AutoOr,
    /// Standard deviation of each measured coordinate of a centre, m.
    pub noise_std: f64,
    /// Bound on an obstacle's acceleration, m/s^2: the filter's process noise, and the
    /// growth `accel_max t^2 / 2` of a disc predicted `t` ahead.
    pub accel_max: f64,
    /// With a lidar: the smallest radius of a disc fitted to a group of points, m (a
    /// group seen from one side only is narrower than its obstacle).
    pub min_radius: f64,
    /// With a lidar: a group is a track once seen in this many of the last
    /// [`CONFIRM_WINDOW`] scans.
    pub confirm: u32,
    /// With a lidar: a track not seen for this long is dropped, s.
    pub lost_s: f64,
    /// With a lidar: the largest Mahalanobis distance of a group from a track it is
    /// associated with.
    pub gate: f64,
    /// With a lidar: the gap between two neighbouring points of one group at range 0, m
    /// (it grows with range as the beams spread).
    pub cluster_gap_m: f64,
    /// With a lidar: assume a phantom at every shadow edge within range, an obstacle that
    /// may come out of what the lidar cannot see (docs/safety.md, "What the lidar cannot
    /// see"). On by default; it needs `mpc.uncertainty_sigmas > 0`.
    pub phantoms: bool,
    /// A phantom's radius, m.
    pub phantom_radius: f64,
    /// The fastest a phantom comes out, m/s.
    pub phantom_speed: f64,
}

/// The largest `perception.gate`, standard deviations (the assignment weighs a pair outside
/// the gate as more than any sum of pairs within it).
pub const MAX_GATE: f64 = 100.0;

/// Scans a lidar track's confirmation looks back on (`perception.confirm` of them).
pub const CONFIRM_WINDOW: u32 = 5;

/// `perception.kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum PerceptionKind {
    Auto,
    Track,
    Lidar,
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        PerceptionConfig {
            kind: PerceptionKind::Auto,
            period_s: AutoOr::Auto(Auto::Auto),
            noise_std: 0.02,
            accel_max: 0.5,
            min_radius: 0.15,
            confirm: 3,
            lost_s: 1.0,
            gate: 3.0,
            cluster_gap_m: 0.1,
            phantoms: true,
            phantom_radius: 0.3,
            phantom_speed: 1.5,
        }
    }
}

/// A circular obstacle (docs/running.md, "Moving obstacles"): at rest at `(x, y)`, moving
/// at a constant `velocity` from `(x, y)` at t = 0, or along a timed `path`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    /// Centre at t = 0, m. With a `path` it may be left out (it is the path's position at
    /// t = 0); without one it is required.
    #[serde(default = "unset")]
    pub x: f64,
    /// Centre at t = 0, m (see `x`).
    #[serde(default = "unset")]
    pub y: f64,
    /// The true radius the judge measures clearance to, m.
    pub radius: f64,
    /// Constant velocity from t = 0, m/s; `[0, 0]`: at rest.
    #[serde(default)]
    pub velocity: [f64; 2],
    /// `[t_s, x_m, y_m]` points, times strictly increasing: the centre moves linearly
    /// between them, and is held at the first before it and at the last after it.
    #[serde(default)]
    pub path: Vec<[f64; 3]>,
    /// Whether the pipeline knows it from the scenario (the map); default: one at rest
    /// is, one that moves is not. One not known is the plant's and the judge's only: the
    /// tracker finds it (measured from the truth, or seen by the lidar).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known: Option<bool>,
}

/// A key left out of the document (refused by the validator where it is required).
fn unset() -> f64 {
    f64::NAN
}

impl Obstacle {
    /// An obstacle at rest.
    pub fn fixed(x: f64, y: f64, radius: f64) -> Obstacle {
        Obstacle {
            x,
            y,
            radius,
            velocity: [0.0; 2],
            path: Vec::new(),
            known: None,
        }
    }

    /// Whether the pipeline knows it from the scenario (`known`, by default whether it
    /// stays at rest).
    pub fn is_known(&self) -> bool {
        self.known.unwrap_or(!self.moves())
    }

    /// Whether the obstacle ever moves.
    pub fn moves(&self) -> bool {
        self.velocity != [0.0; 2] || self.path.windows(2).any(|w| w[0][1..] != w[1][1..])
    }

    /// The true centre at run time `t_s`, m: the world's motion, which the plant's world,
    /// the tracker's measurements and the judge all take from here.
    pub fn center_at(&self, t_s: f64) -> [f64; 2] {
        match self.path.as_slice() {
            [] => [
                self.x + self.velocity[0] * t_s,
                self.y + self.velocity[1] * t_s,
            ],
            [first, ..] if t_s <= first[0] => [first[1], first[2]],
            points => {
                let after = points.iter().position(|p| p[0] > t_s);
                match after {
                    None => {
                        let last = points[points.len() - 1];
                        [last[1], last[2]]
                    }
                    Some(i) => {
                        let (a, b) = (points[i - 1], points[i]);
                        let s = (t_s - a[0]) / (b[0] - a[0]);
                        [a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2])]
                    }
                }
            }
        }
    }

    /// Where the obstacle comes to rest, m: its place, or its path's last point; `None`
    /// for one with a velocity (it never stops).
    pub fn rest(&self) -> Option<[f64; 2]> {
        match self.path.last() {
            Some(last) => Some([last[1], last[2]]),
            None => (self.velocity == [0.0; 2]).then_some([self.x, self.y]),
        }
    }

    /// The true velocity at run time `t_s`, m/s (a path's segment's; at a corner, the
    /// segment after it).
    pub fn velocity_at(&self, t_s: f64) -> [f64; 2] {
        if self.path.is_empty() {
            return self.velocity;
        }
        match self.path.iter().position(|p| p[0] > t_s) {
            Some(i) if i > 0 => {
                let (a, b) = (self.path[i - 1], self.path[i]);
                let dt = b[0] - a[0];
                [(b[1] - a[1]) / dt, (b[2] - a[2]) / dt]
            }
            _ => [0.0; 2],
        }
    }

    /// The obstacle with its `x` and `y` filled in from its path, if it has one and they
    /// were left out.
    pub(super) fn with_start_of_path(mut self) -> Obstacle {
        if !self.path.is_empty() && self.x.is_nan() && self.y.is_nan() {
            [self.x, self.y] = self.center_at(0.0);
        }
        self
    }
}
