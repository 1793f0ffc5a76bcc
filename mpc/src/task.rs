//! The MPC role as a task ([`protocol::task`]): plan(k) from the estimate of sample k's
//! first tick, with the scenario's injected faults.
//!
//! With a planner (`planner.kind = "route"`) plan(k) follows the newest route of an
//! earlier sample, route(k - 1) in a whole run (the planner is never between the estimate
//! and the plan): the task waits for route(k - 1) until the time of sample k is past (in
//! lockstep: until it comes; a restarted planner answers the newest estimate). Without
//! any route (the first sample, a planner not heard yet) it drives to the goal. When it
//! has fallen behind, a sample whose successor's time is past is not solved: only the
//! newest is.

use crate::Mpc;
use crate::error::MpcError;
use crate::solver::ArrivalProbe;
use protocol::task::{Context, header_latency};
use protocol::{Estimate, FaultConfig, Header, Plan, Route, Scenario, Timing};
use std::collections::VecDeque;

/// The MPC with the boundary estimates and the routes it has heard.
pub struct MpcTask {
    mpc: Mpc,
    faults: FaultConfig,
    timing: Timing,
    follows_route: bool,
    /// Boundary estimates of samples not solved yet, with their receipt latency, ns.
    boundary: VecDeque<(Estimate, u64)>,
    /// The sample to solve next.
    next_sample: u64,
    /// The newest routes heard, oldest first (a few samples' worth).
    routes: VecDeque<Route>,
}

impl MpcTask {
    pub fn new(scenario: &Scenario) -> Result<MpcTask, MpcError> {
        Ok(MpcTask {
            mpc: Mpc::new(scenario)?,
            faults: scenario.fault.clone(),
            timing: scenario.timing.clone(),
            follows_route: scenario.planner.is_on(),
            boundary: VecDeque::with_capacity(16),
            next_sample: 0,
            routes: VecDeque::with_capacity(4),
        })
    }

    /// Whether the task takes routes (`planner.kind = "route"`).
    pub fn follows_route(&self) -> bool {
        self.follows_route
    }

    /// An estimate received `latency_ns` after it was published: kept if it starts a
    /// sample not solved yet (a replay repeats one that was).
    pub fn hear_estimate(&mut self, estimate: Estimate, latency_ns: u64) {
        let tick = estimate.header.tick;
        if self.timing.starts_sample(tick) && self.timing.sample_of(tick) >= self.next_sample {
            self.boundary.push_back((estimate, latency_ns));
        }
    }

    /// A route heard.
    pub fn hear_route(&mut self, route: Route) {
        if self.routes.len() == self.routes.capacity() {
            self.routes.pop_front();
        }
        self.routes.push_back(route);
    }

    /// When the next sample starts, s.
    pub fn next_due_s(&self) -> f64 {
        self.timing.sample_time_s(self.next_sample)
    }

    /// Warms the next step's memory before the next sample ([`Mpc::rehearse`]), with a
    /// dry step if the last step took at most `dry_step_max_ns`, stopping by `until_ns`
    /// (monotonic ns) or once the estimate `came` ([`crate::solver::rehearsing`]); changes
    /// no plan.
    pub fn rehearse(&mut self, dry_step_max_ns: u64, until_ns: u64, came: &ArrivalProbe) {
        crate::solver::rehearsing(until_ns, came, || self.mpc.rehearse(dry_step_max_ns));
    }

    /// The next plan, if a boundary estimate is waiting and what it needs has come; the
    /// plan's `injected_delay_ns` is what the executor holds it before publishing.
    pub fn step(&mut self, context: &impl Context) -> Option<Plan> {
        let clock = context.clock();
        // A sample solved already (a replay heard in the same batch as the original), or
        // one whose successor's time is past, is not solved.
        while let Some((e, _)) = self.boundary.front() {
            let solved = self.timing.sample_of(e.header.tick) < self.next_sample;
            let behind = self
                .boundary
                .get(1)
                .is_some_and(|(next, _)| clock.is_past(next.header.time_s));
            if !(solved || behind) {
                break;
            }
            self.boundary.pop_front();
        }
        let &(estimate, latency_ns) = self.boundary.front()?;
        let sample = self.timing.sample_of(estimate.header.tick);
        let route_due = self.follows_route
            && sample > 0
            && self.routes.back().is_none_or(|r| r.sample + 1 < sample);
        if route_due && !clock.is_past(estimate.header.time_s) {
            return None; // route(k - 1) is on its way
        }
        self.boundary.pop_front();
        self.next_sample = sample + 1;
        let route = self.routes.iter().rev().find(|r| r.sample < sample);
        let mut plan =
            self.mpc
                .step_on_route(sample, estimate.state, estimate.position_sigma(), route);
        self.mpc.inject_faults(&mut plan, &self.faults);
        plan.header = Header {
            tick: estimate.header.tick,
            time_s: estimate.header.time_s,
            input_latency_ns: header_latency(latency_ns),
            ..Header::default()
        };
        Some(plan)
    }
}
