//! Tests of the linear MPC on its own model.
use super::*;
use crate::discs::barrier_slack;
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
        let plan = mpc.step(k, protocol::phi_inverse(z.into(), theta), 0.0);
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
    euclidean.mpc.constraint = ConstraintKind::Euclidean;
    euclidean.mpc.gamma = 0.3; // ignored by the Euclidean constraint
    let (a, b) = (
        LinearMpc::new(&cbf).unwrap(),
        LinearMpc::new(&euclidean).unwrap(),
    );
    assert_eq!(
        a.layout.cones(Rows::all(&a.layout)).len(),
        b.layout.cones(Rows::all(&b.layout)).len()
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
        reference_velocity: [0.0; 2],
        max_terminal_speed: 0.0,
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
    let full = crate::terminal::terminal_set(
        &k,
        &(a + b * k),
        c.constraint_horizon,
        c.v_max,
        [[-10.0, 10.0]; 2],
    );
    let pruned = crate::terminal::prune_redundant(full.clone());
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
                z[0] - sparse.robot.goal[0],
                z[1],
                z[2] - sparse.robot.goal[1],
                z[3],
            ];
            other.discs.clone_from(&mpc.discs);
            other.reference.clone_from(&mpc.reference);
            other.reference_velocity = mpc.reference_velocity;
            other.box_and_terminal_needed = mpc.box_and_terminal_needed;
            other.reach.set_initial_state(z0);
            for m in [&mut *mpc, &mut other] {
                assert_eq!(m.solve_once(z0).0, PlanStatus::Solved);
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
            reference_velocity: mpc.reference_velocity,
            max_terminal_speed: 0.0,
        };
        let without_barrier = Rows {
            box_and_terminal: true,
            discs: 0,
            relaxed: false,
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
                reference_velocity: mpc.reference_velocity,
                max_terminal_speed: mpc.reach.max_terminal_speed(),
            };
            if !data
                .barrier(&mpc.layout, &mpc.statics, false)
                .implied(&mpc.reach)
            {
                kept += 1;
                continue;
            }
            left_out += 1;
            // Relaxed where the layout can be: its slack rows hold too, at zero.
            let only_barrier = Rows {
                box_and_terminal: false,
                discs: 1,
                relaxed: mpc.layout.decay_slacks(1) > 0,
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
///
/// With terminal safety a disc's rows also hold the decay slacks, which are zero, and
/// the terminal rows' variables, at their best values for the inputs
/// ([`terminal::TerminalRows::variables_at`]; each violation stays convex in the
/// inputs).
fn assert_holds_at_worst_inputs(mpc: &LinearMpc, data: &StepData, rows: Rows) {
    use clarabel::solver::SupportedConeT;
    let (l, st) = (&mpc.layout, &mpc.statics);
    assert!(!l.condensed, "rows are checked in stage-wise columns");
    let (forced, free) = crate::reach::rollout(l, &st.a, &st.b);
    let mut assembly = Assembly::default();
    program::fill(&mut assembly, l, st, data, rows);
    // Each row's slack as `s0 - coefficients' v - extra_terms' extras(v)`.
    let x_free = &free * Vector4::from(data.z0);
    let stagewise = l.stagewise();
    let mut s0 = assembly.b.clone();
    let mut coefficients = vec![vec![0.0; forced.ncols()]; s0.len()];
    let mut extra_terms = vec![Vec::new(); s0.len()];
    for &(r, column, value) in &assembly.entries {
        if column >= stagewise {
            extra_terms[r].push((column - stagewise, value));
            continue;
        }
        s0[r] -= value * x_free[column];
        for (j, c) in coefficients[r].iter_mut().enumerate() {
            *c += value * forced[(column, j)];
        }
    }
    let terminal = data.barrier(l, st, rows.relaxed).terminal;
    let extras = |v: &[f64]| {
        let mut extras = vec![0.0; l.variables(rows) - stagewise];
        if let Some(terminal) = &terminal {
            let w = [1, 3].map(|c| {
                let row = l.z(l.horizon, c);
                x_free[row] + (0..v.len()).map(|j| forced[(row, j)] * v[j]).sum::<f64>()
            });
            let first = l.terminal_variable(rows) - stagewise;
            for (k, value) in terminal.variables_at(w).enumerate() {
                extras[first + k] = value;
            }
        }
        extras
    };
    let slack = |r: usize, v: &[f64]| {
        let on_extras: f64 = if extra_terms[r].is_empty() {
            0.0
        } else {
            let extras = extras(v);
            extra_terms[r]
                .iter()
                .map(|&(k, value)| value * extras[k])
                .sum()
        };
        s0[r]
            - coefficients[r]
                .iter()
                .zip(v)
                .map(|(c, v)| c * v)
                .sum::<f64>()
            - on_extras
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
        for terminal_safety in [TerminalSafety::None, TerminalSafety::Brake] {
            let mut s = Scenario::default();
            s.mpc.qp_form = qp_form;
            s.mpc.terminal_safety = terminal_safety;
            leaving_out_implied_rows_changes_no_plan_of(&s);
        }
    }
}

fn leaving_out_implied_rows_changes_no_plan_of(s: &Scenario) {
    let mut mpc = LinearMpc::new(s).unwrap();
    let mut compared = vec![0; Rows::count(&mpc.layout)];
    for plan in closed_loop(s, 400).iter().step_by(5) {
        let z = plan.z[0];
        mpc.step(plan.sample, protocol::phi_inverse(z, 0.0), 0.0);
        let z0 = [z[0] - s.robot.goal[0], z[1], z[2] - s.robot.goal[1], z[3]];
        // The rows left out at the current reference, then every row at the same one.
        assert_eq!(mpc.solve_once(z0).0, PlanStatus::Solved);
        let used = mpc.rows;
        mpc.load_solution();
        let reduced = mpc.solution.clone();
        mpc.kept = mpc.discs.clone();
        let all_rows = Rows {
            relaxed: used.relaxed,
            ..Rows::all(&mpc.layout)
        };
        assert_eq!(mpc.solve_with(z0, all_rows).0, PlanStatus::Solved);
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
    // The paper's run leaves out the box and terminal rows, and the obstacle's rows
    // away from it.
    let away = Rows {
        box_and_terminal: false,
        discs: 0,
        relaxed: false,
    };
    let near = Rows { discs: 1, ..away };
    assert!(
        compared[away.index()] > 10 && compared[near.index()] > 10,
        "{compared:?}"
    );
}

/// Rows of a program violated at the stage-wise point `x` (with its extra variables),
/// beyond `tolerance`: `(first row of the cone, violation)`, and separately the number
/// of violated terminal-set rows (eqs. 45, 47).
fn violations(
    mpc: &LinearMpc,
    rows: Rows,
    x: &[f64],
    tolerance: f64,
) -> (Vec<(usize, f64)>, usize) {
    use clarabel::solver::SupportedConeT;
    let l = &mpc.layout;
    let mut s = mpc.assembly.b.clone();
    for &(r, c, value) in &mpc.assembly.entries {
        s[r] -= value * x[c];
    }
    let zero_rows = 4 + 4 * l.horizon;
    let terminal_set = zero_rows + 4 * l.horizon + 4 * (l.horizon - 1);
    let terminal_set = terminal_set..terminal_set + l.terminal_rows;
    let (mut violated, mut terminal_set_violated) = (Vec::new(), 0);
    let mut r = 0;
    for cone in l.cones(rows) {
        match cone {
            SupportedConeT::ZeroConeT(d) => {
                for (row, slack) in s.iter().enumerate().skip(r).take(d) {
                    if slack.abs() > tolerance {
                        violated.push((row, slack.abs()));
                    }
                }
                r += d;
            }
            SupportedConeT::NonnegativeConeT(d) => {
                for (row, slack) in s.iter().enumerate().skip(r).take(d) {
                    if *slack < -tolerance {
                        if terminal_set.contains(&row) {
                            terminal_set_violated += 1;
                        } else {
                            violated.push((row, -slack));
                        }
                    }
                }
                r += d;
            }
            SupportedConeT::SecondOrderConeT(d) => {
                let tail = s[r + 1..r + d].iter().map(|x| x * x).sum::<f64>().sqrt();
                if tail - s[r] > tolerance {
                    violated.push((r, tail - s[r]));
                }
                r += d;
            }
            _ => unreachable!("the MPC uses no other cone"),
        }
    }
    (violated, terminal_set_violated)
}

/// Closed loop of `scenario` on the MPC's own model (noise-free, the model holds). At
/// every sample after the first, before solving, the program is built with all its
/// rows at the candidate the step linearizes at (the previous plan shifted, extended
/// by one braking sample) and every row is evaluated at that candidate, with the decay
/// slacks it needs and the terminal variables at which the terminal rows are exact.
/// Returns `(samples checked, samples whose candidate broke only the terminal set,
/// samples not solved)`; panics on a candidate that breaks any other row.
fn check_candidates(scenario: &Scenario, samples: u64) -> (u64, u64, u64) {
    let mut mpc = LinearMpc::new(scenario).unwrap();
    assert!(
        !mpc.layout.condensed,
        "the candidate is checked in stage-wise columns"
    );
    let (a, b) = model::discretize(scenario.timing.ts_s);
    let [x, y, mut heading] = scenario.robot.start;
    let mut z = Vector4::from(protocol::phi([x, y, heading, scenario.robot.zeta0]));
    let (mut checked, mut terminal_set_only, mut unsolved) = (0, 0, 0);
    let goal = scenario.robot.goal;
    for k in 0..samples {
        let zeta = z[1].hypot(z[3]);
        if zeta > 0.0 {
            heading = z[3].atan2(z[1]);
        }
        let z0 = [z[0] - goal[0], z[1], z[2] - goal[1], z[3]];
        if mpc.last_sample == Some(k.wrapping_sub(1)) {
            checked += 1;
            // The step's own set-up, then the candidate and its extra variables.
            crate::discs::constraint_discs(
                &mpc.obstacles,
                goal,
                mpc.margin_m(0.0),
                zeta,
                mpc.ts_s,
                std::f64::consts::SQRT_2 * mpc.statics.v_max,
                &mut mpc.discs,
            );
            assert!(mpc.shifted_reference(k));
            mpc.reach.set_initial_state(z0);
            mpc.kept = mpc.discs.clone();
            let rows = Rows::all(&mpc.layout);
            mpc.fill(z0, rows);
            let l = mpc.layout.clone();
            let n = l.horizon;
            let brake = l.terminal.unwrap();
            let mut states: Vec<[f64; 4]> = mpc.last_z[1..].to_vec();
            states.push(brake.step(mpc.last_z[n]));
            let mut x = vec![0.0; l.variables(rows)];
            for (i, state) in states.iter().enumerate() {
                for c in 0..4 {
                    x[l.z(i, c)] = state[c];
                }
            }
            for i in 0..n - 1 {
                for c in 0..2 {
                    x[l.v(i, c)] = mpc.solution[l.v(i + 1, c)];
                }
            }
            let braking = brake.input([mpc.last_z[n][1], mpc.last_z[n][3]]);
            for c in 0..2 {
                x[l.v(n - 1, c)] = braking[c];
            }
            // The slacks the candidate needs (stage 0's at the data `p_0`, as the
            // program has it).
            let decay = 1.0 - mpc.statics.gamma;
            let slack_stages = l.decay_slacks(1);
            for (j, disc) in mpc.discs.iter().enumerate() {
                let h = |z: [f64; 4]| disc.barrier([z[0], z[2]]);
                for i in 0..slack_stages {
                    let from = if i == 0 { z0 } else { states[i] };
                    let needed = decay * h(from) - h(states[i + 1]);
                    x[l.decay_slack(j, i)] = needed.max(0.0);
                }
            }
            let data = StepData {
                z0,
                discs: &mpc.discs,
                reference: &mpc.reference,
                reference_velocity: mpc.reference_velocity,
                max_terminal_speed: mpc.reach.max_terminal_speed(),
            };
            let barrier = data.barrier(&l, &mpc.statics, rows.relaxed);
            let first = l.terminal_variable(rows);
            let w_n = [states[n][1], states[n][3]];
            for (k, value) in barrier.terminal.unwrap().variables_at(w_n).enumerate() {
                x[first + k] = value;
            }
            // The candidate comes from a solution that meets the dynamics to the
            // solver's tolerance (1e-6 relative: residuals of 1e-5 m seen here), which
            // moves a barrier near the obstacle by up to 1e-4 m^2.
            let (violated, terminal_set) = violations(&mpc, rows, &x, 1e-4);
            assert!(
                violated.is_empty(),
                "sample {k}: the candidate breaks rows {violated:?}"
            );
            if terminal_set > 0 {
                terminal_set_only += 1;
            }
        }
        let plan = mpc.step(k, [z[0], z[2], heading, zeta], 0.0);
        if !plan.is_solved() {
            unsolved += 1;
            break;
        }
        z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
    }
    (checked, terminal_set_only, unsolved)
}

/// The scenarios of the recursive feasibility test: the paper's, the two that ran into
/// their obstacle before terminal safety (issue 14; README, Known limitations),
/// `gamma = 1`, and three obstacles.
fn hard_scenarios() -> Vec<Scenario> {
    let with = |overrides: &[&str]| {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        let s = Scenario::default().with_overrides(&overrides).unwrap();
        s.validate("test").unwrap();
        s
    };
    let approach = [
        "timing.ts_s=0.02",
        "mpc.horizon=10",
        "mpc.gamma=0.3",
        "mpc.v_max=1",
        "obstacles.0.radius=0.72",
    ];
    let mut three = with(&["mpc.gamma=0.2", "mpc.horizon=12"]);
    three.obstacles.push(Obstacle {
        x: 5.5,
        y: 3.0,
        radius: 0.8,
    });
    three.obstacles.push(Obstacle {
        x: 1.0,
        y: 4.5,
        radius: 0.5,
    });
    vec![
        with(&[]),
        with(&approach),
        with(&["timing.ts_s=0.01"]),
        with(&["mpc.gamma=1"]),
        three,
    ]
}

#[test]
fn the_shifted_plan_extended_by_braking_is_feasible_at_the_next_sample() {
    for form in ["brake", "brake_ball"] {
        for mut s in hard_scenarios() {
            s = s
                .with_overrides(&[
                    format!("mpc.terminal_safety={form}"),
                    "mpc.qp_form=sparse".into(),
                ])
                .unwrap();
            let samples = (25.0 / s.timing.ts_s) as u64;
            let (checked, terminal_set_only, unsolved) = check_candidates(&s, samples);
            assert!(checked > samples / 2, "{form}: {checked} of {samples}");
            // Assumption (d): the terminal set may refuse a candidate; none of these
            // runs meets it (their position boxes are far, the LQR's inputs small).
            assert_eq!(
                (terminal_set_only, unsolved),
                (0, 0),
                "{form}, ts {} N {} gamma {}",
                s.timing.ts_s,
                s.mpc.horizon,
                s.mpc.gamma
            );
        }
    }
}

#[test]
fn without_terminal_safety_the_fast_approach_loses_feasibility() {
    // The same closed loop as the recursive-feasibility test's second scenario, in the
    // paper's formulation: its problem turns infeasible as it nears the obstacle.
    let s = hard_scenarios()[1]
        .with_overrides(&["mpc.terminal_safety=none".into()])
        .unwrap();
    let mut mpc = LinearMpc::new(&s).unwrap();
    let (a, b) = model::discretize(s.timing.ts_s);
    let [x, y, theta] = s.robot.start;
    let mut z = Vector4::from(protocol::phi([x, y, theta, 0.0]));
    let failed = (0..1000).find(|&k| {
        let plan = mpc.step(k, protocol::phi_inverse(z.into(), theta), 0.0);
        z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
        !plan.is_solved()
    });
    assert!(failed.is_some(), "the paper's formulation stayed feasible");
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
    let goal = s.robot.goal;
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
            let z0 = [z[0] - s.robot.goal[0], z[1], z[2] - s.robot.goal[1], z[3]];
            (mpc.max_solves, mpc.refinement_tol_m) = (max_solves, converged_m);
            let converged = mpc.refine(z0);
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
