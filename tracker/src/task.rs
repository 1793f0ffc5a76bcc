//! The tracker role as a task ([`protocol::task`]): at every perception tick of the
//! plant's truth (every `perception.period_s`) it measures the tracked obstacles at that
//! tick's time and publishes its tracks. It takes every perception tick in order, so a
//! run's tracks do not depend on when its truths arrive.

use crate::Tracker;
use protocol::task::{Context, Due, Publish, Task, TaskError};
use protocol::{FaultConfig, GroundTruth, Header, Role, Tracks, Validated};
use std::collections::VecDeque;

/// What the tracker takes: the plant's truth, its clock (the obstacles' true positions
/// are the scenario's motion at the truth's time).
#[derive(Debug, Clone, Copy)]
pub enum TrackerInput {
    Truth(GroundTruth),
}
protocol::task_input!(TrackerInput: Truth);

/// The tracker with the perception ticks waiting for it.
pub struct TrackerTask {
    tracker: Tracker,
    perception_ticks: u64,
    ticks_per_sample: u64,
    dt_s: f64,
    faults: FaultConfig,
    /// Perception ticks heard and not measured yet, with their times, s.
    pending: VecDeque<(u64, f64)>,
    /// The newest perception tick heard.
    last_tick: Option<u64>,
    dropped: u32,
}

impl Task for TrackerTask {
    const ROLE: Role = Role::Tracker;
    type Input = TrackerInput;
    type Output = Tracks;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<TrackerTask, TaskError> {
        Ok(TrackerTask {
            tracker: Tracker::new(scenario),
            perception_ticks: scenario.perception_ticks(),
            ticks_per_sample: scenario.timing.inner_steps as u64,
            dt_s: scenario.timing.dt_s(),
            faults: scenario.fault.clone(),
            pending: VecDeque::with_capacity(8),
            last_tick: None,
            dropped: 0,
        })
    }

    /// A truth at a perception tick newer than the last is queued.
    fn hear(&mut self, input: TrackerInput, _latency_ns: u64, _context: &impl Context) {
        let TrackerInput::Truth(truth) = input;
        let tick = truth.header.tick;
        if tick.is_multiple_of(self.perception_ticks) && self.last_tick.is_none_or(|l| tick > l) {
            self.last_tick = Some(tick);
            self.pending.push_back((tick, truth.header.time_s));
        }
    }

    /// The next perception tick's truth is expected.
    fn next(&self) -> Due {
        let next = self.last_tick.map_or(0, |l| l + self.perception_ticks);
        Due::Expect(Some(next as f64 * self.dt_s))
    }

    /// The tracks after the oldest perception tick waiting (measured, or predicted to it
    /// when its sample is in `fault.tracker_drop_samples`), held `fault.tracker_delay_ms`.
    fn step(&mut self, _context: &impl Context) -> Option<Publish<Tracks>> {
        let (tick, time_s) = self.pending.pop_front()?;
        let sample = tick / self.ticks_per_sample;
        if self.faults.tracker_drop_samples.contains(sample) {
            self.tracker.predict_to(time_s);
            self.dropped += 1;
        } else {
            self.tracker.measure(time_s);
        }
        let mut tracks = Tracks {
            header: Header {
                tick,
                time_s,
                ..Header::default()
            },
            dropped: self.dropped,
            ..Tracks::default()
        };
        self.tracker.tracks(&mut tracks);
        Some(Publish {
            output: tracks,
            hold_ns: (self.faults.tracker_delay_ms * 1e6) as u64,
        })
    }
}
