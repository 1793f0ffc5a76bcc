//! The four roles stepped in one process, in the order of the data flow, with the lockstep
//! semantics of the design (section 3). `scmpc run --in-process`, `sweep`, `figures`, the
//! allocation test and the step benchmarks all step this one loop.
//!
//! Per inner tick `j` (time `t_j = j Ts / M`), phase by phase:
//! 1. [`ClosedLoop::measure`]: the plant's true pose and its measurement;
//! 2. [`ClosedLoop::estimate`]: the estimator predicts with the command of tick `j - 1`
//!    and updates;
//! 3. [`ClosedLoop::plan`]: on a sample boundary (`j = k M`) the MPC solves plan(k), with
//!    the scenario's faults, following route(k - 1) if a planner runs; a plan whose solve
//!    time (measured, plus any injected delay) exceeds `Ts` arrives `ceil(solve / Ts)`
//!    samples late, as it would in real time;
//!    then [`ClosedLoop::route`]: the planner's route(k) from the same estimate, which the
//!    MPC follows from the next sample on (so the planner is never on the path from the
//!    estimate to the plan);
//! 4. [`ClosedLoop::command`]: plans whose arrival sample has come are released to the
//!    DFL, which commands `[t_j, t_j+1)`; on a sample boundary the deadline monitor judges
//!    the sample;
//! 5. [`ClosedLoop::integrate`]: the plant integrates the command over the tick.
//!
//! [`ClosedLoop::step`] runs them in order. The phases are public so that a caller can
//! measure each (the allocation test counts allocations phase by phase).

use dfl::InnerLoop;
use estimator::Estimator;
use mpc::Mpc;
use planner::Planner;
use plant::{Plant, Pose};
use protocol::{
    Actuation, DeadlineVerdict, Estimate, FaultConfig, GroundTruth, Header, Plan, Route, Timing,
    Validated,
};

/// One inner tick of the closed loop: what every role produced.
#[derive(Debug, Clone)]
pub struct Tick {
    /// The plant's pose at the start of the tick.
    pub truth: GroundTruth,
    pub estimate: Estimate,
    /// The plan solved at this tick (sample boundaries only).
    pub plan: Option<Plan>,
    /// The planner's route of this tick (sample boundaries of runs with a planner).
    pub route: Option<Route>,
    /// The deadline monitor's verdict on the sample this tick starts (boundaries only).
    pub verdict: Option<DeadlineVerdict>,
    /// The DFL's command for the tick, with the deadline misses so far.
    pub actuation: Actuation,
}

/// The plant, estimator, MPC and DFL of one scenario, stepped in lockstep.
pub struct ClosedLoop {
    plant: Plant,
    estimator: Estimator,
    mpc: Mpc,
    /// The route planner (`planner.kind = "route"`).
    planner: Option<Planner>,
    /// The newest route, which the MPC follows at the next sample.
    route: Option<Route>,
    /// The DFL with its plan inbox and deadline monitor.
    inner: InnerLoop,
    faults: FaultConfig,
    /// The command the estimator hears at the next tick (none before the first).
    applied: Option<[f64; 2]>,
    tick: u64,
    ticks: u64,
    timing: Timing,
}

impl ClosedLoop {
    /// The roles of `scenario` at their initial states.
    pub fn new(scenario: &Validated) -> Result<Self, mpc::MpcError> {
        Ok(Self {
            plant: Plant::new(scenario),
            estimator: Estimator::new(scenario),
            mpc: Mpc::new(scenario)?,
            planner: scenario.planner.is_on().then(|| Planner::new(scenario)),
            route: None,
            inner: InnerLoop::new(scenario, true),
            faults: scenario.fault.clone(),
            applied: None,
            tick: 0,
            ticks: scenario.tick_count(),
            timing: scenario.timing.clone(),
        })
    }

    /// The tick the next [`step`](Self::step) runs.
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Whether every tick of the run's duration has been stepped.
    pub fn is_done(&self) -> bool {
        self.tick >= self.ticks
    }

    /// The header of the current tick.
    pub fn header(&self) -> Header {
        Header {
            tick: self.tick,
            time_s: self.timing.tick_time_s(self.tick),
            ..Header::default()
        }
    }

    /// The plant's true pose now (after the last integrated tick).
    pub fn truth(&self) -> GroundTruth {
        GroundTruth {
            header: self.header(),
            pose: self.plant.pose(),
        }
    }

    /// Phase 1: the true pose at the start of the tick and the plant's measurement of it.
    pub fn measure(&mut self) -> (GroundTruth, Pose) {
        (self.truth(), self.plant.measure())
    }

    /// Phase 2: the estimate from the measurement and the previous tick's command.
    pub fn estimate(&mut self, measurement: Pose) -> Estimate {
        let header = self.header();
        self.estimator.step(
            self.applied,
            self.timing.dt_s(),
            measurement,
            self.inner.dfl.zeta(),
            header,
        )
    }

    /// Phase 3: on a sample boundary, the MPC's plan from `estimate` (with the scenario's
    /// faults), handed to the DFL's inbox to arrive when its solve time says.
    pub fn plan(&mut self, estimate: &Estimate) -> Option<Plan> {
        let (sample, first_tick) = self.inner.sample_of(self.tick);
        if !first_tick {
            return None;
        }
        let mut plan = self.mpc.step_on_route(
            sample,
            estimate.state,
            estimate.position_sigma(),
            self.route.as_ref(),
        );
        self.mpc.inject_faults(&mut plan, &self.faults);
        plan.header = self.header();
        self.inner.receive(&plan, None);
        Some(plan)
    }

    /// Phase 3b: on a sample boundary of a run with a planner, route(k) from `estimate`.
    pub fn route(&mut self, estimate: &Estimate) -> Option<Route> {
        let planner = self.planner.as_mut()?;
        let (sample, first_tick) = self.inner.sample_of(self.tick);
        if !first_tick {
            return None;
        }
        let mut route = planner.step(sample, estimate);
        route.header = self.header();
        self.route = Some(route);
        Some(route)
    }

    /// Phase 4: the DFL's command for the tick, after releasing the plans that have
    /// arrived, and on a sample boundary the deadline monitor's verdict on the sample.
    pub fn command(&mut self, estimate: &Estimate) -> (Actuation, Option<DeadlineVerdict>) {
        self.inner.command(estimate, self.tick)
    }

    /// Phase 5: the plant integrates `actuation` over the tick; the next tick begins.
    pub fn integrate(&mut self, actuation: &Actuation) {
        self.plant
            .step(actuation.u1, actuation.u2, self.timing.dt_s());
        // The estimator is driven by the command it hears, as over IPC.
        self.applied = Some([actuation.u1, actuation.u2]);
        self.tick += 1;
    }

    /// One inner tick: the five phases in order.
    pub fn step(&mut self) -> Tick {
        let (truth, measurement) = self.measure();
        let estimate = self.estimate(measurement);
        let plan = self.plan(&estimate);
        let route = self.route(&estimate);
        let (actuation, verdict) = self.command(&estimate);
        self.integrate(&actuation);
        Tick {
            truth,
            estimate,
            plan,
            route,
            verdict,
            actuation,
        }
    }
}
