//! The layout of the MPC's conic program: where each variable sits, how many rows of
//! each cone there are, and which rows a solve's program has ([`Rows`]). The rows
//! themselves, in order, are in [`crate::program`].

use crate::brake::TerminalBrake;
use clarabel::solver::SupportedConeT;

/// Dimensions and the fixed parts of the problem.
#[derive(Debug, Clone)]
pub struct Layout {
    /// Prediction horizon `N`.
    pub horizon: usize,
    /// Rows of the terminal set kept after [`crate::terminal::prune_redundant`].
    pub terminal_rows: usize,
    pub obstacles: usize,
    /// All CBF rows linear (`gamma = 1` or the Euclidean benchmark).
    pub linear_barrier: bool,
    /// States eliminated: the solver's variables are the inputs only (the [`crate::assembly::Assembly`]
    /// then carries the [`crate::assembly::Condensing`]).
    pub condensed: bool,
    /// The braking-safe terminal rows and the decay slacks (`mpc.terminal_safety`).
    pub terminal: Option<TerminalBrake>,
}

impl Layout {
    /// The layout of `scenario`'s program, whose terminal set keeps `terminal_rows` rows.
    pub fn of(scenario: &protocol::Scenario, terminal_rows: usize) -> Layout {
        let c = &scenario.mpc;
        Layout {
            horizon: c.horizon,
            terminal_rows,
            obstacles: scenario.max_obstacle_discs(),
            linear_barrier: c.constraint == protocol::ConstraintKind::Euclidean || c.gamma >= 1.0,
            condensed: c.qp_form.condensed(c.horizon),
            terminal: TerminalBrake::of(scenario),
        }
    }

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
        self.base_variables() + self.slacks(rows) + self.terminal_variables(rows.terminal_discs())
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
    pub fn slacks(&self, rows: Rows) -> usize {
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
    /// the stage-wise vector ([`crate::assembly::Assembly::row`] places it after the solver's base
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
        let terminal_discs = rows.terminal_discs();
        let terminal_rows = self
            .terminal
            .map_or(0, |t| t.nonnegative_rows(terminal_discs));
        let inequalities =
            4 * n + box_and_terminal + linear_barrier_rows + 2 * self.slacks(rows) + terminal_rows;
        let mut cones = Vec::with_capacity(5 + cone_barriers + terminal_discs);
        if !self.condensed {
            cones.push(SupportedConeT::ZeroConeT(4 + 4 * n));
        }
        cones.push(SupportedConeT::NonnegativeConeT(inequalities));
        cones.extend((0..cone_barriers).map(|_| SupportedConeT::SecondOrderConeT(4)));
        if let Some(t) = self.terminal {
            t.cones(terminal_discs, &mut cones);
        }
        cones
    }
}

/// Which rows a solve's program has. Rows are left out when the input box implies them for
/// this solve (every input sequence within the input box satisfies them): the same
/// feasible set, a smaller program. The position box and the terminal set go as one
/// group; a disc's rows in two: its CBF rows with their decay slacks, and its terminal
/// rows. A disc is in the program with both groups, with its terminal rows only (its CBF
/// rows implied, or deferred, [`crate::linear`]), or not at all. The discs are data, so
/// one program serves any discs of each kind. With terminal safety a step first solves
/// the program without decay slacks and, only if that fails (infeasible, or the solver
/// stalls), the relaxed one: the decay is relaxed only where braking needs it. (The
/// relaxed program is a relaxation: its slacks' bounds ask `L_i(p_i) >= floor_i`, which
/// the unrelaxed rows imply stage by stage.) One solver per combination, fewer than
/// `4 (M + 1) (1 + MAX_TERMINAL_ONLY)` for `M` obstacles, all built at setup.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rows {
    /// The position box on `z_1 .. z_{N-1}` and the terminal set
    /// ([`crate::program::StaticData::box_and_terminal_implied`]).
    pub box_and_terminal: bool,
    /// Discs with every row in the program: CBF rows, decay slacks, terminal rows
    /// ([`crate::program::Barrier::implied`] is false for them).
    pub discs: usize,
    /// Discs after those with only their terminal rows in the program (terminal safety
    /// only), at most [`MAX_TERMINAL_ONLY`], and none in a relaxed program: a step that
    /// relaxes the decay does so for every disc it keeps.
    pub terminal_only: usize,
    /// The CBF's decay relaxed by slacks ([`Layout::decay_slacks`]).
    pub relaxed: bool,
}

/// The most discs a program holds with their terminal rows only. A step with more such
/// discs keeps the others whole (a larger program, the same optimum); each one more
/// multiplies the programs built at setup.
pub const MAX_TERMINAL_ONLY: usize = 1;

impl Rows {
    /// One whole disc and nothing else: a disc's rows on their own.
    pub const ONE_DISC: Rows = Rows {
        box_and_terminal: false,
        discs: 1,
        terminal_only: 0,
        relaxed: false,
    };

    /// Every row of a layout, relaxed if it can be.
    pub fn all(l: &Layout) -> Rows {
        Rows {
            box_and_terminal: true,
            discs: l.obstacles,
            terminal_only: 0,
            relaxed: l.decay_slacks(l.obstacles) > 0,
        }
    }

    /// Discs with their terminal rows in the program.
    pub fn terminal_discs(self) -> usize {
        self.discs + self.terminal_only
    }

    /// The most discs a program of `l` holds with their terminal rows only.
    pub fn max_terminal_only(l: &Layout) -> usize {
        if l.terminal.is_some() {
            MAX_TERMINAL_ONLY
        } else {
            0
        }
    }

    /// Every combination of a layout (a program is relaxed only if it has slacks, and
    /// then holds no disc with its terminal rows only).
    pub fn every(l: &Layout) -> impl Iterator<Item = Rows> {
        let discs = (0..=l.obstacles).flat_map(move |discs| {
            let most = Rows::max_terminal_only(l).min(l.obstacles - discs);
            (0..=most).map(move |terminal_only| (discs, terminal_only))
        });
        discs.flat_map(move |(discs, terminal_only)| {
            let relaxed = l.decay_slacks(discs) > 0 && terminal_only == 0;
            [(false, false), (true, false), (false, true), (true, true)]
                .into_iter()
                .filter(move |&(r, _)| relaxed || !r)
                .map(move |(relaxed, box_and_terminal)| Rows {
                    box_and_terminal,
                    discs,
                    terminal_only,
                    relaxed,
                })
        })
    }

    /// Index in `0..Rows::count(l)`.
    pub fn index(self) -> usize {
        let discs = (1 + MAX_TERMINAL_ONLY) * self.discs + self.terminal_only;
        4 * discs + 2 * usize::from(self.relaxed) + usize::from(self.box_and_terminal)
    }

    /// Number of indices for a layout.
    pub fn count(l: &Layout) -> usize {
        4 * (1 + MAX_TERMINAL_ONLY) * (l.obstacles + 1)
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
