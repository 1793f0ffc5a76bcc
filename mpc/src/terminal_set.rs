//! The terminal set (eqs. 45, 47) and the sub-goal it is taken about.
//!
//! The paper asks the last state `z_N` to lie in the set from which the LQR closed loop
//! `z+ = (A + BK) z` respects the input box and the position box for `Nc` steps. About the
//! goal, that set is a neighbourhood of it whose size is `v_max` over the LQR gain: with a
//! gentle input box (`v_max = 1`) a few metres. A robot farther away than it can travel in
//! `N` samples cannot put `z_N` into it, and every program is infeasible from the start
//! (issue 27: 14.8 m with `Ts = 0.02 s`, `N = 8`).
//!
//! So the set is taken about a **sub-goal** `s`, a point at rest: the tracking form of the
//! same set, `z_N - s_hat` in the goal's set for the input rows, and the LQR closed loop
//! about `s_hat` (`s_hat = [s_x, 0, s_y, 0]`, an equilibrium: `A s_hat = s_hat`) inside the
//! position box for the others. Each row `coeffs' z_N <= bound` of the goal's set becomes
//! `coeffs' z_N <= bound + shift' s` ([`Bound::at`]), the rest of the program
//! unchanged. [`sub_goal`] picks `s`: the point nearest the target (the goal, or the
//! route's reference at stage `N`) on the segment from the LQR's rest point ahead of the
//! robot to the target such that `z_0` itself lies in the set about `s`. Then the LQR
//! inputs from `z_0` about `s` satisfy the input box and, the set being invariant under
//! them, put `z_N` into it: the terminal set no longer makes the program infeasible. Where
//! the target is within reach, `s` is the target exactly and the program is the paper's
//! (its trajectory byte for byte). The safety rows (CBF, braking-safe terminal rows) and
//! the DFL's gatekeeper do not depend on `s`.

use crate::assembly::csc_with_positions;
use clarabel::algebra::CscMatrix;
use clarabel::solver::SupportedConeT;
use nalgebra::{Matrix2x4, Matrix4};

/// Which constraint of eqs. (45, 47) a row of the terminal set comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SetRowKind {
    /// `±K M_j z_N <= v_max` (eq. 45).
    Input,
    /// The position box on `M_j z_N` (eq. 47).
    Position,
}

/// A row's bound about a sub-goal `s` (goal-relative): `at_goal + shift' s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bound {
    /// The bound about the goal (`s = 0`).
    pub at_goal: f64,
    /// How the bound moves with the sub-goal: a terminal input row's coefficients on the
    /// positions (the set translates with `s`); a terminal position row's minus `±e_axis`
    /// (the box stays where it is: zero for `j = 0`, the box on `z_N` itself); zero for
    /// the position box on the other stages.
    pub shift: [f64; 2],
}

impl Bound {
    /// A bound that does not move with the sub-goal.
    pub fn fixed(at_goal: f64) -> Bound {
        Bound {
            at_goal,
            shift: [0.0; 2],
        }
    }

    /// The bound about the sub-goal `s`, m; the goal's own, bit for bit, at `s = 0`.
    pub fn at(&self, s: [f64; 2]) -> f64 {
        if s == [0.0, 0.0] {
            self.at_goal
        } else {
            self.at_goal + self.shift[0] * s[0] + self.shift[1] * s[1]
        }
    }
}

/// One row of the terminal set about a sub-goal `s`: `coeffs' z_N <= bound.at(s)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetRow {
    pub coeffs: [f64; 4],
    pub bound: Bound,
    pub kind: SetRowKind,
}

impl SetRow {
    /// `coeffs' z`.
    pub fn value(&self, z: [f64; 4]) -> f64 {
        self.coeffs.iter().zip(z).map(|(c, z)| c * z).sum()
    }
}

/// Eqs. (45) and (47): `-v_max <= K M_j z_N <= v_max` and the position box on `M_j z_N`,
/// `M_j = (A + BK)^j`, `j = 0..=Nc`, about the goal, with their shifts for a sub-goal.
pub fn terminal_set(
    k: &Matrix2x4<f64>,
    closed_loop: &Matrix4<f64>,
    constraint_horizon: usize,
    v_max: f64,
    position_box: [[f64; 2]; 2],
) -> Vec<SetRow> {
    let mut rows = Vec::with_capacity(8 * (constraint_horizon + 1));
    let mut m = Matrix4::identity();
    for _ in 0..=constraint_horizon {
        let km = k * m;
        for c in 0..2 {
            let coeffs: [f64; 4] = std::array::from_fn(|i| km[(c, i)]);
            for sign in [1.0, -1.0] {
                let coeffs = coeffs.map(|x| sign * x);
                rows.push(SetRow {
                    coeffs,
                    bound: Bound {
                        at_goal: v_max,
                        shift: [coeffs[0], coeffs[2]],
                    },
                    kind: SetRowKind::Input,
                });
            }
        }
        for (axis, r) in [(0, 0), (1, 2)] {
            let coeffs: [f64; 4] = std::array::from_fn(|i| m[(r, i)]);
            for (sign, bound) in [(1.0, position_box[axis][1]), (-1.0, -position_box[axis][0])] {
                let coeffs = coeffs.map(|x| sign * x);
                let mut shift = [coeffs[0], coeffs[2]];
                shift[axis] -= sign;
                rows.push(SetRow {
                    coeffs,
                    bound: Bound {
                        at_goal: bound,
                        shift,
                    },
                    kind: SetRowKind::Position,
                });
            }
        }
        m = closed_loop * m;
    }
    rows
}

/// The rows of `rows` that the others do not imply, about any sub-goal. An input row is
/// dropped when the largest `coeffs' z` over the remaining input rows, found with a linear
/// program, does not exceed its bound: the input rows translate together with the
/// sub-goal, so what they imply about the goal they imply about every sub-goal. The
/// position rows stay (the box does not move with the sub-goal, so a row the others imply
/// about the goal may bind about a sub-goal near the box's edge). An unbounded or failed
/// program keeps the row. The set described is unchanged; the MPC solves a smaller
/// problem where some input row is implied (in the paper none of the 44 is).
pub fn prune_redundant(mut rows: Vec<SetRow>) -> Vec<SetRow> {
    let mut i = 0;
    while i < rows.len() {
        let row = rows[i];
        let others: Vec<([f64; 4], f64)> = rows
            .iter()
            .enumerate()
            .filter(|&(j, r)| j != i && r.kind == SetRowKind::Input)
            .map(|(_, r)| (r.coeffs, r.bound.at_goal))
            .collect();
        let implied = row.kind == SetRowKind::Input
            && largest(row.coeffs, &others)
                .is_some_and(|m| m <= row.bound.at_goal + 1e-9 * (1.0 + row.bound.at_goal.abs()));
        if implied {
            rows.remove(i);
        } else {
            i += 1;
        }
    }
    rows
}

/// `max a' z` subject to `rows`, if bounded and solved.
fn largest(a: [f64; 4], rows: &[([f64; 4], f64)]) -> Option<f64> {
    use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, SolverStatus};
    if rows.is_empty() {
        return None;
    }
    let entries: Vec<(usize, usize, f64)> = rows
        .iter()
        .enumerate()
        .flat_map(|(r, (coeffs, _))| (0..4).map(move |c| (r, c, coeffs[c])))
        .filter(|e| e.2 != 0.0)
        .collect();
    let (matrix, _) = csc_with_positions(rows.len(), 4, &entries);
    let bounds: Vec<f64> = rows.iter().map(|r| r.1).collect();
    let q = a.map(|x| -x);
    let settings = DefaultSettings::<f64> {
        verbose: false,
        ..DefaultSettings::default()
    };
    let mut solver = DefaultSolver::new(
        &CscMatrix::zeros((4, 4)),
        &q,
        &matrix,
        &bounds,
        &[SupportedConeT::NonnegativeConeT(rows.len())],
        settings,
    )
    .ok()?;
    solver.solve();
    (solver.solution.status == SolverStatus::Solved).then(|| -solver.solution.obj_val)
}

/// The sub-goal of a step (module docs), goal-relative, m: `target` itself when `z0` lies
/// in the terminal set about it; otherwise the point nearest `target` on the segment from
/// the LQR's rest point `r` (where the gain's first input is zero: `r = p_0 + tau w_0` per
/// axis, `tau = K_pv / K_pp`) to `target` at which `z0` lies in the set about it. Each
/// row is linear in the point `r + t (target - r)`, so the admissible `t` is an interval,
/// found row by row; when it is empty (a robot faster than the LQR can stop within the
/// box), the segment's end nearest the admissible side of every row, `t` at its lower
/// bound. No allocation.
pub fn sub_goal(rows: &[SetRow], k: &Matrix2x4<f64>, z0: [f64; 4], target: [f64; 2]) -> [f64; 2] {
    let holds = |s: [f64; 2]| {
        rows.iter()
            .all(|r| r.value(z0) <= r.bound.at(s) + 1e-9 * (1.0 + r.bound.at_goal.abs()))
    };
    if holds(target) {
        return target;
    }
    let lead = |pp: f64, pv: f64| if pp != 0.0 { pv / pp } else { 0.0 };
    let rest = [
        z0[0] + lead(k[(0, 0)], k[(0, 1)]) * z0[1],
        z0[2] + lead(k[(1, 2)], k[(1, 3)]) * z0[3],
    ];
    let along = [target[0] - rest[0], target[1] - rest[1]];
    // Row: value(z0) <= bound_at(rest) + t shift' along.
    let (mut lower, mut upper) = (0.0_f64, 1.0_f64);
    for r in rows {
        let excess = r.value(z0) - r.bound.at(rest);
        let slope = r.bound.shift[0] * along[0] + r.bound.shift[1] * along[1];
        if slope > 0.0 {
            lower = lower.max(excess / slope);
        } else if slope < 0.0 {
            upper = upper.min(excess / slope);
        }
    }
    let t = if lower <= upper {
        upper
    } else {
        lower.min(1.0)
    };
    [rest[0] + t * along[0], rest[1] + t * along[1]]
}

/// The fastest speed, m/s, at which a robot following a point `lead_s` seconds ahead of
/// it along an axis lies in the terminal set about that point at rest (the input rows;
/// the box is the route's concern): the LQR about the point can take it to rest there
/// within the input box. Along a diagonal each axis moves slower, so the axes bound it.
pub fn tracking_speed(rows: &[SetRow], lead_s: f64) -> f64 {
    let per_axis = |axis: usize| {
        let mut unit = [0.0; 4];
        unit[2 * axis] = -lead_s;
        unit[2 * axis + 1] = 1.0;
        rows.iter()
            .filter(|r| r.kind == SetRowKind::Input)
            .map(|r| (r.value(unit), r.bound.at_goal))
            .filter(|(rate, _)| *rate > 0.0)
            .map(|(rate, bound)| bound / rate)
            .fold(f64::INFINITY, f64::min)
    };
    per_axis(0).min(per_axis(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{self, r_matrix, terminal_weight};
    use nalgebra::Vector4;
    use protocol::Scenario;

    /// The pruned terminal set of `scenario`, its gain and closed loop.
    fn set_of(scenario: &Scenario) -> (Vec<SetRow>, Matrix2x4<f64>, Matrix4<f64>) {
        let c = &scenario.mpc;
        let (a, b) = model::discretize(scenario.timing.ts_s);
        let k = model::lqr_gain(
            &a,
            &b,
            &r_matrix(scenario),
            &terminal_weight(scenario).unwrap(),
        )
        .unwrap();
        let goal = scenario.robot.goal.position;
        let position_box =
            [0, 1].map(|i| [c.position_min[i] - goal[i], c.position_max[i] - goal[i]]);
        let rows = prune_redundant(terminal_set(
            &k,
            &(a + b * k),
            c.constraint_horizon,
            c.v_max,
            position_box,
        ));
        (rows, k, a + b * k)
    }

    fn relative_z0(scenario: &Scenario) -> [f64; 4] {
        let r = &scenario.robot;
        let z = protocol::phi([r.start[0], r.start[1], r.start[2], r.zeta0]);
        [
            z[0] - r.goal.position[0],
            z[1],
            z[2] - r.goal.position[1],
            z[3],
        ]
    }

    /// Issue 27's reduced world: 14.8 m from the goal with a gentle input box.
    fn far() -> Scenario {
        Scenario::default()
            .with_overrides(&[
                "timing.ts_s=0.02".into(),
                "mpc.gamma=0.3".into(),
                "mpc.v_max=1".into(),
                "robot.start=[-3.611, -7.369, 3.3138]".into(),
                "robot.zeta0=0.5".into(),
                "robot.goal=[-4.0291, 7.4458]".into(),
            ])
            .unwrap()
    }

    #[test]
    fn within_reach_the_sub_goal_is_the_target_itself() {
        let paper = Scenario::default();
        let (rows, k, _) = set_of(&paper);
        assert_eq!(
            sub_goal(&rows, &k, relative_z0(&paper), [0.0, 0.0]),
            [0.0, 0.0]
        );
        // A target 0.5 m ahead of a robot at rest is one too.
        let z0 = [1.0, 0.0, -2.0, 0.0];
        assert_eq!(sub_goal(&rows, &k, z0, [1.5, -2.0]), [1.5, -2.0]);
    }

    #[test]
    fn far_away_the_sub_goal_lies_towards_the_goal_with_the_lqr_from_z0_feasible_about_it() {
        let s = far();
        let (rows, k, closed_loop) = set_of(&s);
        let z0 = relative_z0(&s);
        // The goal itself is out of reach: z0 violates its set.
        assert!(rows.iter().any(|r| r.value(z0) > r.bound.at_goal));
        let sub = sub_goal(&rows, &k, z0, [0.0, 0.0]);
        let from_goal = |p: [f64; 2]| p[0].hypot(p[1]);
        let progress = from_goal([z0[0], z0[2]]) - from_goal(sub);
        assert!(
            progress > 1.0,
            "{sub:?} is {progress} m nearer than the robot"
        );
        assert!(rows.iter().all(|r| r.value(z0) <= r.bound.at(sub) + 1e-9));
        // The LQR about the sub-goal from z0: every input in the box, every state in the
        // set (so z_N is, for any N), converging to the sub-goal at rest.
        let s_hat = Vector4::new(sub[0], 0.0, sub[1], 0.0);
        let mut z = Vector4::from(z0);
        for _ in 0..4000 {
            let v = k * (z - s_hat);
            assert!(v.amax() <= s.mpc.v_max + 1e-9, "{v:?}");
            let at: [f64; 4] = z.into();
            assert!(rows.iter().all(|r| r.value(at) <= r.bound.at(sub) + 1e-9));
            z = s_hat + closed_loop * (z - s_hat);
        }
        assert!((z - s_hat).norm() < 1e-3, "{z:?} vs {sub:?}");
    }

    /// A spread of states about `centre`: positions up to 6 m off, speeds up to 4 m/s
    /// (a golden-angle spiral, the same every run).
    fn states_about(centre: [f64; 2], count: usize) -> impl Iterator<Item = [f64; 4]> {
        (0..count).map(move |i| {
            let t = i as f64;
            let (r, a) = (6.0 * (t * 0.618_034).fract(), t * 2.399_963);
            let (speed, b) = (4.0 * (t * 0.414_21).fract(), t * 1.3);
            [
                centre[0] + r * a.cos(),
                speed * b.cos(),
                centre[1] + r * a.sin(),
                speed * b.sin(),
            ]
        })
    }

    #[test]
    fn about_a_sub_goal_a_state_is_in_the_set_exactly_when_the_lqr_about_it_keeps_both_boxes() {
        let s = Scenario::default();
        let (rows, k, closed_loop) = set_of(&s);
        let c = &s.mpc;
        let goal = s.robot.goal.position;
        let position_box =
            [0, 1].map(|i| c.position_min[i] - goal[i]..=c.position_max[i] - goal[i]);
        // Eqs. (45, 47) about `sub`, by simulation: the LQR closed loop about `s_hat` from
        // `z0` keeps its inputs and its positions in their boxes for `Nc` steps.
        let keeps_the_boxes = |z0: [f64; 4], sub: [f64; 2]| {
            let s_hat = Vector4::new(sub[0], 0.0, sub[1], 0.0);
            let mut z = Vector4::from(z0);
            (0..=c.constraint_horizon).all(|_| {
                let inside = (k * (z - s_hat)).amax() <= c.v_max
                    && position_box[0].contains(&z[0])
                    && position_box[1].contains(&z[2]);
                z = s_hat + closed_loop * (z - s_hat);
                inside
            })
        };
        let mut seen = [0, 0];
        for sub in [[0.0, 0.0], [2.0, -1.0], [-6.0, 4.5], [7.5, 7.5]] {
            for z in states_about(sub, 3000) {
                let in_set = keeps_the_boxes(z, sub);
                let by_rows = rows.iter().all(|r| r.value(z) <= r.bound.at(sub));
                assert_eq!(by_rows, in_set, "{z:?} about {sub:?}");
                seen[usize::from(in_set)] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n > 500), "outside, inside: {seen:?}");
    }

    #[test]
    fn at_the_tracking_speed_a_robot_a_lead_behind_a_point_is_just_in_its_set() {
        for overrides in [
            vec![],
            vec!["timing.ts_s=0.02".to_string(), "mpc.v_max=1".into()],
        ] {
            let s = Scenario::default().with_overrides(&overrides).unwrap();
            let (rows, _, _) = set_of(&s);
            let lead_s = s.mpc.horizon as f64 * s.timing.ts_s;
            let speed = tracking_speed(&rows, lead_s);
            assert!(speed.is_finite() && speed > 0.0, "{overrides:?}: {speed}");
            // Along y, the point at rest at (0, 0), the robot `lead_s` of travel behind it.
            let state = |c: f64| [0.0, 0.0, -lead_s * c, c];
            let inside = |z: [f64; 4]| rows.iter().all(|r| r.value(z) <= r.bound.at_goal + 1e-9);
            assert!(inside(state(speed)), "{overrides:?}");
            assert!(!inside(state(1.01 * speed)), "{overrides:?}");
        }
    }
}
