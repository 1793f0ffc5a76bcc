//! The planner role as a task ([`protocol::task`]): route(k) from the estimate of sample
//! k's first tick (planned again when [`Planner::step`] says so, else the newest route).
//! When it has fallen behind, a sample whose successor's time is past is not answered:
//! only the newest is.
//!
//! With a lidar it also takes the tracks: route(k) goes round those of the newest
//! perception tick before sample k's first that stand still. In process and in lockstep
//! those are in its hands by then (the MPC took them before the clock moved on), so
//! routes do not depend on timing there; in real time late tracks leave the ones before.

use crate::Planner;
use protocol::samples::SampleQueue;
use protocol::task::{Context, Due, Publish, Task, TaskError};
use protocol::topics::TRACKS;
use protocol::{Estimate, Header, Role, Route, Tracks, Validated};
use std::collections::VecDeque;

/// What the planner takes: the estimator's estimates, and with a lidar the tracks.
#[derive(Debug, Clone, Copy)]
#[allow(clippy::large_enum_variant)] // handed over by value, like `Data`
pub enum PlannerInput {
    Estimate(Estimate),
    Tracks(Tracks),
}
protocol::task_input!(PlannerInput: Estimate, Tracks);

/// The planner with the boundary estimates it has not answered yet.
pub struct PlannerTask {
    planner: Planner,
    samples: SampleQueue<()>,
    /// With a lidar: the newest tracks heard, oldest first (`None`: it takes none).
    tracks: Option<VecDeque<Tracks>>,
    /// The serial of the goal set while the run drives that it plans to (0: none).
    goal_serial: u32,
}

/// Tracks kept for the samples to come.
const TRACKS_KEPT: usize = 4;

impl Task for PlannerTask {
    const ROLE: Role = Role::Planner;
    type Input = PlannerInput;
    type Output = Route;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<PlannerTask, TaskError> {
        Ok(PlannerTask {
            planner: Planner::new(scenario),
            samples: SampleQueue::new(&scenario.timing),
            tracks: (scenario.sees_with_lidar()).then(|| VecDeque::with_capacity(TRACKS_KEPT)),
            goal_serial: 0,
        })
    }

    /// The tracks with a lidar only.
    fn takes(&self, topic: &str) -> bool {
        topic != TRACKS || self.tracks.is_some()
    }

    /// Only the estimates that start a sample are answered.
    fn woken_at_sample_starts(&self, topic: &str) -> bool {
        topic == protocol::topics::ESTIMATE
    }

    /// An estimate heard: kept if it starts a sample not answered yet; tracks: kept.
    fn hear(&mut self, input: PlannerInput, _latency_ns: u64, _context: &impl Context) {
        match (input, &mut self.tracks) {
            (PlannerInput::Estimate(estimate), _) => self.samples.hear(estimate, ()),
            (PlannerInput::Tracks(tracks), Some(kept)) => {
                if kept
                    .back()
                    .is_none_or(|k| tracks.header.tick > k.header.tick)
                {
                    if kept.len() == TRACKS_KEPT {
                        kept.pop_front();
                    }
                    kept.push_back(tracks);
                }
            }
            (PlannerInput::Tracks(_), None) => {}
        }
    }

    /// The estimate that starts the next sample is expected (not each one between).
    fn next(&self) -> Due {
        Due::Expect(Some(self.samples.next_due_s()))
    }

    /// The route of the oldest boundary estimate waiting.
    fn step(&mut self, context: &impl Context) -> Option<Publish<Route>> {
        let (sample, estimate, ()) = self.samples.oldest(context)?;
        self.samples.answered();
        let tick = estimate.header.tick;
        if let Some(change) = context.goals().due(tick, self.goal_serial) {
            self.goal_serial = change.serial;
            self.planner.retarget(change.goal.position);
        }
        let before = |t: &&Tracks| t.header.tick < estimate.header.tick;
        if let Some(tracks) = self
            .tracks
            .as_ref()
            .and_then(|k| k.iter().rev().find(before))
        {
            self.planner.take_tracks(tracks);
        }
        let started_ns = context.monotonic_ns();
        self.planner.step(sample, &estimate);
        let mut route = *self
            .planner
            .took(sample, context.monotonic_ns().saturating_sub(started_ns));
        route.header = Header {
            tick: estimate.header.tick,
            time_s: estimate.header.time_s,
            ..Header::default()
        };
        Some(Publish::now(route))
    }
}
