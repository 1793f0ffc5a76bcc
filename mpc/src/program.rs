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
//! | 3 (ball), then 3 more, then 5 (segment) or 4 (ball) per obstacle | SOC | braking-safe terminal state: the ball's `tau >= \|w_N\|`; with a tracker, `tau` (segment) and `sigma` of the sweep over the plan's own stop; one cone per disc ([`crate::terminal`]) |
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
//! the program without slacks fails ([`crate::layout::Rows::relaxed`]). The slacks and the
//! terminal rows' variables follow the states and inputs (sparse) or the inputs
//! (condensed).
//!
//! The sparsity pattern depends only on the configuration: [`fill`] writes the same
//! entries in the same order every step, and only their values change.
//!
//! Rows the input box implies are left out ([`crate::layout::Rows`]): over every input sequence with
//! `|v| <= v_max`, the states are an affine image of a box, so each row's extreme value
//! has a closed form ([`crate::reach::Span`], [`PositionReach`]). When every row of the position box
//! and the terminal set holds at its extreme, that group is left out for the step; when
//! every row of a disc does, the disc is left out for the solve, and when its CBF rows do,
//! the disc is in the program with its terminal rows only. The feasible set is the
//! same, the program smaller: one solver per combination (with or without the first
//! group, the number of discs kept whole and with their terminal rows only, the discs
//! being data, and relaxed or not), all built at setup. In the
//! paper's run the first group is always implied (the box is 10 m away) and the CBF rows
//! are whenever the obstacle is out of reach of the horizon. A disc the input box does not
//! rule out may still be deferred for a solve, when it lies away from the reference, and
//! joins the program only if the solution runs into it ([`crate::linear`]'s
//! `LinearMpc::solve_once`): a relaxation checked at its solution, so the same optimum.
//! So may its CBF rows alone, the disc keeping its terminal rows.
//!
//! Condensed formulation (`mpc.qp_form = "condensed"`): the states are eliminated with
//! `z_i = A^i z_0 + sum_{j<i} A^(i-1-j) B v_j` (eq. 52 rolled out, [`crate::assembly::Condensing`]), the
//! variables are `x = [v_0, ..., v_{N-1}]`, the zero-cone rows disappear, and every other
//! row above is rewritten in the inputs (its `z_0` part moves into `b`). The objective
//! becomes a dense `2N x 2N` matrix and a linear term `G z_0`. Same program, fewer
//! variables, denser rows.

use crate::assembly::Assembly;
use crate::brake::TerminalBrake;
use crate::layout::{Layout, Rows};
use crate::reach::{PositionReach, Span, below};
use crate::terminal::TerminalRows;
use crate::terminal_set::{Bound, SetRow};
use nalgebra::{Matrix2x4, Matrix4};
use protocol::Disc;

/// Cost per m^2 of decay slack in a relaxed program (solved only when the unrelaxed one is
/// infeasible): a linear penalty, so the decay is relaxed no more than the multipliers of
/// the CBF rows make worth it. They reach about 1e4 in the paper's run, whose cost is in
/// the thousands while the robot is metres from the goal; with 1e6 clarabel, without
/// equilibration, reported a feasible program infeasible. A slack's multiplier can reach
/// this weight, so the solver's feasibility tolerance (1e-6) moves the cost by up to about
/// 0.1.
pub const DECAY_SLACK_WEIGHT: f64 = 1e5;

/// Everything fixed by the configuration.
#[derive(Debug, Clone)]
pub struct StaticData {
    pub a: Matrix4<f64>,
    pub b: nalgebra::Matrix4x2<f64>,
    pub k: Matrix2x4<f64>,
    /// The terminal set (eqs. 45, 47) as rows `coeffs' z_N <= bound`, about a sub-goal,
    /// redundant ones removed ([`crate::terminal_set`]).
    pub terminal_set: Vec<SetRow>,
    pub gamma: f64,
    pub v_max: f64,
    /// Goal-relative position box `[min, max]` per axis.
    pub position_box: [[f64; 2]; 2],
    /// The span of each of [`StaticData::box_and_terminal_rows`], with its bound.
    pub box_and_terminal_spans: Vec<(Span, Bound)>,
}

/// Up to four `(column, value)` terms of a row on one stage's state.
type StateRow = [Option<(usize, f64)>; 4];

impl StaticData {
    /// The data of `scenario` with the discretized model `a`, `b` and the LQR gain `k`:
    /// the goal-relative position box, the terminal set about the goal (eqs. 45-2, 47,
    /// redundant rows pruned), `gamma` (1 for the Euclidean constraint); the rows' spans
    /// come with [`StaticData::with_spans`].
    pub fn of(
        scenario: &protocol::Scenario,
        a: Matrix4<f64>,
        b: nalgebra::Matrix4x2<f64>,
        k: Matrix2x4<f64>,
    ) -> StaticData {
        let (c, goal) = (&scenario.mpc, scenario.robot.goal.position);
        let position_box = [
            [c.position_min[0] - goal[0], c.position_max[0] - goal[0]],
            [c.position_min[1] - goal[1], c.position_max[1] - goal[1]],
        ];
        let terminal_set = crate::terminal_set::prune_redundant(crate::terminal_set::terminal_set(
            &k,
            &(a + b * k),
            c.constraint_horizon,
            c.v_max,
            position_box,
        ));
        let euclidean = c.constraint == protocol::ConstraintKind::Euclidean;
        StaticData {
            a,
            b,
            k,
            terminal_set,
            gamma: if euclidean { 1.0 } else { c.gamma },
            v_max: c.v_max,
            position_box,
            box_and_terminal_spans: Vec::new(),
        }
    }

    /// With the span of every position-box and terminal row over the states the inputs
    /// can reach (`reach`: the forced and free responses, [`crate::reach::rollout`]).
    pub fn with_spans(
        mut self,
        layout: &Layout,
        reach: (&nalgebra::DMatrix<f64>, &nalgebra::DMatrix<f64>),
    ) -> StaticData {
        let spans = self
            .box_and_terminal_rows(layout)
            .map(|(terms, bound)| {
                let terms = terms.into_iter().flatten();
                (Span::of(terms, reach, self.v_max), bound)
            })
            .collect();
        self.box_and_terminal_spans = spans;
        self
    }

    /// The position box on `z_1 .. z_{N-1}` (eq. 53), then the terminal set on `z_N`
    /// (eqs. 45, 47), as rows `sum(value * x[column]) <= bound` (the terminal set's bound
    /// moves with the sub-goal, [`crate::terminal_set`]).
    pub fn box_and_terminal_rows(&self, l: &Layout) -> impl Iterator<Item = (StateRow, Bound)> {
        let position_box = self.position_box;
        let boxes = (1..l.horizon).flat_map(move |i| {
            [(0, 0), (1, 2)].into_iter().flat_map(move |(axis, c)| {
                let [min, max] = position_box[axis];
                let one = |value| [Some((l.z(i, c), value)), None, None, None];
                [
                    (one(1.0), Bound::fixed(max)),
                    (one(-1.0), Bound::fixed(-min)),
                ]
            })
        });
        let n = l.horizon;
        let terminal = self.terminal_set.iter().map(move |row| {
            let coeffs = row.coeffs;
            let terms = std::array::from_fn(|c| (coeffs[c] != 0.0).then(|| (l.z(n, c), coeffs[c])));
            (terms, row.bound)
        });
        boxes.chain(terminal)
    }

    /// Whether every row of the position box and the terminal set about `sub_goal` holds,
    /// with a margin, for every input sequence from `z0`.
    pub fn box_and_terminal_implied(&self, z0: [f64; 4], sub_goal: [f64; 2]) -> bool {
        self.box_and_terminal_spans
            .iter()
            .all(|(span, bound)| below(span.max(z0), bound.at(sub_goal)))
    }
}

/// What changes each step.
#[derive(Debug, Clone, Copy)]
pub struct StepData<'a> {
    /// Goal-relative `z_0`.
    pub z0: [f64; 4],
    /// The sub-goal the terminal set is taken about (goal-relative, m;
    /// [`crate::terminal_set::sub_goal`]).
    pub sub_goal: [f64; 2],
    pub discs: &'a [Disc],
    /// Linearization points `p_bar_1 ..= p_bar_N` (index 0 is unused).
    pub reference: &'a [[f64; 2]],
    /// The reference's last velocity `w_bar_N` (for the terminal rows).
    pub reference_velocity: [f64; 2],
    /// The largest `|w_N|` any input sequence in the box reaches from `z0`
    /// ([`PositionReach::max_terminal_speed`]), m/s.
    pub max_terminal_speed: f64,
    /// How long from the step's time the phantoms and standing tracks stand, s
    /// ([`TerminalRows::stand_s`]).
    pub stand_s: f64,
    /// How the tracks among `discs` are predicted ([`TerminalRows::prediction`]).
    pub prediction: crate::discs::Prediction,
    /// Time between two stages, s: a moving disc is taken at each stage's time
    /// ([`Disc::at`]).
    pub stage_s: f64,
    /// Whether the terminal rows carry a moving disc on for the brake's
    /// `rest_lookahead_s` ([`TerminalRows::stop_discs`]); false: passive safety alone.
    pub rest_lookahead: bool,
}

impl<'a> StepData<'a> {
    /// What the step's CBF rows are built from, in the program with `rows`: the CBF rows
    /// of the first `rows.discs` of the step's discs, the terminal rows of all of them.
    pub fn barrier(&self, l: &Layout, s: &StaticData, rows: Rows) -> Barrier<'a> {
        debug_assert_eq!(
            rows.terminal_discs(),
            self.discs.len(),
            "a program's discs are the step's"
        );
        Barrier {
            horizon: l.horizon,
            linear: l.linear_barrier,
            gamma: s.gamma,
            discs: &self.discs[..rows.discs],
            stage_s: self.stage_s,
            stand_s: self.stand_s,
            reference: self.reference,
            p0: [self.z0[0], self.z0[2]],
            decay_slacks: (l.slacks(rows) > 0).then(|| l.decay_slack(0, 0)),
            terminal: l.terminal.filter(|_| !self.discs.is_empty()).map(|model| {
                let n = l.horizon;
                let p_bar = self.reference[n];
                let w_bar = self.reference_velocity;
                TerminalRows {
                    model: match self.rest_lookahead {
                        true => model,
                        false => TerminalBrake {
                            rest_lookahead_s: 0.0,
                            ..model
                        },
                    },
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
                    horizon_s: n as f64 * self.stage_s,
                    stand_s: self.stand_s,
                    prediction: self.prediction,
                }
            }),
        }
    }
}

/// Writes every row of the step's problem (see the module docs for the order), and
/// the objective's linear term.
pub fn fill(asm: &mut Assembly, l: &Layout, s: &StaticData, d: &StepData, rows: Rows) {
    asm.entries.clear();
    asm.b.clear();
    let n = l.horizon;
    if let Some(condensing) = &mut asm.condensing {
        condensing.set_initial_state(d.z0, &mut asm.q);
    } else {
        asm.q.clear();
        equality_rows(asm, l, s, d.z0);
    }
    let variables = l.variables(rows);
    if variables > l.base_variables() {
        // The decay slacks' cost; the terminal rows' variables (after them) cost
        // nothing.
        asm.q.resize(l.base_variables(), 0.0);
        asm.q.resize(variables, 0.0);
        let slacks = l.base_variables()..l.base_variables() + l.slacks(rows);
        asm.q[slacks].fill(DECAY_SLACK_WEIGHT);
    }
    for i in 0..n {
        for c in 0..2 {
            asm.row([(l.v(i, c), 1.0)], s.v_max);
            asm.row([(l.v(i, c), -1.0)], s.v_max);
        }
    }
    if rows.box_and_terminal {
        for (terms, bound) in s.box_and_terminal_rows(l) {
            asm.row(terms.into_iter().flatten(), bound.at(d.sub_goal));
        }
    }
    write_barrier(asm, &d.barrier(l, s, rows), |i| [l.z(i, 0), l.z(i, 2)]);
}

/// `z_0` = measured state and the dynamics (eq. 52): the zero-cone rows.
fn equality_rows(asm: &mut Assembly, l: &Layout, s: &StaticData, z0: [f64; 4]) {
    for (c, z) in z0.into_iter().enumerate() {
        asm.row([(l.z(0, c), 1.0)], z);
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
            asm.row(terms.into_iter().filter(|t| t.1 != 0.0), 0.0);
        }
    }
}

/// The CBF rows of eq. (54) (see the module docs): linear rows first, then the decay
/// slacks' bounds (both in the nonnegative cone), then the SOC(4) rows, then the
/// braking-safe terminal rows. `position(i)` gives the columns of the position of
/// stage `i`.
pub fn write_barrier(asm: &mut Assembly, b: &Barrier, position: impl Fn(usize) -> [usize; 2]) {
    let n = b.horizon;
    let decay = 1.0 - b.gamma;
    let slack = |j: usize, i: usize| b.decay_slacks.map(|first| first + j * n + i);
    for (j, disc) in b.discs.iter().enumerate() {
        if b.linear {
            // L_i(p_i) >= 0, i = 1..=N.
            for i in 1..=n {
                let (g, c) = b.at(disc, i).linearized_barrier(b.reference[i]);
                let [px, py] = position(i);
                asm.row([(px, -g[0]), (py, -g[1])], c);
            }
        } else {
            // (1 - gamma) H(p_0) - sigma_0 <= L_1(p_1).
            let (g, c) = b.first_row(disc);
            let [px, py] = position(1);
            let relaxed = slack(j, 0).map(|s| (s, -1.0));
            asm.row(
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
                asm.row([(column, -1.0)], 0.0);
                if i == 0 {
                    asm.row([(column, 1.0)], decay * (h0 - floor));
                } else {
                    let (g, c) = b.at(disc, i).linearized_barrier(b.reference[i]);
                    let [px, py] = position(i);
                    let terms = [(column, 1.0), (px, -decay * g[0]), (py, -decay * g[1])];
                    asm.row(terms, decay * (c - floor));
                }
            }
        }
    }
    if let Some(terminal) = &b.terminal {
        terminal.write_nonnegative(asm);
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
                asm.row(slope.into_iter().flatten(), t0 + 1.0);
                asm.row(slope.into_iter().flatten(), t0 - 1.0);
                let center = b.at(disc, i).center;
                asm.row([(px, -2.0)], -2.0 * center[0]);
                asm.row([(py, -2.0)], -2.0 * center[1]);
            }
        }
    }
    if let Some(terminal) = &b.terminal {
        terminal.write_cones(asm);
    }
}

/// What the CBF rows of one problem are built from.
#[derive(Debug, Clone, Copy)]
pub struct Barrier<'a> {
    pub horizon: usize,
    /// Every row linear (`gamma = 1` or the Euclidean benchmark).
    pub linear: bool,
    pub gamma: f64,
    /// The discs at stage 0's time.
    pub discs: &'a [Disc],
    /// Time between two stages, s.
    pub stage_s: f64,
    /// How long from the step's time the phantoms and standing tracks stand, s
    /// ([`Disc::staged`]).
    pub stand_s: f64,
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

impl Barrier<'_> {
    /// `disc` at stage `i`'s time: a moving obstacle's predicted disc (eq. 54 with `H`
    /// of the disc at each stage), a disc at rest itself, a phantom's or a standing
    /// track's as it grows until the next tracks are due and held after
    /// ([`Disc::staged`]).
    fn at(&self, disc: &Disc, i: usize) -> Disc {
        disc.staged(i as f64 * self.stage_s, self.stand_s)
    }

    /// Stage 0's row `(1 - gamma) H_0(p_0) <= L_1(p_1)` (`p_0` being data) as
    /// `g'p_1 + c >= 0`: returns `(g, c)`.
    fn first_row(&self, disc: &Disc) -> ([f64; 2], f64) {
        let (g, c) = self.at(disc, 1).linearized_barrier(self.reference[1]);
        (g, c - (1.0 - self.gamma) * disc.barrier(self.p0))
    }

    /// Stage `i`'s cone (`1 <= i < N`), `||p_i - o_i||^2 <= t0 + h'p_{i+1}` with
    /// `t0 + h'p = (L_{i+1}(p) + (1 - gamma) r_i^2) / (1 - gamma)`: returns `(h, t0)`.
    fn cone_row(&self, disc: &Disc, i: usize) -> ([f64; 2], f64) {
        let decay = 1.0 - self.gamma;
        let (g, c) = self
            .at(disc, i + 1)
            .linearized_barrier(self.reference[i + 1]);
        (
            g.map(|x| x / decay),
            (c + decay * self.at(disc, i).radius.powi(2)) / decay,
        )
    }

    /// Whether every CBF row holds, with a margin, for every input sequence in the input
    /// box ([`PositionReach`]): a linear row `g'p_i + c >= 0` when its minimum over the
    /// inputs is positive; a cone row `||p_i - o||^2 <= t0 + s g'p_{i+1}` when an upper
    /// bound of `||p_i - o||^2 - s g'p_{i+1}` is below `t0`.
    pub fn implied(&self, reach: &PositionReach) -> bool {
        self.cbf_implied(reach) && self.terminal_implied(reach)
    }

    /// [`Barrier::implied`] for the terminal rows.
    pub fn terminal_implied(&self, reach: &PositionReach) -> bool {
        self.terminal.is_none_or(|t| t.implied(reach))
    }

    /// Whether the terminal rows fail for every input sequence in `reach`
    /// ([`TerminalRows::impossible`]): no program holding them has a solution.
    pub fn terminal_impossible(&self, reach: &PositionReach) -> bool {
        self.terminal.is_some_and(|t| t.impossible(reach))
    }

    /// [`Barrier::implied`] for the CBF rows (with zero decay slacks).
    pub fn cbf_implied(&self, reach: &PositionReach) -> bool {
        self.discs
            .iter()
            .all(|disc| (0..self.horizon).all(|k| self.stage_implied(disc, k, reach)))
    }

    /// [`Barrier::cbf_implied`] for `disc`'s CBF row of stage `k` (`0..N`): with a
    /// linear barrier `L_{k+1}(p_{k+1}) >= 0`; otherwise stage 0's linear first row, and
    /// for `k >= 1` the cone on `p_k` and `p_{k+1}`.
    fn stage_implied(&self, disc: &Disc, k: usize, reach: &PositionReach) -> bool {
        if self.linear {
            let (g, c) = self
                .at(disc, k + 1)
                .linearized_barrier(self.reference[k + 1]);
            return below(0.0, reach.min_linear(k + 1, g) + c);
        }
        if k == 0 {
            let (g, c) = self.first_row(disc);
            return below(0.0, reach.min_linear(1, g) + c);
        }
        let (h, t0) = self.cone_row(disc, k);
        reach.squared_distance_minus_linear_below(k, self.at(disc, k).center, (k + 1, h), t0)
    }
}
