//! Rows left out because the input box implies them change nothing.

use super::*;

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
        if !mpc.statics.box_and_terminal_implied(z0, [0.0; 2]) {
            kept += 1;
            continue;
        }
        left_out += 1;
        let data = StepData {
            z0,
            sub_goal: [0.0; 2],
            discs: &[],
            reference: &mpc.reference,
            reference_velocity: mpc.reference_velocity,
            max_terminal_speed: 0.0,
            stand_s: 0.0,
            prediction: crate::discs::Prediction::Bounded,
            stage_s: 0.05,
            rest_lookahead: true,
        };
        let without_barrier = Rows {
            box_and_terminal: true,
            discs: 0,
            terminal_only: 0,
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
    // A disc at rest, a tracked obstacle's walking, bounded (swept over the fastest
    // stop), and one standing (swept over the plan's own stop: `tau`, `sigma`).
    let moving = Disc {
        motion: protocol::DiscMotion {
            velocity: [-0.4, 0.3],
            radius_rate: 0.3,
            radius_accel: 0.25,
            hidden: false,
            standing: false,
            held: false,
        },
        ..Disc::still([3.0, 3.5], 1.0)
    };
    let mut standing = moving;
    standing.motion.velocity = [0.05, 0.0];
    standing.motion.standing = true;
    standing.motion.held = true;
    for (gamma, disc) in [
        (0.1, Disc::still([3.0, 3.5], 1.5)),
        (1.0, Disc::still([3.0, 3.5], 1.5)),
        (0.1, moving),
        (0.1, standing),
    ] {
        let mut s = Scenario::default();
        s.mpc.gamma = gamma;
        s.mpc.qp_form = QpForm::Sparse; // rows checked in stage-wise columns
        if disc.moves() {
            let mut person = protocol::Obstacle::fixed(-5.0, 5.0, 0.3);
            person.velocity = [0.5, 0.0];
            s.obstacles.push(person);
        }
        let mut mpc = LinearMpc::new(&s).unwrap();
        assert_eq!(mpc.layout.terminal.unwrap().sweeps, disc.moves());
        mpc.discs = vec![disc];
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
                sub_goal: mpc.sub_goal,
                discs: &mpc.discs,
                reference: &mpc.reference,
                reference_velocity: mpc.reference_velocity,
                max_terminal_speed: mpc.reach.max_terminal_speed(),
                stand_s: 0.0,
                prediction: crate::discs::Prediction::Bounded,
                stage_s: 0.05,
                rest_lookahead: true,
            };
            if !data
                .barrier(&mpc.layout, &mpc.statics, Rows::ONE_DISC)
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
                terminal_only: 0,
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
    let terminal = data.barrier(l, st, rows).terminal;
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
        let z0 = [
            z[0] - s.robot.goal.position[0],
            z[1],
            z[2] - s.robot.goal.position[1],
            z[3],
        ];
        // The rows left out at the current reference, then every row at the same one.
        assert_eq!(mpc.solve_once(z0, true).0, PlanStatus::Solved);
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
    // away from it; with terminal safety, its CBF rows alone for a while after the pass.
    let away = Rows {
        box_and_terminal: false,
        discs: 0,
        terminal_only: 0,
        relaxed: false,
    };
    let near = Rows { discs: 1, ..away };
    let passed = Rows {
        terminal_only: 1,
        ..away
    };
    let terminal_safety = mpc.layout.terminal.is_some();
    assert!(
        compared[away.index()] > 10
            && compared[near.index()] > 10
            && (compared[passed.index()] > 5) == terminal_safety,
        "{compared:?}"
    );
}
