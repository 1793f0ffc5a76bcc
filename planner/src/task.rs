//! The planner role as a task ([`protocol::task`]): route(k) from the estimate of sample
//! k's first tick (planned again when [`Planner::step`] says so, else the newest route).
//! When it has fallen behind, a sample whose successor's time is past is not answered:
//! only the newest is.

use crate::Planner;
use protocol::task::{Context, Due, Publish, Task, TaskError};
use protocol::topics::{ESTIMATE, ROUTE};
use protocol::{Estimate, Header, Role, Route, Timing, Validated};
use std::collections::VecDeque;

/// What the planner takes: the estimator's estimates.
#[derive(Debug, Clone, Copy)]
pub enum PlannerInput {
    Estimate(Estimate),
}
protocol::task_input!(PlannerInput: Estimate);

/// The planner with the boundary estimates it has not answered yet.
pub struct PlannerTask {
    planner: Planner,
    timing: Timing,
    boundary: VecDeque<Estimate>,
    /// The sample to answer next.
    next_sample: u64,
}

impl Task for PlannerTask {
    const ROLE: Role = Role::Planner;
    const OUTPUTS: &'static [&'static str] = &[ROUTE];
    type Input = PlannerInput;
    type Output = Route;

    fn new(scenario: &Validated, _epoch: u32) -> Result<PlannerTask, TaskError> {
        Ok(PlannerTask {
            planner: Planner::new(scenario),
            timing: scenario.timing.clone(),
            boundary: VecDeque::with_capacity(16),
            next_sample: 0,
        })
    }

    fn inputs(&self) -> &'static [&'static str] {
        &[ESTIMATE]
    }

    /// An estimate heard: kept if it starts a sample not answered yet.
    fn hear(&mut self, input: PlannerInput, _latency_ns: u64, _context: &impl Context) {
        let PlannerInput::Estimate(estimate) = input;
        let tick = estimate.header.tick;
        if self.timing.starts_sample(tick) && self.timing.sample_of(tick) >= self.next_sample {
            self.boundary.push_back(estimate);
        }
    }

    /// The estimate that starts the next sample is expected (not each one between).
    fn next(&self) -> Due {
        Due::Expect(Some(self.timing.sample_time_s(self.next_sample)))
    }

    /// The route of the oldest boundary estimate waiting.
    fn step(&mut self, context: &impl Context) -> Option<Publish<Route>> {
        let clock = context;
        // A sample answered already (a replay heard in the same batch as the original), or
        // one whose successor's time is past, is not answered.
        while let Some(e) = self.boundary.front() {
            let answered = self.timing.sample_of(e.header.tick) < self.next_sample;
            let behind = self
                .boundary
                .get(1)
                .is_some_and(|next| clock.is_past(next.header.time_s));
            if !(answered || behind) {
                break;
            }
            self.boundary.pop_front();
        }
        let estimate = self.boundary.pop_front()?;
        let sample = self.timing.sample_of(estimate.header.tick);
        self.next_sample = sample + 1;
        let mut route = self.planner.step(sample, &estimate);
        route.header = Header {
            tick: estimate.header.tick,
            time_s: estimate.header.time_s,
            ..Header::default()
        };
        Some(Publish::now(route))
    }
}
