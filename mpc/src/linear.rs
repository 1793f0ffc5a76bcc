//! The paper's linear scheme (problem of eqs. 51 to 47) on the DFL-linearized model: each step builds
//! `z_0 = Phi(x_hat)`, picks a linearization reference for the CBF rows (the previous plan
//! shifted by one sample, or a braking rollout when cold), solves, and re-linearizes at
//! the new plan until it moves less than `refinement_tol_m` (sequential convex
//! programming; every iterate is feasible for the paper's nonconvex constraint and the
//! cost never rises, up to the solver's duality gap). The conic programs are built once,
//! at setup (one per set of rows the input box may imply, [`Rows`]), and only their
//! values are updated afterwards.

use crate::assembly::{Assembly, Condensing};
use crate::discs::Prediction;
use crate::error::MpcError;
use crate::follow;
use crate::layout::{Layout, Rows};
use crate::model::{self, q_matrix, r_matrix};
use crate::program::{self, StaticData, StepData};
use crate::reach::PositionReach;
use crate::solver::{CancelSlot, ConicSolver, Outcome};
use clarabel::algebra::CscMatrix;
use nalgebra::Matrix4;
use protocol::task::Cancel;
use protocol::{Disc, Header, ObstacleGrowth, Plan, PlanStatus, Scenario, Tracks};

/// How far about the reference a disc must be out of reach to be deferred from a solve's
/// program ([`LinearMpc::solve_once`]): its rows must hold for every input within this
/// share of the input box of the reference's. Larger: fewer solves again, larger programs.
/// Measured on the obstacle field at N = 16 and 30 (docs/performance.md): 0.05 had the
/// lowest p99 of 0, 0.05, 0.1 and 0.25.
const DEFERRAL_SHARE: f64 = 0.05;

/// The linear scheme (problem of eqs. 51 to 47) on the DFL-linearized model.
pub struct LinearMpc {
    layout: Layout,
    statics: StaticData,
    /// `Q_bar`, the DARE solution (eq. 56).
    terminal_weight: Matrix4<f64>,
    goal: [f64; 2],
    /// The cost's state weight `Q` (diagonal) on every stage before the last.
    q_diag: [f64; 4],
    /// Whether the objective's linear term is written every step, zero or not: once the
    /// cost has tracked anything but the goal (a route, a sub-goal), since a solver keeps
    /// the last linear term it was given.
    writes_linear_term: bool,
    /// How fast the reference moves along a route ([`route_speed`]).
    route_speed: follow::SpeedProfile,
    /// Whether the next step tracks `route_reference` (else the goal, or a sub-goal).
    on_route: bool,
    /// The stage-wise reference states on a route ([`follow::reference`]; absolute).
    route_reference: Vec<[f64; 4]>,
    /// The step's sub-goal ([`crate::terminal_set::sub_goal`]; goal-relative, m): the
    /// terminal set and cost are taken about it.
    sub_goal: [f64; 2],
    /// The cost's linear term for the step's reference, as `(stage-wise column, value)`
    /// ([`LinearMpc::write_reference_cost`]); empty: the goal.
    reference_cost: Vec<(usize, f64)>,
    /// The obstacles known from the scenario and the newest tracks of the others.
    world: crate::discs::World,
    /// How every obstacle grows (the robot's radius, the margin `m`, `kappa sigma`).
    growth: ObstacleGrowth,
    /// What the discs grow by for what follows the solver.
    plan_margin: crate::discs::PlanMargin,
    max_solves: usize,
    refinement_tol_m: f64,
    ts_s: f64,
    /// Upper triangle of the sparse formulation's `P` (eq. 51).
    hessian: CscMatrix<f64>,
    // Reused every step.
    /// One solver per [`Rows`] ([`Rows::index`]), all built at setup.
    solvers: Vec<ConicSolver>,
    /// A warm-up's cancel check while one runs: it cuts the solvers' solves short and
    /// keeps a step from trying anything more ([`LinearMpc::warm_up`]).
    cancel: CancelSlot,
    /// The rows of the last solve's program.
    rows: Rows,
    /// Whether this step needs the position box and the terminal set.
    box_and_terminal_needed: bool,
    /// Where the positions can be this step.
    reach: PositionReach,
    assembly: Assembly,
    /// The step's constraint discs ([`crate::discs::constraint_discs`]).
    discs: Vec<Disc>,
    /// How the tracked obstacles among `discs` are predicted: bounded, or at their
    /// velocity in the escape program ([`Prediction`]).
    prediction: Prediction,
    /// How long from the step's time the phantoms and standing tracks among `discs`
    /// stand, s ([`protocol::KeptTracks::stand_for_s`]).
    stand_s: f64,
    /// Whether the terminal rows carry the moving discs on for `mpc.rest_lookahead_s`
    /// ([`StepData::rest_lookahead`]): false only for a step's last resort
    /// ([`LinearMpc::drops_rest_lookahead`]).
    rest_lookahead: bool,
    /// Those of a solve's program: discs whose rows the input box does not imply and
    /// that lie near the plan ([`LinearMpc::solve_once`]), the first `kept_whole` of them
    /// with all their rows, the others with their terminal rows only.
    kept: Vec<Disc>,
    kept_whole: usize,
    /// Discs whose rows the input box does not imply, left out of a solve's program while
    /// its solution meets their rows.
    deferred: Vec<Disc>,
    /// Whether discs away from the plan are deferred (false: every disc the input box does
    /// not rule out is in the program, as a test's reference).
    defers_discs: bool,
    /// [`DEFERRAL_SHARE`] (a test defers more).
    deferral_share: f64,
    /// Whether a program whose terminal rows no input sequence meets is failed without a
    /// solve ([`Barrier::terminal_impossible`]; false: clarabel proves it, as a test's
    /// reference).
    ///
    /// [`Barrier::terminal_impossible`]: crate::program::Barrier::terminal_impossible
    proves_infeasible: bool,
    /// The positions about a plan ([`PositionReach::set_plan`]): the reference's, then a
    /// solution's.
    plan_reach: PositionReach,
    /// A solve's solution, stage-wise, while its deferred discs are checked.
    iterate: Vec<f64>,
    reference: Vec<[f64; 2]>,
    /// The reference's last velocity `w_bar_N` (the terminal rows are built at it).
    reference_velocity: [f64; 2],
    /// The last solved iterate, stage-wise (`[z_0, ..., z_N, v_0, ..., v_{N-1}]`,
    /// [`Layout::z`], [`Layout::v`]): every convex solve's solution is feasible for the
    /// paper's constraint (a relaxed program's for its relaxed decay and `H >= 0`), so a
    /// failed refinement keeps this one.
    solution: Vec<f64>,
    /// Sample of the last solved plan, whose goal-relative states are in `last_z`.
    last_sample: Option<u64>,
    /// Whether the last solved plan is the escape program's (the tracks at their
    /// velocity): the next step then tries the bounded program once, at the shifted plan
    /// and not relaxed, before the escape program again.
    ///
    /// Measured on `swap8` in process (2026-12-04, 5637 steps, half of them escapes):
    /// after 3012 escape plans the cold retry never found a bounded plan, and the relaxed
    /// program found one 7 times in 3016; the bounded program was feasible again at the
    /// shifted plan 145 times. Proving a program infeasible took 11-14 interior-point
    /// iterations against 7 for a solve: without the three solves the run's MPC
    /// iterations fell from 244,433 to 108,837, and every robot still reached its goal,
    /// 3 s later (docs/fleet.md, "Speed"). The DFL's check judges an escape plan as it
    /// does any other.
    last_escaped: bool,
    last_z: Vec<[f64; 4]>,
    /// The last step's estimate `x_bar` and position standard deviation, m, and its
    /// duration, ns.
    last_estimate: Option<([f64; 4], f64)>,
    last_step_ns: u64,
    /// What [`LinearMpc::warm_up`] keeps while its dry step runs: `last_z`, `solution`.
    saved_last_z: Vec<[f64; 4]>,
    saved_solution: Vec<f64>,
}

impl LinearMpc {
    /// Builds everything a step reuses, in the order the pieces depend on each other: the
    /// model (paper eq. mobile46-1, discretized), the LQR terminal weight and set, the layout and Hessian, the spans
    /// of the box and terminal rows, the rows' solvers (long, as a list: no step may
    /// allocate, so all of it is made here).
    pub fn new(scenario: &Scenario) -> Result<LinearMpc, MpcError> {
        let c = &scenario.mpc;
        crate::error::check_horizon(c.horizon)?;
        // The model (eq. mobile46-1), discretized once; the terminal weight (eq. 56) and
        // the LQR gain of it.
        let (a, b) = model::discretize(scenario.timing.ts_s);
        let terminal_weight = model::dare(&a, &b, &q_matrix(scenario), &r_matrix(scenario))?;
        let k = model::lqr_gain(&a, &b, &r_matrix(scenario), &terminal_weight)?;
        let goal = scenario.robot.goal.position;
        let statics = StaticData::of(scenario, a, b, k);
        let route_speed = follow::route_speed(scenario, &statics.terminal_set);
        let layout = Layout::of(scenario, statics.terminal_set.len());
        let hessian =
            crate::assembly::stagewise_hessian(&layout, c.q_diag, c.r_diag, &terminal_weight);
        let (forced, free) = crate::reach::rollout(&layout, &a, &b);
        let statics = statics.with_spans(&layout, (&forced, &free));
        let reach = PositionReach::new(&layout, (&forced, &free), c.v_max);
        let assembly = Assembly {
            condensing: layout
                .condensed
                .then(|| Condensing::new(&layout, (forced, free), &hessian)),
            ..Assembly::default()
        };
        let cancel = CancelSlot::default();
        let solvers = (0..Rows::count(&layout))
            .map(|_| ConicSolver::new(crate::solver::solver_settings, cancel.clone()))
            .collect();
        let rows = Rows::all(&layout);
        let layout_stagewise = layout.stagewise();
        let mut mpc = LinearMpc {
            cancel,
            solution: vec![0.0; layout_stagewise],
            saved_solution: vec![0.0; layout_stagewise],
            hessian,
            layout,
            statics,
            terminal_weight,
            goal,
            q_diag: c.q_diag,
            writes_linear_term: scenario.plans_routes(),
            route_speed,
            on_route: false,
            route_reference: vec![[0.0; 4]; c.horizon + 1],
            sub_goal: [0.0; 2],
            reference_cost: Vec::with_capacity(4 * c.horizon + 4),
            world: crate::discs::World::of(scenario),
            growth: ObstacleGrowth::of(scenario),
            plan_margin: crate::discs::PlanMargin::of(scenario),
            max_solves: c.max_solves.max(1),
            refinement_tol_m: c.refinement_tol_m,
            ts_s: scenario.timing.ts_s,
            solvers,
            rows,
            box_and_terminal_needed: true,
            plan_reach: reach.clone(),
            reach,
            assembly,
            // Every track's disc before the nearest are kept (`World::discs`).
            discs: Vec::with_capacity(scenario.max_obstacle_discs() + protocol::MAX_TRACKS),
            prediction: Prediction::Bounded,
            stand_s: 0.0,
            rest_lookahead: true,
            kept: Vec::with_capacity(scenario.max_obstacle_discs()),
            kept_whole: 0,
            deferred: Vec::with_capacity(scenario.max_obstacle_discs()),
            defers_discs: true,
            deferral_share: DEFERRAL_SHARE,
            proves_infeasible: true,
            iterate: vec![0.0; layout_stagewise],
            reference: vec![[0.0; 2]; c.horizon + 1],
            reference_velocity: [0.0; 2],
            last_sample: None,
            last_escaped: false,
            last_z: vec![[0.0; 4]; c.horizon + 1],
            last_estimate: None,
            last_step_ns: 0,
            saved_last_z: vec![[0.0; 4]; c.horizon + 1],
        };
        mpc.build_solvers()?;
        Ok(mpc)
    }

    /// Builds the solver of each [`Rows`] (their patterns do not depend on the data, so
    /// any values do), so that no step allocates for one.
    fn build_solvers(&mut self) -> Result<(), MpcError> {
        crate::discs::constraint_discs(
            self.world.known(),
            self.goal,
            self.growth.fixed_m,
            0.0,
            self.ts_s,
            0.0,
            &mut self.discs,
        );
        // The tracked obstacles' discs (any values do).
        self.discs
            .resize(self.layout.obstacles, Disc::still([0.0; 2], 0.0));
        for rows in Rows::every(&self.layout).collect::<Vec<_>>() {
            self.kept.clear();
            self.kept
                .extend_from_slice(&self.discs[..rows.terminal_discs()]);
            self.fill([0.0; 4], rows);
            let variables = self.layout.variables(rows);
            let hessian = crate::assembly::padded(
                crate::assembly::solver_hessian(&self.assembly, &self.hessian),
                variables,
            );
            let built = self.solvers[rows.index()].build(
                &self.assembly,
                variables,
                &hessian,
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
    /// margin `m + kappa sigma` (docs/design.md).
    pub fn constraint_discs(&self) -> &[Disc] {
        &self.discs
    }

    /// What every obstacle's radius grows by in the constraints
    /// ([`crate::discs::obstacle_growth_m`]), m.
    fn margin_m(&self, position_sigma_m: f64) -> f64 {
        crate::discs::obstacle_growth_m(&self.growth, position_sigma_m, self.plan_margin)
    }

    /// Forgets the previous plan: the next step linearizes at a braking rollout.
    pub fn reset(&mut self) {
        self.last_sample = None;
        self.last_escaped = false;
    }

    /// A warm-up: a dry run of the next step, for its memory's sake: a process that slept since its
    /// last step finds its working set (the discs, the reference, the assembly, the
    /// solver it will use) in cache at the next one. It steps the next sample from the
    /// estimate the last plan predicts (its `z_1`), then puts back what a step leaves for
    /// the next (`last_sample`, `last_z`, `solution`, the last estimate), so the next
    /// step's plan is the same. Everything else a step reads it writes first, except
    /// `writes_linear_term`, which only ever turns on, and writing the linear term is
    /// always right. Without a solved last plan, or when the last step took longer than
    /// `dry_step_max_ns` (a dry step as long could run into the sample), it only solves
    /// the last program again ([`ConicSolver::solve_again`]). Every solve in it stops
    /// once `cancel` holds, and the step then tries nothing more.
    pub fn warm_up(&mut self, dry_step_max_ns: u64, cancel: &Cancel) {
        let slot = self.cancel.clone();
        slot.during(cancel, || self.dry_step(dry_step_max_ns));
    }

    /// Notes how long the last step took, ns, as its caller timed it (the task, on its
    /// context's clock: a role reads no clock of its own): the warm-up steps the next
    /// sample dry only after a step that took at most its bound.
    pub fn took(&mut self, step_ns: u64) {
        self.last_step_ns = step_ns;
    }

    /// The warm-up of [`LinearMpc::warm_up`], its cancel check in place.
    fn dry_step(&mut self, dry_step_max_ns: u64) {
        let (Some(sample), Some((x_bar, sigma_m)), true) = (
            self.last_sample,
            self.last_estimate,
            self.last_step_ns <= dry_step_max_ns,
        ) else {
            self.solvers[self.rows.index()].solve_again();
            return;
        };
        let z1 = self.last_z[1];
        let predicted = protocol::phi_inverse(
            [z1[0] + self.goal[0], z1[1], z1[2] + self.goal[1], z1[3]],
            x_bar[2],
        );
        self.saved_last_z.copy_from_slice(&self.last_z);
        self.saved_solution.copy_from_slice(&self.solution);
        let last_escaped = self.last_escaped;
        self.step(sample + 1, predicted, sigma_m);
        self.last_z.copy_from_slice(&self.saved_last_z);
        self.solution.copy_from_slice(&self.saved_solution);
        self.last_sample = Some(sample);
        self.last_escaped = last_escaped;
        self.last_estimate = Some((x_bar, sigma_m));
    }

    /// The states the next steps' cost drives to, stage by stage (absolute `z_i`,
    /// `reference[i]` for `i = 1..=N`): eq. (51) with `z_i - r_i` for `z_i`, on every stage
    /// after the first and in the terminal weight; `None`: the goal at rest (eq. 51
    /// itself). The terminal set and cost are taken about the sub-goal nearest `r_N`
    /// ([`LinearMpc::step`]); the other constraints stay those of the goal.
    pub fn set_reference(&mut self, reference: Option<&[[f64; 4]]>) {
        self.on_route = reference.is_some();
        if let Some(reference) = reference {
            self.route_reference
                .copy_from_slice(&reference[..=self.layout.horizon]);
        }
    }

    /// Drives the next steps along `route` from `position` ([`follow::reference`] at
    /// [`route_speed`]), or to the goal without one or on its last segment.
    pub fn follow(&mut self, route: Option<&protocol::Route>, position: [f64; 2]) {
        self.on_route = route.is_some_and(|r| {
            follow::reference(
                r,
                position,
                &self.route_speed,
                self.ts_s,
                &mut self.route_reference,
            )
        });
    }

    /// Sets the step's sub-goal from `z0` (goal-relative): the one nearest the route's
    /// reference at stage `N`, or the goal ([`crate::terminal_set::sub_goal`]).
    fn choose_sub_goal(&mut self, z0: [f64; 4]) {
        let target = if self.on_route {
            let r = goal_relative(self.route_reference[self.layout.horizon], self.goal);
            [r[0], r[2]]
        } else {
            [0.0; 2]
        };
        self.sub_goal =
            crate::terminal_set::sub_goal(&self.statics.terminal_set, &self.statics.k, z0, target);
    }

    /// The cost's linear term: `-2 Q r_i` on stages `1..N` and `-2 Q_bar r_N`, the `r_i`
    /// the route's reference (its last moved to the sub-goal) or, off a route, the
    /// sub-goal at rest; nothing for the goal itself (eq. 51 as the paper has it).
    fn write_reference_cost(&mut self) {
        self.reference_cost.clear();
        let s = self.sub_goal;
        if !self.on_route && s == [0.0; 2] {
            return;
        }
        let (l, goal) = (&self.layout, self.goal);
        let stage = |i: usize| match self.on_route {
            true => goal_relative(self.route_reference[i], goal),
            false => [s[0], 0.0, s[1], 0.0],
        };
        let cost = &mut self.reference_cost;
        for i in 1..l.horizon {
            for (c, (q, r)) in self.q_diag.iter().zip(stage(i)).enumerate() {
                cost.push((l.z(i, c), -2.0 * q * r));
            }
        }
        let mut r = stage(l.horizon);
        [r[0], r[2]] = s;
        for c in 0..4 {
            let weighted: f64 = (0..4).map(|k| self.terminal_weight[(c, k)] * r[k]).sum();
            cost.push((l.z(l.horizon, c), -2.0 * weighted));
        }
        self.writes_linear_term = true;
    }

    /// Takes the tracker's newest tracks: the next steps keep clear of the discs they
    /// predict ([`crate::discs::World::set_tracks`]).
    pub fn set_tracks(&mut self, tracks: &Tracks) {
        self.world.set_tracks(tracks);
    }

    /// plan(k) from the estimate `x_bar = [x, y, theta, zeta]` and the standard deviation
    /// `position_sigma_m` of its position. The header is left for the caller to fill.
    pub fn step(&mut self, sample: u64, x_bar: [f64; 4], position_sigma_m: f64) -> Plan {
        self.last_estimate = Some((x_bar, position_sigma_m));
        let z = protocol::phi(x_bar);
        let z0 = goal_relative(z, self.goal);
        let growth = crate::discs::StepGrowth {
            goal: self.goal,
            margin_m: self.margin_m(position_sigma_m),
            speed_m_s: x_bar[3],
            ts_s: self.ts_s,
            accel_max: std::f64::consts::SQRT_2 * self.statics.v_max,
            uncertainty_sigmas: self.growth.uncertainty_sigmas,
        };
        let t_s = sample as f64 * self.ts_s;
        self.stand_s = self.world.stand_for_s(t_s);
        self.prediction = Prediction::Bounded;
        self.world.discs(
            growth,
            t_s,
            self.prediction,
            [z0[0], z0[2]],
            &mut self.discs,
        );

        let warm = self.shifted_reference(sample);
        if !warm {
            self.braking_reference(z0);
        }
        self.choose_sub_goal(z0);
        self.write_reference_cost();
        self.box_and_terminal_needed = !self.statics.box_and_terminal_implied(z0, self.sub_goal);
        self.reach.set_initial_state(z0);
        let mut outcome = self.refine(z0, self.relaxes(false));
        if outcome.status != PlanStatus::Solved && self.retries_cold(warm) {
            self.braking_reference(z0);
            outcome = outcome.then(self.refine(z0, self.relaxes(true)));
        }

        if outcome.status != PlanStatus::Solved
            && self.world.has_tracks()
            && !self.cancel.cancelled()
        {
            // No plan keeps clear of the obstacles moving as fast as they may: one that
            // keeps clear of them moving as they do is offered instead. The DFL's check
            // judges it against the bounded predictions, and flies it only when every
            // other choice (the brake, the robot at rest) would touch too: a person
            // coming at the robot, say (docs/safety.md, "Moving obstacles").
            self.prediction = Prediction::ConstantVelocity;
            self.world.discs(
                growth,
                t_s,
                self.prediction,
                [z0[0], z0[2]],
                &mut self.discs,
            );
            self.braking_reference(z0);
            outcome = outcome.then(self.refine(z0, self.relaxes(false)));
        }

        if outcome.status != PlanStatus::Solved
            && self.drops_rest_lookahead()
            && !self.cancel.cancelled()
        {
            // The last resort: the last program again without the margin of the rest
            // lookahead, for passive safety alone.
            self.rest_lookahead = false;
            self.braking_reference(z0);
            outcome = outcome.then(self.refine(z0, self.relaxes(false)));
            self.rest_lookahead = true;
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
        let solved = outcome.status == PlanStatus::Solved;
        if solved {
            self.write_solution(&mut plan);
        }
        self.last_sample = solved.then_some(sample);
        self.last_escaped = solved && self.prediction == Prediction::ConstantVelocity;
        plan
    }

    /// Whether a warm program (`warm`) that failed is tried again cold: the shifted plan
    /// may no longer be a usable linearization point. Not after an escape plan
    /// (`last_escaped`), nor among other robots ([`World::has_peers`]), whatever else is
    /// tracked, a person, a phantom or a lidar's track (since 2026-12-05, ee09c77; before,
    /// only when every track was another robot's): counted with a print
    /// (not kept, 2026-12-04, d540fda's tree), the cold retry found a plan 2 times of
    /// 1,685 in `scmpc fuzz --robots 2..6 --count 60 --seed 5` (and 3 of 30 among people,
    /// `scmpc fuzz --count 200 --seed 11`, where it is kept); the escape plan after it is
    /// what the robot flies, and the retry's solve was a fifth of the costliest steps
    /// among robots (docs/performance.md, "A fleet"). A warm-up cut short tries nothing
    /// more (`CancelSlot`).
    ///
    /// [`World::has_peers`]: crate::discs::World::has_peers
    fn retries_cold(&self, warm: bool) -> bool {
        warm && !self.last_escaped && !self.world.has_peers() && !self.cancel.cancelled()
    }

    /// Whether a program that fails is tried again relaxed ([`LinearMpc::solve_once`]):
    /// not the bounded program after an escape plan (`last_escaped`), nor the cold retry
    /// (`cold_retry`) in a world with tracks. Counted with a print (not kept, 2026-12-04):
    /// of the relaxed cold retries among tracks, 0 of 42 found a plan in `scmpc fuzz
    /// --count 300 --seed 11` (people) and 0 of 2835 in `scmpc fuzz --robots 2..6 --count
    /// 100 --seed 5`, each after the unrelaxed retry had taken 11-14 interior-point
    /// iterations to fail, and the relaxed one 15-19 more; the relaxed warm program found
    /// 9 of 56 and 86 of 2925, and is kept.
    fn relaxes(&self, cold_retry: bool) -> bool {
        let bounded_after_escape = self.last_escaped && self.prediction == Prediction::Bounded;
        let cold_among_tracks = cold_retry && self.world.has_tracks();
        !(bounded_after_escape || cold_among_tracks)
    }

    /// Solves, re-linearizes at the solution, and repeats until the plan settles; a failed
    /// program is tried again relaxed if `relaxes`.
    /// On a failed refinement the last solved iterate (feasible for the paper's
    /// constraint) is kept in `solution`.
    fn refine(&mut self, z0: [f64; 4], relaxes: bool) -> Outcome {
        let mut outcome = Outcome {
            status: PlanStatus::NumericalError,
            iterations: 0,
            solves: 0,
        };
        for _ in 0..self.max_solves {
            let (status, iterations, solves) = self.solve_once(z0, relaxes);
            outcome.iterations += iterations;
            outcome.solves += solves;
            if status != PlanStatus::Solved {
                if outcome.status != PlanStatus::Solved {
                    outcome.status = status;
                }
                break;
            }
            outcome.status = PlanStatus::Solved;
            // `solve_once` left the solution in `iterate`.
            self.solution.copy_from_slice(&self.iterate);
            if self.relinearize() < self.refinement_tol_m {
                break;
            }
        }
        outcome
    }

    /// Copies the last solve's solution into `iterate` (stage-wise); false without one.
    fn load_iterate(&mut self) -> bool {
        let Some(x) = self.solvers[self.rows.index()].x() else {
            return false;
        };
        // The states and inputs (sparse) or the inputs (condensed) come first; the decay
        // slacks and the terminal rows' variables after them are not kept.
        match &self.assembly.condensing {
            Some(condensing) => condensing.expand(&x[..2 * self.layout.horizon], &mut self.iterate),
            None => {
                let stagewise = self.iterate.len();
                self.iterate.copy_from_slice(&x[..stagewise]);
            }
        }
        true
    }

    /// Copies the last solve's solution into `solution` (stage-wise).
    #[cfg(test)]
    fn load_solution(&mut self) {
        if self.load_iterate() {
            self.solution.copy_from_slice(&self.iterate);
        }
    }

    /// One convex solve at the current reference, without the rows the input box
    /// implies; with terminal safety, if that fails and `relaxes`, a second of the
    /// relaxed program.
    /// Returns the status, the interior-point iterations and the solves.
    ///
    /// Discs are deferred exactly (constraint generation): a disc whose rows hold for every
    /// input sequence within [`DEFERRAL_SHARE`] of the input box about the reference's is
    /// left out of the program; when the solution misses a row of a deferred disc, that
    /// disc joins the program and it is solved again. The program without a disc is a
    /// relaxation of the one with it, so a solution that meets every deferred disc's rows
    /// is the optimum of the program with every disc: the same plan, to the solver's
    /// tolerance, from a smaller program. (The check is [`Barrier::implied`] at the
    /// solution, where only the terminal rows are bounded rather than evaluated: with the
    /// solution's `|w_N|` for the approach speed too, which errs towards taking a disc in.)
    /// The same holds for a disc's two groups of rows: a disc whose CBF rows are implied or
    /// deferrable but whose terminal rows are not joins with its terminal rows only
    /// ([`Rows::terminal_only`]), and whole if the solution misses a CBF row of it, or if
    /// the program fails (the whole disc's decay may need relaxing).
    ///
    /// A program whose terminal rows no input sequence meets is infeasible without a solve
    /// ([`Barrier::terminal_impossible`]), relaxed or not.
    ///
    /// A solved program leaves its solution in `iterate`.
    ///
    /// [`Barrier::terminal_impossible`]: crate::program::Barrier::terminal_impossible
    /// [`Barrier::implied`]: crate::program::Barrier::implied
    fn solve_once(&mut self, z0: [f64; 4], relaxes: bool) -> (PlanStatus, u32, u32) {
        self.kept.clear();
        self.kept_whole = 0;
        self.deferred.clear();
        let p0 = [z0[0], z0[2]];
        let reference = &self.reference;
        self.plan_reach.set_plan(
            |i| if i == 0 { p0 } else { reference[i] },
            self.reference_velocity,
            self.deferral_share,
        );
        let most_terminal_only = Rows::max_terminal_only(&self.layout);
        for j in 0..self.discs.len() {
            let disc = self.discs[j];
            let barrier = self.step_data(z0, std::slice::from_ref(&disc)).barrier(
                &self.layout,
                &self.statics,
                Rows::ONE_DISC,
            );
            if self.proves_infeasible && barrier.terminal_impossible(&self.reach) {
                return (PlanStatus::Infeasible, 0, 0);
            }
            let cbf_implied = barrier.cbf_implied(&self.reach);
            let terminal_implied = barrier.terminal_implied(&self.reach);
            if cbf_implied && terminal_implied {
                continue;
            }
            let defers = self.defers_discs;
            let cbf_met = cbf_implied || (defers && barrier.cbf_implied(&self.plan_reach));
            let terminal_met =
                terminal_implied || (defers && barrier.terminal_implied(&self.plan_reach));
            if cbf_met && terminal_met {
                self.deferred.push(disc);
            } else if cbf_met && self.kept.len() - self.kept_whole < most_terminal_only {
                self.kept.push(disc);
            } else {
                self.keep_whole(disc);
            }
        }
        let (mut iterations, mut solves) = (0, 0);
        let mut relaxed = false;
        loop {
            let rows = Rows {
                box_and_terminal: self.box_and_terminal_needed,
                discs: self.kept_whole,
                terminal_only: self.kept.len() - self.kept_whole,
                relaxed,
            };
            let (status, more) = self.solve_with(z0, rows);
            (iterations, solves) = (iterations + more, solves + 1);
            if status != PlanStatus::Solved {
                if relaxed
                    || !relaxes
                    || self.layout.decay_slacks(rows.terminal_discs()) == 0
                    || self.cancel.cancelled()
                {
                    return (status, iterations, solves);
                }
                // Infeasible (or stalled): braking may need the decay relaxed (module docs
                // of `terminal`), of every disc the program holds.
                self.kept_whole = self.kept.len();
                relaxed = true;
            } else if !self.admit_missed_rows(z0) {
                return (status, iterations, solves);
            }
        }
    }

    /// Whether a step whose every program failed has a margin left to drop: the rest
    /// lookahead (`mpc.rest_lookahead_s`, docs/safety.md "The stop and the person's way")
    /// when another robot moves ([`World::peers_move`]). Without it the terminal rows ask
    /// for passive safety alone, which the DFL's check asks too; so a robot squeezed
    /// between others coming towards it (`swap8`) gets a plan that stops before they could
    /// reach it rather than fly its shifted plan. Not for a robot alone among people: one
    /// offered such a plan flies it as the least unsafe choice where it would have stepped
    /// out of the person's way (`dfl.evasion`), and at rest in their way is walked into
    /// (docs/fleet.md, "The rest lookahead as a last resort"). Among other robots nothing
    /// else tracked (a person, a phantom or a lidar's track) keeps it from the last resort
    /// (since 2026-12-05, ee09c77): a person did before, and there were a third more
    /// walk-ins, 193 against 145 (docs/fleet.md, "A person among robots").
    ///
    /// [`World::peers_move`]: crate::discs::World::peers_move
    fn drops_rest_lookahead(&self) -> bool {
        let lookahead = self
            .layout
            .terminal
            .map_or(0.0, |brake| brake.rest_lookahead_s);
        lookahead > 0.0 && self.world.peers_move()
    }

    /// Puts `disc` in the program with all its rows: into `kept` after the whole discs
    /// before it (so before those with their terminal rows only).
    fn keep_whole(&mut self, disc: Disc) {
        self.kept.push(disc);
        let last = self.kept.len() - 1;
        self.kept.swap(self.kept_whole, last);
        self.kept_whole += 1;
    }

    /// Moves every deferred disc whose rows the last solution misses into `kept`, and
    /// makes whole every disc in it with its terminal rows only whose CBF rows the
    /// solution misses; true if there was one. The solution is in `iterate` after it.
    fn admit_missed_rows(&mut self, z0: [f64; 4]) -> bool {
        if !self.load_iterate() || (self.deferred.is_empty() && self.kept_whole == self.kept.len())
        {
            return false;
        }
        let (l, x) = (&self.layout, &self.iterate);
        let n = l.horizon;
        let w_n = [x[l.z(n, 1)], x[l.z(n, 3)]];
        self.plan_reach
            .set_plan(|i| [x[l.z(i, 0)], x[l.z(i, 2)]], w_n, 0.0);
        let mut admitted = false;
        for j in self.kept_whole..self.kept.len() {
            let met = self
                .step_data(z0, std::slice::from_ref(&self.kept[j]))
                .barrier(&self.layout, &self.statics, Rows::ONE_DISC)
                .cbf_implied(&self.plan_reach);
            if !met {
                // The disc swapped to `j` comes from before it: checked already.
                self.kept.swap(self.kept_whole, j);
                self.kept_whole += 1;
                admitted = true;
            }
        }
        let most_terminal_only = Rows::max_terminal_only(&self.layout);
        let mut j = 0;
        while j < self.deferred.len() {
            let disc = self.deferred[j];
            let barrier = self.step_data(z0, std::slice::from_ref(&disc)).barrier(
                &self.layout,
                &self.statics,
                Rows::ONE_DISC,
            );
            let cbf_met = barrier.cbf_implied(&self.plan_reach);
            if cbf_met && barrier.terminal_implied(&self.plan_reach) {
                j += 1;
                continue;
            }
            self.deferred.swap_remove(j);
            let terminal_only = self.kept.len() - self.kept_whole;
            if cbf_met && !self.rows.relaxed && terminal_only < most_terminal_only {
                self.kept.push(disc);
            } else {
                self.keep_whole(disc);
            }
            admitted = true;
        }
        admitted
    }

    /// The step's data for the program on `discs`.
    fn step_data<'a>(&'a self, z0: [f64; 4], discs: &'a [Disc]) -> StepData<'a> {
        StepData {
            z0,
            sub_goal: self.sub_goal,
            discs,
            reference: &self.reference,
            reference_velocity: self.reference_velocity,
            max_terminal_speed: self.reach.max_terminal_speed(),
            stand_s: self.stand_s,
            prediction: self.prediction,
            stage_s: self.ts_s,
            rest_lookahead: self.rest_lookahead,
        }
    }

    /// One convex solve of the program with `rows`, on the discs in `kept`.
    fn solve_with(&mut self, z0: [f64; 4], rows: Rows) -> (PlanStatus, u32) {
        self.rows = rows;
        self.fill(z0, rows);
        self.solvers[rows.index()].solve(&self.assembly)
    }

    fn fill(&mut self, z0: [f64; 4], rows: Rows) {
        let data = StepData {
            z0,
            sub_goal: self.sub_goal,
            discs: &self.kept,
            reference: &self.reference,
            reference_velocity: self.reference_velocity,
            max_terminal_speed: self.reach.max_terminal_speed(),
            stand_s: self.stand_s,
            prediction: self.prediction,
            stage_s: self.ts_s,
            rest_lookahead: self.rest_lookahead,
        };
        program::fill(&mut self.assembly, &self.layout, &self.statics, &data, rows);
        if self.writes_linear_term {
            self.assembly
                .add_linear_cost(&self.layout, &self.reference_cost);
        }
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

/// `z = [x, xdot, y, ydot]` (absolute) relative to `goal`.
fn goal_relative(z: [f64; 4], goal: [f64; 2]) -> [f64; 4] {
    [z[0] - goal[0], z[1], z[2] - goal[1], z[3]]
}

mod reference;
#[cfg(test)]
mod tests;
