//! The planner role as a task ([`protocol::task`]): route(k) from the estimate of sample
//! k's first tick (planned again when [`Planner::step`] says so, else the newest route).
//! When it has fallen behind, a sample whose successor's time is past is not answered:
//! only the newest is.

use crate::Planner;
use protocol::task::Context;
use protocol::{Estimate, Header, Route, Timing, Validated};
use std::collections::VecDeque;

/// The planner with the boundary estimates it has not answered yet.
pub struct PlannerTask {
    planner: Planner,
    timing: Timing,
    boundary: VecDeque<Estimate>,
    /// The sample to answer next.
    next_sample: u64,
}

impl PlannerTask {
    pub fn new(scenario: &Validated) -> PlannerTask {
        PlannerTask {
            planner: Planner::new(scenario),
            timing: scenario.timing.clone(),
            boundary: VecDeque::with_capacity(16),
            next_sample: 0,
        }
    }

    /// An estimate heard: kept if it starts a sample not answered yet.
    pub fn hear_estimate(&mut self, estimate: Estimate) {
        let tick = estimate.header.tick;
        if self.timing.starts_sample(tick) && self.timing.sample_of(tick) >= self.next_sample {
            self.boundary.push_back(estimate);
        }
    }

    /// When the next sample starts, s.
    pub fn next_due_s(&self) -> f64 {
        self.timing.sample_time_s(self.next_sample)
    }

    /// The route of the oldest boundary estimate waiting.
    pub fn step(&mut self, context: &impl Context) -> Option<Route> {
        let clock = context.clock();
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
        Some(route)
    }
}
