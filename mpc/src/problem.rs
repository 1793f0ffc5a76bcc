//! The conic program of one MPC step, in clarabel's form
//! `min 1/2 x'Px + q'x  s.t.  Ax + s = b, s in K`.
//!
//! Variables (sparse formulation): `x = [z_0, ..., z_N, v_0, ..., v_{N-1}]`, all in
//! goal-relative coordinates (the goal is the origin of the MPC). Rows, in cone order:
//!
//! | rows | cone | meaning |
//! |---|---|---|
//! | 4 | zero | `z_0` = measured state |
//! | 4N | zero | dynamics `z_{i+1} = A z_i + B v_i` (eq. 52) |
//! | 4N | nonneg | input box `|v_i| <= v_max` (eq. 531) |
//! | 4(N-1) | nonneg | position box on `z_1 .. z_{N-1}` (eq. 53) |
//! | at most 8(Nc+1) | nonneg | terminal input and position boxes on `(A+BK)^j z_N` (eqs. 45, 47), those the others do not imply |
//! | 1 or N per obstacle | nonneg | CBF rows that are linear (see below) |
//! | 4 per obstacle and stage | SOC(4) | CBF rows that are cones |
//!
//! The CBF `H(p_{i+1}) >= (1 - gamma) H(p_i)` (eq. 54) is convexified by replacing
//! `H(p_{i+1})` with its linearization `L` at a reference `p_bar` (`L <= H` everywhere, so
//! this is an inner approximation). Stage 0 has `p_0` as data and is linear; for stage
//! `i >= 1`, `||p_i - o||^2 <= t` with `t = (L(p_{i+1}) + (1 - gamma) r^2) / (1 - gamma)` is
//! the cone `(t + 1, t - 1, 2 (p_i - o)) in SOC(4)`. With `gamma = 1`, or the Euclidean
//! benchmark `H(p_i) >= 0`, every row is the linear `L(p_i) >= 0` on stages `1..=N`.
//!
//! The sparsity pattern depends only on the configuration: [`Assembly`] writes the same
//! entries in the same order every step, and only their values change.

use clarabel::algebra::CscMatrix;
use clarabel::solver::SupportedConeT;
use nalgebra::{Matrix2x4, Matrix4};

/// Dimensions and the fixed parts of the problem.
#[derive(Debug, Clone)]
pub struct Layout {
    /// Prediction horizon `N`.
    pub horizon: usize,
    /// Rows of the terminal set kept after [`prune_redundant`].
    pub terminal_rows: usize,
    pub obstacles: usize,
    /// All CBF rows linear (`gamma = 1` or the Euclidean benchmark).
    pub linear_barrier: bool,
}

impl Layout {
    /// Index of component `c` of `z_i`.
    pub fn z(&self, i: usize, c: usize) -> usize {
        4 * i + c
    }
    /// Index of component `c` of `v_i`.
    pub fn v(&self, i: usize, c: usize) -> usize {
        4 * (self.horizon + 1) + 2 * i + c
    }
    pub fn variables(&self) -> usize {
        4 * (self.horizon + 1) + 2 * self.horizon
    }
    fn linear_barrier_rows(&self) -> usize {
        barrier_row_counts(self.horizon, self.obstacles, self.linear_barrier).0
    }
    fn cone_barriers(&self) -> usize {
        barrier_row_counts(self.horizon, self.obstacles, self.linear_barrier).1
    }

    /// The cones, in row order.
    pub fn cones(&self) -> Vec<SupportedConeT<f64>> {
        let n = self.horizon;
        let equalities = 4 + 4 * n;
        let inequalities = 4 * n + 4 * (n - 1) + self.terminal_rows + self.linear_barrier_rows();
        let mut cones = vec![
            SupportedConeT::ZeroConeT(equalities),
            SupportedConeT::NonnegativeConeT(inequalities),
        ];
        cones.extend((0..self.cone_barriers()).map(|_| SupportedConeT::SecondOrderConeT(4)));
        cones
    }
}

/// A circular obstacle in goal-relative coordinates, with the radius the constraints use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disc {
    pub center: [f64; 2],
    pub radius: f64,
}

impl Disc {
    /// The barrier `H(p) = ||p - o||^2 - r^2` (eq. 100), m^2.
    pub fn barrier(&self, p: [f64; 2]) -> f64 {
        (p[0] - self.center[0]).powi(2) + (p[1] - self.center[1]).powi(2) - self.radius.powi(2)
    }

    /// Linearization of the barrier at `p_bar`: `L(p) = g'p + c`, returned as `(g, c)`.
    pub fn linearized_barrier(&self, p_bar: [f64; 2]) -> ([f64; 2], f64) {
        let g = [
            2.0 * (p_bar[0] - self.center[0]),
            2.0 * (p_bar[1] - self.center[1]),
        ];
        (g, self.barrier(p_bar) - g[0] * p_bar[0] - g[1] * p_bar[1])
    }
}

/// clarabel's settings for every MPC subproblem: what the accuracy needs and no more
/// (measured with callgrind on the paper run, instructions per MPC step, README): no
/// iterative refinement of the KKT solves (their residual products were half the work;
/// 4.8 M -> 2.5 M), no equilibration (the problem is well scaled: -0.4 M), and duality
/// gap and feasibility tolerances of 1e-6 instead of 1e-8 (a micrometre on positions in
/// metres: -0.4 M). Together 4.8 M -> 1.7 M instructions, the same trajectory.
pub fn solver_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettings {
        verbose: false,
        iterative_refinement_enable: false,
        equilibrate_enable: false,
        tol_gap_abs: 1e-6,
        tol_gap_rel: 1e-6,
        tol_feas: 1e-6,
        ..clarabel::solver::DefaultSettings::default()
    }
}

/// Fills `discs` with the constraint discs of one step: `obstacles` in coordinates
/// relative to `goal`, each radius inflated by `margin_m` (the safety margin and the
/// uncertainty term) and by the inter-sample dip. The CBF holds at the sample instants;
/// between two of them the robot moves along a chord of at most
/// `d = |speed| Ts + accel_max Ts^2 / 2`, which dips up to `d^2 / (8 r)` inside a circle
/// of radius `r` both end points lie on. That much more radius keeps the path between
/// samples out of the obstacle too (about 0.2 mm at 1 m/s in the paper's scenario).
pub fn constraint_discs(
    obstacles: &[protocol::Obstacle],
    goal: [f64; 2],
    margin_m: f64,
    speed_m_s: f64,
    ts_s: f64,
    accel_max: f64,
    discs: &mut Vec<Disc>,
) {
    let chord = speed_m_s.abs() * ts_s + 0.5 * accel_max * ts_s * ts_s;
    discs.clear();
    discs.extend(obstacles.iter().map(|o| {
        let radius = o.radius + margin_m;
        Disc {
            center: [o.x - goal[0], o.y - goal[1]],
            radius: radius + chord * chord / (8.0 * radius.max(chord)),
        }
    }));
}

/// Everything fixed by the configuration.
#[derive(Debug, Clone)]
pub struct StaticData {
    pub a: Matrix4<f64>,
    pub b: nalgebra::Matrix4x2<f64>,
    pub k: Matrix2x4<f64>,
    /// The terminal set (eqs. 45, 47) as rows `coeffs' z_N <= bound`, redundant ones
    /// removed ([`terminal_set`]).
    pub terminal_set: Vec<([f64; 4], f64)>,
    pub gamma: f64,
    pub v_max: f64,
    /// Goal-relative position box `[min, max]` per axis.
    pub position_box: [[f64; 2]; 2],
}

/// What changes each step.
#[derive(Debug, Clone, Copy)]
pub struct StepData<'a> {
    /// Goal-relative `z_0`.
    pub z0: [f64; 4],
    pub discs: &'a [Disc],
    /// Linearization points `p_bar_1 ..= p_bar_N` (index 0 is unused).
    pub reference: &'a [[f64; 2]],
}

/// The rows of `A` and `b`, written in a fixed order; buffers are reused between steps.
#[derive(Debug, Default)]
pub struct Assembly {
    /// `(row, column, value)` of every structural entry of `A`, in a fixed order.
    pub entries: Vec<(usize, usize, f64)>,
    pub b: Vec<f64>,
}

impl Assembly {
    /// Appends the row `sum(value * x[column]) + s = b`.
    pub fn row(&mut self, terms: impl IntoIterator<Item = (usize, f64)>, b: f64) {
        let r = self.b.len();
        self.entries
            .extend(terms.into_iter().map(|(c, v)| (r, c, v)));
        self.b.push(b);
    }

    /// Writes every row of the step's problem (see the module docs for the order).
    pub fn fill(&mut self, l: &Layout, s: &StaticData, d: &StepData) {
        self.entries.clear();
        self.b.clear();
        let n = l.horizon;
        for c in 0..4 {
            self.row([(l.z(0, c), 1.0)], d.z0[c]);
        }
        for i in 0..n {
            for r in 0..4 {
                let mut terms = [(0, 0.0); 7];
                terms[0] = (l.z(i + 1, r), 1.0);
                for c in 0..4 {
                    terms[1 + c] = (l.z(i, c), -s.a[(r, c)]);
                }
                for c in 0..2 {
                    terms[5 + c] = (l.v(i, c), -s.b[(r, c)]);
                }
                // Structural zeros of A and B are the same every step: leave them out.
                self.row(terms.into_iter().filter(|t| t.1 != 0.0), 0.0);
            }
        }
        for i in 0..n {
            for c in 0..2 {
                self.row([(l.v(i, c), 1.0)], s.v_max);
                self.row([(l.v(i, c), -1.0)], s.v_max);
            }
        }
        for i in 1..n {
            for (axis, c) in [(0, 0), (1, 2)] {
                self.row([(l.z(i, c), 1.0)], s.position_box[axis][1]);
                self.row([(l.z(i, c), -1.0)], -s.position_box[axis][0]);
            }
        }
        self.terminal_rows(l, s);
        self.barrier_rows(l, s, d);
    }

    /// The terminal set (eqs. 45, 47) on `z_N`.
    fn terminal_rows(&mut self, l: &Layout, s: &StaticData) {
        let n = l.horizon;
        for &(coeffs, bound) in &s.terminal_set {
            let terms = (0..4)
                .filter(|&c| coeffs[c] != 0.0)
                .map(|c| (l.z(n, c), coeffs[c]));
            self.row(terms, bound);
        }
    }

    fn barrier_rows(&mut self, l: &Layout, s: &StaticData, d: &StepData) {
        let barrier = Barrier {
            horizon: l.horizon,
            linear: l.linear_barrier,
            gamma: s.gamma,
            discs: d.discs,
            reference: d.reference,
            p0: [d.z0[0], d.z0[2]],
        };
        self.barrier(&barrier, |i| [l.z(i, 0), l.z(i, 2)]);
    }

    /// The CBF rows of eq. (54) (see the module docs): linear rows first (they belong to
    /// the nonnegative cone), then the SOC(4) rows. `position(i)` gives the columns of
    /// the position of stage `i`.
    pub fn barrier(&mut self, b: &Barrier, position: impl Fn(usize) -> [usize; 2]) {
        let n = b.horizon;
        for disc in b.discs {
            if b.linear {
                // L_i(p_i) >= 0, i = 1..=N.
                for i in 1..=n {
                    let (g, c) = disc.linearized_barrier(b.reference[i]);
                    let [px, py] = position(i);
                    self.row([(px, -g[0]), (py, -g[1])], c);
                }
            } else {
                // (1 - gamma) H(p_0) <= L_1(p_1), p_0 being data.
                let (g, c) = disc.linearized_barrier(b.reference[1]);
                let [px, py] = position(1);
                self.row(
                    [(px, -g[0]), (py, -g[1])],
                    c - (1.0 - b.gamma) * disc.barrier(b.p0),
                );
            }
        }
        if b.linear {
            return;
        }
        let scale = 1.0 / (1.0 - b.gamma);
        for disc in b.discs {
            for i in 1..n {
                let (g, c) = disc.linearized_barrier(b.reference[i + 1]);
                let t0 = scale * (c + (1.0 - b.gamma) * disc.radius.powi(2));
                let [nx, ny] = position(i + 1);
                let [px, py] = position(i);
                let slope = [(nx, -scale * g[0]), (ny, -scale * g[1])];
                self.row(slope, t0 + 1.0);
                self.row(slope, t0 - 1.0);
                self.row([(px, -2.0)], -2.0 * disc.center[0]);
                self.row([(py, -2.0)], -2.0 * disc.center[1]);
            }
        }
    }
}

/// What the CBF rows of one problem are built from.
#[derive(Debug, Clone, Copy)]
pub struct Barrier<'a> {
    pub horizon: usize,
    /// Every row linear (`gamma = 1` or the Euclidean benchmark).
    pub linear: bool,
    pub gamma: f64,
    pub discs: &'a [Disc],
    /// Linearization points of the positions of stages `1..=N` (index 0 unused).
    pub reference: &'a [[f64; 2]],
    /// Position of stage 0 (data).
    pub p0: [f64; 2],
}

/// Rows of the CBF part of the problem: `(linear rows, second-order cones)`.
pub fn barrier_row_counts(horizon: usize, obstacles: usize, linear: bool) -> (usize, usize) {
    if linear {
        (obstacles * horizon, 0)
    } else {
        (obstacles, obstacles * (horizon - 1))
    }
}

/// Eqs. (45) and (47) as rows `coeffs' z_N <= bound`: `-v_max <= K M_j z_N <= v_max` and
/// the position box on `M_j z_N`, `M_j = (A + BK)^j`, `j = 0..=Nc`.
pub fn terminal_set(
    k: &Matrix2x4<f64>,
    closed_loop: &Matrix4<f64>,
    constraint_horizon: usize,
    v_max: f64,
    position_box: [[f64; 2]; 2],
) -> Vec<([f64; 4], f64)> {
    let mut rows = Vec::with_capacity(8 * (constraint_horizon + 1));
    let mut m = Matrix4::identity();
    for _ in 0..=constraint_horizon {
        let km = k * m;
        for c in 0..2 {
            let coeffs: [f64; 4] = std::array::from_fn(|i| km[(c, i)]);
            rows.push((coeffs, v_max));
            rows.push((coeffs.map(|x| -x), v_max));
        }
        for (axis, r) in [(0, 0), (1, 2)] {
            let coeffs: [f64; 4] = std::array::from_fn(|i| m[(r, i)]);
            rows.push((coeffs, position_box[axis][1]));
            rows.push((coeffs.map(|x| -x), -position_box[axis][0]));
        }
        m = closed_loop * m;
    }
    rows
}

/// The rows of `rows` (`a' z <= b`, `z` in R^4) that the others do not imply. A row is
/// dropped when the largest `a' z` over the remaining rows, found with a linear program,
/// does not exceed `b`; an unbounded or failed program keeps the row. The set described
/// is unchanged; the MPC only solves a smaller problem (for the paper: 88 rows to 48).
pub fn prune_redundant(mut rows: Vec<([f64; 4], f64)>) -> Vec<([f64; 4], f64)> {
    let mut i = 0;
    while i < rows.len() {
        let (a, b) = rows[i];
        let others: Vec<([f64; 4], f64)> = rows
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, r)| *r)
            .collect();
        let implied = largest(a, &others).is_some_and(|m| m <= b + 1e-9 * (1.0 + b.abs()));
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

/// A clarabel solver for a problem whose sparsity never changes: built from the first
/// assembly, afterwards only its values are updated (`update_A`, `update_b`).
#[derive(Default)]
pub struct ConicSolver {
    solver: Option<clarabel::solver::DefaultSolver<f64>>,
    /// Where each [`Assembly`] entry sits in the CSC values.
    nz_position: Vec<usize>,
    nzval: Vec<f64>,
}

impl ConicSolver {
    /// Solves the problem of `assembly` (`objective` and `cones` are only asked for when
    /// the solver is built). Returns the plan status and the interior-point iterations.
    pub fn solve(
        &mut self,
        assembly: &Assembly,
        variables: usize,
        objective: impl FnOnce() -> CscMatrix<f64>,
        cones: impl FnOnce() -> Vec<SupportedConeT<f64>>,
    ) -> (protocol::PlanStatus, u32) {
        use clarabel::solver::{DefaultSolver, IPSolver};
        let solver = match self.solver.as_mut() {
            Some(solver) => {
                for (t, &(_, _, v)) in assembly.entries.iter().enumerate() {
                    self.nzval[self.nz_position[t]] = v;
                }
                let updated = solver
                    .update_A(&self.nzval)
                    .and_then(|()| solver.update_b(&assembly.b));
                if updated.is_err() {
                    return (protocol::PlanStatus::NumericalError, 0);
                }
                solver
            }
            None => {
                let (a, positions) =
                    csc_with_positions(assembly.b.len(), variables, &assembly.entries);
                self.nzval = a.nzval.clone();
                self.nz_position = positions;
                match DefaultSolver::new(
                    &objective(),
                    &vec![0.0; variables],
                    &a,
                    &assembly.b,
                    &cones(),
                    solver_settings(),
                ) {
                    Ok(solver) => self.solver.insert(solver),
                    Err(_) => return (protocol::PlanStatus::NumericalError, 0),
                }
            }
        };
        solver.solve();
        (
            crate::plan_status(solver.solution.status),
            solver.solution.iterations,
        )
    }

    /// The last solution's variables (none before the first solve).
    pub fn x(&self) -> Option<&[f64]> {
        self.solver.as_ref().map(|s| s.solution.x.as_slice())
    }

    pub fn x_mut(&mut self) -> Option<&mut [f64]> {
        self.solver.as_mut().map(|s| s.solution.x.as_mut_slice())
    }
}

/// Compressed-column matrix of `entries`, and for each entry its position in `nzval`
/// (so later values can be scattered into the same pattern).
pub fn csc_with_positions(
    rows: usize,
    cols: usize,
    entries: &[(usize, usize, f64)],
) -> (CscMatrix<f64>, Vec<usize>) {
    let mut order: Vec<usize> = (0..entries.len()).collect();
    order.sort_by_key(|&t| (entries[t].1, entries[t].0));
    let mut colptr = vec![0usize; cols + 1];
    let mut rowval = Vec::with_capacity(entries.len());
    let mut nzval = Vec::with_capacity(entries.len());
    let mut position = vec![0usize; entries.len()];
    for (nz, &t) in order.iter().enumerate() {
        let (r, c, v) = entries[t];
        colptr[c + 1] += 1;
        rowval.push(r);
        nzval.push(v);
        position[t] = nz;
    }
    for c in 0..cols {
        colptr[c + 1] += colptr[c];
    }
    (CscMatrix::new(rows, cols, colptr, rowval, nzval), position)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linearized_barrier_is_tight_at_the_reference_and_below_elsewhere() {
        let disc = Disc {
            center: [3.0, 3.5],
            radius: 1.5,
        };
        let p_bar = [5.0, 1.0];
        let (g, c) = disc.linearized_barrier(p_bar);
        let l = |p: [f64; 2]| g[0] * p[0] + g[1] * p[1] + c;
        assert!((l(p_bar) - disc.barrier(p_bar)).abs() < 1e-12);
        for p in [[0.0, 0.0], [3.0, 3.5], [10.0, -4.0], [5.1, 1.2]] {
            assert!(l(p) <= disc.barrier(p) + 1e-12);
        }
    }

    #[test]
    fn csc_positions_point_at_each_entry() {
        let entries = [(2, 1, 5.0), (0, 0, 1.0), (1, 1, 3.0), (0, 2, 7.0)];
        let (m, pos) = csc_with_positions(3, 3, &entries);
        for (t, &(_, _, v)) in entries.iter().enumerate() {
            assert_eq!(m.nzval[pos[t]], v);
        }
        assert_eq!(m.colptr, vec![0, 1, 3, 4]);
    }
}
