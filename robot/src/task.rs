//! The robot as the plant's task: tick `j` is due at `t_j`; it measures the robot by its
//! newest odometry, and each command the DFL gives is sent to the robot as soon as it is
//! heard. Unlike every other task it does I/O and reads the clock: the robot is outside
//! the pipeline's time.

use crate::watchdog::{Verdict, Watchdog};
use crate::{Heard, Link, RobotError};
use plant::task::{PlantInput, PlantOutput};
use protocol::task::{Context, Due, Publish, Task, TaskError, header_latency};
use protocol::topics::{ACTUATION, MEASUREMENT, TRUTH};
use protocol::{GroundTruth, Header, Measurement, Role, Timing, Validated};
use std::sync::atomic::AtomicBool;

/// The robot, the newest command sent, and the tick to measure next.
pub struct RobotTask {
    /// `None` once closed (never before the task is dropped).
    link: Option<Link>,
    timing: Timing,
    watchdog: Watchdog,
    verdict: Verdict,
    /// The tick of the newest actuation sent.
    sent: Option<u64>,
    /// The tick to measure next.
    tick: u64,
    /// The newest odometry, for the tick's measurement.
    newest: Heard,
}

impl RobotTask {
    /// Sends a command; a failure is logged (the robot's own watchdog covers a lost one).
    fn send(&mut self, forward_m_s: f64, turn_rad_s: f64) {
        if let Some(link) = &mut self.link
            && let Err(e) = link.command(forward_m_s, turn_rad_s)
        {
            tracing::warn!("sending a command: {e}");
        }
    }
}

impl Task for RobotTask {
    const ROLE: Role = Role::Plant;
    const OUTPUTS: &'static [&'static str] = &[TRUTH, MEASUREMENT];
    type Input = PlantInput;
    type Output = PlantOutput;

    /// Connects to the robot and waits for its first odometry (nothing is sent before).
    fn new(scenario: &Validated, _epoch: u32) -> Result<RobotTask, TaskError> {
        let error = |e: RobotError| TaskError {
            role: "robot",
            reason: e.to_string(),
        };
        let link = Link::open(&scenario.ros2, &hosts::net::Security::from_env()).map_err(error)?;
        let newest = link
            .first_odometry(&AtomicBool::new(false))
            .map_err(error)?;
        Ok(RobotTask {
            link: Some(link),
            timing: scenario.timing.clone(),
            watchdog: Watchdog::new(scenario.ros2.odom_timeout_s),
            verdict: Verdict::Drive,
            sent: None,
            tick: 0,
            newest,
        })
    }

    fn inputs(&self) -> &'static [&'static str] {
        &[ACTUATION]
    }

    /// A command newer than the last one sent goes to the robot at once (not while the
    /// watchdog brakes).
    fn hear(&mut self, input: PlantInput, _latency_ns: u64, _context: &impl Context) {
        let PlantInput::Actuation(actuation) = input;
        let newer = self.sent.is_none_or(|sent| actuation.header.tick > sent);
        if newer && self.verdict == Verdict::Drive {
            self.sent = Some(actuation.header.tick);
            self.send(actuation.u1, actuation.u2);
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
        self.verdict = self
            .watchdog
            .check(runtime::clock::monotonic_ns(), &self.newest);
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
            truth: GroundTruth {
                header,
                pose: self.newest.pose,
            },
            measurement: Measurement {
                header,
                y: self.newest.pose,
            },
        }))
    }

    fn gave_up(&self) -> Option<String> {
        let link = self.link.as_ref()?;
        (self.verdict == Verdict::GiveUp).then(|| {
            format!(
                "the odometry on `{}` stopped: the robot was sent a zero twist",
                link.odometry_key()
            )
        })
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
