//! The watchdog of an input the robot cannot drive without (docs/ros2.md, "Safety at the
//! edge"): odometry older than `ros2.odom_timeout_s` (with a lidar, a scan older than
//! `ros2.scan_timeout_s`) stops the robot, and the run ends once the robot is at rest or
//! the input is twice that old.

use crate::Heard;

/// Below these the robot is at rest: forward speed, m/s, and turn rate, rad/s.
pub const AT_REST: [f64; 2] = [0.01, 0.01];

/// What the robot is sent now (ordered: the worse of two verdicts is the greater).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verdict {
    /// The pipeline's commands.
    Drive,
    /// Zero twists: the odometry is stale.
    Brake,
    /// The run ends (aborted): the robot was stopped, and is at rest or its odometry is
    /// twice the timeout old.
    GiveUp,
}

/// The watchdog of one run: once it has braked, it brakes until the run ends.
#[derive(Debug, Clone, Copy)]
pub struct Watchdog {
    timeout_ns: u64,
    /// When the input was first found stale (monotonic ns).
    braking_since_ns: Option<u64>,
}

impl Watchdog {
    pub fn new(timeout_s: f64) -> Watchdog {
        Watchdog {
            timeout_ns: (timeout_s * 1e9) as u64,
            braking_since_ns: None,
        }
    }

    /// The verdict at `now_ns` (monotonic) for an input whose newest message arrived at
    /// `arrived_ns`, with `odometry` the newest odometry (which says when the robot is at
    /// rest: a fresh one after the brake began, with a twist below [`AT_REST`]).
    pub fn check(&mut self, now_ns: u64, arrived_ns: u64, odometry: &Heard) -> Verdict {
        let age_ns = now_ns.saturating_sub(arrived_ns);
        if age_ns > self.timeout_ns.saturating_mul(2) {
            return Verdict::GiveUp;
        }
        match self.braking_since_ns {
            Some(since) => {
                let at_rest = odometry.arrived_ns > since
                    && odometry.twist[0].abs() < AT_REST[0]
                    && odometry.twist[1].abs() < AT_REST[1];
                if at_rest {
                    Verdict::GiveUp
                } else {
                    Verdict::Brake
                }
            }
            None if age_ns > self.timeout_ns => {
                self.braking_since_ns = Some(now_ns);
                Verdict::Brake
            }
            None => Verdict::Drive,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn heard(arrived_ns: u64, twist: [f64; 2]) -> Heard {
        Heard {
            pose: [0.0; 3],
            twist,
            arrived_ns,
            age_at_arrival_ns: 0,
        }
    }

    #[test]
    fn fresh_odometry_drives_stale_brakes_and_twice_stale_gives_up() {
        let mut watchdog = Watchdog::new(0.2);
        let moving = heard(1000 * MS, [0.5, 0.0]);
        assert_eq!(
            watchdog.check(1100 * MS, moving.arrived_ns, &moving),
            Verdict::Drive
        );
        assert_eq!(
            watchdog.check(1200 * MS, moving.arrived_ns, &moving),
            Verdict::Drive
        );
        assert_eq!(
            watchdog.check(1201 * MS, moving.arrived_ns, &moving),
            Verdict::Brake
        );
        assert_eq!(
            watchdog.check(1400 * MS, moving.arrived_ns, &moving),
            Verdict::Brake
        );
        assert_eq!(
            watchdog.check(1401 * MS, moving.arrived_ns, &moving),
            Verdict::GiveUp
        );
    }

    #[test]
    fn once_braked_it_brakes_until_the_robot_reports_rest() {
        let mut watchdog = Watchdog::new(0.2);
        assert_eq!(
            watchdog.check(1300 * MS, 1000 * MS, &heard(1000 * MS, [0.5, 0.0])),
            Verdict::Brake
        );
        // Odometry again, the robot still moving: fresh, but the brake holds.
        assert_eq!(
            watchdog.check(1310 * MS, 1305 * MS, &heard(1305 * MS, [0.2, 0.0])),
            Verdict::Brake
        );
        assert_eq!(
            watchdog.check(1320 * MS, 1315 * MS, &heard(1315 * MS, [0.0, 0.005])),
            Verdict::GiveUp
        );
    }

    #[test]
    fn a_stale_scan_gives_up_once_the_odometry_says_the_robot_is_at_rest() {
        let mut watchdog = Watchdog::new(0.5);
        let last_scan_ns = 1000 * MS;
        let moving = heard(1600 * MS, [0.4, 0.0]);
        assert_eq!(
            watchdog.check(1600 * MS, last_scan_ns, &moving),
            Verdict::Brake
        );
        let resting = heard(1700 * MS, [0.0, 0.0]);
        assert_eq!(
            watchdog.check(1700 * MS, last_scan_ns, &resting),
            Verdict::GiveUp
        );
    }
}
