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
    /// between them, and is held at the first before it and at the last after it; each
    /// change of velocity at a point takes [`PATH_CORNER_S`] ([`path_state`]).
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
            path => path_state(path, t_s).0,
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

    /// The true velocity at run time `t_s`, m/s.
    pub fn velocity_at(&self, t_s: f64) -> [f64; 2] {
        match self.path.as_slice() {
            [] => self.velocity,
            path => path_state(path, t_s).1,
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

/// How long a path's change of velocity at one of its points takes, s, at most: its
/// velocity turns linearly from one segment's to the next over this time centred on the
/// point (or over the shorter of the two segments, if that takes less). So a timed path
/// drawn every tenth of a second or more finely from a motion of bounded acceleration
/// keeps that bound, with no jump of velocity a tracker's bound would not cover (a person
/// stepping in, drawn at 0.1 s with a change of 0.05 m/s at each point, accelerates at
/// 0.5 m/s^2, `study::fuzz`); a corner a user writes turns at its change of velocity over
/// this time, and passes within `|dv| PATH_CORNER_S / 8` of its point. At a first point
/// after time 0 it starts no sooner than 0 ([`path_state`]): a path that starts 1 ms into
/// the run sets off over 2 ms.
pub const PATH_CORNER_S: f64 = 0.1;

/// The centre (m) and velocity (m/s) at run time `t_s` along a timed `path` of
/// `[t_s, x_m, y_m]` points (at least one, times strictly increasing): at rest at its
/// first point before it and at its last after it, linear between, with each change of
/// velocity at a point `j` (from `v_{j-1}` to `v_j`, at rest before the first and after the
/// last) spread over `2 tau` about it ([`PATH_CORNER_S`]): there the velocity is
/// `v_{j-1} + dv (t - t_j + tau) / (2 tau)` and the centre is off the polyline by
/// `dv (tau - |t - t_j|)^2 / (4 tau)`. A path that starts at or before time 0 has no
/// corner at its first point: it is moving there already when the run starts; one that
/// starts later turns at its first point no sooner than time 0 (over less than
/// [`PATH_CORNER_S`] if it starts sooner than half of it), so it is at rest there when
/// the run starts.
pub fn path_state(path: &[[f64; 3]], t_s: f64) -> ([f64; 2], [f64; 2]) {
    let last = path.len() - 1;
    let point = |j: usize| [path[j][1], path[j][2]];
    let segment_velocity = |j: usize| -> [f64; 2] {
        let (a, b) = (path[j], path[j + 1]);
        let dt = b[0] - a[0];
        [(b[1] - a[1]) / dt, (b[2] - a[2]) / dt]
    };
    // The velocity just before and just after point `j` (a first point at or before
    // time 0 has no corner: `half_corner` is 0 there).
    let before = |j: usize| match j {
        0 => [0.0; 2],
        _ => segment_velocity(j - 1),
    };
    let after = |j: usize| {
        if j < last {
            segment_velocity(j)
        } else {
            [0.0; 2]
        }
    };
    let half_corner = |j: usize| {
        let mut tau = PATH_CORNER_S / 2.0;
        if j == 0 {
            // Not before the run starts: at rest at its first point until then.
            tau = tau.min(path[0][0].max(0.0));
        } else {
            tau = tau.min((path[j][0] - path[j - 1][0]) / 2.0);
        }
        if j < last {
            tau = tau.min((path[j + 1][0] - path[j][0]) / 2.0);
        }
        tau
    };
    // The polyline's state, and the corner of the point nearest in time.
    let after_t = path.iter().position(|p| p[0] > t_s);
    let (linear, velocity, nearest) = match after_t {
        Some(0) => (point(0), [0.0; 2], 0),
        None => (point(last), [0.0; 2], last),
        Some(i) => {
            let s = (t_s - path[i - 1][0]) / (path[i][0] - path[i - 1][0]);
            let (a, b) = (point(i - 1), point(i));
            let nearest = if t_s - path[i - 1][0] <= path[i][0] - t_s {
                i - 1
            } else {
                i
            };
            (
                [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])],
                segment_velocity(i - 1),
                nearest,
            )
        }
    };
    let tau = half_corner(nearest);
    let from_corner_s = t_s - path[nearest][0];
    if tau <= 0.0 || from_corner_s.abs() >= tau {
        return (linear, velocity);
    }
    let (v0, v1) = (before(nearest), after(nearest));
    let dv = [v1[0] - v0[0], v1[1] - v0[1]];
    let off = (tau - from_corner_s.abs()).powi(2) / (4.0 * tau);
    let share = (from_corner_s + tau) / (2.0 * tau);
    (
        [linear[0] + dv[0] * off, linear[1] + dv[1] * off],
        [v0[0] + dv[0] * share, v0[1] + dv[1] * share],
    )
}
