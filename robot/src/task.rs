//! The robot as the plant's task: tick `j` is due at `t_j`; it measures the robot by its
//! newest odometry, and each command the DFL gives is sent to the robot as soon as it is
//! heard. It shows the MPC's plans, the route and the obstacles to RViz as they come.
//! It is handed its link to the robot ([`RobotLink`], a resource: the I/O and the clock of
//! the odometry's arrivals are the link's), and reads the time from its context as every
//! task does.

use crate::link::RobotLink;
use crate::watchdog::{Verdict, Watchdog};
use crate::{Heard, Link, RobotError};
use protocol::task::PlantOutput;
use protocol::task::{
    Context, Due, Publish, RoleError, Task, TaskError, header_latency, keep_newest,
};
use protocol::{
    Actuation, GroundTruth, Header, Measurement, Obstacle, Plan, Role, Route, Timing, Tracks,
    Validated,
};

/// What the robot process takes: the DFL's commands, and what it shows (the plans, the
/// route, the tracks).
#[derive(Debug, Clone, Copy)]
pub enum RobotInput {
    Actuation(Actuation),
    Plan(Plan),
    Route(Route),
    Tracks(Tracks),
}
protocol::task_input!(RobotInput: Actuation, Plan, Route, Tracks);

/// The robot, the newest command sent, and the tick to measure next.
pub struct RobotTask {
    /// `None` once closed (never before the task is dropped).
    link: Option<Link>,
    timing: Timing,
    watchdog: Watchdog,
    /// With a lidar: the scans' watchdog.
    scan_watchdog: Option<Watchdog>,
    verdict: Verdict,
    /// The input whose watchdog gave the verdict, when it is not to drive.
    stale: Stale,
    /// The tick of the newest actuation sent.
    sent: Option<u64>,
    /// The tick to measure next.
    tick: u64,
    /// The newest odometry, for the tick's measurement.
    newest: Heard,
    /// The obstacles, where they start; the tracked ones are shown where tracked.
    obstacles: Vec<Obstacle>,
    tracks: Option<Tracks>,
    /// The plans of the route shown last.
    route_plans: u32,
}

/// An input the robot cannot drive without, gone stale ([`RobotTask::lost_input`] is its
/// index).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stale {
    Odometry = 0,
    Scan = 1,
}

impl Stale {
    fn name(self) -> &'static str {
        match self {
            Stale::Odometry => "odometry",
            Stale::Scan => "scan",
        }
    }
}

impl RobotTask {
    /// The verdict of the watchdogs at `now_ns` (the worse of the two), and the input it
    /// is for.
    fn check(&mut self, now_ns: u64) -> (Verdict, Stale) {
        let odometry = (self.watchdog).check(now_ns, self.newest.arrived_ns, &self.newest);
        let scan_arrived = self.link.as_ref().and_then(Link::newest_scan);
        let scan = match (&mut self.scan_watchdog, scan_arrived) {
            (Some(watchdog), Some((_, arrived_ns))) => {
                watchdog.check(now_ns, arrived_ns, &self.newest)
            }
            _ => Verdict::Drive,
        };
        if scan > odometry {
            (scan, Stale::Scan)
        } else {
            (odometry, Stale::Odometry)
        }
    }

    /// Sends a command; a failure is logged (the robot's own watchdog covers a lost one).
    fn send(&mut self, forward_m_s: f64, turn_rad_s: f64) {
        if let Some(link) = &mut self.link
            && let Err(e) = link.command(forward_m_s, turn_rad_s)
        {
            tracing::warn!("sending a command: {e}");
        }
    }

    /// A command newer than the last one sent goes to the robot at once (not while the
    /// watchdog brakes).
    fn command(&mut self, actuation: Actuation) {
        let newer = self.sent.is_none_or(|sent| actuation.header.tick > sent);
        if newer && self.verdict == Verdict::Drive {
            self.sent = Some(actuation.header.tick);
            self.send(actuation.u1, actuation.u2);
        }
    }

    /// Shows a plan and the obstacles as they are now.
    fn show_plan(&mut self, plan: &Plan) {
        let Some(link) = &mut self.link else {
            return;
        };
        let poses = (plan.z.iter())
            .take(plan.horizon as usize + 1)
            .map(|&[x, xdot, y, ydot]| [x, y, ydot.atan2(xdot)]);
        let t_s = plan.header.time_s;
        let tracked = |i: usize| {
            let tracks = self.tracks.as_ref()?;
            (tracks.tracks.iter())
                .take(tracks.count as usize)
                .find(|t| t.obstacle as usize == i)
        };
        let discs = self
            .obstacles
            .iter()
            .enumerate()
            .map(|(i, o)| match tracked(i) {
                Some(track) => (i as i32, track.center, track.radius_m),
                None => (i as i32, o.center_at(t_s), o.radius),
            });
        if let Err(e) = link
            .show_plan(poses)
            .and_then(|_| link.show_obstacles(discs))
        {
            tracing::warn!("showing the plan: {e}");
        }
    }

    /// Shows a route the first time it is heard.
    fn show_route(&mut self, route: &Route) {
        let Some(link) = &mut self.link else {
            return;
        };
        let waypoints = route
            .waypoints
            .get(..route.count as usize)
            .unwrap_or_default();
        if route.plans != self.route_plans && !waypoints.is_empty() {
            self.route_plans = route.plans;
            if let Err(e) = link.show_route(waypoints) {
                tracing::warn!("showing the route: {e}");
            }
        }
    }
}

impl Task for RobotTask {
    const ROLE: Role = Role::Plant;
    type Input = RobotInput;
    type Output = PlantOutput;
    type Resources = RobotLink;

    /// The robot's task, with its link open and its first odometry heard (nothing is
    /// sent before).
    fn new(
        scenario: &Validated,
        _epoch: u32,
        RobotLink { link, first }: RobotLink,
    ) -> Result<RobotTask, TaskError> {
        let newest = first;
        let watches_scan = link.newest_scan().is_some();
        Ok(RobotTask {
            link: Some(link),
            timing: scenario.timing.clone(),
            watchdog: Watchdog::new(scenario.ros2.odom_timeout_s),
            scan_watchdog: watches_scan.then(|| Watchdog::new(scenario.ros2.scan_timeout_s)),
            verdict: Verdict::Drive,
            stale: Stale::Odometry,
            sent: None,
            tick: 0,
            newest,
            obstacles: scenario.obstacles.clone(),
            tracks: None,
            route_plans: 0,
        })
    }

    /// A command goes to the robot at once; a plan, a new route and the obstacles go to
    /// RViz.
    fn hear(&mut self, input: RobotInput, _latency_ns: u64, _context: &impl Context) {
        match input {
            RobotInput::Actuation(actuation) => self.command(actuation),
            RobotInput::Plan(plan) => self.show_plan(&plan),
            RobotInput::Route(route) => self.show_route(&route),
            RobotInput::Tracks(tracks) => keep_newest(&mut self.tracks, tracks),
        }
    }

    /// A command as soon as it comes, the next measurement at its tick's time.
    fn next(&self) -> Due {
        Due::Wait(Some(self.timing.tick_time_s(self.tick)))
    }

    /// The tick's measurement, the newest odometry's pose (the truth recorded is the same:
    /// the pipeline knows the robot by its odometry alone). A stale odometry stops the
    /// robot: a zero twist every tick.
    fn step(&mut self, context: &impl Context) -> Option<Publish<PlantOutput>> {
        let tick = self.tick;
        let due_s = self.timing.tick_time_s(tick);
        if !context.has_reached(due_s) || self.verdict == Verdict::GiveUp {
            return None;
        }
        if let Some(newest) = self.link.as_ref().and_then(Link::newest_odometry) {
            self.newest = newest;
        }
        let (verdict, stale) = self.check(context.monotonic_ns());
        if verdict > self.verdict {
            // The input that made it worse is the one the run says was lost.
            self.stale = stale;
            if self.verdict == Verdict::Drive {
                tracing::warn!("the {} is stale: the robot brakes", stale.name());
            }
        }
        self.verdict = verdict;
        if self.verdict != Verdict::Drive {
            self.send(0.0, 0.0);
        }
        self.tick += 1;
        let header = Header {
            tick,
            time_s: due_s,
            input_latency_ns: header_latency(self.newest.age_at_arrival_ns),
            ..Header::default()
        };
        Some(Publish::now(PlantOutput {
            // What a ROS 2 base applied is its own: the truth leaves `applied` 0.
            truth: GroundTruth {
                header,
                pose: self.newest.pose,
                ..GroundTruth::default()
            },
            measurement: Measurement {
                header,
                y: self.newest.pose,
                odometry: self.newest.twist,
            },
        }))
    }

    fn gave_up(&self) -> Option<RoleError> {
        let link = self.link.as_ref()?;
        (self.verdict == Verdict::GiveUp).then(|| match (self.stale, link.newest_scan()) {
            (Stale::Scan, Some((key, _))) => RoleError::from(RobotError::ScanStopped {
                key: key.to_string(),
            }),
            _ => RoleError::from(RobotError::OdometryStopped {
                key: link.odometry_key().to_string(),
            }),
        })
    }

    /// The odometry (0) or, with a lidar, the scans (1).
    fn lost_input(&self) -> u32 {
        self.stale as u32
    }
}

/// Every end of the process (a stop, a signal, the orchestrator gone, a failure) leaves
/// the robot with a zero twist.
impl Drop for RobotTask {
    fn drop(&mut self) {
        if let Some(link) = self.link.take()
            && let Err(e) = link.stop_and_close()
        {
            tracing::warn!("stopping the robot: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_robot_takes_what_its_declaration_names_and_nothing_else() {
        for data in protocol::Data::one_of_each() {
            assert_eq!(
                RobotInput::try_from(data).is_ok(),
                protocol::graph::ROBOT.inputs.contains(&data.topic()),
                "`{}`",
                data.topic()
            );
        }
    }
}
