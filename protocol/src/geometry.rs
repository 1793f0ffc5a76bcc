//! Plane geometry every role shares (m): points, segments and polylines, and the obstacle
//! discs everyone keeps clear of, grown by one rule ([`ObstacleGrowth`]).

use crate::{Obstacle, Scenario};

/// A disc in the plane, m: an obstacle as one consumer sees it (grown, and for the MPC in
/// goal-relative coordinates), at its time, and how it moves and grows after it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disc {
    pub center: [f64; 2],
    pub radius: f64,
    pub motion: DiscMotion,
}

/// How a predicted disc changes `t` seconds after its time: its centre moves at
/// `velocity`, its radius grows by `radius_rate t + radius_accel t^2` (docs/safety.md,
/// "Moving obstacles"). Zero for an obstacle at rest.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DiscMotion {
    /// m/s.
    pub velocity: [f64; 2],
    /// m/s.
    pub radius_rate: f64,
    /// m/s^2.
    pub radius_accel: f64,
    /// A phantom's disc (docs/safety.md, "What the lidar cannot see"): what grows is where
    /// an obstacle hidden at the shadow's edge *could* be if it came out, not where one
    /// is. Once the next scan would show it, a plan passes by it as by a disc at rest
    /// ([`Disc::staged`]); the robot's stop from there must end before the grown disc
    /// could reach it.
    pub hidden: bool,
    /// A tracked obstacle that stands still ([`crate::Track::stands_still`]): a stop need
    /// only end before it could reach the robot from the plan's own last speed, not from
    /// the fastest.
    pub standing: bool,
    /// Whether a plan passes the disc as grown only until the next tracks are due, and
    /// held after ([`Disc::staged`]): a phantom's, and the disc of a track that stands
    /// still and is not overdue (if it sets off, the next tracks show it).
    pub held: bool,
}

impl Disc {
    /// A disc at rest.
    pub fn still(center: [f64; 2], radius: f64) -> Disc {
        Disc {
            center,
            radius,
            motion: DiscMotion::default(),
        }
    }

    /// `obstacle` grown by `growth_m` (absolute coordinates), where it is at t = 0.
    pub fn around(obstacle: &Obstacle, growth_m: f64) -> Disc {
        Disc::still([obstacle.x, obstacle.y], obstacle.radius + growth_m)
    }

    /// Whether the disc moves or grows with time.
    pub fn moves(&self) -> bool {
        self.motion != DiscMotion::default()
    }

    /// The disc `t_s` after its time (itself, exactly, for a disc at rest).
    pub fn at(&self, t_s: f64) -> Disc {
        if !self.moves() {
            return *self;
        }
        let m = &self.motion;
        Disc {
            center: [
                self.center[0] + m.velocity[0] * t_s,
                self.center[1] + m.velocity[1] * t_s,
            ],
            radius: self.radius + m.radius_rate * t_s + m.radius_accel * t_s * t_s,
            motion: DiscMotion {
                radius_rate: m.radius_rate + 2.0 * m.radius_accel * t_s,
                ..*m
            },
        }
    }

    /// The disc as a plan's stage `t_s` after its time keeps clear of it: [`Disc::at`],
    /// but a held one's (a phantom's, a standing track's: [`DiscMotion::held`]) as it is
    /// at its time once the next tracks are due (`stand_s` after its time): by then what
    /// came out of a shadow, or set off, is seen, and the next tracks take over.
    pub fn staged(&self, t_s: f64, stand_s: f64) -> Disc {
        match self.motion.held && t_s >= stand_s {
            true => Disc::still(self.center, self.radius),
            false => self.at(t_s),
        }
    }

    /// A disc at rest that holds this one over the `duration_s` after its time: centred
    /// half way along the path of the centre, its radius the radius at the end plus half
    /// that path (itself for a disc at rest).
    pub fn swept(&self, duration_s: f64) -> Disc {
        if !self.moves() {
            return *self;
        }
        let end = self.at(duration_s);
        let half = self.at(duration_s / 2.0);
        Disc::still(
            half.center,
            end.radius + distance(self.center, end.center) / 2.0,
        )
    }

    /// A disc at rest that holds this one and this one moved on by `velocity` for
    /// `duration_s` (the path its centre would take at that velocity, with its radius as
    /// it is now): centred half way, its radius this one's plus half the way.
    pub fn carried_on(&self, velocity: [f64; 2], duration_s: f64) -> Disc {
        let way = [velocity[0] * duration_s, velocity[1] * duration_s];
        Disc::still(
            [self.center[0] + way[0] / 2.0, self.center[1] + way[1] / 2.0],
            self.radius + way[0].hypot(way[1]) / 2.0,
        )
    }

    /// The barrier `H(p) = ||p - o||^2 - r^2` (paper eq. 100), m^2.
    pub fn barrier(&self, p: [f64; 2]) -> f64 {
        (p[0] - self.center[0]).powi(2) + (p[1] - self.center[1]).powi(2) - self.radius.powi(2)
    }

    /// Linearization of the barrier at `p_bar`: `L(p) = g'p + c`, returned as `(g, c)`.
    pub fn linearized_barrier(&self, p_bar: [f64; 2]) -> ([f64; 2], f64) {
        let g = [
            2.0 * (p_bar[0] - self.center[0]),
            2.0 * (p_bar[1] - self.center[1]),
        ];
        (g, self.barrier(p_bar) - g[0] * p_bar[0] - g[1] * p_bar[1])
    }
}

/// The one rule by which an obstacle grows before anyone keeps clear of it (docs/safety.md): its radius, plus a fixed part (the robot's footprint `robot.radius_m` and
/// the safety margin `mpc.safety_margin_m`), plus `kappa sigma` for an estimate whose
/// position has standard deviation `sigma`. On top of it each consumer adds only its own
/// term: the MPC its plan margin and the inter-sample chord, the DFL's check its commit
/// margin, the planner its clearance. The judge grows the true obstacles by the footprint
/// alone ([`ObstacleGrowth::footprint`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleGrowth {
    /// The fixed part, m.
    pub fixed_m: f64,
    /// `kappa`: standard deviations of the position estimate.
    pub uncertainty_sigmas: f64,
}

impl ObstacleGrowth {
    /// The growth of `scenario`'s MPC, DFL check and planner.
    pub fn of(scenario: &Scenario) -> ObstacleGrowth {
        ObstacleGrowth {
            fixed_m: scenario.robot.radius_m
                + scenario.mpc.safety_margin_m
                + disturbance_margin_m(scenario),
            uncertainty_sigmas: scenario.mpc.uncertainty_sigmas,
        }
    }

    /// The robot's footprint alone: what the judge keeps the true obstacles apart by.
    pub fn footprint(scenario: &Scenario) -> ObstacleGrowth {
        ObstacleGrowth {
            fixed_m: scenario.robot.radius_m,
            uncertainty_sigmas: 0.0,
        }
    }

    /// `kappa sigma`, m.
    pub fn uncertainty_m(&self, sigma_m: f64) -> f64 {
        self.uncertainty_sigmas * sigma_m
    }

    /// The whole growth for an estimate with position standard deviation `sigma_m`, m.
    pub fn total_m(&self, sigma_m: f64) -> f64 {
        self.fixed_m + self.uncertainty_m(sigma_m)
    }

    /// How far a robot centred at `p` keeps clear of `obstacle` grown by the fixed part
    /// (its edge to the obstacle's surface, for the footprint), m; negative inside.
    pub fn clearance_m(&self, obstacle: &Obstacle, p: [f64; 2]) -> f64 {
        distance(p, [obstacle.x, obstacle.y]) - obstacle.radius - self.fixed_m
    }
}

/// The room a robot held at an obstacle needs against the process disturbance
/// (`plant.disturbance_std`, a white velocity drawn every inner tick), m; 0 without one.
/// Over one sample the disturbance moves the robot by `sigma_1 = std dt sqrt(M)` (one
/// standard deviation per axis); the CBF takes a robot pushed into a disc back out at the
/// rate `gamma` a sample, so its depth is an AR(1) process with stationary deviation
/// `sigma_1 / sqrt(1 - (1 - gamma)^2)`, and the growth is `kappa` of those. (The safety
/// argument assumes no disturbance; a robot pinned at an obstacle in a disturbed world
/// random-walked into it by 0.07 mm without this, issue 27.)
pub fn disturbance_margin_m(scenario: &Scenario) -> f64 {
    let std = scenario.plant.disturbance_std;
    if std <= 0.0 {
        return 0.0;
    }
    let t = &scenario.timing;
    let per_sample = std * t.dt_s() * (t.inner_steps as f64).sqrt();
    let decay = 1.0 - scenario.mpc.gamma.clamp(0.0, 1.0);
    scenario.mpc.uncertainty_sigmas * per_sample / (1.0 - decay * decay).sqrt()
}

/// The pose in the world of a sensor mounted at `offset` (`[x_m, y_m, yaw_rad]`, x
/// forward) on a robot at `pose` (`[x, y, theta]`).
pub fn mounted(pose: [f64; 3], offset: [f64; 3]) -> [f64; 3] {
    let [x, y, theta] = pose;
    let [dx, dy, yaw] = offset;
    let (s, c) = theta.sin_cos();
    [x + c * dx - s * dy, y + s * dx + c * dy, theta + yaw]
}

/// Distance between two points, m.
pub fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The point of the segment from `a` to `b` closest to `point`.
pub fn closest_point_on_segment(a: [f64; 2], b: [f64; 2], point: [f64; 2]) -> [f64; 2] {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let length_sq = dx * dx + dy * dy;
    let t = if length_sq > 0.0 {
        (((point[0] - a[0]) * dx + (point[1] - a[1]) * dy) / length_sq).clamp(0.0, 1.0)
    } else {
        0.0
    };
    [a[0] + t * dx, a[1] + t * dy]
}

/// Distance from `point` to the segment from `a` to `b`, m.
pub fn segment_distance(a: [f64; 2], b: [f64; 2], point: [f64; 2]) -> f64 {
    let c = closest_point_on_segment(a, b, point);
    (c[0] - point[0]).hypot(c[1] - point[1])
}

/// The segment of the polyline through `points` (at least two) closest to `point` (the
/// first of equals), the closest point on it, and its distance from `point`, m.
pub fn closest_on_polyline(points: &[[f64; 2]], point: [f64; 2]) -> (usize, [f64; 2], f64) {
    let mut best = (0, points[0], f64::INFINITY);
    for (i, w) in points.windows(2).enumerate() {
        let c = closest_point_on_segment(w[0], w[1], point);
        let d = distance(c, point);
        if d < best.2 {
            best = (i, c, d);
        }
    }
    best
}

/// Length of the polyline through `points`, m.
pub fn polyline_length(points: &[[f64; 2]]) -> f64 {
    points.windows(2).map(|w| distance(w[0], w[1])).sum()
}

#[cfg(test)]
mod disturbance_tests {
    use super::*;

    #[test]
    fn the_disturbance_margin_is_kappa_stationary_deviations_and_nothing_without_one() {
        let paper = Scenario::default();
        assert_eq!(disturbance_margin_m(&paper), 0.0);
        assert_eq!(ObstacleGrowth::of(&paper).fixed_m, 0.0);
        let s = paper
            .with_overrides(&["plant.disturbance_std=0.02".into(), "mpc.gamma=0.19".into()])
            .unwrap();
        // sigma_1 = 0.02 * 0.005 * sqrt(10); 1 - 0.81^2 = 0.3439.
        let expected = 3.0 * 0.02 * 0.005 * 10f64.sqrt() / 0.3439f64.sqrt();
        assert!((disturbance_margin_m(&s) - expected).abs() < 1e-12);
        assert!((ObstacleGrowth::of(&s).fixed_m - expected).abs() < 1e-12);
    }
}
