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
//! | 2 per obstacle and stage | nonneg | bounds of the decay slacks (relaxed programs, below) |
//! | 0 or 2 per obstacle | nonneg | the terminal rows' linear part ([`crate::terminal`]) |
//! | 4 per obstacle and stage | SOC(4) | CBF rows that are cones |
//! | 5 per obstacle, or 3 and then 4 per obstacle | SOC | braking-safe terminal state: segment, or ball ([`crate::terminal`]) |
//!
//! The CBF `H(p_{i+1}) >= (1 - gamma) H(p_i)` (eq. 54) is convexified by replacing
//! `H(p_{i+1})` with its linearization `L` at a reference `p_bar` (`L <= H` everywhere, so
//! this is an inner approximation). Stage 0 has `p_0` as data and is linear; for stage
//! `i >= 1`, `||p_i - o||^2 <= t` with `t = (L(p_{i+1}) + (1 - gamma) r^2) / (1 - gamma)` is
//! the cone `(t + 1, t - 1, 2 (p_i - o)) in SOC(4)`. With `gamma = 1`, or the Euclidean
//! benchmark `H(p_i) >= 0`, every row is the linear `L(p_i) >= 0` on stages `1..=N`.
//!
//! Terminal safety (`mpc.terminal_safety`, [`crate::terminal`]): the last state `z_N`
//! must be able to stop under the DFL's brake without entering a disc, and the CBF's
//! decay may be relaxed by a slack `sigma_i` per obstacle and stage, penalized in the cost
//! and bounded by the linearized barrier: `(1 - gamma) H(p_i) - sigma_i <= L_{i+1}(p_{i+1})`
//! with `0 <= sigma_i <= (1 - gamma) (L_i(p_i) - floor_i)` (at stage 0, `H(p_0)` itself),
//! `floor_i = (1 - gamma)^i min(H(p_0), 0)`. The bound keeps `H(p_i) >= floor_i` at every
//! stage, which is `H >= 0` whenever the robot starts outside the disc: the relaxation
//! trades the decay rate, never the barrier. A step solves the relaxed program only when
//! the program without slacks fails ([`Rows::relaxed`]). The slacks and the
//! terminal rows' variables follow the states and inputs (sparse) or the inputs
//! (condensed).
//!
//! The sparsity pattern depends only on the configuration: [`Assembly`] writes the same
//! entries in the same order every step, and only their values change.
//!
//! Rows the input box implies are left out ([`Rows`]): over every input sequence with
//! `|v| <= v_max`, the states are an affine image of a box, so each row's extreme value
//! has a closed form ([`Span`], [`PositionReach`]). When every row of the position box
//! and the terminal set holds at its extreme, that group is left out for the step; when
//! every row of a disc does, the disc is left out for the solve. The feasible set is the
//! same, the program smaller: one solver per combination (with or without the first
//! group, the number of discs kept, the discs being data, and relaxed or not), all built
//! at setup. In the
//! paper's run the first group is always implied (the box is 10 m away) and the CBF rows
//! are whenever the obstacle is out of reach of the horizon.
//!
//! Condensed formulation (`mpc.qp_form = "condensed"`): the states are eliminated with
//! `z_i = A^i z_0 + sum_{j<i} A^(i-1-j) B v_j` (eq. 52 rolled out, [`Condensing`]), the
//! variables are `x = [v_0, ..., v_{N-1}]`, the zero-cone rows disappear, and every other
//! row above is rewritten in the inputs (its `z_0` part moves into `b`). The objective
//! becomes a dense `2N x 2N` matrix and a linear term `G z_0`. Same program, fewer
//! variables, denser rows.

use crate::terminal::{TerminalBrake, TerminalRows};
use clarabel::algebra::CscMatrix;
use clarabel::solver::SupportedConeT;
use nalgebra::{DMatrix, DVector, Matrix2x4, Matrix4};

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
    /// States eliminated: the solver's variables are the inputs only (the [`Assembly`]
    /// then carries the [`Condensing`]).
    pub condensed: bool,
    /// The braking-safe terminal rows and the decay slacks (`mpc.terminal_safety`).
    pub terminal: Option<TerminalBrake>,
}

impl Layout {
    /// Stage-wise index (the sparse formulation's variable) of component `c` of `z_i`.
    pub fn z(&self, i: usize, c: usize) -> usize {
        4 * i + c
    }
    /// Stage-wise index (the sparse formulation's variable) of component `c` of `v_i`.
    pub fn v(&self, i: usize, c: usize) -> usize {
        4 * (self.horizon + 1) + 2 * i + c
    }
    /// Length of the stage-wise vector `[z_0, ..., z_N, v_0, ..., v_{N-1}]`.
    pub fn stagewise(&self) -> usize {
        4 * (self.horizon + 1) + 2 * self.horizon
    }
    /// Number of the solver's variables of the states and inputs (sparse) or the inputs
    /// (condensed).
    pub fn base_variables(&self) -> usize {
        if self.condensed {
            2 * self.horizon
        } else {
            self.stagewise()
        }
    }
    /// Number of the solver's variables in the program with `rows`: the base ones, and
    /// for its discs the terminal rows' variables and, relaxed, the decay slacks.
    pub fn variables(&self, rows: Rows) -> usize {
        self.base_variables() + self.slacks(rows) + self.terminal_variables(rows.discs)
    }
    /// Decay slacks a relaxed program with `discs` discs has: one per disc and stage, with
    /// terminal safety on a CBF that is not linear.
    pub fn decay_slacks(&self, discs: usize) -> usize {
        if self.terminal.is_some() && !self.linear_barrier {
            discs * self.horizon
        } else {
            0
        }
    }
    /// Decay slacks of the program with `rows`.
    fn slacks(&self, rows: Rows) -> usize {
        if rows.relaxed {
            self.decay_slacks(rows.discs)
        } else {
            0
        }
    }
    /// Variables of the terminal rows for `discs` discs ([`TerminalBrake::variables`]).
    pub fn terminal_variables(&self, discs: usize) -> usize {
        self.terminal.map_or(0, |t| t.variables(discs))
    }
    /// Column of the decay slack of the program's disc `j` at stage `i`, numbered after
    /// the stage-wise vector ([`Assembly::row`] places it after the solver's base
    /// variables).
    pub fn decay_slack(&self, j: usize, i: usize) -> usize {
        self.stagewise() + j * self.horizon + i
    }
    /// Column of the first of the terminal rows' variables in the program with `rows`,
    /// numbered as [`Layout::decay_slack`].
    pub fn terminal_variable(&self, rows: Rows) -> usize {
        self.stagewise() + self.slacks(rows)
    }

    /// The cones, in row order.
    pub fn cones(&self, rows: Rows) -> Vec<SupportedConeT<f64>> {
        let n = self.horizon;
        let (linear_barrier_rows, cone_barriers) =
            barrier_row_counts(n, rows.discs, self.linear_barrier);
        let box_and_terminal = if rows.box_and_terminal {
            4 * (n - 1) + self.terminal_rows
        } else {
            0
        };
        let terminal_rows = self.terminal.map_or(0, |t| t.nonnegative_rows(rows.discs));
        let inequalities =
            4 * n + box_and_terminal + linear_barrier_rows + 2 * self.slacks(rows) + terminal_rows;
        let mut cones = Vec::with_capacity(3 + cone_barriers + rows.discs);
        if !self.condensed {
            cones.push(SupportedConeT::ZeroConeT(4 + 4 * n));
        }
        cones.push(SupportedConeT::NonnegativeConeT(inequalities));
        cones.extend((0..cone_barriers).map(|_| SupportedConeT::SecondOrderConeT(4)));
        if let Some(t) = self.terminal {
            t.cones(rows.discs, &mut cones);
        }
        cones
    }
}

/// Which rows a solve's program has. Rows are left out when the input box implies them for
/// this solve (every input sequence within the input box satisfies them): the same
/// feasible set, a smaller program. The position box and the terminal set go as one
/// group; the rows of each disc (its CBF rows, decay slacks and terminal rows) go with the
/// disc. The discs are data, so one program serves any `discs` of them. With terminal
/// safety a step first solves the program without decay slacks and, only if that fails
/// (infeasible, or the solver stalls), the relaxed one: the decay is relaxed only where
/// braking needs it. (The relaxed program is a relaxation: its slacks' bounds ask
/// `L_i(p_i) >= floor_i`, which the unrelaxed rows imply stage by stage.) One solver per
/// combination, at most `4 (M + 1)` for `M` obstacles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rows {
    /// The position box on `z_1 .. z_{N-1}` and the terminal set
    /// ([`StaticData::box_and_terminal_implied`]).
    pub box_and_terminal: bool,
    /// Discs whose rows are in the program ([`Barrier::implied`] is false for them).
    pub discs: usize,
    /// The CBF's decay relaxed by slacks ([`Layout::decay_slacks`]).
    pub relaxed: bool,
}

impl Rows {
    /// Every row of a layout, relaxed if it can be.
    pub fn all(l: &Layout) -> Rows {
        Rows {
            box_and_terminal: true,
            discs: l.obstacles,
            relaxed: l.decay_slacks(l.obstacles) > 0,
        }
    }

    /// Every combination of a layout (a program is relaxed only if it has slacks).
    pub fn every(l: &Layout) -> impl Iterator<Item = Rows> {
        (0..=l.obstacles).flat_map(move |discs| {
            let relaxed = l.decay_slacks(discs) > 0;
            [(false, false), (true, false), (false, true), (true, true)]
                .into_iter()
                .filter(move |&(r, _)| relaxed || !r)
                .map(move |(relaxed, box_and_terminal)| Rows {
                    box_and_terminal,
                    discs,
                    relaxed,
                })
        })
    }

    /// Index in `0..Rows::count(l)`.
    pub fn index(self) -> usize {
        4 * self.discs + 2 * usize::from(self.relaxed) + usize::from(self.box_and_terminal)
    }

    /// Number of indices for a layout.
    pub fn count(l: &Layout) -> usize {
        4 * (l.obstacles + 1)
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

/// Cost per m^2 of decay slack in a relaxed program (solved only when the unrelaxed one is
/// infeasible): a linear penalty, so the decay is relaxed no more than the multipliers of
/// the CBF rows make worth it. They reach about 1e4 in the paper's run, whose cost is in
/// the thousands while the robot is metres from the goal; with 1e6 clarabel, without
/// equilibration, reported a feasible program infeasible. A slack's multiplier can reach
/// this weight, so the solver's feasibility tolerance (1e-6) moves the cost by up to about
/// 0.1.
pub const DECAY_SLACK_WEIGHT: f64 = 1e5;

/// clarabel's settings for every MPC subproblem: what the accuracy needs and no more
/// (measured with callgrind on the paper run, instructions per MPC step, README): no
/// iterative refinement of the KKT solves (their residual products were half the work),
/// no equilibration (the problem is well scaled), a feasibility tolerance of 1e-6
/// instead of 1e-8 (a micrometre on positions in metres: safety is decided by
/// feasibility), and an absolute duality gap of 1e-3 (optimality only: with `R = 100 I`
/// the inputs are then within `sqrt(2e-3 / 200)`, about 3 mm/s^2, of the optimal ones).
/// The relative gap is 1e-7 so that the absolute one decides: the cost includes the
/// large `z_i'Q z_i` of a robot metres from its goal, and a relative 1e-6 of it would
/// allow inputs ten times further from the optimum. The trajectory of the paper run is
/// the same to the millisecond. A solve that stops short of these (`AlmostSolved`,
/// counted as solved) must still be feasible to 1e-6, with a gap of at most 1e-2.
pub fn solver_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettings {
        tol_gap_abs: 1e-3,
        tol_gap_rel: 1e-7,
        reduced_tol_gap_abs: 1e-2,
        reduced_tol_gap_rel: 1e-6,
        ..base_settings()
    }
}

/// The settings [`solver_settings`] starts from, and the nonlinear baseline's as they
/// are (its SQP's step test needs the tighter gap): no iterative refinement, no
/// equilibration, feasibility to 1e-6 (also when `AlmostSolved`), duality gap 1e-6.
pub fn base_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettings {
        verbose: false,
        iterative_refinement_enable: false,
        equilibrate_enable: false,
        tol_gap_abs: 1e-6,
        tol_gap_rel: 1e-6,
        tol_feas: 1e-6,
        reduced_tol_feas: 1e-6,
        ..clarabel::solver::DefaultSettings::default()
    }
}

/// What the MPC keeps clear beyond the obstacles grown by the robot's radius, `m` and
/// `kappa sigma`, for what happens to a plan after the solver: it is met only to the
/// solver's tolerance (about a micrometre), and the DFL realizes it on the robot to a few
/// micrometres more.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanMargin {
    /// The paper's formulation (no safety layer): none.
    None,
    /// Braking-safe plans without the DFL's check: [`protocol::COMMIT_MARGIN_M`] (without
    /// it 10 of 1000 noise-free fuzz worlds touched an obstacle, by up to 11 um).
    Realization,
    /// The DFL checks the plans (`dfl.gatekeeper`): the check's commit margin
    /// ([`protocol::commit_margin_m`]) and a millimetre more, so that the check passes
    /// the MPC's own plans.
    Checked,
}

impl PlanMargin {
    /// The margin of the scenario's safety layers.
    pub fn of(scenario: &protocol::Scenario) -> Self {
        if scenario.dfl.gatekeeper {
            Self::Checked
        } else if scenario.mpc.terminal_safety != protocol::TerminalSafety::None {
            Self::Realization
        } else {
            Self::None
        }
    }

    /// The margin for an estimate with position standard deviation `sigma_m`, m.
    pub fn m(self, sigma_m: f64) -> f64 {
        match self {
            Self::None => 0.0,
            Self::Realization => protocol::COMMIT_MARGIN_M,
            Self::Checked => protocol::commit_margin_m(sigma_m) + 1e-3,
        }
    }
}

/// What every obstacle's radius grows by in the MPC's constraints, m, before the
/// inter-sample term: `obstacle_margin_m` (the robot's radius and the safety margin `m`),
/// `kappa sigma` for an estimate with position standard deviation `sigma_m`, and the
/// [`PlanMargin`].
pub fn obstacle_growth_m(
    obstacle_margin_m: f64,
    kappa: f64,
    sigma_m: f64,
    plan_margin: PlanMargin,
) -> f64 {
    obstacle_margin_m + kappa * sigma_m + plan_margin.m(sigma_m)
}

/// Fills `discs` with the constraint discs of one step: `obstacles` in coordinates
/// relative to `goal`, each radius inflated by `margin_m` (the safety margin and the
/// uncertainty term, [`obstacle_growth_m`]) and by the inter-sample dip. The CBF holds at the sample instants;
/// between two of them the robot moves along a chord of at most
/// `d = |speed| Ts + accel_max Ts^2 / 2`. A segment of length `d` whose end points lie
/// outside radius `R` comes no closer to the centre than `sqrt(R^2 - d^2 / 4)`, so the
/// radius `R = sqrt(r^2 + d^2 / 4)` keeps the path between samples out of radius `r`
/// too: about `r + d^2 / (8 r)` for a large obstacle (0.2 mm at 1 m/s in the paper's
/// scenario), `d / 2` for a point.
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
            radius: radius.hypot(chord / 2.0),
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
    /// The span of each of [`StaticData::box_and_terminal_rows`], with its bound.
    pub box_and_terminal_spans: Vec<(Span, f64)>,
}

/// Up to four `(column, value)` terms of a row on one stage's state.
type StateRow = [Option<(usize, f64)>; 4];

impl StaticData {
    /// The position box on `z_1 .. z_{N-1}` (eq. 53), then the terminal set on `z_N`
    /// (eqs. 45, 47), as rows `sum(value * x[column]) <= bound`.
    pub fn box_and_terminal_rows(&self, l: &Layout) -> impl Iterator<Item = (StateRow, f64)> {
        let position_box = self.position_box;
        let boxes = (1..l.horizon).flat_map(move |i| {
            [(0, 0), (1, 2)].into_iter().flat_map(move |(axis, c)| {
                let [min, max] = position_box[axis];
                let one = |value| [Some((l.z(i, c), value)), None, None, None];
                [(one(1.0), max), (one(-1.0), -min)]
            })
        });
        let n = l.horizon;
        let terminal = self.terminal_set.iter().map(move |&(coeffs, bound)| {
            let terms = std::array::from_fn(|c| (coeffs[c] != 0.0).then(|| (l.z(n, c), coeffs[c])));
            (terms, bound)
        });
        boxes.chain(terminal)
    }

    /// Whether every row of the position box and the terminal set holds, with a margin,
    /// for every input sequence from `z0`.
    pub fn box_and_terminal_implied(&self, z0: [f64; 4]) -> bool {
        self.box_and_terminal_spans
            .iter()
            .all(|(span, bound)| below(span.max(z0), *bound))
    }
}

/// `value <= bound` with a margin (relative 1e-9) against rounding. (A row left out then
/// holds as well as the solver meets the input box, to its feasibility tolerance, as a
/// kept row would.)
pub(crate) fn below(value: f64, bound: f64) -> bool {
    value <= bound - 1e-9 * (1.0 + bound.abs())
}

/// The positions over every input sequence in the input box: `p_i = c_i + D_i v` with
/// `|v| <= v_max` elementwise (eq. 52 rolled out, [`rollout`]), `c_i` the positions with
/// zero inputs from the step's `z_0`.
#[derive(Debug, Clone)]
pub struct PositionReach {
    /// `D`: row `2i + k` is axis `k` of stage `i`'s position, one column per input.
    forced: DMatrix<f64>,
    /// The rows of `F` for the same positions.
    free: DMatrix<f64>,
    v_max: f64,
    /// `c_i` of the step.
    centers: Vec<[f64; 2]>,
    /// The spans of the last state's velocity components `z_N[1]`, `z_N[3]`.
    terminal_velocity: [Span; 2],
    /// The step's `z_0`.
    z0: [f64; 4],
}

impl PositionReach {
    pub fn new(
        l: &Layout,
        (forced, free): (&DMatrix<f64>, &DMatrix<f64>),
        v_max: f64,
    ) -> PositionReach {
        let rows: Vec<usize> = (0..=l.horizon)
            .flat_map(|i| [l.z(i, 0), l.z(i, 2)])
            .collect();
        let velocity = |c| Span::of([(l.z(l.horizon, c), 1.0)], (forced, free), v_max);
        PositionReach {
            forced: forced.select_rows(&rows),
            free: free.select_rows(&rows),
            v_max,
            centers: vec![[0.0; 2]; l.horizon + 1],
            terminal_velocity: [velocity(1), velocity(3)],
            z0: [0.0; 4],
        }
    }

    /// Sets `c_i` from the step's `z_0`.
    pub fn set_initial_state(&mut self, z0: [f64; 4]) {
        self.z0 = z0;
        for (i, center) in self.centers.iter_mut().enumerate() {
            *center =
                std::array::from_fn(|k| (0..4).map(|c| self.free[(2 * i + k, c)] * z0[c]).sum());
        }
    }

    /// The horizon `N`.
    pub fn horizon(&self) -> usize {
        self.centers.len() - 1
    }

    /// The largest speed `|w_N|` of the last state.
    pub fn max_terminal_speed(&self) -> f64 {
        let [x, y] = self
            .terminal_velocity
            .map(|span| span.max(self.z0).max(-span.min(self.z0)));
        x.hypot(y)
    }

    /// `v_max ||sum_k a_k D_i[k] + b_k D_j[k]||_1`: the largest `a'(p_i - c_i) + b'(p_j - c_j)`.
    fn reach(&self, (i, a): (usize, [f64; 2]), (j, b): (usize, [f64; 2])) -> f64 {
        let d = &self.forced;
        let norm: f64 = (0..d.ncols())
            .map(|col| {
                let on_input: f64 = (0..2)
                    .map(|k| a[k] * d[(2 * i + k, col)] + b[k] * d[(2 * j + k, col)])
                    .sum();
                on_input.abs()
            })
            .sum();
        self.v_max * norm
    }

    /// `min g'p_i`.
    pub fn min_linear(&self, i: usize, g: [f64; 2]) -> f64 {
        let c = self.centers[i];
        g[0] * c[0] + g[1] * c[1] - self.reach((i, g), (i, [0.0; 2]))
    }

    /// An upper bound of `||p_i - o||^2 - h'p_j`: with `p_i - o = (c_i - o) + e`, the
    /// part linear in the inputs at its largest, and `||e||^2` at most the sum of each
    /// axis' largest `e_k^2`.
    fn max_squared_distance_minus_linear(
        &self,
        i: usize,
        o: [f64; 2],
        (j, h): (usize, [f64; 2]),
    ) -> f64 {
        let (ci, cj) = (self.centers[i], self.centers[j]);
        let offset = [ci[0] - o[0], ci[1] - o[1]];
        let at_center = offset[0].powi(2) + offset[1].powi(2) - h[0] * cj[0] - h[1] * cj[1];
        let linear = self.reach((i, offset.map(|x| 2.0 * x)), (j, h.map(|x| -x)));
        let quadratic: f64 = (0..2)
            .map(|k| {
                let axis = if k == 0 { [1.0, 0.0] } else { [0.0, 1.0] };
                self.reach((i, axis), (i, [0.0; 2])).powi(2)
            })
            .sum();
        at_center + linear + quadratic
    }
}

/// The values a linear function `a' z_i` of one stage's state takes over every input
/// sequence in the input box: with `z_i = F_i z_0 + T_i v` ([`rollout`]) and
/// `|v| <= v_max` elementwise, exactly the interval `(F_i' a)' z_0 +- v_max ||T_i' a||_1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Span {
    /// `F_i' a`.
    free: [f64; 4],
    /// `v_max ||T_i' a||_1`.
    reach: f64,
}

impl Span {
    /// The span of `sum(value * x_stagewise[column])` through `(T, F)` of [`rollout`].
    pub fn of(
        terms: impl IntoIterator<Item = (usize, f64)>,
        (forced, free): (&DMatrix<f64>, &DMatrix<f64>),
        v_max: f64,
    ) -> Span {
        let mut on_inputs = vec![0.0; forced.ncols()];
        let mut on_z0 = [0.0; 4];
        for (column, value) in terms {
            for (j, x) in on_inputs.iter_mut().enumerate() {
                *x += value * forced[(column, j)];
            }
            for (c, x) in on_z0.iter_mut().enumerate() {
                *x += value * free[(column, c)];
            }
        }
        Span {
            free: on_z0,
            reach: v_max * on_inputs.iter().map(|x| x.abs()).sum::<f64>(),
        }
    }

    /// The value with zero inputs.
    fn center(&self, z0: [f64; 4]) -> f64 {
        self.free.iter().zip(z0).map(|(f, z)| f * z).sum()
    }

    /// The largest value.
    pub fn max(&self, z0: [f64; 4]) -> f64 {
        self.center(z0) + self.reach
    }

    /// The smallest value.
    pub fn min(&self, z0: [f64; 4]) -> f64 {
        self.center(z0) - self.reach
    }
}

/// The stage-wise vector as an affine map of the inputs and `z_0` (eq. 52 rolled out):
/// `[z_0, ..., z_N, v] = T v + F z_0`, `z_i = A^i z_0 + sum_{j<i} A^(i-1-j) B v_j`.
/// Returns `(T, F)`.
pub fn rollout(
    l: &Layout,
    a: &Matrix4<f64>,
    b: &nalgebra::Matrix4x2<f64>,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let (n, rows, nv) = (l.horizon, l.stagewise(), 2 * l.horizon);
    let mut forced = DMatrix::zeros(rows, nv);
    let mut free = DMatrix::zeros(rows, 4);
    free.view_mut((0, 0), (4, 4))
        .copy_from(&Matrix4::identity());
    // z_i = A z_{i-1} + B v_{i-1}, row block by row block.
    for i in 1..=n {
        let previous = forced.view((l.z(i - 1, 0), 0), (4, nv)).into_owned();
        let previous_free = free.view((l.z(i - 1, 0), 0), (4, 4)).into_owned();
        free.view_mut((l.z(i, 0), 0), (4, 4))
            .copy_from(&(a * previous_free));
        let mut block = forced.view_mut((l.z(i, 0), 0), (4, nv));
        block.copy_from(&(a * previous));
        block.view_mut((0, 2 * (i - 1)), (4, 2)).copy_from(b);
    }
    for j in 0..nv {
        forced[(l.v(0, 0) + j, j)] = 1.0;
    }
    (forced, free)
}

/// What changes each step.
#[derive(Debug, Clone, Copy)]
pub struct StepData<'a> {
    /// Goal-relative `z_0`.
    pub z0: [f64; 4],
    pub discs: &'a [Disc],
    /// Linearization points `p_bar_1 ..= p_bar_N` (index 0 is unused).
    pub reference: &'a [[f64; 2]],
    /// The reference's last velocity `w_bar_N` (for the terminal rows).
    pub reference_velocity: [f64; 2],
    /// The largest `|w_N|` any input sequence in the box reaches from `z0`
    /// ([`PositionReach::max_terminal_speed`]), m/s.
    pub max_terminal_speed: f64,
}

impl<'a> StepData<'a> {
    /// What the step's CBF rows are built from, in a program `relaxed` or not.
    pub fn barrier(&self, l: &Layout, s: &StaticData, relaxed: bool) -> Barrier<'a> {
        let rows = Rows {
            box_and_terminal: false,
            discs: self.discs.len(),
            relaxed,
        };
        Barrier {
            horizon: l.horizon,
            linear: l.linear_barrier,
            gamma: s.gamma,
            discs: self.discs,
            reference: self.reference,
            p0: [self.z0[0], self.z0[2]],
            decay_slacks: (l.slacks(rows) > 0).then(|| l.decay_slack(0, 0)),
            terminal: l.terminal.filter(|_| !self.discs.is_empty()).map(|model| {
                let n = l.horizon;
                let p_bar = self.reference[n];
                let w_bar = self.reference_velocity;
                TerminalRows {
                    model,
                    discs: self.discs,
                    reference: [p_bar[0], w_bar[0], p_bar[1], w_bar[1]],
                    p0: [self.z0[0], self.z0[2]],
                    position: [l.z(n, 0), l.z(n, 2)],
                    velocity: [l.z(n, 1), l.z(n, 3)],
                    first_variable: l.terminal_variable(rows),
                    max_speed: self.max_terminal_speed,
                    floor_share: if l.linear_barrier {
                        0.0
                    } else {
                        (1.0 - s.gamma).powi(n as i32)
                    },
                }
            }),
        }
    }
}

/// The rows of `A` and `b`, written in a fixed order; buffers are reused between steps.
/// Rows are given in stage-wise columns ([`Layout::z`], [`Layout::v`]); with a
/// [`Condensing`] they are rewritten in the inputs as they are appended.
#[derive(Debug, Default)]
pub struct Assembly {
    /// `(row, column, value)` of every structural entry of `A`, in a fixed order.
    pub entries: Vec<(usize, usize, f64)>,
    pub b: Vec<f64>,
    /// The objective's linear term `q` (empty: zero).
    pub q: Vec<f64>,
    /// Set for the condensed formulation.
    pub condensing: Option<Condensing>,
}

impl Assembly {
    /// Appends the row `sum(value * x[column]) + s = b`.
    pub fn row(&mut self, terms: impl IntoIterator<Item = (usize, f64)>, b: f64) {
        let r = self.b.len();
        let b = match &mut self.condensing {
            Some(condensing) => condensing.rewrite(r, terms, b, &mut self.entries),
            None => {
                self.entries
                    .extend(terms.into_iter().map(|(c, v)| (r, c, v)));
                b
            }
        };
        self.b.push(b);
    }

    /// Writes every row of the step's problem (see the module docs for the order), and
    /// the objective's linear term.
    pub fn fill(&mut self, l: &Layout, s: &StaticData, d: &StepData, rows: Rows) {
        self.entries.clear();
        self.b.clear();
        let n = l.horizon;
        if let Some(condensing) = &mut self.condensing {
            condensing.set_initial_state(d.z0, &mut self.q);
        } else {
            self.q.clear();
            self.equality_rows(l, s, d.z0);
        }
        debug_assert_eq!(
            rows.discs,
            d.discs.len(),
            "a program's discs are the step's"
        );
        let variables = l.variables(rows);
        if variables > l.base_variables() {
            // The decay slacks' cost; the terminal rows' variables (after them) cost
            // nothing.
            self.q.resize(l.base_variables(), 0.0);
            self.q.resize(variables, 0.0);
            let slacks = l.base_variables()..l.base_variables() + l.slacks(rows);
            self.q[slacks].fill(DECAY_SLACK_WEIGHT);
        }
        for i in 0..n {
            for c in 0..2 {
                self.row([(l.v(i, c), 1.0)], s.v_max);
                self.row([(l.v(i, c), -1.0)], s.v_max);
            }
        }
        if rows.box_and_terminal {
            for (terms, bound) in s.box_and_terminal_rows(l) {
                self.row(terms.into_iter().flatten(), bound);
            }
        }
        self.barrier(&d.barrier(l, s, rows.relaxed), |i| [l.z(i, 0), l.z(i, 2)]);
    }

    /// Adds `value` to the objective's linear term at each stage-wise `column` (rewritten
    /// in the inputs when condensed: `T' q`). The term is written even when `terms` is
    /// empty, so a solver that tracked a reference before is given zeros.
    pub fn add_linear_cost(&mut self, l: &Layout, terms: &[(usize, f64)]) {
        if self.q.len() < l.base_variables() {
            self.q.resize(l.base_variables(), 0.0);
        }
        match &self.condensing {
            Some(condensing) => {
                for &(column, value) in terms {
                    let inputs = condensing.forced_transposed.column(column);
                    for (q, t) in self.q.iter_mut().zip(inputs.iter()) {
                        *q += value * t;
                    }
                }
            }
            None => {
                for &(column, value) in terms {
                    self.q[column] += value;
                }
            }
        }
    }

    /// `z_0` = measured state and the dynamics (eq. 52): the zero-cone rows.
    fn equality_rows(&mut self, l: &Layout, s: &StaticData, z0: [f64; 4]) {
        for (c, z) in z0.into_iter().enumerate() {
            self.row([(l.z(0, c), 1.0)], z);
        }
        for i in 0..l.horizon {
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
    }

    /// The CBF rows of eq. (54) (see the module docs): linear rows first, then the decay
    /// slacks' bounds (both in the nonnegative cone), then the SOC(4) rows, then the
    /// braking-safe terminal rows. `position(i)` gives the columns of the position of
    /// stage `i`.
    pub fn barrier(&mut self, b: &Barrier, position: impl Fn(usize) -> [usize; 2]) {
        let n = b.horizon;
        let decay = 1.0 - b.gamma;
        let slack = |j: usize, i: usize| b.decay_slacks.map(|first| first + j * n + i);
        for (j, disc) in b.discs.iter().enumerate() {
            if b.linear {
                // L_i(p_i) >= 0, i = 1..=N.
                for i in 1..=n {
                    let (g, c) = disc.linearized_barrier(b.reference[i]);
                    let [px, py] = position(i);
                    self.row([(px, -g[0]), (py, -g[1])], c);
                }
            } else {
                // (1 - gamma) H(p_0) - sigma_0 <= L_1(p_1).
                let (g, c) = b.first_row(disc);
                let [px, py] = position(1);
                let relaxed = slack(j, 0).map(|s| (s, -1.0));
                self.row(
                    [Some((px, -g[0])), Some((py, -g[1])), relaxed]
                        .into_iter()
                        .flatten(),
                    c,
                );
            }
        }
        if b.decay_slacks.is_some() {
            // 0 <= sigma_i <= (1 - gamma) (L_i(p_i) - floor_i), L_0 = H at the data p_0.
            for (j, disc) in b.discs.iter().enumerate() {
                let h0 = disc.barrier(b.p0);
                for i in 0..n {
                    let Some(column) = slack(j, i) else { continue };
                    let floor = decay.powi(i as i32) * h0.min(0.0);
                    self.row([(column, -1.0)], 0.0);
                    if i == 0 {
                        self.row([(column, 1.0)], decay * (h0 - floor));
                    } else {
                        let (g, c) = disc.linearized_barrier(b.reference[i]);
                        let [px, py] = position(i);
                        let terms = [(column, 1.0), (px, -decay * g[0]), (py, -decay * g[1])];
                        self.row(terms, decay * (c - floor));
                    }
                }
            }
        }
        if let Some(terminal) = &b.terminal {
            terminal.write_nonnegative(self);
        }
        if !b.linear {
            for (j, disc) in b.discs.iter().enumerate() {
                for i in 1..n {
                    // ||p_i - o||^2 <= t0 + h'p_{i+1} + sigma_i / (1 - gamma).
                    let (h, t0) = b.cone_row(disc, i);
                    let [nx, ny] = position(i + 1);
                    let [px, py] = position(i);
                    let relaxed = slack(j, i).map(|s| (s, -1.0 / decay));
                    let slope = [Some((nx, -h[0])), Some((ny, -h[1])), relaxed];
                    self.row(slope.into_iter().flatten(), t0 + 1.0);
                    self.row(slope.into_iter().flatten(), t0 - 1.0);
                    self.row([(px, -2.0)], -2.0 * disc.center[0]);
                    self.row([(py, -2.0)], -2.0 * disc.center[1]);
                }
            }
        }
        if let Some(terminal) = &b.terminal {
            terminal.write_cones(self);
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
    /// Terminal safety: the column of the first decay slack (obstacle `j`, stage `i` at
    /// `first + j N + i`); none without terminal safety or with a linear CBF.
    pub decay_slacks: Option<usize>,
    /// Terminal safety: the braking-safe terminal rows.
    pub terminal: Option<TerminalRows<'a>>,
}

/// The states as affine functions of the inputs (eq. 52 rolled out): the stage-wise
/// vector is `T v + F z_0`, `z_i = A^i z_0 + sum_{j<i} A^(i-1-j) B v_j`. Rewrites rows
/// and the objective of the sparse formulation in the inputs `v` alone.
#[derive(Debug, Clone)]
pub struct Condensing {
    /// `T'` (inputs x stage-wise), so that each stage-wise column is contiguous.
    forced_transposed: DMatrix<f64>,
    /// `F` (stage-wise x 4).
    free: DMatrix<f64>,
    /// Upper triangle of `T' P T`, the objective's quadratic term in the inputs.
    hessian: CscMatrix<f64>,
    /// `G = T' P F`: the objective's linear term is `G z_0`.
    gradient_map: DMatrix<f64>,
    /// `F z_0` of the current step.
    free_response: DVector<f64>,
    /// Scratch for one row: its coefficients on the inputs and which are structural.
    coefficients: Vec<f64>,
    structural: Vec<bool>,
}

impl Condensing {
    /// `stagewise_hessian`: the upper triangle of the sparse formulation's `P`.
    pub fn new(
        l: &Layout,
        (forced, free): (DMatrix<f64>, DMatrix<f64>),
        stagewise_hessian: &CscMatrix<f64>,
    ) -> Condensing {
        let (rows, nv) = (l.stagewise(), 2 * l.horizon);
        let mut p = DMatrix::zeros(rows, rows);
        for col in 0..rows {
            for k in stagewise_hessian.colptr[col]..stagewise_hessian.colptr[col + 1] {
                let row = stagewise_hessian.rowval[k];
                p[(row, col)] = stagewise_hessian.nzval[k];
                p[(col, row)] = stagewise_hessian.nzval[k];
            }
        }
        let p_forced = &p * &forced;
        let hessian = forced.transpose() * &p_forced;
        let entries: Vec<(usize, usize, f64)> = (0..nv)
            .flat_map(|c| (0..=c).map(move |r| (r, c)))
            .map(|(r, c)| (r, c, hessian[(r, c)]))
            .filter(|e| e.2 != 0.0)
            .collect();
        Condensing {
            gradient_map: p_forced.transpose() * &free,
            forced_transposed: forced.transpose(),
            free,
            hessian: csc_with_positions(nv, nv, &entries).0,
            free_response: DVector::zeros(rows),
            coefficients: vec![0.0; nv],
            structural: vec![false; nv],
        }
    }

    /// Upper triangle of the objective's quadratic term in the inputs.
    pub fn hessian(&self) -> &CscMatrix<f64> {
        &self.hessian
    }

    /// Sets the step's `z_0`, and writes the objective's linear term `G z_0` into `q`.
    fn set_initial_state(&mut self, z0: [f64; 4], q: &mut Vec<f64>) {
        let z0 = nalgebra::Vector4::from(z0);
        self.free_response.gemv(1.0, &self.free, &z0, 0.0);
        q.resize(self.gradient_map.nrows(), 0.0);
        for (r, q) in q.iter_mut().enumerate() {
            *q = (0..4).map(|c| self.gradient_map[(r, c)] * z0[c]).sum();
        }
    }

    /// Appends to `entries` the row `sum(value * x_stagewise[column]) + s = b`, in the
    /// inputs, and returns its right-hand side `b - sum(value * (F z_0)[column])`.
    /// The structure comes from `T` alone, so it is the same every step.
    fn rewrite(
        &mut self,
        row: usize,
        terms: impl IntoIterator<Item = (usize, f64)>,
        b: f64,
        entries: &mut Vec<(usize, usize, f64)>,
    ) -> f64 {
        let mut b = b;
        let stagewise = self.free_response.len();
        for (column, value) in terms {
            if column >= stagewise {
                // A variable after the states and inputs (a decay slack, the stop
                // speed): it follows the inputs.
                entries.push((row, self.coefficients.len() + column - stagewise, value));
                continue;
            }
            b -= value * self.free_response[column];
            for (j, &t) in self.forced_transposed.column(column).iter().enumerate() {
                if t != 0.0 {
                    self.coefficients[j] += value * t;
                    self.structural[j] = true;
                }
            }
        }
        for j in 0..self.coefficients.len() {
            if std::mem::take(&mut self.structural[j]) {
                entries.push((row, j, std::mem::take(&mut self.coefficients[j])));
            }
        }
        b
    }

    /// The stage-wise vector `T v + F z_0` of the inputs `v` (the step's `z_0`).
    pub fn expand(&self, v: &[f64], stagewise: &mut [f64]) {
        for (r, out) in stagewise.iter_mut().enumerate() {
            *out = self.free_response[r]
                + v.iter()
                    .enumerate()
                    .map(|(j, v)| self.forced_transposed[(j, r)] * v)
                    .sum::<f64>();
        }
    }
}

impl Barrier<'_> {
    /// Stage 0's row `(1 - gamma) H(p_0) <= L_1(p_1)` (`p_0` being data) as
    /// `g'p_1 + c >= 0`: returns `(g, c)`.
    fn first_row(&self, disc: &Disc) -> ([f64; 2], f64) {
        let (g, c) = disc.linearized_barrier(self.reference[1]);
        (g, c - (1.0 - self.gamma) * disc.barrier(self.p0))
    }

    /// Stage `i`'s cone (`1 <= i < N`), `||p_i - o||^2 <= t0 + h'p_{i+1}` with
    /// `t0 + h'p = (L_{i+1}(p) + (1 - gamma) r^2) / (1 - gamma)`: returns `(h, t0)`.
    fn cone_row(&self, disc: &Disc, i: usize) -> ([f64; 2], f64) {
        let decay = 1.0 - self.gamma;
        let (g, c) = disc.linearized_barrier(self.reference[i + 1]);
        (
            g.map(|x| x / decay),
            (c + decay * disc.radius.powi(2)) / decay,
        )
    }

    /// Whether every CBF row holds, with a margin, for every input sequence in the input
    /// box ([`PositionReach`]): a linear row `g'p_i + c >= 0` when its minimum over the
    /// inputs is positive; a cone row `||p_i - o||^2 <= t0 + s g'p_{i+1}` when an upper
    /// bound of `||p_i - o||^2 - s g'p_{i+1}` is below `t0`.
    pub fn implied(&self, reach: &PositionReach) -> bool {
        self.cbf_implied(reach) && self.terminal.is_none_or(|t| t.implied(reach))
    }

    /// [`Barrier::implied`] for the CBF rows (with zero decay slacks).
    fn cbf_implied(&self, reach: &PositionReach) -> bool {
        let n = self.horizon;
        self.discs.iter().all(|disc| {
            let lowest = |i: usize| {
                let (g, c) = disc.linearized_barrier(self.reference[i]);
                reach.min_linear(i, g) + c
            };
            if self.linear {
                return (1..=n).all(|i| below(0.0, lowest(i)));
            }
            let (g, c) = self.first_row(disc);
            below(0.0, reach.min_linear(1, g) + c)
                && (1..n).all(|i| {
                    let (h, t0) = self.cone_row(disc, i);
                    let largest =
                        reach.max_squared_distance_minus_linear(i, disc.center, (i + 1, h));
                    below(largest, t0)
                })
        })
    }
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

/// A clarabel solver for a problem whose sparsity never changes: built from one
/// assembly, afterwards only its values are updated (`update_A`, `update_b`, `update_q`).
///
/// Every program has a careful twin, built with it: clarabel's equilibration and
/// iterative refinement of the KKT solves on (the settings leave both off for speed:
/// README, Performance). It solves only when the plain solve stalls (`NumericalError`,
/// `InsufficientProgress`, the primal residual stuck at 1e-6 to 1e-3: seen with the
/// terminal rows where several discs squeeze the plan, and at Ts = 10 ms, where the inputs
/// move the positions of a short horizon by millimetres). Either switch on every solve
/// doubles the paper run's solve time; either alone in the twin left stalls. clarabel
/// equilibrates once, at the build, and re-applies that scaling to every update: the
/// twin's scaling is that of the setup's data, not of the stalled step's (it still
/// finished every stall in the tests and the fuzz batches).
pub struct ConicSolver {
    settings: fn() -> clarabel::solver::DefaultSettings<f64>,
    solver: Option<clarabel::solver::DefaultSolver<f64>>,
    careful: Option<clarabel::solver::DefaultSolver<f64>>,
    /// Whether the last solution is the careful twin's.
    careful_last: bool,
    /// Where each [`Assembly`] entry sits in the CSC values.
    nz_position: Vec<usize>,
    nzval: Vec<f64>,
}

impl ConicSolver {
    pub fn new(settings: fn() -> clarabel::solver::DefaultSettings<f64>) -> ConicSolver {
        ConicSolver {
            settings,
            solver: None,
            careful: None,
            careful_last: false,
            nz_position: Vec::new(),
            nzval: Vec::new(),
        }
    }

    /// Solves the problem of `assembly` (the pattern it was built with), on the careful
    /// twin if the plain solve stalls. Returns the plan status and the
    /// interior-point iterations of both.
    pub fn solve(&mut self, assembly: &Assembly) -> (protocol::PlanStatus, u32) {
        use clarabel::solver::SolverStatus;
        self.careful_last = false;
        for (t, &(_, _, v)) in assembly.entries.iter().enumerate() {
            self.nzval[self.nz_position[t]] = v;
        }
        let Some((status, mut iterations)) = solve_with(&mut self.solver, &self.nzval, assembly)
        else {
            return (protocol::PlanStatus::NumericalError, 0);
        };
        let mut status = status;
        if matches!(
            status,
            SolverStatus::NumericalError | SolverStatus::InsufficientProgress
        ) && let Some((twin, twin_iterations)) =
            solve_with(&mut self.careful, &self.nzval, assembly)
        {
            self.careful_last = true;
            (status, iterations) = (twin, iterations + twin_iterations);
        }
        (crate::plan_status(status), iterations)
    }

    /// Builds the solver (and its careful twin) for the pattern of `assembly` (kept
    /// from then on) and solves once, so that clarabel's bookkeeping is in place before
    /// the next solve ([`timers_kept_between_solves`]). False if clarabel refuses the
    /// data.
    pub fn build(
        &mut self,
        assembly: &Assembly,
        variables: usize,
        objective: &CscMatrix<f64>,
        cones: &[SupportedConeT<f64>],
    ) -> bool {
        let (a, positions) = csc_with_positions(assembly.b.len(), variables, &assembly.entries);
        self.nzval = a.nzval.clone();
        self.nz_position = positions;
        let q = if assembly.q.is_empty() {
            vec![0.0; variables]
        } else {
            assembly.q.clone()
        };
        let built = |settings: clarabel::solver::DefaultSettings<f64>| {
            debug_assert!(
                settings.time_limit.is_infinite(),
                "clarabel's clock runs from the build (timers_kept_between_solves)"
            );
            let solver = clarabel::solver::DefaultSolver::new(
                objective,
                &q,
                &a,
                &assembly.b,
                cones,
                settings,
            );
            solver.ok().map(|mut solver| {
                use clarabel::solver::IPSolver;
                solver.timers = Some(timers_kept_between_solves());
                solver.solve();
                solver
            })
        };
        self.solver = built((self.settings)());
        self.careful = built(clarabel::solver::DefaultSettings {
            equilibrate_enable: true,
            iterative_refinement_enable: true,
            ..(self.settings)()
        });
        self.solver.is_some() && self.careful.is_some()
    }

    pub fn is_built(&self) -> bool {
        self.solver.is_some()
    }

    /// The last solution's variables (none before the first solve).
    pub fn x(&self) -> Option<&[f64]> {
        let last = if self.careful_last {
            &self.careful
        } else {
            &self.solver
        };
        last.as_ref().map(|s| s.solution.x.as_slice())
    }
}

/// Writes the values (`nzval` of `A`, and `b`, `q` of `assembly`) into `solver` and solves;
/// `None` if it is not built or refuses them.
#[allow(clippy::ptr_arg)] // clarabel's `update_A` takes a `Vec`, not a slice (it needs `Sized`)
fn solve_with(
    solver: &mut Option<clarabel::solver::DefaultSolver<f64>>,
    nzval: &Vec<f64>,
    assembly: &Assembly,
) -> Option<(clarabel::solver::SolverStatus, u32)> {
    use clarabel::solver::IPSolver;
    let solver = solver.as_mut()?;
    solver
        .update_A(nzval)
        .and_then(|()| solver.update_b(&assembly.b))
        .and_then(|()| {
            if assembly.q.is_empty() {
                Ok(())
            } else {
                solver.update_q(&assembly.q)
            }
        })
        .ok()?;
    solver.solve();
    Some((solver.solution.status, solver.solution.iterations))
}

/// clarabel's timers, arranged so that `solve()` allocates nothing once it has run once.
///
/// clarabel 0.11 starts every `solve()` by resetting its root-level "solve" timer, which
/// drops the timers nested in it with their hash maps and rebuilds them during the solve:
/// heap allocations in every solve, with no setting to turn timing off. Here a frame
/// timer is left open around the solver's own timers, so "solve" and everything under it
/// nest inside the frame and survive; the reset then hits an empty root-level "solve".
/// The cost: clarabel's `info.solve_time` becomes the wall time since the build, which
/// would trip any finite `time_limit` (none is set: `build` checks it in debug builds);
/// this crate times its steps itself.
fn timers_kept_between_solves() -> clarabel::timers::Timers {
    let mut timers = clarabel::timers::Timers::default();
    timers.start_as_current("scmpc frame");
    timers
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
    fn the_plan_margin_follows_the_safety_layers() {
        let with = |sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            PlanMargin::of(&protocol::Scenario::default().with_overrides(&sets).unwrap())
        };
        let paper = with(&["mpc.terminal_safety=none", "dfl.gatekeeper=false"]);
        assert_eq!(paper, PlanMargin::None);
        assert_eq!(paper.m(0.02), 0.0, "the paper's formulation exactly");
        let unchecked = with(&["dfl.gatekeeper=false"]);
        assert_eq!(unchecked, PlanMargin::Realization);
        assert_eq!(unchecked.m(0.02), protocol::COMMIT_MARGIN_M);
        for sets in [&[][..], &["mpc.terminal_safety=none"][..]] {
            let checked = with(sets);
            assert_eq!(checked, PlanMargin::Checked);
            // Outside the check's commit margin, so the check passes the MPC's own plans.
            assert!(checked.m(0.02) > protocol::commit_margin_m(0.02));
        }
    }

    #[test]
    fn no_chord_between_two_samples_outside_the_constraint_disc_enters_the_obstacle() {
        for radius in [0.0, 0.05, 1.5] {
            for speed in [0.0, 0.5, 3.0] {
                let (ts, accel_max) = (0.05, 4.0);
                let chord = speed * ts + 0.5 * accel_max * ts * ts;
                let obstacle = protocol::Obstacle {
                    x: 1.0,
                    y: 2.0,
                    radius,
                };
                let mut discs = Vec::new();
                constraint_discs(&[obstacle], [0.0; 2], 0.0, speed, ts, accel_max, &mut discs);
                let disc = discs[0];
                // Segments of the longest length with both ends on the constraint circle
                // (the deepest any chord of at most that length reaches), all directions.
                for k in 0..360 {
                    let phi = f64::from(k).to_radians();
                    let half_angle = (chord / (2.0 * disc.radius)).min(1.0).asin();
                    let end = |a: f64| {
                        let r = disc.radius;
                        [disc.center[0] + r * a.cos(), disc.center[1] + r * a.sin()]
                    };
                    let (a, b) = (end(phi - half_angle), end(phi + half_angle));
                    let closest = (0..=100)
                        .map(|t| {
                            let t = f64::from(t) / 100.0;
                            let p = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
                            (p[0] - disc.center[0]).hypot(p[1] - disc.center[1])
                        })
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        closest >= radius - 1e-12,
                        "r {radius}, speed {speed}: a chord reaches {closest} m from the centre"
                    );
                }
            }
        }
    }

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
