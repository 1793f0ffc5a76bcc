//! The in-process executor: every role's task ([`protocol::task`]) stepped in one process,
//! in the order of the data flow, on a lockstep clock standing at the current tick.
//! `scmpc run --in-process`, `sweep`, `figures`, the allocation test and the step
//! benchmarks all step this one loop; the role processes step the same tasks.
//!
//! Per inner tick `j` (time `t_j = j Ts / M`), phase by phase:
//! 1. [`ClosedLoop::measure`]: the plant integrates the command of tick `j - 1` and
//!    outputs its true pose and measurement;
//! 2. [`ClosedLoop::estimate`]: the estimator's estimate of the measurement;
//! 3. [`ClosedLoop::plan`]: on a sample boundary (`j = k M`) the MPC's plan(k), handed to
//!    the DFL (a plan whose production time exceeds `Ts` arrives `ceil(production / Ts)`
//!    samples late, as it would in real time); then [`ClosedLoop::route`]: the planner's
//!    route(k) from the same estimate, which the MPC follows from the next sample on (so
//!    the planner is never on the path from the estimate to the plan);
//! 4. [`ClosedLoop::command`]: the DFL's command for `[t_j, t_j+1)` and, on a sample
//!    boundary, its verdict on the previous sample's deadline;
//! 5. [`ClosedLoop::integrate`]: the command is heard by the plant and the estimator; the
//!    next tick begins.
//!
//! What a process executor adds, this one does as its supervision would: an estimate its
//! consumers would refuse ([`protocol::Message::content_rejection`]) is replaced by the
//! estimate of a restarted estimator (the scenario's restart policy), so that every
//! injected fault gives the same run here as over iceoryx2 in lockstep.
//! [`ClosedLoop::step`] runs the phases in order; they are public so that a caller can
//! measure each (the allocation test counts allocations phase by phase).

use dfl::DflTask;
use estimator::EstimatorTask;
use mpc::MpcTask;
use planner::PlannerTask;
use plant::PlantTask;
use protocol::clock::RunClock;
use protocol::{
    Actuation, DeadlineVerdict, Estimate, GroundTruth, Measurement, Message, Plan, RestartPolicy,
    Route, Validated,
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
    /// The estimator was restarted at this tick (its estimate was refused).
    pub restarted_estimator: bool,
}

/// The tasks of one scenario, stepped in lockstep.
pub struct ClosedLoop {
    scenario: Validated,
    plant: PlantTask,
    estimator: EstimatorTask,
    mpc: MpcTask,
    /// The route planner (`planner.kind = "route"`).
    planner: Option<PlannerTask>,
    dfl: DflTask,
    /// The newest command, which a restarted estimator hears again.
    last_actuation: Option<Actuation>,
    /// Estimator restarts so far, and the epoch of the one running.
    restarts: u32,
    estimator_epoch: u32,
    tick: u64,
    ticks: u64,
}

impl ClosedLoop {
    /// The tasks of `scenario` at their initial states.
    pub fn new(scenario: &Validated) -> Result<Self, mpc::MpcError> {
        Ok(Self {
            scenario: scenario.clone(),
            plant: PlantTask::new(scenario),
            estimator: EstimatorTask::new(scenario, 0),
            mpc: MpcTask::new(scenario)?,
            planner: scenario.planner.is_on().then(|| PlannerTask::new(scenario)),
            dfl: DflTask::new(scenario),
            last_actuation: None,
            restarts: 0,
            estimator_epoch: 0,
            tick: 0,
            ticks: scenario.tick_count(),
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

    /// The clock of the current tick.
    fn clock(&self) -> RunClock {
        RunClock::simulated_at(self.tick, self.scenario.timing.dt_s())
    }

    /// Phase 1: the plant's truth and measurement of the tick, after integrating the
    /// command of the tick before.
    pub fn measure(&mut self) -> (GroundTruth, Measurement) {
        let clock = self.clock();
        self.plant
            .step(&clock)
            .expect("in process the plant has heard the command of every earlier tick")
    }

    /// Phase 2: the estimate of `measurement`; `None` when it was refused and the
    /// scenario's restart policy allows no new estimator (the run is aborted).
    pub fn estimate(&mut self, measurement: Measurement) -> Option<(Estimate, bool)> {
        let clock = self.clock();
        self.estimator.hear_measurement(measurement, 0);
        let estimate = self
            .estimator
            .step(&clock)
            .expect("in process the estimator has heard the command of the tick before");
        if estimate.content_rejection().is_none() {
            return Some((estimate, false));
        }
        let supervision = &self.scenario.supervision;
        if supervision.restart != RestartPolicy::Always || self.restarts >= supervision.max_restarts
        {
            return None;
        }
        self.restarts += 1;
        self.estimator_epoch += 1;
        self.estimator = EstimatorTask::new(&self.scenario, self.estimator_epoch);
        self.estimator.hear_measurement(measurement, 0);
        if let Some(actuation) = self.last_actuation {
            self.estimator.hear_actuation(actuation);
        }
        let estimate = self
            .estimator
            .step(&clock)
            .expect("a restarted estimator estimates the measurement it joined at");
        Some((estimate, true))
    }

    /// Phase 3: on a sample boundary, the MPC's plan from `estimate` (with the scenario's
    /// faults), handed to the DFL.
    pub fn plan(&mut self, estimate: &Estimate) -> Option<Plan> {
        let clock = self.clock();
        self.mpc.hear_estimate(*estimate, 0);
        let plan = self.mpc.step(&clock)?;
        self.dfl.hear_plan(&plan, &clock);
        Some(plan)
    }

    /// Phase 3b: on a sample boundary of a run with a planner, route(k) from `estimate`,
    /// handed to the MPC.
    pub fn route(&mut self, estimate: &Estimate) -> Option<Route> {
        let clock = self.clock();
        let planner = self.planner.as_mut()?;
        planner.hear_estimate(*estimate);
        let route = planner.step(&clock)?;
        self.mpc.hear_route(route);
        Some(route)
    }

    /// Phase 4: the DFL's command for the tick and, on a sample boundary, its verdict on
    /// the previous sample.
    pub fn command(&mut self, estimate: &Estimate) -> (Actuation, Option<DeadlineVerdict>) {
        let clock = self.clock();
        self.dfl.hear_estimate(*estimate, 0);
        self.dfl
            .step(&clock)
            .expect("in process the DFL has every plan it waits for")
    }

    /// Phase 5: the plant and the estimator hear `actuation`; the next tick begins.
    pub fn integrate(&mut self, actuation: &Actuation) {
        self.plant.hear(*actuation);
        self.estimator.hear_actuation(*actuation);
        self.last_actuation = Some(*actuation);
        self.tick += 1;
    }

    /// One inner tick: the five phases in order; `None` when the run is aborted (a
    /// refused estimate with no restart left).
    pub fn step(&mut self) -> Option<Tick> {
        let (truth, measurement) = self.measure();
        let (estimate, restarted_estimator) = self.estimate(measurement)?;
        let plan = self.plan(&estimate);
        let route = self.route(&estimate);
        let (actuation, verdict) = self.command(&estimate);
        self.integrate(&actuation);
        Some(Tick {
            truth,
            estimate,
            plan,
            route,
            verdict,
            actuation,
            restarted_estimator,
        })
    }

    /// After the last tick: the plant's truth at the end of the run (its pose after the
    /// last command).
    pub fn final_truth(&mut self) -> GroundTruth {
        self.measure().0
    }
}
