//! The free range seen ahead (issue 56, 4a and 4c; docs/safety.md, "What the lidar cannot
//! see"): whatever perception made of the newest scan, the robot does not drive faster
//! than it can stop short of its raw points. The scan's returns, put in the world where
//! the lidar was when it was taken and less the ones on the obstacles the scenario maps,
//! are points; the way ahead is the robot's straight path along its heading (behind it
//! when it reverses: the brake's path, along its velocity), as wide as the robot; the DFL
//! brakes when a point lies on that way nearer than the robot's
//! stopping distance ([`protocol::stopping_distance`]) and [`AHEAD_MARGIN_M`].

use protocol::{Disc, Scan, Scenario};

/// Kept between the robot's front (its centre plus its radius) and a point once it has
/// stopped, m.
pub const AHEAD_MARGIN_M: f64 = 0.05;
/// A return this near a mapped obstacle's true edge is that obstacle's, m (a lidar's
/// noise is a centimetre).
pub const ON_MAP_M: f64 = 0.05;

/// The newest scan's points and how the robot stops.
#[derive(Debug, Clone)]
pub struct FreeRange {
    /// The scan's returns off the map, in the world (m); none before the first scan.
    points: Vec<[f64; 2]>,
    /// The mapped obstacles (the scenario's known ones), at their true size.
    map: Vec<Disc>,
    /// Half the width of the way ahead: the robot's radius, m.
    half_width_m: f64,
    brake_decel: f64,
    /// Whether a scan has come.
    seen: bool,
}

impl FreeRange {
    pub fn new(scenario: &Scenario) -> FreeRange {
        FreeRange {
            points: Vec::with_capacity(protocol::MAX_BEAMS),
            map: (scenario.known_obstacles())
                .map(|o| Disc::around(o, ON_MAP_M))
                .collect(),
            half_width_m: scenario.robot.radius_m,
            brake_decel: scenario.brake_decel(),
            seen: false,
        }
    }

    /// Takes `scan`, taken with the lidar at `lidar` (`[x_m, y_m, yaw_rad]` in the world);
    /// a scan of no beams (none new) leaves the points as they are.
    pub fn take(&mut self, scan: &Scan, lidar: [f64; 3]) {
        if scan.beams == 0 {
            return;
        }
        let [lx, ly, yaw] = lidar;
        self.seen = true;
        self.points.clear();
        for (i, &range) in scan.ranges().iter().enumerate() {
            if !range.is_finite() || range <= 0.0 {
                continue;
            }
            let (sin, cos) = (yaw + scan.angle_rad(i)).sin_cos();
            let r = f64::from(range);
            let point = [lx + r * cos, ly + r * sin];
            let mapped = (self.map.iter()).any(|d| protocol::distance(d.center, point) <= d.radius);
            if !mapped {
                self.points.push(point);
            }
        }
    }

    /// How far the nearest point on the way ahead of a robot at `pose` moving at
    /// `speed_m_s` (its forward speed `zeta`: behind it when negative) is short of what it
    /// needs to stop (its stopping distance and [`AHEAD_MARGIN_M`]), m; `None` when the way
    /// is free that far (or the robot is at rest). Before the first scan nothing is seen:
    /// every speed is too fast.
    pub fn shortfall_m(&self, pose: [f64; 3], speed_m_s: f64) -> Option<f64> {
        let speed = speed_m_s.abs();
        if speed <= protocol::REST_SPEED_M_S {
            return None;
        }
        let needed = protocol::stopping_distance(speed, self.brake_decel, 0.0)
            + self.half_width_m
            + AHEAD_MARGIN_M;
        if !self.seen {
            return Some(needed);
        }
        let [x, y, theta] = pose;
        let (sin, cos) = theta.sin_cos();
        let (sin, cos) = (sin * speed_m_s.signum(), cos * speed_m_s.signum());
        let nearest = (self.points.iter())
            .filter_map(|&[px, py]| {
                let (dx, dy) = (px - x, py - y);
                let along = dx * cos + dy * sin;
                let across = (dy * cos - dx * sin).abs();
                (along > 0.0 && across <= self.half_width_m).then_some(along)
            })
            .fold(f64::INFINITY, f64::min);
        (nearest < needed).then_some(needed - nearest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan_of(ranges: &[f32]) -> Scan {
        let mut scan = Scan {
            beams: ranges.len() as u32,
            angle_min_rad: -std::f64::consts::FRAC_PI_2,
            angle_increment_rad: std::f64::consts::FRAC_PI_2,
            ..Scan::default()
        };
        scan.ranges_m[..ranges.len()].copy_from_slice(ranges);
        scan
    }

    fn free_range(radius_m: f64) -> FreeRange {
        let mut scenario = Scenario::default();
        scenario.robot.radius_m = radius_m;
        scenario.obstacles.clear();
        FreeRange::new(&scenario)
    }

    #[test]
    fn a_point_on_the_way_within_the_stopping_distance_is_short_ahead_or_behind_a_reversing_robot_and_one_aside_or_farther_is_not()
     {
        let mut free = free_range(0.2);
        let decel = free.brake_decel;
        let speed = 1.0;
        let needed = speed * speed / (2.0 * decel) + 0.2 + AHEAD_MARGIN_M;
        // Beams to the right, ahead and to the left; the lidar at the origin facing +x.
        free.take(&scan_of(&[1.0, (needed - 0.1) as f32, 0.3]), [0.0; 3]);
        let short = free.shortfall_m([0.0; 3], speed).unwrap();
        assert!((short - 0.1).abs() < 1e-6, "{short}");
        // At rest, or slow enough, or facing away: nothing to brake for.
        assert_eq!(free.shortfall_m([0.0; 3], 0.0), None);
        assert_eq!(free.shortfall_m([0.0; 3], 0.3), None);
        assert_eq!(free.shortfall_m([0.0, 0.0, 3.0], speed), None);
        // Reversing towards it, facing away, is the same as driving at it.
        let reversing = free
            .shortfall_m([0.0, 0.0, std::f64::consts::PI], -speed)
            .unwrap();
        assert!((reversing - 0.1).abs() < 1e-6, "{reversing}");
        assert_eq!(free.shortfall_m([0.0; 3], -speed), None, "it is behind");
        free.take(&scan_of(&[1.0, f32::INFINITY, 0.3]), [0.0; 3]);
        assert_eq!(free.shortfall_m([0.0; 3], speed), None);
    }

    #[test]
    fn before_any_scan_every_forward_speed_is_too_fast_and_mapped_points_do_not_count() {
        let free = free_range(0.0);
        assert!(free.shortfall_m([0.0; 3], 0.5).is_some());
        let scenario = Scenario {
            obstacles: vec![protocol::Obstacle::fixed(1.0, 0.0, 0.5)],
            ..Scenario::default()
        };
        let mut mapped = FreeRange::new(&scenario);
        // The return ahead is on the mapped obstacle's edge (0.5 m from the lidar).
        mapped.take(&scan_of(&[f32::INFINITY, 0.5, f32::INFINITY]), [0.0; 3]);
        assert_eq!(mapped.shortfall_m([0.0; 3], 1.0), None);
    }
}
