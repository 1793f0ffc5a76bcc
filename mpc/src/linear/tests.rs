//! Tests of the linear MPC on its own model.
use super::*;
use crate::discs::barrier_slack;
use crate::model::terminal_weight;
use crate::terminal_set::SetRow;
use nalgebra::Vector4;
use protocol::{Obstacle, QpForm, TerminalSafety};
use std::rc::Rc;

mod implied_rows;
mod moving;
mod recursive_feasibility;

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
        let plan = mpc.step(k, protocol::phi_inverse(z.into(), theta), 0.0);
        assert!(plan.is_solved(), "sample {k}: {:?}", plan.status());
        z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
        after_step(&mut mpc, &plan);
    }
}

fn absolute_discs(s: &Scenario) -> Vec<Disc> {
    s.obstacles
        .iter()
        .map(|o| Disc::still([o.x, o.y], o.radius))
        .collect()
}

#[test]
fn every_solved_plan_satisfies_the_papers_nonconvex_cbf_at_every_stage() {
    // With terminal safety too: these runs never need the decay relaxed.
    for (gamma, terminal_safety) in [0.1, 0.5, 0.9]
        .into_iter()
        .flat_map(|g| [(g, TerminalSafety::None), (g, TerminalSafety::Brake)])
    {
        let mut s = Scenario::default();
        s.mpc.gamma = gamma;
        s.mpc.terminal_safety = terminal_safety;
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
    euclidean.mpc.constraint = protocol::ConstraintKind::Euclidean;
    euclidean.mpc.gamma = 0.3; // ignored by the Euclidean constraint
    let (a, b) = (
        LinearMpc::new(&cbf).unwrap(),
        LinearMpc::new(&euclidean).unwrap(),
    );
    assert_eq!(
        a.layout.cones(Rows::all(&a.layout)).len(),
        b.layout.cones(Rows::all(&b.layout)).len()
    );
    let discs = [Disc::still([3.0, 3.5], 1.5)];
    let reference: Vec<[f64; 2]> = (0..=8)
        .map(|i| [6.0 - 0.1 * i as f64, 6.0 - 0.12 * i as f64])
        .collect();
    let data = StepData {
        z0: [7.0, -0.5, 7.0, -0.5],
        sub_goal: [0.0; 2],
        discs: &discs,
        reference: &reference,
        reference_velocity: [0.0; 2],
        max_terminal_speed: 0.0,
        stand_s: 0.0,
        prediction: crate::discs::Prediction::Bounded,
        stage_s: 0.05,
        rest_lookahead: true,
    };
    let (mut fa, mut fb) = (Assembly::default(), Assembly::default());
    program::fill(&mut fa, &a.layout, &a.statics, &data, Rows::all(&a.layout));
    program::fill(&mut fb, &b.layout, &b.statics, &data, Rows::all(&b.layout));
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
    let full = crate::terminal_set::terminal_set(
        &k,
        &(a + b * k),
        c.constraint_horizon,
        c.v_max,
        [[-10.0, 10.0]; 2],
    );
    let pruned = crate::terminal_set::prune_redundant(full.clone());
    assert_eq!((full.len(), pruned.len()), (88, 88));
    let inside =
        |rows: &[SetRow], z: [f64; 4]| rows.iter().all(|r| r.value(z) <= r.bound.at_goal + 1e-9);
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
    for (gamma, terminal_safety) in [(0.1, "none"), (1.0, "none"), (0.1, "brake"), (1.0, "brake")] {
        let sparse = Scenario::default()
            .with_overrides(&[
                format!("mpc.gamma={gamma}"),
                format!("mpc.terminal_safety={terminal_safety}"),
                "mpc.qp_form=sparse".into(),
            ])
            .unwrap();
        let condensed = sparse
            .with_overrides(&["mpc.qp_form=condensed".into()])
            .unwrap();
        let mut other = LinearMpc::new(&condensed).unwrap();
        let mut compared = 0;
        // On the sparse closed loop's states, both programs solved on the same data:
        // the same reference, discs and rows.
        closed_loop_with(&sparse, 200, |mpc, plan| {
            let z = plan.z[0];
            let z0 = [
                z[0] - sparse.robot.goal.position[0],
                z[1],
                z[2] - sparse.robot.goal.position[1],
                z[3],
            ];
            other.discs.clone_from(&mpc.discs);
            other.reference.clone_from(&mpc.reference);
            other.reference_velocity = mpc.reference_velocity;
            other.box_and_terminal_needed = mpc.box_and_terminal_needed;
            other.reach.set_initial_state(z0);
            for m in [&mut *mpc, &mut other] {
                assert_eq!(m.solve_once(z0, true).0, PlanStatus::Solved);
                m.load_solution();
            }
            assert_eq!(mpc.rows, other.rows);
            let l = &mpc.layout;
            let gap = (0..=l.horizon)
                .flat_map(|i| (0..4).map(move |c| l.z(i, c)))
                .map(|k| (mpc.solution[k] - other.solution[k]).abs())
                .fold(0.0, f64::max);
            // Both solved to clarabel's accuracy (duality gap 1e-3, feasibility 1e-6).
            assert!(
                gap < 1e-3,
                "gamma {gamma}, {terminal_safety}, sample {}: {gap:e}",
                plan.sample
            );
            compared += 1;
        });
        assert_eq!(compared, 200);
    }
}

#[test]
fn a_reference_draws_the_plan_to_it_in_both_programs_and_none_gives_the_goals_plan_back() {
    let s = Scenario::default()
        .with_overrides(&["planner.kind=route".into(), "obstacles=[]".into()])
        .unwrap();
    let x_bar = [7.0, 7.0, -2.356, 0.5];
    let reference = [7.0, 0.0];
    let at_rest = vec![[reference[0], 0.0, reference[1], 0.0]; s.mpc.horizon + 1];
    let end = |p: &Plan| [p.z[p.horizon as usize][0], p.z[p.horizon as usize][2]];
    // How well the first input points from the robot to `target` (cosine).
    let aims_at = |p: &Plan, target: [f64; 2]| {
        let (dx, dy) = (target[0] - x_bar[0], target[1] - x_bar[1]);
        (p.v[0][0] * dx + p.v[0][1] * dy) / (p.v[0][0].hypot(p.v[0][1]) * dx.hypot(dy))
    };
    let mut ends = Vec::new();
    for form in ["sparse", "condensed"] {
        let s = s.with_overrides(&[format!("mpc.qp_form={form}")]).unwrap();
        let mut mpc = LinearMpc::new(&s).unwrap();
        let goal_plan = mpc.step(0, x_bar, 0.0);
        let to_goal = end(&goal_plan);
        mpc.reset();
        mpc.set_reference(Some(&at_rest));
        let reference_plan = mpc.step(0, x_bar, 0.0);
        let to_reference = end(&reference_plan);
        let from = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
        assert!(from(to_reference, reference) < from(to_goal, reference));
        assert!(
            aims_at(&reference_plan, reference) > 0.9 && aims_at(&goal_plan, reference) < 0.8,
            "{form}: {:?} vs {:?}",
            reference_plan.v[0],
            goal_plan.v[0]
        );
        // Back to the goal: the same plan as before any reference (the linear term
        // is zeroed, not left at the reference's).
        mpc.reset();
        mpc.set_reference(None);
        let again = end(&mpc.step(0, x_bar, 0.0));
        assert!(
            from(again, to_goal) < 1e-9,
            "{form}: {again:?} vs {to_goal:?}"
        );
        ends.push(to_reference);
    }
    let gap = (ends[0][0] - ends[1][0]).hypot(ends[0][1] - ends[1][1]);
    assert!(gap < 1e-3, "sparse and condensed differ by {gap}");
}

#[test]
fn from_inside_a_constraint_disc_the_plan_leaves_it_no_slower_than_the_decay_allows() {
    // With a safety margin of 0.3 m (and the check's 2 mm), 1 cm inside the constraint
    // disc (H(p_0) < 0), at rest. The CBF asks the plan to leave as the decay does,
    // H(p_i) >= (1 - gamma)^i H(p_0), and the terminal rows no more than that. (From
    // deeper in, the paper's CBF alone asks more than the input box gives.)
    let s = Scenario::default()
        .with_overrides(&[
            "mpc.safety_margin_m=0.3".into(),
            "robot.start=[3.0, 5.292, 0.0]".into(),
        ])
        .unwrap();
    s.validate("test").unwrap();
    let mut mpc = LinearMpc::new(&s).unwrap();
    let plan = mpc.step(0, [3.0, 5.292, 0.0, 0.0], 0.0);
    assert!(plan.is_solved(), "{:?}", plan.status());
    let disc = mpc.constraint_discs()[0];
    let goal = s.robot.goal.position;
    let h = |z: [f64; 4]| disc.barrier([z[0] - goal[0], z[2] - goal[1]]);
    let h0 = h(plan.z[0]);
    assert!(h0 < 0.0, "the start should be inside the constraint disc");
    for i in 1..=plan.horizon as usize {
        let floor = (1.0 - s.mpc.gamma).powi(i as i32) * h0;
        assert!(
            h(plan.z[i]) >= floor - 1e-6,
            "stage {i}: {} < {floor}",
            h(plan.z[i])
        );
    }
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
    s.obstacles.push(Obstacle::fixed(5.5, 3.0, 0.8));
    s.obstacles.push(Obstacle::fixed(1.0, 4.5, 0.5));
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
    assert!(plan.solves >= 1);
}

/// Over closed loops at `gamma` 0.1 and 0.5 of `s`, carries the sequential
/// convexification on from where each step stopped, at the same state, to convergence
/// (plans moving less than `converged_m`, in fewer than `max_solves` solves); returns
/// the largest distance of a stopped plan's position from the converged one, m, and
/// the samples where the tolerance stopped early.
fn refinement_gap(s: &Scenario, max_solves: usize, converged_m: f64) -> (f64, usize) {
    let (mut largest, mut stopped_early): (f64, usize) = (0.0, 0);
    for gamma in [0.1, 0.5] {
        let mut s = s.clone();
        s.mpc.gamma = gamma;
        closed_loop_with(&s, 400, |mpc, plan| {
            let stopped = mpc.solution.clone();
            let z = plan.z[0];
            let z0 = [
                z[0] - s.robot.goal.position[0],
                z[1],
                z[2] - s.robot.goal.position[1],
                z[3],
            ];
            (mpc.max_solves, mpc.refinement_tol_m) = (max_solves, converged_m);
            let converged = mpc.refine(z0, true);
            assert!(
                converged.status == PlanStatus::Solved && (converged.solves as usize) < max_solves,
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
            largest = largest.max(gap);
            if plan.solves == 1 && gap > 1e-5 {
                stopped_early += 1;
            }
        });
    }
    (largest, stopped_early)
}

#[test]
fn the_default_refinement_tolerance_stops_within_half_a_millimetre_of_convergence() {
    let mut s = Scenario::default();
    s.mpc.terminal_safety = TerminalSafety::None;
    let (gap, stopped_early) = refinement_gap(&s, 10, 1e-7);
    assert!(gap < 5e-4, "{gap:e} m from the converged plan");
    // Along the obstacle the first solve moves the plan by millimetres to
    // centimetres: those are the refinements the tolerance skips.
    assert!(stopped_early > 20, "{stopped_early}");
}

#[test]
fn with_terminal_safety_the_default_tolerance_stops_within_4_mm_of_convergence() {
    // The terminal rows' majorant is exact only at the reference's velocity, so the
    // first solve from the shifted plan's braking extension ends farther from
    // convergence than the CBF's `d^2` alone would put it (3.0 mm measured), and the
    // refinement converges more slowly (up to 26 solves to 10 µm, along the obstacle
    // at gamma 0.5).
    let (gap, stopped_early) = refinement_gap(&Scenario::default(), 40, 1e-5);
    assert!(gap < 4e-3, "{gap:e} m from the converged plan");
    assert!(stopped_early > 20, "{stopped_early}");
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

/// A deterministic sequence in (0, 1).
fn logistic(mut x: f64) -> impl FnMut() -> f64 {
    move || {
        x = (x * 3.9 * (1.0 - x)).clamp(1e-6, 1.0 - 1e-6);
        x
    }
}

#[test]
fn a_sub_goal_moves_the_terminal_set_bounds_and_nothing_else_in_the_program() {
    // The safety rows (CBF, braking-safe terminal rows), the dynamics, the input box and
    // the position box do not depend on the sub-goal: only the terminal set's bounds do.
    let s = Scenario::default()
        .with_overrides(&["mpc.qp_form=sparse".into()])
        .unwrap();
    let mut mpc = LinearMpc::new(&s).unwrap();
    mpc.step(0, [7.0, 7.0, -2.356, 0.5], 0.0);
    let data = |sub_goal| StepData {
        z0: [7.0, -0.4, 7.0, -0.3],
        sub_goal,
        discs: &mpc.discs,
        reference: &mpc.reference,
        reference_velocity: mpc.reference_velocity,
        max_terminal_speed: mpc.reach.max_terminal_speed(),
        stand_s: 0.0,
        prediction: crate::discs::Prediction::Bounded,
        stage_s: 0.05,
        rest_lookahead: true,
    };
    let rows = Rows::all(&mpc.layout);
    let (mut at_goal, mut at_sub) = (Assembly::default(), Assembly::default());
    program::fill(
        &mut at_goal,
        &mpc.layout,
        &mpc.statics,
        &data([0.0; 2]),
        rows,
    );
    program::fill(
        &mut at_sub,
        &mpc.layout,
        &mpc.statics,
        &data([4.0, 3.0]),
        rows,
    );
    assert_eq!(at_goal.entries, at_sub.entries);
    let l = &mpc.layout;
    let first = 4 + 4 * l.horizon + 4 * l.horizon + 4 * (l.horizon - 1);
    let terminal_set = first..first + l.terminal_rows;
    let moved: Vec<usize> = (0..at_goal.b.len())
        .filter(|&r| at_goal.b[r] != at_sub.b[r])
        .collect();
    assert!(!moved.is_empty());
    assert!(
        moved.iter().all(|r| terminal_set.contains(r)),
        "{moved:?} outside {terminal_set:?}"
    );
}

#[test]
fn far_from_the_goal_with_a_gentle_input_box_the_first_plan_is_solved() {
    // Issue 27's reduced world: with the terminal set about the goal every solve was
    // infeasible from sample 0.
    let s = Scenario::default()
        .with_overrides(&[
            "timing.ts_s=0.02".into(),
            "mpc.gamma=0.3".into(),
            "mpc.v_max=1".into(),
            "robot.goal=[-4.0291, 7.4458]".into(),
            "obstacles=[{x = -2.6492, y = 2.2158, radius = 0.9735}, {x = -4.4048, y = 2.5833, radius = 1.4645}]".into(),
        ])
        .unwrap();
    let mut mpc = LinearMpc::new(&s).unwrap();
    let x_bar = [-3.611, -7.369, 3.3138, 0.5];
    for sample in 0..5 {
        let plan = mpc.step(sample, x_bar, 0.0);
        assert_eq!(plan.status, PlanStatus::Solved as u32, "sample {sample}");
        assert!(mpc.sub_goal != [0.0; 2], "the goal is out of reach");
    }
}

/// The largest distance between the planned positions of two plans, m.
fn plan_distance_m(a: &Plan, b: &Plan) -> f64 {
    (0..=a.horizon as usize)
        .map(|i| (a.z[i][0] - b.z[i][0]).hypot(a.z[i][2] - b.z[i][2]))
        .fold(0.0, f64::max)
}

#[test]
fn deferring_discs_away_from_the_plan_gives_the_plans_of_the_program_with_every_disc() {
    // The paper's world at N = 30 with six more obstacles scattered about its path.
    let s = Scenario::default()
        .with_overrides(&[
            "mpc.horizon=30".into(),
            "obstacles=[{x = 3.0, y = 3.5, radius = 1.5}, {x = 6.0, y = 3.5, radius = 0.4}, \
             {x = 1.5, y = 5.5, radius = 0.4}, {x = 5.5, y = 1.0, radius = 0.4}, \
             {x = 0.5, y = 3.0, radius = 0.3}, {x = 2.0, y = 0.8, radius = 0.3}, \
             {x = 8.0, y = 4.5, radius = 0.4}]"
                .into(),
        ])
        .unwrap();
    let mut deferring = LinearMpc::new(&s).unwrap();
    let mut every = LinearMpc::new(&s).unwrap();
    every.defers_discs = false;
    let (a, b) = model::discretize(s.timing.ts_s);
    let [x, y, theta] = s.robot.start;
    let mut z = Vector4::from(protocol::phi([x, y, theta, s.robot.zeta0]));
    let (mut deferring_discs, mut every_discs) = (0, 0);
    let (mut first_apart, mut apart): (f64, f64) = (0.0, 0.0);
    for k in 0..200 {
        let x_bar = protocol::phi_inverse(z.into(), theta);
        let plan = deferring.step(k, x_bar, 0.0);
        let reference = every.step(k, x_bar, 0.0);
        assert!(plan.is_solved(), "sample {k}: {:?}", plan.status());
        deferring_discs += deferring.rows.terminal_discs();
        every_discs += every.rows.terminal_discs();
        let [p, r] = [plan.z[1], reference.z[1]];
        first_apart = first_apart.max((p[0] - r[0]).hypot(p[2] - r[2]));
        apart = apart.max(plan_distance_m(&plan, &reference));
        z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
    }
    // The same optimum to the solver's tolerance: a duality gap of 1e-3 leaves the
    // inputs within millimetres per s^2 of it, so 30 stages on within a few millimetres.
    assert!(
        first_apart < 1e-4,
        "the next positions {first_apart} m apart"
    );
    assert!(apart < 5e-3, "plans {apart} m apart");
    assert!(
        3 * deferring_discs < every_discs,
        "discs in the programs: {deferring_discs} deferring, {every_discs} with every disc"
    );
}

/// A robot at rest at `(-3, 0)` heading for the origin at N = 30, a disc of radius 0.3 m
/// at `(disc_x_m, 0.05)`: the scenario and the estimate `x_bar`.
fn at_rest_before_a_disc(disc_x_m: f64) -> (Scenario, [f64; 4]) {
    let s = Scenario::default()
        .with_overrides(&[
            "mpc.horizon=30".into(),
            "robot.start=[-3.0, 0.0, 0.0]".into(),
            "robot.goal=[0.0, 0.0]".into(),
            format!("obstacles=[{{x = {disc_x_m}, y = 0.05, radius = 0.3}}]"),
        ])
        .unwrap();
    (s, [-3.0, 0.0, 0.0, 0.0])
}

#[test]
fn a_deferred_disc_the_solution_runs_into_joins_the_program() {
    // At rest, the cold reference stays at the start; with no spread about it every disc
    // off the start is deferred, and the plan towards the goal would run through this one.
    let (s, x_bar) = at_rest_before_a_disc(-1.8);
    let mut deferring = LinearMpc::new(&s).unwrap();
    deferring.deferral_share = 0.0;
    let plan = deferring.step(0, x_bar, 0.0);
    assert!(plan.is_solved(), "{:?}", plan.status());
    let slack = barrier_slack(&plan, &absolute_discs(&s), s.mpc.gamma);
    assert!(slack >= -1e-6, "CBF slack {slack:e}");
    let mut every = LinearMpc::new(&s).unwrap();
    every.defers_discs = false;
    let reference = every.step(0, x_bar, 0.0);
    // One more solve: the first, without the disc, ran into it.
    assert_eq!(plan.solves, reference.solves + 1);
    let apart = plan_distance_m(&plan, &reference);
    assert!(apart < 5e-4, "plans {apart} m apart");
}

#[test]
fn a_disc_kept_for_its_terminal_rows_whose_cbf_rows_the_solution_misses_becomes_whole() {
    // A disc just ahead of a robot at rest: its terminal rows alone keep the plan out of
    // it, but not at the CBF's decay rate (eq. 54).
    let (s, x_bar) = at_rest_before_a_disc(-2.4);
    let mut mpc = LinearMpc::new(&s).unwrap();
    assert!(mpc.step(0, x_bar, 0.0).is_solved());
    let z0 = goal_relative(protocol::phi(x_bar), mpc.goal);
    let discs = absolute_discs(&s);
    let solve = |mpc: &mut LinearMpc, rows: Rows| {
        assert_eq!(mpc.solve_with(z0, rows).0, PlanStatus::Solved, "{rows:?}");
        mpc.load_solution();
        let mut plan = Plan {
            horizon: s.mpc.horizon as u32,
            ..Plan::default()
        };
        mpc.write_solution(&mut plan);
        barrier_slack(&plan, &discs, s.mpc.gamma)
    };
    mpc.kept = mpc.discs.clone();
    mpc.kept_whole = 0;
    mpc.deferred.clear();
    let terminal_only = Rows {
        box_and_terminal: mpc.box_and_terminal_needed,
        discs: 0,
        terminal_only: 1,
        relaxed: false,
    };
    let missed = solve(&mut mpc, terminal_only);
    assert!(
        missed < -1e-3,
        "CBF slack {missed:e}: the solution keeps the CBF"
    );
    assert!(mpc.admit_missed_rows(z0));
    assert_eq!((mpc.kept.len(), mpc.kept_whole), (1, 1));
    let whole = Rows {
        discs: 1,
        terminal_only: 0,
        ..terminal_only
    };
    let met = solve(&mut mpc, whole);
    assert!(met >= -1e-6, "CBF slack {met:e}");
    assert!(!mpc.admit_missed_rows(z0));
}

#[test]
fn a_warm_up_before_every_step_changes_no_plan_even_cut_short() {
    // The robot drifts off every plan (as a real one does), so each warm-up's dry step,
    // from the state its last plan predicts, solves another program than the real step;
    // a field of discs and the sparse program too, so discs join, leave and are deferred.
    let field = "obstacles=[{x = 3.0, y = 3.5, radius = 1.5}, {x = 6.0, y = 3.5, radius = 0.4}, \
                 {x = 1.5, y = 5.5, radius = 0.4}, {x = 5.5, y = 1.0, radius = 0.4}]";
    let never: Cancel = Rc::new(|| false);
    let at_once: Cancel = Rc::new(|| true);
    let polls_left = Rc::new(std::cell::Cell::new(0_u64));
    let after_polls: Cancel = {
        let polls_left = polls_left.clone();
        Rc::new(move || {
            let left = polls_left.get();
            polls_left.set(left.saturating_sub(1));
            left == 0
        })
    };
    for overrides in [vec![], vec![field.into(), "mpc.qp_form=\"sparse\"".into()]] {
        let s = Scenario::default().with_overrides(&overrides).unwrap();
        let mut warming = LinearMpc::new(&s).unwrap();
        let mut plain = LinearMpc::new(&s).unwrap();
        let (a, b) = model::discretize(s.timing.ts_s);
        let [x, y, theta] = s.robot.start;
        let mut z = Vector4::from(protocol::phi([x, y, theta, s.robot.zeta0]));
        let mut drift = logistic(0.3);
        for k in 0..200 {
            let x_bar = protocol::phi_inverse(z.into(), theta);
            // Warm-ups that run to the end, that are cancelled before they begin, and
            // that are cancelled in their solves, after 2, 3, 6 or 7 polls.
            polls_left.set(k % 8);
            let cancel = match k % 4 {
                0 => &never,
                1 => &at_once,
                _ => &after_polls,
            };
            warming.warm_up(u64::MAX, cancel);
            let plan = warming.step(k, x_bar, 0.01);
            let reference = plain.step(k, x_bar, 0.01);
            assert!(
                reference.is_solved(),
                "sample {k}: {:?}",
                reference.status()
            );
            assert_eq!(
                (plan.v, plan.z, plan.status, plan.iterations, plan.solves),
                (
                    reference.v,
                    reference.z,
                    reference.status,
                    reference.iterations,
                    reference.solves
                ),
                "sample {k} of {overrides:?}"
            );
            let push = nalgebra::Vector4::new(drift() - 0.5, 0.0, drift() - 0.5, 0.0) * 0.02;
            z = a * z + b * nalgebra::Vector2::from(plan.v[0]) + push;
        }
    }
}

#[test]
fn a_cancelled_warm_up_stops_every_solve_in_it_and_none_after_it() {
    let s = Scenario::default();
    let mut mpc = LinearMpc::new(&s).unwrap();
    let [x, y, theta] = s.robot.start;
    let x_bar = [x, y, theta, s.robot.zeta0];
    assert!(mpc.step(0, x_bar, 0.0).is_solved());
    let (never, at_once): (Cancel, Cancel) = (Rc::new(|| false), Rc::new(|| true));
    // Cancelled: a solve about to start does not (the check in `ConicSolver::solve`), one
    // under way stops before its first iteration (clarabel's termination callback), and
    // the dry step tries no relaxed or cold program after its first.
    let slot = mpc.cancel.clone();
    let dry = slot.during(&at_once, || mpc.step(1, x_bar, 0.0));
    assert_eq!((dry.iterations, dry.solves, dry.is_solved()), (0, 1, false));
    let solver = &mut mpc.solvers[mpc.rows.index()];
    assert_eq!(slot.during(&at_once, || solver.solve_again()), 0);
    // Right after one that ended: nothing stops the solves.
    assert!(solver.solve_again() > 0, "outside a warm-up a solve runs");
    let plan = mpc.step(1, x_bar, 0.0);
    assert!(plan.is_solved() && plan.iterations > 0);
    let solver = &mut mpc.solvers[mpc.rows.index()];
    assert!(
        slot.during(&never, || solver.solve_again()) > 0,
        "a warm-up not cancelled solves"
    );
}
