//! The safety-critical linear MPC (paper eqs. 51-47) on the DFL-linearized model, solved
//! as a sequence of convex conic programs with clarabel.
//!
//! Each step: build `z_0 = Phi(x_hat)`, pick a linearization reference for the CBF rows
//! (the previous plan shifted by one sample, or a braking rollout when cold), solve, and
//! re-linearize at the new plan until it moves less than `refinement_tol_m` (sequential
//! convex programming; every iterate is feasible for the paper's nonconvex constraint and
//! the cost never rises, up to the solver's duality gap). The conic programs are built
//! once, at setup (one per set of rows the input box may imply, [`problem::Rows`]), and
//! only their values are updated afterwards.

pub mod model;
pub mod nonlinear;
pub mod problem;
pub mod process;

use clarabel::algebra::CscMatrix;
use clarabel::solver::SolverStatus;
use nalgebra::{Matrix2, Matrix4, Vector4};
use problem::{
    Assembly, Condensing, ConicSolver, Disc, Layout, PositionReach, Rows, Span, StaticData,
    StepData, csc_with_positions,
};
use protocol::{ConstraintKind, Formulation, Header, MAX_HORIZON, Plan, PlanStatus, Scenario};
use std::time::Instant;

/// Why an MPC cannot be set up for a configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpcError {
    #[error("terminal weight: {0}")]
    Dare(#[from] model::DareError),
    #[error("horizon {0} is outside 1..={MAX_HORIZON}")]
    Horizon(usize),
    #[error("clarabel refused the conic program ({0:?})")]
    Solver(Rows),
}

/// The linear scheme (eqs. 51-47) on the DFL-linearized model.
pub struct LinearMpc {
    layout: Layout,
    statics: StaticData,
    /// `Q_bar`, the DARE solution (eq. 56).
    terminal_weight: Matrix4<f64>,
    goal: [f64; 2],
    /// Obstacles as given (absolute coordinates, true radii).
    obstacles: Vec<protocol::Obstacle>,
    safety_margin_m: f64,
    uncertainty_sigmas: f64,
    max_solves: usize,
    refinement_tol_m: f64,
    ts_s: f64,
    /// Upper triangle of the sparse formulation's `P` (eq. 51).
    hessian: CscMatrix<f64>,
    // Reused every step.
    /// One solver per [`Rows`] ([`Rows::index`]), all built at setup.
    solvers: [ConicSolver; 4],
    /// The rows of the last solve's program.
    rows: Rows,
    /// Whether this step needs the position box and the terminal set.
    box_and_terminal_needed: bool,
    /// Where the positions can be this step.
    reach: PositionReach,
    assembly: Assembly,
    discs: Vec<Disc>,
    reference: Vec<[f64; 2]>,
    /// The last solved iterate, stage-wise (`[z_0, ..., z_N, v_0, ..., v_{N-1}]`,
    /// [`Layout::z`], [`Layout::v`]): every convex solve's solution is feasible for the
    /// paper's constraint, so a failed refinement keeps this one.
    solution: Vec<f64>,
    /// Sample of the last solved plan, whose goal-relative states are in `last_z`.
    last_sample: Option<u64>,
    last_z: Vec<[f64; 4]>,
}

impl LinearMpc {
    pub fn new(scenario: &Scenario) -> Result<LinearMpc, MpcError> {
        let c = &scenario.mpc;
        if c.horizon == 0 || c.horizon > MAX_HORIZON {
            return Err(MpcError::Horizon(c.horizon));
        }
        let (a, b) = model::discretize(scenario.timing.ts_s);
        let r = r_matrix(scenario);
        let terminal_weight = terminal_weight(scenario)?;
        let k = model::lqr_gain(&a, &b, &r, &terminal_weight)?;
        let goal = scenario.robot.goal;
        let position_box = [
            [c.position_min[0] - goal[0], c.position_max[0] - goal[0]],
            [c.position_min[1] - goal[1], c.position_max[1] - goal[1]],
        ];
        let terminal_set = problem::prune_redundant(problem::terminal_set(
            &k,
            &(a + b * k),
            c.constraint_horizon,
            c.v_max,
            position_box,
        ));
        let layout = Layout {
            horizon: c.horizon,
            terminal_rows: terminal_set.len(),
            obstacles: scenario.obstacles.len(),
            linear_barrier: c.constraint == ConstraintKind::Euclidean || c.gamma >= 1.0,
            condensed: c.qp_form.condensed(c.horizon),
        };
        let hessian = stagewise_hessian(&layout, c.q_diag, c.r_diag, &terminal_weight);
        let mut statics = StaticData {
            a,
            b,
            k,
            terminal_set,
            gamma: if c.constraint == ConstraintKind::Euclidean {
                1.0
            } else {
                c.gamma
            },
            v_max: c.v_max,
            position_box,
            box_and_terminal_spans: Vec::new(),
        };
        let (forced, free) = problem::rollout(&layout, &a, &b);
        let spans = statics
            .box_and_terminal_rows(&layout)
            .map(|(terms, bound)| {
                let terms = terms.into_iter().flatten();
                (Span::of(terms, (&forced, &free), c.v_max), bound)
            })
            .collect();
        statics.box_and_terminal_spans = spans;
        let reach = PositionReach::new(&layout, (&forced, &free), c.v_max);
        let assembly = Assembly {
            condensing: layout
                .condensed
                .then(|| Condensing::new(&layout, (forced, free), &hessian)),
            ..Assembly::default()
        };
        let mut mpc = LinearMpc {
            solution: vec![0.0; layout.stagewise()],
            hessian,
            layout,
            statics,
            terminal_weight,
            goal,
            obstacles: scenario.obstacles.clone(),
            safety_margin_m: c.safety_margin_m,
            uncertainty_sigmas: c.uncertainty_sigmas,
            max_solves: c.max_solves.max(1),
            refinement_tol_m: c.refinement_tol_m,
            ts_s: scenario.timing.ts_s,
            solvers: std::array::from_fn(|_| ConicSolver::new(problem::solver_settings)),
            rows: Rows::ALL,
            box_and_terminal_needed: true,
            reach,
            assembly,
            discs: Vec::with_capacity(scenario.obstacles.len()),
            reference: vec![[0.0; 2]; c.horizon + 1],
            last_sample: None,
            last_z: vec![[0.0; 4]; c.horizon + 1],
        };
        mpc.build_solvers()?;
        Ok(mpc)
    }

    /// Builds the solver of each [`Rows`] (their patterns do not depend on the data, so
    /// any values do), so that no step allocates for one.
    fn build_solvers(&mut self) -> Result<(), MpcError> {
        problem::constraint_discs(
            &self.obstacles,
            self.goal,
            self.safety_margin_m,
            0.0,
            self.ts_s,
            0.0,
            &mut self.discs,
        );
        for rows in Rows::EVERY {
            self.fill([0.0; 4], rows);
            let hessian = solver_hessian(&self.assembly, &self.hessian);
            let built = self.solvers[rows.index()].build(
                &self.assembly,
                self.layout.variables(),
                hessian,
                &self.layout.cones(rows),
            );
            if !built {
                return Err(MpcError::Solver(rows));
            }
        }
        Ok(())
    }

    /// The terminal weight `Q_bar` (DARE solution, eq. 56).
    pub fn terminal_weight(&self) -> &Matrix4<f64> {
        &self.terminal_weight
    }

    /// The obstacles as the constraints see them: goal-relative, radius inflated by the
    /// margin `m + kappa sigma` (DESIGN.md section 1).
    pub fn constraint_discs(&self) -> &[Disc] {
        &self.discs
    }

    /// Forgets the previous plan: the next step linearizes at a braking rollout.
    pub fn reset(&mut self) {
        self.last_sample = None;
    }

    /// plan(k) from the estimate `x_bar = [x, y, theta, zeta]` and the standard deviation
    /// `position_sigma_m` of its position. The header is left for the caller to fill.
    pub fn step(&mut self, sample: u64, x_bar: [f64; 4], position_sigma_m: f64) -> Plan {
        let started = Instant::now();
        let z = protocol::phi(x_bar);
        let z0 = [z[0] - self.goal[0], z[1], z[2] - self.goal[1], z[3]];
        let margin = self.safety_margin_m + self.uncertainty_sigmas * position_sigma_m;
        problem::constraint_discs(
            &self.obstacles,
            self.goal,
            margin,
            x_bar[3],
            self.ts_s,
            std::f64::consts::SQRT_2 * self.statics.v_max,
            &mut self.discs,
        );

        let warm = self.shifted_reference(sample);
        if !warm {
            self.braking_reference(z0);
        }
        self.box_and_terminal_needed = !self.statics.box_and_terminal_implied(z0);
        self.reach.set_initial_state(z0);
        let mut outcome = self.refine(z0);
        if outcome.status != PlanStatus::Solved && warm {
            // The shifted plan is no longer a usable linearization point: start cold.
            self.braking_reference(z0);
            let retry = self.refine(z0);
            outcome = Outcome {
                iterations: outcome.iterations + retry.iterations,
                solves: outcome.solves + retry.solves,
                ..retry
            };
        }

        let mut plan = Plan {
            header: Header::default(),
            sample,
            status: outcome.status as u32,
            horizon: self.layout.horizon as u32,
            iterations: outcome.iterations,
            solves: outcome.solves,
            ..Plan::default()
        };
        if outcome.status == PlanStatus::Solved {
            self.write_solution(&mut plan);
            self.last_sample = Some(sample);
        } else {
            self.last_sample = None;
        }
        plan.solve_ns = started.elapsed().as_nanos() as u64;
        plan
    }

    /// Solves, re-linearizes at the solution, and repeats until the plan settles.
    /// On a failed refinement the last solved iterate (feasible for the paper's
    /// constraint) is kept in `solution`.
    fn refine(&mut self, z0: [f64; 4]) -> Outcome {
        let mut outcome = Outcome {
            status: PlanStatus::NumericalError,
            iterations: 0,
            solves: 0,
        };
        for _ in 0..self.max_solves {
            let (status, iterations) = self.solve_once(z0);
            outcome.iterations += iterations;
            outcome.solves += 1;
            if status != PlanStatus::Solved {
                if outcome.status != PlanStatus::Solved {
                    outcome.status = status;
                }
                break;
            }
            outcome.status = PlanStatus::Solved;
            self.load_solution();
            if self.relinearize() < self.refinement_tol_m {
                break;
            }
        }
        outcome
    }

    /// Copies the solver's solution into `solution` (stage-wise).
    fn load_solution(&mut self) {
        let Some(x) = self.solvers[self.rows.index()].x() else {
            return;
        };
        match &self.assembly.condensing {
            Some(condensing) => condensing.expand(x, &mut self.solution),
            None => self.solution.copy_from_slice(x),
        }
    }

    /// One convex solve at the current reference, without the rows the input box
    /// implies.
    fn solve_once(&mut self, z0: [f64; 4]) -> (PlanStatus, u32) {
        let data = StepData {
            z0,
            discs: &self.discs,
            reference: &self.reference,
        };
        let barrier_implied = data
            .barrier(&self.layout, &self.statics)
            .implied(&self.reach);
        let rows = Rows {
            box_and_terminal: self.box_and_terminal_needed,
            barrier: !barrier_implied,
        };
        self.solve_with(z0, rows)
    }

    /// One convex solve of the program with `rows`.
    fn solve_with(&mut self, z0: [f64; 4], rows: Rows) -> (PlanStatus, u32) {
        self.rows = rows;
        self.fill(z0, rows);
        self.solvers[rows.index()].solve(&self.assembly)
    }

    fn fill(&mut self, z0: [f64; 4], rows: Rows) {
        let data = StepData {
            z0,
            discs: &self.discs,
            reference: &self.reference,
        };
        self.assembly.fill(&self.layout, &self.statics, &data, rows);
    }

    /// The previous plan shifted by one sample, extended by one step of the LQR closed
    /// loop (the candidate of the paper's feasibility argument). False when there is no
    /// plan of the previous sample.
    fn shifted_reference(&mut self, sample: u64) -> bool {
        if self.last_sample.is_none_or(|last| sample != last + 1) {
            return false;
        }
        let z = &self.last_z;
        let n = self.layout.horizon;
        for i in 1..n {
            self.reference[i] = [z[i + 1][0], z[i + 1][2]];
        }
        let z_n = Vector4::from(z[n]);
        let next = (self.statics.a + self.statics.b * self.statics.k) * z_n;
        self.reference[n] = [next[0], next[2]];
        true
    }

    /// Positions of the state braking at the input limit from `z0` (held at rest).
    fn braking_reference(&mut self, z0: [f64; 4]) {
        let (ts, v_max) = (self.ts_s, self.statics.v_max);
        let mut z = z0;
        for i in 1..=self.layout.horizon {
            for (p, vel) in [(0, 1), (2, 3)] {
                let acc = (-z[vel] / ts).clamp(-v_max, v_max);
                z[p] += z[vel] * ts + 0.5 * acc * ts * ts;
                z[vel] += acc * ts;
            }
            self.reference[i] = [z[0], z[2]];
        }
    }

    /// Moves the reference to the current solution; returns the largest move, m.
    fn relinearize(&mut self) -> f64 {
        let x = &self.solution;
        let mut moved: f64 = 0.0;
        for i in 1..=self.layout.horizon {
            let p = [x[self.layout.z(i, 0)], x[self.layout.z(i, 2)]];
            moved = moved.max((p[0] - self.reference[i][0]).hypot(p[1] - self.reference[i][1]));
            self.reference[i] = p;
        }
        moved
    }

    /// Writes the solution into `plan` (absolute coordinates) and keeps its goal-relative
    /// states for the next step's shifted reference.
    fn write_solution(&mut self, plan: &mut Plan) {
        let (x, l) = (&self.solution, &self.layout);
        for i in 0..l.horizon {
            plan.v[i] = [x[l.v(i, 0)], x[l.v(i, 1)]];
        }
        for i in 0..=l.horizon {
            let z: [f64; 4] = std::array::from_fn(|c| x[l.z(i, c)]);
            self.last_z[i] = z;
            plan.z[i] = [z[0] + self.goal[0], z[1], z[2] + self.goal[1], z[3]];
        }
    }
}

/// Upper triangle of the solver's `P`: the sparse formulation's, or its condensed form.
fn solver_hessian<'a>(assembly: &'a Assembly, stagewise: &'a CscMatrix<f64>) -> &'a CscMatrix<f64> {
    match &assembly.condensing {
        Some(condensing) => condensing.hessian(),
        None => stagewise,
    }
}

/// Upper triangle of `P` with `1/2 x'Px` = eq. (51),
/// `sum z_i'Q z_i + v_i'R v_i + z_N' Q_bar z_N`, on the stage-wise variables.
fn stagewise_hessian(
    l: &Layout,
    q_diag: [f64; 4],
    r_diag: [f64; 2],
    terminal_weight: &Matrix4<f64>,
) -> CscMatrix<f64> {
    let n = l.horizon;
    let mut entries = Vec::new();
    for i in 0..n {
        for (c, q) in q_diag.iter().enumerate() {
            entries.push((l.z(i, c), l.z(i, c), 2.0 * q));
        }
    }
    for c in 0..4 {
        for r in 0..=c {
            entries.push((l.z(n, r), l.z(n, c), 2.0 * terminal_weight[(r, c)]));
        }
    }
    for i in 0..n {
        for (c, r) in r_diag.iter().enumerate() {
            entries.push((l.v(i, c), l.v(i, c), 2.0 * r));
        }
    }
    csc_with_positions(l.stagewise(), l.stagewise(), &entries).0
}

/// `Q` and `R` of the scenario (eq. 51).
fn q_matrix(scenario: &Scenario) -> Matrix4<f64> {
    Matrix4::from_diagonal(&Vector4::from(scenario.mpc.q_diag))
}
fn r_matrix(scenario: &Scenario) -> Matrix2<f64> {
    Matrix2::from_diagonal(&nalgebra::Vector2::from(scenario.mpc.r_diag))
}

/// `Q_bar`, the DARE solution of the scenario's linearized model (eq. 56).
pub fn terminal_weight(scenario: &Scenario) -> Result<Matrix4<f64>, MpcError> {
    let (a, b) = model::discretize(scenario.timing.ts_s);
    Ok(model::dare(
        &a,
        &b,
        &q_matrix(scenario),
        &r_matrix(scenario),
    )?)
}

/// The MPC role: the paper's linear scheme, or the nonlinear baseline
/// (`mpc.formulation`).
pub enum Mpc {
    Linear(Box<LinearMpc>),
    Nonlinear(Box<nonlinear::NonlinearMpc>),
}

impl Mpc {
    pub fn new(scenario: &Scenario) -> Result<Mpc, MpcError> {
        let horizon = scenario.mpc.horizon;
        if horizon == 0 || horizon > MAX_HORIZON {
            return Err(MpcError::Horizon(horizon));
        }
        Ok(match scenario.mpc.formulation {
            Formulation::Linear => Mpc::Linear(Box::new(LinearMpc::new(scenario)?)),
            Formulation::Nonlinear => Mpc::Nonlinear(Box::new(nonlinear::NonlinearMpc::new(
                scenario,
                &terminal_weight(scenario)?,
            ))),
        })
    }

    /// plan(k) from the estimate `x_bar = [x, y, theta, zeta]` and the standard deviation
    /// `position_sigma_m` of its position. The header is left for the caller to fill.
    pub fn step(&mut self, sample: u64, x_bar: [f64; 4], position_sigma_m: f64) -> Plan {
        match self {
            Mpc::Linear(m) => m.step(sample, x_bar, position_sigma_m),
            Mpc::Nonlinear(m) => m.step(sample, x_bar, position_sigma_m),
        }
    }

    /// Forgets the previous plan: the next step starts cold.
    pub fn reset(&mut self) {
        match self {
            Mpc::Linear(m) => m.reset(),
            Mpc::Nonlinear(m) => m.reset(),
        }
    }

    /// Applies the scenario's injected faults to plan(k): a forced failure (reported as
    /// `numerical_error`, and the MPC starts cold next time, as after a real failure) and
    /// the delay to add before publishing.
    pub fn inject_faults(&mut self, plan: &mut Plan, faults: &protocol::FaultConfig) {
        if faults.mpc_fails(plan.sample) {
            plan.status = PlanStatus::NumericalError as u32;
            self.reset();
        }
        plan.injected_delay_ns = faults.mpc_delay_ns(plan.sample);
    }
}

#[derive(Debug, Clone, Copy)]
struct Outcome {
    status: PlanStatus,
    iterations: u32,
    solves: u32,
}

pub(crate) fn plan_status(status: SolverStatus) -> PlanStatus {
    match status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => PlanStatus::Solved,
        SolverStatus::PrimalInfeasible
        | SolverStatus::AlmostPrimalInfeasible
        | SolverStatus::DualInfeasible
        | SolverStatus::AlmostDualInfeasible => PlanStatus::Infeasible,
        SolverStatus::MaxIterations | SolverStatus::MaxTime => PlanStatus::MaxIterations,
        _ => PlanStatus::NumericalError,
    }
}

/// The smallest slack of the paper's (nonconvex) CBF inequality over a plan:
/// `min_i H(p_{i+1}) - (1 - gamma) H(p_i)` over stages and discs (eq. 54), m^2.
pub fn barrier_slack(plan: &Plan, discs_absolute: &[Disc], gamma: f64) -> f64 {
    let mut slack = f64::INFINITY;
    for disc in discs_absolute {
        for i in 0..plan.horizon as usize {
            let h = |z: [f64; 4]| disc.barrier([z[0], z[2]]);
            slack = slack.min(h(plan.z[i + 1]) - (1.0 - gamma) * h(plan.z[i]));
        }
    }
    slack
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Obstacle, QpForm};

    /// Closed loop of the MPC on its own linear model (exact DFL): returns every plan.
    fn closed_loop(scenario: &Scenario, samples: u64) -> Vec<Plan> {
        let mut plans = Vec::new();
        closed_loop_with(scenario, samples, |_, plan| plans.push(*plan));
        plans
    }

    /// [`closed_loop`], calling `after_step` with the MPC and each plan.
    fn closed_loop_with(
        scenario: &Scenario,
        samples: u64,
        mut after_step: impl FnMut(&mut LinearMpc, &Plan),
    ) {
        let mut mpc = LinearMpc::new(scenario).unwrap();
        let (a, b) = model::discretize(scenario.timing.ts_s);
        let [x, y, theta] = scenario.robot.start;
        let mut z = Vector4::from(protocol::phi([x, y, theta, scenario.robot.zeta0]));
        for k in 0..samples {
            // x_bar with the same z (theta is irrelevant to z when zeta = 0).
            let zeta = z[1].hypot(z[3]);
            let heading = if zeta > 0.0 { z[3].atan2(z[1]) } else { theta };
            let plan = mpc.step(k, [z[0], z[2], heading, zeta], 0.0);
            assert!(plan.is_solved(), "sample {k}: {:?}", plan.status());
            z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
            after_step(&mut mpc, &plan);
        }
    }

    fn absolute_discs(s: &Scenario) -> Vec<Disc> {
        s.obstacles
            .iter()
            .map(|o| Disc {
                center: [o.x, o.y],
                radius: o.radius,
            })
            .collect()
    }

    #[test]
    fn every_solved_plan_satisfies_the_papers_nonconvex_cbf_at_every_stage() {
        for gamma in [0.1, 0.5, 0.9] {
            let mut s = Scenario::default();
            s.mpc.gamma = gamma;
            let plans = closed_loop(&s, 400);
            for p in &plans {
                let slack = barrier_slack(p, &absolute_discs(&s), gamma);
                assert!(
                    slack >= -1e-6,
                    "gamma {gamma}, sample {}: CBF slack {slack:e}",
                    p.sample
                );
            }
            let end = plans.last().unwrap().z[0];
            assert!(
                end[0].hypot(end[2]) < 0.5,
                "gamma {gamma}: did not approach the goal: {end:?}"
            );
        }
    }

    #[test]
    fn euclidean_mode_and_gamma_one_give_the_same_constraint_set() {
        let mut cbf = Scenario::default();
        cbf.mpc.gamma = 1.0;
        cbf.mpc.qp_form = QpForm::Sparse; // rows compared in stage-wise columns
        let mut euclidean = cbf.clone();
        euclidean.mpc.constraint = ConstraintKind::Euclidean;
        euclidean.mpc.gamma = 0.3; // ignored by the Euclidean constraint
        let (a, b) = (
            LinearMpc::new(&cbf).unwrap(),
            LinearMpc::new(&euclidean).unwrap(),
        );
        assert_eq!(
            a.layout.cones(Rows::ALL).len(),
            b.layout.cones(Rows::ALL).len()
        );
        let discs = [Disc {
            center: [3.0, 3.5],
            radius: 1.5,
        }];
        let reference: Vec<[f64; 2]> = (0..=8)
            .map(|i| [6.0 - 0.1 * i as f64, 6.0 - 0.12 * i as f64])
            .collect();
        let data = StepData {
            z0: [7.0, -0.5, 7.0, -0.5],
            discs: &discs,
            reference: &reference,
        };
        let (mut fa, mut fb) = (Assembly::default(), Assembly::default());
        fa.fill(&a.layout, &a.statics, &data, Rows::ALL);
        fb.fill(&b.layout, &b.statics, &data, Rows::ALL);
        assert_eq!(fa.entries, fb.entries);
        assert_eq!(fa.b, fb.b);
        // And the closed loops agree number for number.
        let (pa, pb) = (closed_loop(&cbf, 60), closed_loop(&euclidean, 60));
        assert_eq!(
            pa.iter().map(|p| p.v).collect::<Vec<_>>(),
            pb.iter().map(|p| p.v).collect::<Vec<_>>()
        );
    }

    #[test]
    fn the_pruned_terminal_set_is_the_papers_set() {
        let s = Scenario::default();
        let c = &s.mpc;
        let (a, b) = model::discretize(s.timing.ts_s);
        let k = model::lqr_gain(&a, &b, &r_matrix(&s), &terminal_weight(&s).unwrap()).unwrap();
        let full = problem::terminal_set(
            &k,
            &(a + b * k),
            c.constraint_horizon,
            c.v_max,
            [[-10.0, 10.0]; 2],
        );
        let pruned = problem::prune_redundant(full.clone());
        assert_eq!((full.len(), pruned.len()), (88, 48));
        let inside = |rows: &[([f64; 4], f64)], z: [f64; 4]| {
            rows.iter()
                .all(|(a, b)| a.iter().zip(z).map(|(a, z)| a * z).sum::<f64>() <= *b + 1e-9)
        };
        // A deterministic cloud of points, in and out of the set.
        let mut next = logistic(0.5);
        let (mut seen_in, mut seen_out) = (0, 0);
        for _ in 0..20_000 {
            // Speeds of every scale, so that points fall on both sides of every face.
            let speed = 8.0 * next().powi(3);
            let z = [
                24.0 * next() - 12.0,
                speed * (2.0 * next() - 1.0),
                24.0 * next() - 12.0,
                speed * (2.0 * next() - 1.0),
            ];
            let full_in = inside(&full, z);
            assert_eq!(full_in, inside(&pruned, z), "{z:?}");
            if full_in { seen_in += 1 } else { seen_out += 1 }
        }
        assert!(
            seen_in > 100 && seen_out > 100,
            "{seen_in} in, {seen_out} out"
        );
    }

    #[test]
    fn the_condensed_program_gives_the_sparse_programs_plans() {
        for gamma in [0.1, 1.0] {
            let mut sparse = Scenario::default();
            sparse.mpc.gamma = gamma;
            sparse.mpc.qp_form = QpForm::Sparse;
            let mut condensed = sparse.clone();
            condensed.mpc.qp_form = QpForm::Condensed;
            let (a, b) = (closed_loop(&sparse, 200), closed_loop(&condensed, 200));
            for (a, b) in a.iter().zip(&b) {
                for i in 0..=a.horizon as usize {
                    let gap = (0..4)
                        .map(|c| (a.z[i][c] - b.z[i][c]).abs())
                        .fold(0.0, f64::max);
                    // Both solved to clarabel's accuracy (duality gap 1e-3).
                    assert!(
                        gap < 1e-3,
                        "gamma {gamma}, sample {} stage {i}: {gap:e}",
                        a.sample
                    );
                }
            }
        }
    }

    /// A deterministic sequence in (0, 1).
    fn logistic(mut x: f64) -> impl FnMut() -> f64 {
        move || {
            x = (x * 3.9 * (1.0 - x)).clamp(1e-6, 1.0 - 1e-6);
            x
        }
    }

    #[test]
    fn box_and_terminal_rows_left_out_hold_for_every_input_sequence_in_the_box() {
        let mut s = Scenario::default();
        s.mpc.qp_form = QpForm::Sparse; // rows checked in stage-wise columns
        let mpc = LinearMpc::new(&s).unwrap();
        let mut next = logistic(0.3);
        let (mut left_out, mut kept) = (0, 0);
        for _ in 0..2_000 {
            let z0 = [
                30.0 * next() - 15.0,
                8.0 * next() - 4.0,
                30.0 * next() - 15.0,
                8.0 * next() - 4.0,
            ];
            if !mpc.statics.box_and_terminal_implied(z0) {
                kept += 1;
                continue;
            }
            left_out += 1;
            let data = StepData {
                z0,
                discs: &[],
                reference: &mpc.reference,
            };
            let without_barrier = Rows {
                box_and_terminal: true,
                barrier: false,
            };
            assert_holds_at_worst_inputs(&mpc, &data, without_barrier);
        }
        assert!(
            left_out > 100 && kept > 100,
            "{left_out} left out, {kept} kept"
        );
    }

    #[test]
    fn cbf_rows_left_out_hold_for_every_input_sequence_in_the_box() {
        for gamma in [0.1, 1.0] {
            let mut s = Scenario::default();
            s.mpc.gamma = gamma;
            s.mpc.qp_form = QpForm::Sparse; // rows checked in stage-wise columns
            let mut mpc = LinearMpc::new(&s).unwrap();
            mpc.discs = vec![Disc {
                center: [3.0, 3.5],
                radius: 1.5,
            }];
            let mut next = logistic(0.7);
            let (mut left_out, mut kept) = (0, 0);
            for _ in 0..1_000 {
                // Around the obstacle, within about two radii of its edge.
                let z0 = [
                    8.0 * next() - 1.0,
                    4.0 * next() - 2.0,
                    8.0 * next() - 0.5,
                    4.0 * next() - 2.0,
                ];
                mpc.braking_reference(z0);
                mpc.reach.set_initial_state(z0);
                let data = StepData {
                    z0,
                    discs: &mpc.discs,
                    reference: &mpc.reference,
                };
                if !data.barrier(&mpc.layout, &mpc.statics).implied(&mpc.reach) {
                    kept += 1;
                    continue;
                }
                left_out += 1;
                let only_barrier = Rows {
                    box_and_terminal: false,
                    barrier: true,
                };
                assert_holds_at_worst_inputs(&mpc, &data, only_barrier);
            }
            assert!(
                left_out > 50 && kept > 50,
                "{left_out} left out, {kept} kept"
            );
        }
    }

    /// Panics unless every row of the program with `rows` (stage-wise columns) holds at
    /// the worst input sequence in the input box from `data.z0`: exactly for a linear row
    /// (its slack is smallest at the vertex `v_max sign(coefficients)`), and for a cone at
    /// local maxima over the box's vertices of its violation `||s_2..|| - s_1` (convex
    /// in the inputs, so largest at a vertex), climbed by single sign flips from the
    /// vertices that make each of its rows extreme.
    fn assert_holds_at_worst_inputs(mpc: &LinearMpc, data: &StepData, rows: Rows) {
        use clarabel::solver::SupportedConeT;
        let (l, st) = (&mpc.layout, &mpc.statics);
        assert!(!l.condensed, "rows are checked in stage-wise columns");
        let (forced, free) = problem::rollout(l, &st.a, &st.b);
        let mut assembly = Assembly::default();
        assembly.fill(l, st, data, rows);
        // Each row's slack as `s0 - coefficients' v`.
        let x_free = &free * Vector4::from(data.z0);
        let mut s0 = assembly.b.clone();
        let mut coefficients = vec![vec![0.0; forced.ncols()]; s0.len()];
        for &(r, column, value) in &assembly.entries {
            s0[r] -= value * x_free[column];
            for (j, c) in coefficients[r].iter_mut().enumerate() {
                *c += value * forced[(column, j)];
            }
        }
        let slack = |r: usize, v: &[f64]| {
            s0[r]
                - coefficients[r]
                    .iter()
                    .zip(v)
                    .map(|(c, v)| c * v)
                    .sum::<f64>()
        };
        let extreme = |r: usize, sign: f64| -> Vec<f64> {
            coefficients[r]
                .iter()
                .map(|c| sign * st.v_max * if *c >= 0.0 { 1.0 } else { -1.0 })
                .collect()
        };
        let mut r = 0;
        for cone in l.cones(rows) {
            match cone {
                SupportedConeT::ZeroConeT(d) => r += d, // the rollout satisfies them
                SupportedConeT::NonnegativeConeT(d) => {
                    for row in r..r + d {
                        let worst = slack(row, &extreme(row, 1.0));
                        assert!(worst > -1e-9, "z0 {:?}: row {row}: {worst:e}", data.z0);
                    }
                    r += d;
                }
                SupportedConeT::SecondOrderConeT(d) => {
                    let violation = |v: &[f64]| {
                        let tail: f64 = (r + 1..r + d).map(|k| slack(k, v).powi(2)).sum();
                        tail.sqrt() - slack(r, v)
                    };
                    for start in (r..r + d).flat_map(|k| [extreme(k, 1.0), extreme(k, -1.0)]) {
                        let mut v = start;
                        let mut worst = violation(&v);
                        let mut climbed = true;
                        while climbed {
                            climbed = false;
                            for j in 0..v.len() {
                                v[j] = -v[j];
                                let flipped = violation(&v);
                                if flipped > worst {
                                    (worst, climbed) = (flipped, true);
                                } else {
                                    v[j] = -v[j];
                                }
                            }
                        }
                        assert!(worst < 1e-9, "z0 {:?}: cone at row {r}: {worst:e}", data.z0);
                    }
                    r += d;
                }
                _ => unreachable!("the MPC uses no other cone"),
            }
        }
    }

    /// `1/2 x'Px` of a stage-wise vector (eq. 51).
    fn cost(mpc: &LinearMpc, x: &[f64]) -> f64 {
        let p = &mpc.hessian;
        let mut quadratic = 0.0;
        for c in 0..x.len() {
            for k in p.colptr[c]..p.colptr[c + 1] {
                let r = p.rowval[k];
                let both = if r == c { 1.0 } else { 2.0 };
                quadratic += both * p.nzval[k] * x[r] * x[c];
            }
        }
        0.5 * quadratic
    }

    #[test]
    fn leaving_out_implied_rows_changes_no_plan() {
        for qp_form in [QpForm::Sparse, QpForm::Condensed] {
            let mut s = Scenario::default();
            s.mpc.qp_form = qp_form;
            leaving_out_implied_rows_changes_no_plan_of(&s);
        }
    }

    fn leaving_out_implied_rows_changes_no_plan_of(s: &Scenario) {
        let mut mpc = LinearMpc::new(s).unwrap();
        let mut compared = [0; 4];
        for plan in closed_loop(s, 400).iter().step_by(5) {
            let z = plan.z[0];
            let zeta = z[1].hypot(z[3]);
            mpc.step(plan.sample, [z[0], z[2], z[3].atan2(z[1]), zeta], 0.0);
            let z0 = [z[0] - s.robot.goal[0], z[1], z[2] - s.robot.goal[1], z[3]];
            // The rows left out at the current reference, then every row at the same one.
            assert_eq!(mpc.solve_once(z0).0, PlanStatus::Solved);
            let used = mpc.rows;
            mpc.load_solution();
            let reduced = mpc.solution.clone();
            assert_eq!(mpc.solve_with(z0, Rows::ALL).0, PlanStatus::Solved);
            mpc.load_solution();
            let all = mpc.solution.clone();
            compared[used.index()] += 1;
            // The same optimum, to the solver's accuracy: a duality gap of 1e-3 and
            // feasibility to 1e-6 (relative), which large multipliers of the CBF rows
            // turn into a cost difference of 1e-5 relative.
            let (c_all, c_reduced) = (cost(&mpc, &all), cost(&mpc, &reduced));
            assert!(
                (c_all - c_reduced).abs() < 2e-3 + 1e-5 * c_all,
                "sample {} {used:?}: cost {c_all} with every row, {c_reduced} without",
                plan.sample
            );
            let l = &mpc.layout;
            for i in 1..=l.horizon {
                for c in [0, 2] {
                    let gap = (all[l.z(i, c)] - reduced[l.z(i, c)]).abs();
                    assert!(gap < 1e-4, "sample {}, z_{i}[{c}]: {gap:e} m", plan.sample);
                }
            }
        }
        // The paper's run leaves out the box and terminal rows, and the CBF rows away from
        // the obstacle.
        assert!(compared[0] > 10 && compared[1] > 10, "{compared:?}");
    }

    #[test]
    fn smaller_gamma_keeps_more_clearance() {
        let clearance = |gamma: f64| {
            let mut s = Scenario::default();
            s.mpc.gamma = gamma;
            let o = &s.obstacles[0];
            closed_loop(&s, 300)
                .iter()
                .map(|p| (p.z[0][0] - o.x).hypot(p.z[0][2] - o.y) - o.radius)
                .fold(f64::INFINITY, f64::min)
        };
        let (tight, loose) = (clearance(0.1), clearance(0.9));
        assert!(
            tight > loose,
            "gamma 0.1 clearance {tight} <= gamma 0.9 clearance {loose}"
        );
    }

    #[test]
    fn several_obstacles_are_all_respected() {
        let mut s = Scenario::default();
        s.obstacles.push(Obstacle {
            x: 5.5,
            y: 3.0,
            radius: 0.8,
        });
        s.obstacles.push(Obstacle {
            x: 1.0,
            y: 4.5,
            radius: 0.5,
        });
        for p in closed_loop(&s, 400) {
            assert!(barrier_slack(&p, &absolute_discs(&s), s.mpc.gamma) >= -1e-6);
        }
    }

    #[test]
    fn an_unavoidable_collision_is_reported_infeasible() {
        // Moving at 20 m/s straight at the obstacle 0.2 m away with |v| <= 3: no input
        // sequence keeps the barrier decaying slowly enough.
        let mut s = Scenario::default();
        s.robot.start = [1.3, 3.5, 0.0];
        let mut mpc = LinearMpc::new(&s).unwrap();
        let plan = mpc.step(0, [1.3, 3.5, 0.0, 20.0], 0.0);
        assert_eq!(plan.status(), Some(PlanStatus::Infeasible));
        assert!(plan.solves >= 1 && plan.solve_ns > 0);
    }

    #[test]
    fn the_default_refinement_tolerance_stops_within_half_a_millimetre_of_convergence() {
        for gamma in [0.1, 0.5] {
            let mut s = Scenario::default();
            s.mpc.gamma = gamma;
            let mut stopped_early = 0;
            closed_loop_with(&s, 400, |mpc, plan| {
                // Carry the sequential convexification on from where the step stopped,
                // at the same state, to convergence.
                let stopped = mpc.solution.clone();
                let z = plan.z[0];
                let z0 = [z[0] - s.robot.goal[0], z[1], z[2] - s.robot.goal[1], z[3]];
                (mpc.max_solves, mpc.refinement_tol_m) = (10, 1e-7);
                let converged = mpc.refine(z0);
                assert!(
                    converged.status == PlanStatus::Solved && converged.solves < 10,
                    "gamma {gamma}, sample {}: {converged:?}",
                    plan.sample
                );
                (mpc.max_solves, mpc.refinement_tol_m) = (s.mpc.max_solves, s.mpc.refinement_tol_m);
                let l = &mpc.layout;
                let gap = (1..=l.horizon)
                    .map(|i| {
                        let d = |c| stopped[l.z(i, c)] - mpc.solution[l.z(i, c)];
                        d(0).hypot(d(2))
                    })
                    .fold(0.0, f64::max);
                assert!(
                    gap < 5e-4,
                    "gamma {gamma}, sample {}: {gap:e} m from the converged plan",
                    plan.sample
                );
                if plan.solves == 1 && gap > 1e-5 {
                    stopped_early += 1;
                }
            });
            // Along the obstacle the first solve moves the plan by millimetres to
            // centimetres: those are the refinements the tolerance skips.
            assert!(stopped_early > 10, "gamma {gamma}: {stopped_early}");
        }
    }

    #[test]
    fn refinement_stops_at_the_cap_and_never_raises_the_cost() {
        // Near the obstacle and moving, where the linearization matters.
        let x_bar = [5.0, 4.2, -1.23, 1.0];
        let cost = |max_solves: usize| {
            let mut s = Scenario::default();
            s.mpc.max_solves = max_solves;
            let mut mpc = LinearMpc::new(&s).unwrap();
            let p = mpc.step(0, x_bar, 0.0);
            assert!(
                p.is_solved() && p.solves as usize <= max_solves,
                "{:?} {}",
                p.status(),
                p.solves
            );
            let n = p.horizon as usize;
            let q = |z: [f64; 4]| {
                z.iter()
                    .zip(s.mpc.q_diag)
                    .map(|(z, q)| q * z * z)
                    .sum::<f64>()
            };
            let stage: f64 = (0..n)
                .map(|i| {
                    q(p.z[i])
                        + p.v[i]
                            .iter()
                            .zip(s.mpc.r_diag)
                            .map(|(v, r)| r * v * v)
                            .sum::<f64>()
                })
                .sum();
            let z_n = Vector4::from(p.z[n]);
            (
                stage + (z_n.transpose() * mpc.terminal_weight() * z_n)[0],
                p.solves,
            )
        };
        let (single, one) = cost(1);
        let (refined, solves) = cost(10);
        assert_eq!(one, 1);
        assert!(solves > 1, "the reference should have needed refining");
        assert!(
            refined <= single + 2e-3, // twice clarabel's duality gap
            "refined cost {refined} > single-solve cost {single}"
        );
    }
}
