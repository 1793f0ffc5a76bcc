//! The lidar role played by a ROS 2 robot's lidar (docs/ros2.md, "The robot's lidar"): at
//! every perception tick of the robot's truth the newest scan its link heard
//! ([`ScanLink`]) goes out as the pipeline's [`Scan`].
//!
//! Each scan is published once, at the first perception tick after it arrived, with its
//! age then in inner ticks ([`Scan::age_ticks`]): the tracker places its points with the
//! estimate of its arrival (its stamp is the robot's clock, not this host's) and measures
//! its obstacles as at its arrival, predicting them on to the tick (docs/ros2.md).

use crate::link::scan::{BASE_FRAME, ScanLink};
use protocol::task::{Context, Due, PerceptionTicks, Publish, Task, TaskError};
use protocol::{GroundTruth, Role, Scan, Validated};

/// What the robot's lidar takes: the robot's truth, the clock of its perception ticks.
#[derive(Debug, Clone, Copy)]
pub enum ScanInput {
    Truth(GroundTruth),
}
protocol::task_input!(ScanInput: Truth);

/// The robot's lidar as the lidar role's task.
pub struct ScanTask {
    link: ScanLink,
    /// `lidar.offset`, where `tf_static` says nothing of the scan's frame.
    offset: [f64; 3],
    timeout_ns: u64,
    perception: PerceptionTicks,
    /// The inner tick, s.
    dt_s: f64,
    /// The perception tick to publish the newest scan at.
    pending: Option<GroundTruth>,
    /// The scan published (kept to copy into without allocating).
    scan: Box<Scan>,
    /// When the scan published last arrived (monotonic ns): each is published once.
    published_ns: u64,
    /// Whether the fallback to `lidar.offset` was said.
    said_offset: bool,
}

impl Task for ScanTask {
    const ROLE: Role = Role::Lidar;
    type Input = ScanInput;
    type Output = Scan;
    type Resources = ScanLink;

    fn new(scenario: &Validated, _epoch: u32, link: ScanLink) -> Result<ScanTask, TaskError> {
        Ok(ScanTask {
            link,
            offset: scenario.lidar.clone().unwrap_or_default().offset,
            timeout_ns: (scenario.ros2.scan_timeout_s * 1e9) as u64,
            perception: PerceptionTicks::of(scenario),
            dt_s: scenario.timing.dt_s(),
            pending: None,
            scan: Box::default(),
            published_ns: 0,
            said_offset: false,
        })
    }

    /// The truth of a perception tick newer than the last is the time to publish.
    fn hear(&mut self, input: ScanInput, _latency_ns: u64, _context: &impl Context) {
        let ScanInput::Truth(truth) = input;
        if self.perception.take(truth.header.tick) {
            self.pending = Some(truth);
        }
    }

    fn next(&self) -> Due {
        Due::Expect(Some(self.perception.next_s()))
    }

    /// At the perception tick heard, the newest scan if it was not published yet and is
    /// younger than `ros2.scan_timeout_s`, with its age in inner ticks; else a scan of no
    /// beams, so that the tick goes on without waiting (the tracker predicts its tracks;
    /// scans that stop brake the robot by its own watchdog, [`crate::RobotTask`]).
    fn step(&mut self, context: &impl Context) -> Option<Publish<Scan>> {
        let truth = self.pending.take()?;
        let header = protocol::Header {
            tick: truth.header.tick,
            time_s: truth.header.time_s,
            ..protocol::Header::default()
        };
        let now_ns = context.monotonic_ns();
        let after_ns = (now_ns.saturating_sub(self.timeout_ns)).max(self.published_ns);
        let Some((arrived_ns, mount)) = self.link.newest_after(after_ns, &mut self.scan) else {
            // No new scan: the tick goes on without one.
            return Some(Publish::now(Scan {
                header,
                ..Scan::default()
            }));
        };
        self.published_ns = arrived_ns;
        let age_ticks = (now_ns - arrived_ns.min(now_ns)) as f64 * 1e-9 / self.dt_s;
        if mount.is_none() && !self.said_offset {
            self.said_offset = true;
            tracing::warn!(
                "tf_static has no transform from {BASE_FRAME} to the scan's frame: the \
                 lidar is taken at lidar.offset {:?}",
                self.offset
            );
        }
        self.scan.header = header;
        self.scan.offset = mount.unwrap_or(self.offset);
        self.scan.age_ticks = (age_ticks.round() as u32).min(truth.header.tick as u32);
        Some(Publish::now(*self.scan))
    }
}
