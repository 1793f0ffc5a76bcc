//! Where the states can be over every input sequence in the input box: the rollout of the
//! model (eq. 52), the exact span of a linear function of one stage's state ([`Span`]) and
//! bounds on the positions ([`PositionReach`]). They decide which rows a step's program
//! may leave out (the input box implies them).

use crate::layout::Layout;
use nalgebra::{DMatrix, Matrix4};

/// `value <= bound` with a margin (relative 1e-9) against rounding. (A row left out then
/// holds as well as the solver meets the input box, to its feasibility tolerance, as a
/// kept row would.)
pub fn below(value: f64, bound: f64) -> bool {
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
    /// How far each input may be from the centres' inputs: `v_max` for the input box,
    /// less about a plan ([`PositionReach::set_plan`]).
    spread: f64,
    /// `||D_i[k]||_1` per stage `i` and axis `k`: how far each axis of `p_i` reaches per
    /// unit of spread.
    axis_reach: Vec<[f64; 2]>,
    /// `c_i` of the step.
    centers: Vec<[f64; 2]>,
    /// The spans of the last state's velocity components `z_N[1]`, `z_N[3]`.
    terminal_velocity: [Span; 2],
    /// The step's `z_0`.
    z0: [f64; 4],
    /// About a plan: the largest `|w_N|` ([`PositionReach::set_plan`]).
    plan_terminal_speed: Option<f64>,
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
        let forced = forced.select_rows(&rows);
        let axis_reach = (0..=l.horizon)
            .map(|i| std::array::from_fn(|k| forced.row(2 * i + k).iter().map(|x| x.abs()).sum()))
            .collect();
        PositionReach {
            axis_reach,
            forced,
            free: free.select_rows(&rows),
            v_max,
            spread: v_max,
            centers: vec![[0.0; 2]; l.horizon + 1],
            terminal_velocity: [velocity(1), velocity(3)],
            z0: [0.0; 4],
            plan_terminal_speed: None,
        }
    }

    /// Sets `c_i` from the step's `z_0`: the positions over the whole input box.
    pub fn set_initial_state(&mut self, z0: [f64; 4]) {
        self.z0 = z0;
        self.spread = self.v_max;
        self.plan_terminal_speed = None;
        for (i, center) in self.centers.iter_mut().enumerate() {
            *center =
                std::array::from_fn(|k| (0..4).map(|c| self.free[(2 * i + k, c)] * z0[c]).sum());
        }
    }

    /// The positions about one plan instead of the input box: `c_i = position(i)`, the plan's
    /// stage-`i` position, its last velocity `w_N`, and every input within `share v_max`
    /// of the plan's (`share = 0`: the plan alone).
    pub fn set_plan(&mut self, position: impl Fn(usize) -> [f64; 2], w_n: [f64; 2], share: f64) {
        self.spread = share * self.v_max;
        let [x, y] = [0, 1].map(|k| w_n[k].abs() + share * self.terminal_velocity[k].reach);
        self.plan_terminal_speed = Some(x.hypot(y));
        for (i, center) in self.centers.iter_mut().enumerate() {
            *center = position(i);
        }
    }

    /// The horizon `N`.
    pub fn horizon(&self) -> usize {
        self.centers.len() - 1
    }

    /// The largest speed `|w_N|` of the last state (over the input box from `z_0`, or
    /// about the plan).
    pub fn max_terminal_speed(&self) -> f64 {
        if let Some(speed) = self.plan_terminal_speed {
            return speed;
        }
        let [x, y] = self
            .terminal_velocity
            .map(|span| span.max(self.z0).max(-span.min(self.z0)));
        x.hypot(y)
    }

    /// `spread ||sum_k a_k D_i[k] + b_k D_j[k]||_1`: the largest `a'(p_i - c_i) + b'(p_j - c_j)`.
    fn reach(&self, (i, a): (usize, [f64; 2]), (j, b): (usize, [f64; 2])) -> f64 {
        if self.spread == 0.0 {
            return 0.0;
        }
        let d = &self.forced;
        // The inputs from stage `max(i, j)` on move neither position.
        let norm: f64 = (0..2 * i.max(j))
            .map(|col| {
                let on_input: f64 = (0..2)
                    .map(|k| a[k] * d[(2 * i + k, col)] + b[k] * d[(2 * j + k, col)])
                    .sum();
                on_input.abs()
            })
            .sum();
        self.spread * norm
    }

    /// `min g'p_i`.
    pub fn min_linear(&self, i: usize, g: [f64; 2]) -> f64 {
        let c = self.centers[i];
        g[0] * c[0] + g[1] * c[1] - self.reach((i, g), (i, [0.0; 2]))
    }

    /// Whether `||p_i - o||^2 - h'p_j` stays below `bound` over the reach: first by
    /// [`PositionReach::boxed_max_squared_distance_minus_linear`], which decides in a
    /// constant number of operations for a disc far from the reach, then by the tighter
    /// [`PositionReach::max_squared_distance_minus_linear`], whose cost grows with the
    /// stage. The first is never below the second, so the answer is the second's.
    pub fn squared_distance_minus_linear_below(
        &self,
        i: usize,
        o: [f64; 2],
        (j, h): (usize, [f64; 2]),
        bound: f64,
    ) -> bool {
        below(
            self.boxed_max_squared_distance_minus_linear(i, o, (j, h)),
            bound,
        ) || below(self.max_squared_distance_minus_linear(i, o, (j, h)), bound)
    }

    /// A looser upper bound of `||p_i - o||^2 - h'p_j` than
    /// [`PositionReach::max_squared_distance_minus_linear`]: each position in its own box,
    /// every axis at its farthest, independently of the other position.
    fn boxed_max_squared_distance_minus_linear(
        &self,
        i: usize,
        o: [f64; 2],
        (j, h): (usize, [f64; 2]),
    ) -> f64 {
        let (ci, cj) = (self.centers[i], self.centers[j]);
        (0..2)
            .map(|k| {
                let farthest = (ci[k] - o[k]).abs() + self.spread * self.axis_reach[i][k];
                farthest.powi(2) - h[k] * cj[k] + h[k].abs() * self.spread * self.axis_reach[j][k]
            })
            .sum()
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
        let quadratic: f64 = self.axis_reach[i]
            .iter()
            .map(|norm| (self.spread * norm).powi(2))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Layout;

    /// The cone row of a disc at `o` with radius `r` on stage `i` (as
    /// `crate::program::Barrier`'s, with the decay `1 - gamma` = 0.9), linearized at the
    /// reach's centre of stage `i + 1`: `(h, t0)`.
    fn cone_row(reach: &PositionReach, i: usize, o: [f64; 2], r: f64) -> ([f64; 2], f64) {
        let decay = 0.9;
        let p_bar = reach.centers[i + 1];
        let g = [2.0 * (p_bar[0] - o[0]), 2.0 * (p_bar[1] - o[1])];
        let h_bar = (p_bar[0] - o[0]).powi(2) + (p_bar[1] - o[1]).powi(2) - r * r;
        let c = h_bar - g[0] * p_bar[0] - g[1] * p_bar[1];
        (g.map(|x| x / decay), (c + decay * r * r) / decay)
    }

    /// The box bound makes a far disc cheap to rule out. It must never rule out a row
    /// that the tight bound keeps, both must bound the true value, and on discs within
    /// 4 m of the robot it should rule out most of the rows the tight bound does.
    #[test]
    fn the_boxed_bound_is_never_below_the_tight_one_and_rules_out_most_rows() {
        let layout = Layout {
            horizon: 30,
            terminal_rows: 0,
            obstacles: 1,
            linear_barrier: false,
            condensed: false,
            terminal: None,
        };
        let (a, b) = crate::model::discretize(0.05);
        let (forced, free) = rollout(&layout, &a, &b);
        let mut reach = PositionReach::new(&layout, (&forced, &free), 1.0);
        let mut x = 0.3_f64;
        let mut next = move || {
            x = (x * 3.9 * (1.0 - x)).clamp(1e-6, 1.0 - 1e-6);
            x
        };
        // Rows ruled out by the tight bound, and of them by the box.
        let mut ruled_out = (0, 0);
        for sample in 0..3_000 {
            let z0 = [0.0, 4.0 * next() - 2.0, 0.0, 4.0 * next() - 2.0];
            reach.set_initial_state(z0);
            if sample % 2 == 1 {
                // About a plan (the zero-input rollout), a tenth of the box about it.
                let centers = reach.centers.clone();
                reach.set_plan(|i| centers[i], [z0[1], z0[3]], 0.1);
            }
            let i = 1 + (next() * 28.0) as usize;
            let o = [8.0 * next() - 4.0, 8.0 * next() - 4.0];
            let r = 0.2 + next();
            let (h, t0) = cone_row(&reach, i, o, r);
            let tight = reach.max_squared_distance_minus_linear(i, o, (i + 1, h));
            let boxed = reach.boxed_max_squared_distance_minus_linear(i, o, (i + 1, h));
            assert!(
                boxed >= tight,
                "stage {i}, disc at {o:?}: {boxed} < {tight}"
            );
            assert_eq!(
                reach.squared_distance_minus_linear_below(i, o, (i + 1, h), t0),
                below(tight, t0)
            );
            // The tight bound holds at the box's corners (inputs alternating in blocks).
            for corner in 0..8_u32 {
                let v: Vec<f64> = (0..forced.ncols())
                    .map(|c| {
                        reach.spread
                            * if (corner >> (c % 3)) & 1 == 1 {
                                1.0
                            } else {
                                -1.0
                            }
                    })
                    .collect();
                let at = |stage: usize| -> [f64; 2] {
                    std::array::from_fn(|k| {
                        let row = reach.forced.row(2 * stage + k);
                        let moved: f64 = row.iter().zip(&v).map(|(d, x)| d * x).sum();
                        reach.centers[stage][k] + moved
                    })
                };
                let (p, q) = (at(i), at(i + 1));
                let value =
                    (p[0] - o[0]).powi(2) + (p[1] - o[1]).powi(2) - h[0] * q[0] - h[1] * q[1];
                assert!(
                    value <= tight + 1e-9 * (1.0 + tight.abs()),
                    "{value} > {tight}"
                );
            }
            if below(tight, t0) {
                ruled_out.0 += 1;
                ruled_out.1 += usize::from(below(boxed, t0));
            }
        }
        let (by_tight, by_box) = ruled_out;
        assert!(
            (1_000..2_000).contains(&by_tight) && 2 * by_box > by_tight,
            "of {by_tight} rows of 3000 ruled out, the box rules out {by_box}"
        );
    }
}
