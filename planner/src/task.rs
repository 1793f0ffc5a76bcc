//! The planner role as a task ([`protocol::task`]): route(k) from the estimate of sample
//! k's first tick (planned again when [`Planner::step`] says so, else the newest route).
//! When it has fallen behind, a sample whose successor's time is past is not answered:
//! only the newest is.

use crate::Planner;
use protocol::samples::SampleQueue;
use protocol::task::{Context, Due, Publish, Task, TaskError};
use protocol::{Estimate, Header, Role, Route, Validated};

/// What the planner takes: the estimator's estimates.
#[derive(Debug, Clone, Copy)]
pub enum PlannerInput {
    Estimate(Estimate),
}
protocol::task_input!(PlannerInput: Estimate);

/// The planner with the boundary estimates it has not answered yet.
pub struct PlannerTask {
    planner: Planner,
    samples: SampleQueue<()>,
}

impl Task for PlannerTask {
    const ROLE: Role = Role::Planner;
    type Input = PlannerInput;
    type Output = Route;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<PlannerTask, TaskError> {
        Ok(PlannerTask {
            planner: Planner::new(scenario),
            samples: SampleQueue::new(&scenario.timing),
        })
    }

    /// An estimate heard: kept if it starts a sample not answered yet.
    fn hear(&mut self, input: PlannerInput, _latency_ns: u64, _context: &impl Context) {
        let PlannerInput::Estimate(estimate) = input;
        self.samples.hear(estimate, ());
    }

    /// The estimate that starts the next sample is expected (not each one between).
    fn next(&self) -> Due {
        Due::Expect(Some(self.samples.next_due_s()))
    }

    /// The route of the oldest boundary estimate waiting.
    fn step(&mut self, context: &impl Context) -> Option<Publish<Route>> {
        let (sample, estimate, ()) = self.samples.oldest(context)?;
        self.samples.answered();
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
