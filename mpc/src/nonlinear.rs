//! The nonlinear baseline, SCNMPC (paper eqs. pr3-pr7): MPC with the same CBF on the
//! unicycle itself, solved by sequential conic programming with clarabel.
//!
//! The model is the unicycle with its speed as a state, as the plant is driven here
//! (`s = [x, y, theta, v]`, input `u = [a, omega]`, `a = dv/dt`), so a plan runs through
//! the same DFL as the linear scheme's: the DFL reproduces `a` and `omega` exactly from
//! the z-space accelerations the plan carries. The discrete dynamics are one RK4 step of
//! `Ts` with the input held.
//!
//! Each SQP iteration linearizes the dynamics (central differences) and the CBF (the same
//! rows as the linear scheme, [`Assembly::barrier`]) at the current iterate, limits the
//! input change to a trust region, solves the conic subproblem, and takes the full step;
//! it stops when the inputs move less than [`STEP_TOLERANCE`] or after
//! [`MAX_ITERATIONS`]. The cost (eq. pr3) is the linear scheme's, written on the unicycle:
//! stages `z'Qz + u'Ru` with `z = Phi(s)` (for a diagonal `Q` with equal velocity weights
//! this is `q0 x^2 + q2 y^2 + q1 v^2`; heading is free), and the terminal cost
//! `Phi(s_N)' Q_bar Phi(s_N)` with the linear scheme's `Q_bar`, through extra variables
//! `w = Phi(s_N)` tied to `s_N` by the linearization of `Phi` (Gauss-Newton). Here
//! `R` weighs `[a, omega]`. The terminal set (eq. pr8) is left out.

use crate::assembly::{Assembly, csc_with_positions};
use crate::layout::barrier_row_counts;
use crate::program::{Barrier, write_barrier};
use crate::solver::{CancelSlot, ConicSolver};
use clarabel::algebra::CscMatrix;
use clarabel::solver::SupportedConeT;
use protocol::Disc;
use protocol::task::Cancel;
use protocol::{ConstraintKind, Header, Plan, PlanStatus, Scenario};

/// Largest number of SQP iterations per sample.
pub const MAX_ITERATIONS: usize = 15;
/// Converged when no input moved more than this between iterations (m/s^2, rad/s).
pub const STEP_TOLERANCE: f64 = 1e-3;
/// Largest change of each input in one iteration (m/s^2, rad/s).
pub const TRUST_RADIUS: f64 = 1.0;

/// Structural non-zeros of the dynamics Jacobian `[A | B]` (rows: next state; columns:
/// x, y, theta, v, a, omega).
const JACOBIAN_PATTERN: [[bool; 6]; 4] = [
    [true, false, true, true, true, true],
    [false, true, true, true, true, true],
    [false, false, true, false, false, true],
    [false, false, false, true, true, false],
];

/// Continuous unicycle with speed state: `[v cos theta, v sin theta, omega, a]`.
fn unicycle(s: [f64; 4], u: [f64; 2]) -> [f64; 4] {
    [s[3] * s[2].cos(), s[3] * s[2].sin(), u[1], u[0]]
}

/// One RK4 step of `dt_s` with the input held (eq. pr4).
pub fn step_dynamics(s: [f64; 4], u: [f64; 2], dt_s: f64) -> [f64; 4] {
    let add = |s: [f64; 4], k: [f64; 4], h: f64| std::array::from_fn(|i| s[i] + h * k[i]);
    let k1 = unicycle(s, u);
    let k2 = unicycle(add(s, k1, dt_s / 2.0), u);
    let k3 = unicycle(add(s, k2, dt_s / 2.0), u);
    let k4 = unicycle(add(s, k3, dt_s), u);
    std::array::from_fn(|i| s[i] + dt_s / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
}

/// `[A | B]` of [`step_dynamics`] at `(s, u)` by central differences.
fn jacobian(s: [f64; 4], u: [f64; 2], dt_s: f64) -> [[f64; 6]; 4] {
    let h = 1e-6;
    let mut jac = [[0.0; 6]; 4];
    for c in 0..6 {
        let perturbed = |sign: f64| {
            let (mut s, mut u) = (s, u);
            if c < 4 {
                s[c] += sign * h;
            } else {
                u[c - 4] += sign * h;
            }
            step_dynamics(s, u, dt_s)
        };
        let (plus, minus) = (perturbed(1.0), perturbed(-1.0));
        for r in 0..4 {
            jac[r][c] = (plus[r] - minus[r]) / (2.0 * h);
        }
    }
    jac
}

/// The z-space state and acceleration of the DFL-linearized model for a unicycle state
/// and input: `z = Phi(s)`, `z_dot_dot = [a cos - v omega sin, a sin + v omega cos]`.
pub fn to_flat(s: [f64; 4], u: [f64; 2]) -> ([f64; 4], [f64; 2]) {
    let (sin, cos) = s[2].sin_cos();
    let z = [s[0], s[3] * cos, s[1], s[3] * sin];
    let acc = [
        u[0] * cos - s[3] * u[1] * sin,
        u[0] * sin + s[3] * u[1] * cos,
    ];
    (z, acc)
}

/// The nonlinear MPC.
pub struct NonlinearMpc {
    horizon: usize,
    ts_s: f64,
    gamma: f64,
    linear_barrier: bool,
    /// Bounds of `|a|` (m/s^2) and `|omega|` (rad/s): `mpc.v_max` for both.
    input_max: f64,
    position_box: [[f64; 2]; 2],
    /// Stage weights on `[x, y, theta, v]`, input weights, terminal weight on `Phi(s_N)`.
    q: [f64; 4],
    r: [f64; 2],
    terminal: nalgebra::Matrix4<f64>,
    goal: [f64; 2],
    obstacles: Vec<protocol::Obstacle>,
    /// How every obstacle grows (the robot's radius, the margin `m`, `kappa sigma`).
    growth: protocol::ObstacleGrowth,
    /// What the discs grow by for what follows the solver.
    plan_margin: crate::discs::PlanMargin,
    // Reused every step.
    solver: ConicSolver,
    /// A warm-up's cancel check while one runs ([`NonlinearMpc::warm_up`]).
    cancel: CancelSlot,
    assembly: Assembly,
    discs: Vec<Disc>,
    reference: Vec<[f64; 2]>,
    /// The current iterate: goal-relative states `0..=N` and inputs `0..N`.
    states: Vec<[f64; 4]>,
    inputs: Vec<[f64; 2]>,
    last_sample: Option<u64>,
}

impl NonlinearMpc {
    /// `terminal_weight_z` is the linear scheme's `Q_bar` (on `z`).
    pub fn new(scenario: &Scenario, terminal_weight_z: &nalgebra::Matrix4<f64>) -> NonlinearMpc {
        let c = &scenario.mpc;
        let goal = scenario.robot.goal.position;
        let n = c.horizon;
        let cancel = CancelSlot::default();
        NonlinearMpc {
            horizon: n,
            ts_s: scenario.timing.ts_s,
            gamma: if c.constraint == ConstraintKind::Euclidean {
                1.0
            } else {
                c.gamma
            },
            linear_barrier: c.constraint == ConstraintKind::Euclidean || c.gamma >= 1.0,
            input_max: c.v_max,
            position_box: [
                [c.position_min[0] - goal[0], c.position_max[0] - goal[0]],
                [c.position_min[1] - goal[1], c.position_max[1] - goal[1]],
            ],
            q: [c.q_diag[0], c.q_diag[2], 0.0, c.q_diag[1]],
            r: c.r_diag,
            terminal: *terminal_weight_z,
            goal,
            obstacles: scenario.obstacles.clone(),
            growth: protocol::ObstacleGrowth::of(scenario),
            plan_margin: crate::discs::PlanMargin::of(scenario),
            solver: ConicSolver::new(crate::solver::base_settings, cancel.clone()),
            cancel,
            assembly: Assembly::default(),
            discs: Vec::with_capacity(scenario.obstacles.len()),
            reference: vec![[0.0; 2]; n + 1],
            states: vec![[0.0; 4]; n + 1],
            inputs: vec![[0.0; 2]; n],
            last_sample: None,
        }
    }

    pub fn reset(&mut self) {
        self.last_sample = None;
    }

    /// A warm-up: solves the last subproblem again ([`ConicSolver::solve_again`]), cut
    /// short once `cancel` holds.
    pub fn warm_up(&mut self, cancel: &Cancel) {
        let slot = self.cancel.clone();
        slot.during(cancel, || self.solver.solve_again());
    }

    fn s(&self, i: usize, c: usize) -> usize {
        4 * i + c
    }
    fn u(&self, i: usize, c: usize) -> usize {
        4 * (self.horizon + 1) + 2 * i + c
    }
    /// Component `c` of `w = Phi(s_N)`.
    fn w(&self, c: usize) -> usize {
        6 * self.horizon + 4 + c
    }
    fn variables(&self) -> usize {
        6 * self.horizon + 8
    }

    /// plan(k) from the estimate `x_bar = [x, y, theta, zeta]` (zeta is the speed).
    pub fn step(&mut self, sample: u64, x_bar: [f64; 4], position_sigma_m: f64) -> Plan {
        let s0 = [
            x_bar[0] - self.goal[0],
            x_bar[1] - self.goal[1],
            x_bar[2],
            x_bar[3],
        ];
        let margin =
            crate::discs::obstacle_growth_m(&self.growth, position_sigma_m, self.plan_margin);
        crate::discs::constraint_discs(
            &self.obstacles,
            self.goal,
            margin,
            x_bar[3],
            self.ts_s,
            self.input_max,
            &mut self.discs,
        );
        self.initial_iterate(sample, s0);

        let mut status = PlanStatus::NumericalError;
        let (mut iterations, mut solves) = (0, 0);
        for _ in 0..MAX_ITERATIONS {
            let (sub_status, sub_iterations) = self.solve_subproblem(s0);
            iterations += sub_iterations;
            solves += 1;
            if sub_status != PlanStatus::Solved {
                if solves == 1 {
                    status = sub_status;
                }
                break;
            }
            status = PlanStatus::Solved;
            if self.take_step() < STEP_TOLERANCE {
                break;
            }
        }
        let mut plan = Plan {
            header: Header::default(),
            sample,
            status: status as u32,
            horizon: self.horizon as u32,
            iterations,
            solves,
            ..Plan::default()
        };
        if status == PlanStatus::Solved {
            for i in 0..=self.horizon {
                let u = self.inputs.get(i).copied().unwrap_or([0.0; 2]);
                let (z, acc) = to_flat(self.states[i], u);
                plan.z[i] = [z[0] + self.goal[0], z[1], z[2] + self.goal[1], z[3]];
                if i < self.horizon {
                    plan.v[i] = acc;
                }
            }
            self.last_sample = Some(sample);
        } else {
            self.last_sample = None;
        }
        plan
    }

    /// The previous solution shifted by one sample (last input repeated), or from cold a
    /// rollout braking to rest without turning; in both cases rolled out from `s0`.
    fn initial_iterate(&mut self, sample: u64, s0: [f64; 4]) {
        let warm = self.last_sample.is_some_and(|last| sample == last + 1);
        if warm {
            self.inputs.rotate_left(1);
            let n = self.horizon;
            if n > 1 {
                self.inputs[n - 1] = self.inputs[n - 2];
            }
        }
        let mut s = s0;
        self.states[0] = s0;
        for i in 0..self.horizon {
            if !warm {
                let brake = (-s[3] / self.ts_s).clamp(-self.input_max, self.input_max);
                self.inputs[i] = [brake, 0.0];
            }
            s = step_dynamics(s, self.inputs[i], self.ts_s);
            self.states[i + 1] = s;
        }
    }

    /// Moves the iterate to the subproblem's solution; returns the largest input change.
    fn take_step(&mut self) -> f64 {
        let Some(x) = self.solver.x() else {
            return 0.0;
        };
        let mut moved: f64 = 0.0;
        for i in 0..self.horizon {
            for c in 0..2 {
                let new = x[4 * (self.horizon + 1) + 2 * i + c];
                moved = moved.max((new - self.inputs[i][c]).abs());
                self.inputs[i][c] = new;
            }
        }
        for i in 0..=self.horizon {
            self.states[i] = std::array::from_fn(|c| x[4 * i + c]);
        }
        moved
    }

    /// Fills and solves the conic subproblem at the current iterate.
    fn solve_subproblem(&mut self, s0: [f64; 4]) -> (PlanStatus, u32) {
        for i in 1..=self.horizon {
            self.reference[i] = [self.states[i][0], self.states[i][1]];
        }
        self.fill(s0);
        if !self.solver.is_built() {
            let (objective, cones) = (self.objective(), self.cones());
            let variables = self.variables();
            self.solver
                .build(&self.assembly, variables, &objective, &cones);
        }
        self.solver.solve(&self.assembly)
    }

    fn cones(&self) -> Vec<SupportedConeT<f64>> {
        let n = self.horizon;
        let (linear, socs) = barrier_row_counts(n, self.obstacles.len(), self.linear_barrier);
        let mut cones = vec![
            SupportedConeT::ZeroConeT(4 + 4 * n + 4),
            SupportedConeT::NonnegativeConeT(4 * n + 4 * n + 4 * (n - 1) + linear),
        ];
        cones.extend((0..socs).map(|_| SupportedConeT::SecondOrderConeT(4)));
        cones
    }

    /// Rows: initial state, linearized dynamics (eq. pr4), linearized `w = Phi(s_N)`,
    /// input box (eq. pr6), trust region, position box (eq. pr5), CBF (eq. pr7). Same
    /// entries in the same order every time.
    fn fill(&mut self, s0: [f64; 4]) {
        let n = self.horizon;
        let mut asm = std::mem::take(&mut self.assembly);
        asm.entries.clear();
        asm.b.clear();
        for (c, value) in s0.into_iter().enumerate() {
            asm.row([(self.s(0, c), 1.0)], value);
        }
        for i in 0..n {
            let (s_bar, u_bar) = (self.states[i], self.inputs[i]);
            let jac = jacobian(s_bar, u_bar, self.ts_s);
            let f = step_dynamics(s_bar, u_bar, self.ts_s);
            for r in 0..4 {
                // s_{i+1} - A s_i - B u_i = f - A s_bar - B u_bar
                let mut rhs = f[r];
                let mut terms = [(self.s(i + 1, r), 1.0); 7];
                let mut used = 1;
                for c in (0..6).filter(|&c| JACOBIAN_PATTERN[r][c]) {
                    let (column, at) = if c < 4 {
                        (self.s(i, c), s_bar[c])
                    } else {
                        (self.u(i, c - 4), u_bar[c - 4])
                    };
                    terms[used] = (column, -jac[r][c]);
                    used += 1;
                    rhs -= jac[r][c] * at;
                }
                asm.row(terms.into_iter().take(used), rhs);
            }
        }
        // w - J s_N = Phi(s_bar_N) - J s_bar_N, J the Jacobian of Phi at s_bar_N.
        let s_n = self.states[n];
        let (sin, cos) = s_n[2].sin_cos();
        let (z_n, _) = to_flat(s_n, [0.0; 2]);
        let flat_rows: [[(usize, f64); 2]; 4] = [
            [(0, 1.0), (3, 0.0)],
            [(2, -s_n[3] * sin), (3, cos)],
            [(1, 1.0), (3, 0.0)],
            [(2, s_n[3] * cos), (3, sin)],
        ];
        for (c, jac) in flat_rows.iter().enumerate() {
            let terms = jac.iter().filter(|t| c % 2 == 1 || t.0 != 3);
            let rhs = z_n[c] - terms.clone().map(|&(k, d)| d * s_n[k]).sum::<f64>();
            let row =
                std::iter::once((self.w(c), 1.0)).chain(terms.map(|&(k, d)| (self.s(n, k), -d)));
            asm.row(row, rhs);
        }
        for i in 0..n {
            for c in 0..2 {
                asm.row([(self.u(i, c), 1.0)], self.input_max);
                asm.row([(self.u(i, c), -1.0)], self.input_max);
            }
        }
        for i in 0..n {
            for c in 0..2 {
                let at = self.inputs[i][c];
                asm.row([(self.u(i, c), 1.0)], at + TRUST_RADIUS);
                asm.row([(self.u(i, c), -1.0)], TRUST_RADIUS - at);
            }
        }
        for i in 1..n {
            for axis in 0..2 {
                asm.row([(self.s(i, axis), 1.0)], self.position_box[axis][1]);
                asm.row([(self.s(i, axis), -1.0)], -self.position_box[axis][0]);
            }
        }
        let barrier = Barrier {
            horizon: n,
            linear: self.linear_barrier,
            gamma: self.gamma,
            discs: &self.discs,
            // The baseline knows obstacles at rest only (the validator refuses it with a
            // tracked one): every stage's disc is the same.
            stage_s: 0.0,
            stand_s: 0.0,
            reference: &self.reference,
            p0: [s0[0], s0[1]],
            decay_slacks: None,
            terminal: None,
        };
        write_barrier(&mut asm, &barrier, |i| [4 * i, 4 * i + 1]);
        self.assembly = asm;
    }

    /// `1/2 x'Px` = eq. (pr3): `sum s'Qs + u'Ru + w' Q_bar w` (upper triangle of P).
    fn objective(&self) -> CscMatrix<f64> {
        let n = self.horizon;
        let mut entries = Vec::new();
        for i in 0..n {
            for c in 0..4 {
                entries.push((self.s(i, c), self.s(i, c), 2.0 * self.q[c]));
            }
        }
        for c in 0..4 {
            for r in 0..=c {
                entries.push((self.w(r), self.w(c), 2.0 * self.terminal[(r, c)]));
            }
        }
        for i in 0..n {
            for c in 0..2 {
                entries.push((self.u(i, c), self.u(i, c), 2.0 * self.r[c]));
            }
        }
        csc_with_positions(self.variables(), self.variables(), &entries).0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flat_acceleration_reproduces_the_unicycle_inputs_through_the_dfl_law() {
        let s = [1.0, 2.0, 0.7, 0.8];
        let u = [0.3, -0.4];
        let (z, acc) = to_flat(s, u);
        assert!((z[1].hypot(z[3]) - 0.8).abs() < 1e-12);
        let ([u1, u2], guarded) = dfl_law(s[2], s[3], acc);
        assert!(!guarded);
        assert!((u1 - u[0]).abs() < 1e-12 && (u2 - u[1]).abs() < 1e-12);
    }

    /// The DFL's law (eq. 1101), restated here to keep this crate free of the dfl crate.
    fn dfl_law(theta: f64, zeta: f64, v: [f64; 2]) -> ([f64; 2], bool) {
        let (s, c) = theta.sin_cos();
        ([v[0] * c + v[1] * s, (-v[0] * s + v[1] * c) / zeta], false)
    }

    #[test]
    fn the_jacobian_matches_its_structural_pattern() {
        let jac = jacobian([0.5, -1.0, 0.3, 1.2], [0.2, 0.1], 0.05);
        for r in 0..4 {
            for c in 0..6 {
                if !JACOBIAN_PATTERN[r][c] {
                    assert_eq!(jac[r][c], 0.0, "entry ({r}, {c})");
                }
            }
        }
    }

    #[test]
    fn the_nonlinear_mpc_plans_around_the_obstacle_within_its_cbf() {
        let scenario = Scenario::default();
        let mut mpc = NonlinearMpc::new(
            &scenario,
            &crate::model::terminal_weight(&scenario).unwrap(),
        );
        let start = scenario.robot.start;
        let plan = mpc.step(0, [start[0], start[1], start[2], 0.0], 0.0);
        assert_eq!(plan.status(), Some(PlanStatus::Solved));
        let discs: Vec<Disc> = scenario
            .obstacles
            .iter()
            .map(|o| Disc::still([o.x, o.y], o.radius))
            .collect();
        assert!(crate::discs::barrier_slack(&plan, &discs, scenario.mpc.gamma) > -1e-6);
        assert!(
            plan.solves >= 2,
            "a cold start needs more than one iteration"
        );
    }
}
