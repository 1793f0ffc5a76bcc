//! The braking-safe terminal rows of `mpc.terminal_safety` (docs/safety.md), and the
//! recursive feasibility they give the linear scheme.
//!
//! The DFL's fallback brake (`U2 = 0`, zeta taken to zero at the deceleration `a`) moves
//! the robot straight along its velocity `w`, for at most
//! `S(|w|) = |w|^2 / (2 a) + Ts |w| / 2` ([`TerminalBrake::stop_distance_bound`]). The
//! rows ask that the last state `z_N = (p_N, w_N)` can brake so without touching a
//! constraint disc (centre `o`, radius `R`: the obstacle grown by the robot's radius, the
//! margins and the inter-sample term, as the CBF's). Like the CBF rows they are an inner
//! approximation, built at the reference `z_bar_N` (the shifted previous plan's last state,
//! or the braking rollout when cold), with a unit normal `n` per disc: `n'(p - o) <= |p - o|`
//! under-estimates the distance, and the stopping distance is over-estimated by a convex
//! function of `w_N`. Two forms:
//!
//! - [`BrakeForm::Segment`] (the default): the stopping *segment* `p_N + t w_N / |w_N|`,
//!   `t in [0, S]`, must stay in the half-plane `n'(q - o) >= R`, `n` pointing at the
//!   closest point of the reference's segment. With `D = n'(p_N - o) - R` and the approach
//!   speed `alpha = -n'w_N`, that is `D >= alpha+ (|w_N| / (2 a) + Ts / 2)` (and `D >= 0`).
//!   The product `alpha+ |w|` is not convex; it is bounded by a convex majorant equal to it
//!   at the reference, with a variable `e >= alpha+` (`e >= alpha`, `e >= 0`): when the
//!   reference approaches (`alpha_bar > 0`), AM-GM, `(c e^2 + |w|^2 / c) / 2` with
//!   `c = |w_bar| / alpha_bar`; otherwise `e W`, `W` the largest `|w_N|` any input sequence
//!   in the box reaches, which is zero at the reference (`alpha_bar+ = 0`) and leaves the
//!   robot free to brake or to pass along the disc. One variable, two linear rows and one
//!   SOC(5) per disc. A robot passing a disc tangentially needs no standoff at all.
//! - [`BrakeForm::Ball`] (`brake_ball`, conservative): the whole ball of radius `S` around
//!   `p_N`, `n` pointing at `p_bar_N`: `n'(p_N - o) - R >= |w|^2 / (2 a) + Ts tau / 2`,
//!   `tau >= |w_N|`. One shared variable `tau` with an SOC(3), then one SOC(4) per disc. It
//!   keeps a standoff of `S` whatever the direction of travel.
//!
//! # Recursive feasibility
//!
//! Assumptions: (a) no noise and the model holds, so the state at sample `k + 1` is the
//! plan's `z_1`; (b) `a = dfl.brake_decel <= mpc.v_max`, so the braking input
//! `-min(a, |w| / Ts) w / |w|` ([`TerminalBrake::input`]) is in the input box; (c) the
//! constraint discs at `k + 1` lie within those at `k`: the obstacles are fixed and,
//! noise-free, `sigma` does not grow, but the inter-sample term `sqrt(r^2 + d^2 / 4)`
//! grows with the speed: by micrometres for the paper's obstacle, by 14 mm for `r = 0.2 m`
//! at `Ts = 0.1 s` and `v_max = 5` speeding from 1 to 1.7 m/s; (d) the robot starts
//! every sample outside every constraint disc, so every decay floor is zero (a robot
//! inside a disc grown by a larger `kappa sigma` is not covered); (e) the braking state
//! `z_N+` lies in the terminal set of eqs. (45, 47) and the position box.
//!
//! Claim: if the convexified program at `k` has a solution, the program at `k + 1`
//! (linearized, as the MPC does, at that solution shifted by one sample and extended by one
//! braking sample, [`TerminalBrake::step`]) has one: that very candidate.
//! - Dynamics and input box: by (a) and (b).
//! - Position box on stages `1..N-1`: they are the old stages `2..N` (the old `z_N` by the
//!   terminal set's first rows); the new `z_N = z_N+` by (e).
//! - CBF rows: at the candidate every linearization is exact (`L = H` at the reference),
//!   so the new row between stages `i` and `i + 1` holds if the true CBF does. For the
//!   stages taken from the old plan it does, with the old decay slack (which satisfies the
//!   new, exact, bound as well: `L_old <= H`, and by (d) both floors are zero). For the
//!   last row, between the old `z_N` and `z_N+`, the slack
//!   `max(0, (1 - gamma) H(p_N) - H(p_N+))` does, within its bound `(1 - gamma) H(p_N)`,
//!   because `H(p_N+) >= 0`: `p_N+` lies on the old stopping path, which the old terminal
//!   rows kept outside the disc.
//! - Terminal rows: one braking sample moves the robot by at most the drop of `S`
//!   (`S(s) - S(s+) >= s Ts - a Ts^2 / 2` for `s >= a Ts`, and `S(s) >= s Ts / 2`, the
//!   whole last step, below), along the same line, so the new stopping path is a part of the
//!   old one: outside the disc. The new rows are built at the candidate itself and are exact
//!   there (the segment form's normal points at the closest point of the new segment; the
//!   majorant equals `alpha+ |w|` at the reference, but for a reference approaching at
//!   less than `1 / MAX_C` of its speed, where it exceeds the stopping distance by at most
//!   `|w|^2 / (4 a MAX_C)`, 75 µm at 3 m/s), so they hold. (The ball shrinks by at least the
//!   distance moved: `|p_N+ - o| >= |p_N - o| - d >= R + S(s+)`.)
//! - Terminal set (eqs. 45, 47): *not* guaranteed. It is invariant under the LQR step, not
//!   under braking: this is assumption (e), and where it fails the MPC starts cold from the
//!   braking rollout (feasible whenever braking from `z_0` is safe), and failing that the
//!   DFL flies its committed trajectory. The test
//!   `the_shifted_plan_extended_by_braking_is_feasible_at_the_next_sample` measures it.
//!
//! The refinement solves that follow keep feasibility: each program is built at the
//! previous solution, where its rows are exact. Where (c) or (d) fails, or the 75 µm, the
//! MPC's first solve may be infeasible: it retries relaxed, then cold, and the DFL's
//! safety check stays.
//!
//! Without the decay slacks the last row can fail: braking towards a disc lowers `H` by
//! more than the factor `1 - gamma` allows. So a step first solves the program without
//! them (the paper's CBF exactly), and only if that fails the relaxed one, which the
//! candidate makes feasible. The paper's candidate (the LQR step) satisfies
//! the terminal set but not the stopping condition: that is how a short horizon ran into
//! obstacles (issue 14).

use crate::assembly::Assembly;
use crate::brake::{BrakeForm, TerminalBrake};
use crate::reach::{PositionReach, below};
use protocol::Disc;

/// Largest `c` of the segment form's AM-GM majorant (a reference approaching at less than
/// `1 / MAX_C` of its speed): the majorant then exceeds `alpha_bar |w_bar|` at the
/// reference by at most `|w_bar|^2 / (2 MAX_C)`, a stopping distance of
/// `|w_bar|^2 / (4 a MAX_C)`: 75 µm at 3 m/s with `a = 3`.
const MAX_C: f64 = 1e4;

/// The terminal rows of one program.
#[derive(Debug, Clone, Copy)]
pub struct TerminalRows<'a> {
    pub model: TerminalBrake,
    pub discs: &'a [Disc],
    /// The reference last state `z_bar_N` (goal-relative).
    pub reference: [f64; 4],
    /// Position of stage 0 (data), for a normal when the reference sits on a centre.
    pub p0: [f64; 2],
    /// Columns of `p_N` and `w_N`.
    pub position: [usize; 2],
    pub velocity: [usize; 2],
    /// Column of the first of [`TerminalBrake::variables`].
    pub first_variable: usize,
    /// The largest `|w_N|` any input sequence in the box reaches, m/s.
    pub max_speed: f64,
    /// The speed whose stop a moving disc is swept over ([`TerminalRows::discs`]), m/s:
    /// `max_speed` in every plan's program, the reference's last speed in the escape
    /// program's (`mpc::discs::Prediction::ConstantVelocity`, docs/safety.md).
    pub sweep_speed: f64,
    /// `(1 - gamma)^N` (0 with a linear CBF): the share of a negative `H(p_0)` the decay
    /// floor keeps at the last stage ([`TerminalRows::radius`]).
    pub floor_share: f64,
    /// Time of stage `N` after the discs' time, s: a moving disc is taken there, swept
    /// over the stop from `sweep_speed` ([`TerminalRows::discs`]).
    pub horizon_s: f64,
    /// How long after the discs' time the phantoms stand, s
    /// ([`protocol::KeptTracks::phantoms_stand_for_s`]): a phantom's disc is taken then
    /// (or at stage `N`, if sooner).
    pub phantoms_stand_s: f64,
}

/// The data of one disc's segment row: the normal, and the majorant of `alpha+ |w|`
/// (module docs), `beta e + q (c e^2 + |w|^2 / c) / 2` with `q` 0 or 1.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SegmentRow {
    normal: [f64; 2],
    beta: f64,
    quadratic: f64,
    c: f64,
}

impl TerminalRows<'_> {
    /// The discs the stopping path must stay out of: each at stage `N`, and a moving one
    /// swept over the stop from there (from `sweep_speed`, with a sample's hold), so that
    /// the robot is stopped before the obstacle comes (passive safety, docs/safety.md),
    /// then carried on at its velocity for `rest_lookahead_s`, so that the robot does not
    /// stop where the obstacle walking on would meet it at rest. A disc at rest is itself.
    ///
    /// A phantom's disc (`motion.hidden`) is taken when the phantoms stop standing
    /// (`phantoms_stand_s`: what comes out of a shadow before then is seen by then) and
    /// swept over the stop from the reference's last speed: nothing comes at the robot
    /// from it, so the robot need only be at rest before where something hidden could be
    /// by then reaches it, and the stop from the fastest speed would sweep the phantom of
    /// every corner passed over the way. This is a heuristic of the DFL's exact check,
    /// which brakes from where the robot is at `phantoms_stand_s`: the rows stay at stage
    /// `N`, built at the reference, refined at each solve.
    fn discs(&self) -> impl Iterator<Item = Disc> + '_ {
        let stop_s = |speed: f64| speed / self.model.decel + self.model.ts_s;
        let [_, wx, _, wy] = self.reference;
        let (sweep_s, hidden_sweep_s) = (stop_s(self.sweep_speed), stop_s(wx.hypot(wy)));
        let hidden_s = self.phantoms_stand_s.min(self.horizon_s);
        let rest_s = self.model.rest_lookahead_s;
        self.discs.iter().map(move |d| match d.motion.hidden {
            true => d.at(hidden_s).swept(hidden_sweep_s),
            false => d
                .at(self.horizon_s)
                .swept(sweep_s)
                .carried_on(d.motion.velocity, rest_s),
        })
    }

    /// The radius the stopping path must stay outside, m: the disc's, or, for a robot that
    /// starts inside it (`H(p_0) < 0`), that of the CBF's decay floor at the last stage,
    /// `sqrt(R^2 + (1 - gamma)^N H(p_0))`, so the robot may leave the disc as the decay
    /// lets it instead of having to be out of it within the horizon.
    fn radius(&self, disc: &Disc) -> f64 {
        let floor = self.floor_share * disc.barrier(self.p0).min(0.0);
        (disc.radius * disc.radius + floor).max(0.0).sqrt()
    }

    /// The unit vector from `disc`'s centre towards `p` (towards `p_0`, or along x, when
    /// `p` is the centre).
    fn unit_from_center(&self, disc: &Disc, p: [f64; 2]) -> [f64; 2] {
        let towards = |p: [f64; 2]| {
            let d = [p[0] - disc.center[0], p[1] - disc.center[1]];
            let length = d[0].hypot(d[1]);
            (length > 0.0).then(|| [d[0] / length, d[1] / length])
        };
        towards(p)
            .or_else(|| towards(self.p0))
            .unwrap_or([1.0, 0.0])
    }

    fn reference_position(&self) -> [f64; 2] {
        [self.reference[0], self.reference[2]]
    }

    fn reference_velocity(&self) -> [f64; 2] {
        [self.reference[1], self.reference[3]]
    }

    /// The segment row of `disc` at the reference.
    fn segment_row(&self, disc: &Disc) -> SegmentRow {
        let (p, w) = (self.reference_position(), self.reference_velocity());
        let speed = w[0].hypot(w[1]);
        let end = if speed > 0.0 {
            let stop = self.model.stop_distance_bound(speed) / speed;
            [p[0] + w[0] * stop, p[1] + w[1] * stop]
        } else {
            p
        };
        let closest = protocol::closest_point_on_segment(p, end, disc.center);
        let normal = self.unit_from_center(disc, closest);
        let approach = -(normal[0] * w[0] + normal[1] * w[1]);
        if approach > 0.0 {
            SegmentRow {
                normal,
                beta: 0.0,
                quadratic: 1.0,
                c: (speed / approach).min(MAX_C),
            }
        } else {
            SegmentRow {
                normal,
                beta: self.max_speed,
                quadratic: 0.0,
                c: 1.0,
            }
        }
    }

    /// The best values of the rows' variables for a last velocity `w_N`: `tau = |w_N|`
    /// (ball), `e = alpha+ = max(0, -n'w_N)` per disc (segment). At the reference the rows
    /// are exact with them.
    pub fn variables_at(&self, w: [f64; 2]) -> impl Iterator<Item = f64> + '_ {
        let (ball, segment) = match self.model.form {
            BrakeForm::Ball => (Some(w[0].hypot(w[1])), None),
            BrakeForm::Segment => (
                None,
                Some(self.discs().map(move |disc| {
                    let n = self.segment_row(&disc).normal;
                    (-(n[0] * w[0] + n[1] * w[1])).max(0.0)
                })),
            ),
        };
        ball.into_iter().chain(segment.into_iter().flatten())
    }

    /// Writes the rows of the nonnegative cone (segment: `e >= -n'w_N`, `e >= 0`).
    pub fn write_nonnegative(&self, asm: &mut Assembly) {
        if self.model.form != BrakeForm::Segment {
            return;
        }
        let [vx, vy] = self.velocity;
        for (j, disc) in self.discs().enumerate() {
            let n = self.segment_row(&disc).normal;
            let e = self.first_variable + j;
            asm.row([(e, -1.0), (vx, -n[0]), (vy, -n[1])], 0.0);
            asm.row([(e, -1.0)], 0.0);
        }
    }

    /// Writes the cones (module docs for each form).
    pub fn write_cones(&self, asm: &mut Assembly) {
        let ([px, py], [vx, vy]) = (self.position, self.velocity);
        let (a, ts) = (self.model.decel, self.model.ts_s);
        // The distance's under-estimate scaled by 2a: 2a n'(p - o) - 2a R.
        let offset = |n: [f64; 2], disc: &Disc| {
            2.0 * a * (n[0] * disc.center[0] + n[1] * disc.center[1] + self.radius(disc))
        };
        match self.model.form {
            BrakeForm::Ball => {
                // tau >= |w_N|, then (t + 1, t - 1, 2 w_N) with
                // t = 2a (n'(p_N - o) - R) - a Ts tau.
                let tau = self.first_variable;
                asm.row([(tau, -1.0)], 0.0);
                asm.row([(vx, -1.0)], 0.0);
                asm.row([(vy, -1.0)], 0.0);
                for disc in self.discs() {
                    let n = self.unit_from_center(&disc, self.reference_position());
                    let t = [(px, -2.0 * a * n[0]), (py, -2.0 * a * n[1]), (tau, a * ts)];
                    asm.row(t, 1.0 - offset(n, &disc));
                    asm.row(t, -1.0 - offset(n, &disc));
                    asm.row([(vx, -2.0)], 0.0);
                    asm.row([(vy, -2.0)], 0.0);
                }
            }
            BrakeForm::Segment => {
                // (t + 1, t - 1, q sqrt(2c) e, q sqrt(2/c) w_N) with
                // t = 2a (n'(p_N - o) - R) - (a Ts + beta) e.
                for (j, disc) in self.discs().enumerate() {
                    let row = self.segment_row(&disc);
                    let (n, e) = (row.normal, self.first_variable + j);
                    let t = [
                        (px, -2.0 * a * n[0]),
                        (py, -2.0 * a * n[1]),
                        (e, a * ts + row.beta),
                    ];
                    asm.row(t, 1.0 - offset(n, &disc));
                    asm.row(t, -1.0 - offset(n, &disc));
                    asm.row([(e, -row.quadratic * (2.0 * row.c).sqrt())], 0.0);
                    let scale = row.quadratic * (2.0 / row.c).sqrt();
                    asm.row([(vx, -scale)], 0.0);
                    asm.row([(vy, -scale)], 0.0);
                }
            }
        }
    }

    /// Whether every row holds, with a margin, for every input sequence in `reach` (the
    /// input box, or about a plan): the smallest `n'(p_N - o) - R` against the largest
    /// right-hand side, with the speed `|w_N|` (and the approach speed) at their largest.
    pub fn implied(&self, reach: &PositionReach) -> bool {
        let speed = reach.max_terminal_speed();
        let horizon = reach.horizon();
        let a = self.model.decel;
        self.discs().all(|disc| {
            let disc = &disc;
            let (n, largest) = match self.model.form {
                BrakeForm::Ball => (
                    self.unit_from_center(disc, self.reference_position()),
                    self.model.stop_distance_bound(speed),
                ),
                BrakeForm::Segment => {
                    // With e = alpha+ <= |w_N| <= speed.
                    let row = self.segment_row(disc);
                    let quadratic = row.quadratic * (row.c + 1.0 / row.c) / 2.0;
                    let majorant = (row.beta + quadratic * speed) * speed;
                    (
                        row.normal,
                        majorant / (2.0 * a) + 0.5 * self.model.ts_s * speed,
                    )
                }
            };
            let offset = n[0] * disc.center[0] + n[1] * disc.center[1] + self.radius(disc);
            below(largest, reach.min_linear(horizon, n) - offset)
        })
    }
}
