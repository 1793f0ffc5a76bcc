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
//! A moving disc is swept over the robot's stop ([`TerminalRows::stop_discs`]). Over the
//! plan's own stop (`d = Ts + |w_N| / a`: an obstacle that stands still, a phantom, the
//! escape plan) its support `n'o + R` grows by `k d + q d^2` with `k, q >= 0`, so with two
//! shared variables, `tau >= |w_N|` (an SOC(3); the ball's own) and
//! `sigma >= (Ts + tau / a)^2` (an SOC(3): `(sigma + 1, sigma - 1, 2 (Ts + tau / a))`;
//! not the decay slacks `sigma_i`), the support is affine in them and every row stays
//! convex; a larger `tau` or `sigma` only asks more. Over the fastest stop (a walking
//! obstacle in every other plan) it is data, and the recursive feasibility below does not
//! cover it (nor a track that starts or stops standing between two samples).
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
//!   distance moved: `|p_N+ - o| >= |p_N - o| - d >= R + S(s+)`.) A moving disc swept
//!   over the plan's own stop: the candidate's stop, one sample later from a speed
//!   `a Ts` lower, ends when the old one did, so its swept disc lies in the old one (for
//!   `s >= a Ts`; from slower, the candidate is at rest and its stop ends up to `Ts`
//!   later: not covered, like (c)).
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
use crate::discs::Prediction;
use crate::reach::{PositionReach, below};
use protocol::Disc;

/// Largest `c` of the segment form's AM-GM majorant (a reference approaching at less than
/// `1 / MAX_C` of its speed): the majorant then exceeds `alpha_bar |w_bar|` at the
/// reference by at most `|w_bar|^2 / (2 MAX_C)`, a stopping distance of
/// `|w_bar|^2 / (4 a MAX_C)`: 75 µm at 3 m/s with `a = 3`.
const MAX_C: f64 = 1e4;

/// How far beyond every input sequence's reach a disc's terminal row must ask the last
/// position to be before [`TerminalRows::impossible`] calls the program infeasible
/// without solving it, m: a thousand times the solver's feasibility tolerance
/// (`mpc::solver::base_settings`). That tolerance is relative (to the program's data
/// and iterate), so this is a wide margin rather than a bound: a program skipped that
/// clarabel would have called solved would miss the row by about a millimetre.
const IMPOSSIBLE_MARGIN_M: f64 = 1e-3;

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
    /// `(1 - gamma)^N` (0 with a linear CBF): the share of a negative `H(p_0)` the decay
    /// floor keeps at the last stage ([`TerminalRows::radius`]).
    pub floor_share: f64,
    /// Time of stage `N` after the discs' time, s: a moving disc is taken there
    /// ([`TerminalRows::stop_discs`]).
    pub horizon_s: f64,
    /// How long after the discs' time the phantoms and the tracks that stand still stand,
    /// s ([`protocol::KeptTracks::stand_for_s`]): their discs are taken then (or at stage
    /// `N`, if sooner).
    pub stand_s: f64,
    /// How the tracks are predicted: bounded, a walking obstacle's disc is swept over the
    /// fastest stop ([`TerminalRows::stop_discs`]); at constant velocity (the escape
    /// plan), over the plan's own.
    pub prediction: Prediction,
}

/// A disc as the stopping path must stay out of it, over a stop that lasts `d` seconds:
/// centre `center + drift d`, radius `radius + rate d + accel d^2`. That is the disc at
/// the stop's start swept over the stop ([`Disc::swept`]) and carried on for the rest
/// lookahead ([`Disc::carried_on`]); at rest, the disc itself whatever `d`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct StopDisc {
    /// Whether the stop is the plan's own (`d = Ts + |w_N| / a`), or the fastest one
    /// the input box reaches.
    own_stop: bool,
    center: [f64; 2],
    radius: f64,
    /// m/s.
    drift: [f64; 2],
    /// m/s.
    rate: f64,
    /// m/s^2.
    accel: f64,
}

impl StopDisc {
    /// `start` swept over the stop, then carried on at its velocity for `rest_s`.
    fn of(start: &Disc, rest_s: f64, own_stop: bool) -> StopDisc {
        let m = &start.motion;
        let [vx, vy] = m.velocity;
        let speed = vx.hypot(vy);
        StopDisc {
            own_stop,
            center: [
                start.center[0] + vx * rest_s / 2.0,
                start.center[1] + vy * rest_s / 2.0,
            ],
            radius: start.radius + speed * rest_s / 2.0,
            drift: [vx / 2.0, vy / 2.0],
            rate: m.radius_rate + speed / 2.0,
            accel: m.radius_accel,
        }
    }

    /// The disc over a stop of `duration_s`.
    fn at(&self, duration_s: f64) -> Disc {
        let d = duration_s;
        Disc::still(
            [
                self.center[0] + self.drift[0] * d,
                self.center[1] + self.drift[1] * d,
            ],
            self.radius + self.rate * d + self.accel * d * d,
        )
    }

    /// How fast the disc's support `n'o + R` in direction `n` grows with the stop's
    /// duration, m/s: `n'drift + rate`, never negative since `|drift| <= rate`.
    fn support_rate(&self, n: [f64; 2]) -> f64 {
        (n[0] * self.drift[0] + n[1] * self.drift[1] + self.rate).max(0.0)
    }
}

/// The data of one disc's row: the normal, the support `n'o + R` of the disc over the
/// shortest stop, `Ts`, or over the fastest one when it is not the plan's own (its radius
/// lowered to the decay floor's), its growth per second of stop and per second squared
/// (zero over the fastest stop), and the majorant of `alpha+ |w|` (module docs),
/// `beta e + q (c e^2 + |w|^2 / c) / 2` with `q` 0 or 1 (segment form).
#[derive(Debug, Clone, Copy, PartialEq)]
struct DiscRow {
    normal: [f64; 2],
    support: f64,
    support_rate: f64,
    support_accel: f64,
    beta: f64,
    quadratic: f64,
    c: f64,
}

impl DiscRow {
    /// The support over a stop from `speed`, m.
    fn support_at(&self, speed: f64, model: &TerminalBrake) -> f64 {
        let extra_s = speed / model.decel;
        let d = model.ts_s + extra_s;
        self.support
            + self.support_rate * extra_s
            + self.support_accel * (d * d - model.ts_s * model.ts_s)
    }
}

impl TerminalRows<'_> {
    /// The discs the stopping path must stay out of, as functions of the stop's duration:
    /// each at stage `N`, a moving one swept over the stop, so that the robot is stopped
    /// before the obstacle comes (passive safety, docs/safety.md), then carried on at its
    /// velocity for `rest_lookahead_s`, so that the robot does not stop where the obstacle
    /// walking on would meet it at rest. A disc at rest is itself.
    ///
    /// The stop is the plan's own (`Ts + |w_N| / a`, with a sample's hold: the variables
    /// `tau` and `sigma`) for an obstacle that stands still
    /// ([`protocol::Track::stands_still`]) and in the escape program. A walking one's, in
    /// every other plan, is the fastest stop the input box reaches: a robot that keeps
    /// that far from the people who walk is not walked into where it stops (docs/safety.md,
    /// "The stop and the person's way"). Swept over the fastest stop, a box the lidar sees
    /// held a robot 4 m off, and it circled the box until its time ran out.
    ///
    /// A held disc (`motion.held`: a phantom's, a standing track's not overdue) is taken
    /// when the next tracks are due (`stand_s`: what comes out of a shadow, or sets off,
    /// before then is seen by then), or at stage `N` if sooner, in the escape program too;
    /// a phantom's is swept over the stop alone (nothing comes at the robot from it), a
    /// standing track's is carried on as any track's. So the robot need only be at rest
    /// before where the obstacle could be by then reaches it: grown over the whole
    /// horizon, a box the lidar sees within about 0.7 m of the goal kept the robot turning
    /// on the spot short of it (docs/safety.md). This is a heuristic of the DFL's exact
    /// check, which brakes from where the robot is at `stand_s`: the rows stay at stage
    /// `N`.
    fn stop_discs(&self) -> impl Iterator<Item = StopDisc> + '_ {
        let held_s = self.stand_s.min(self.horizon_s);
        let rest_s = self.model.rest_lookahead_s;
        let escape = self.prediction == Prediction::ConstantVelocity;
        // Only a scenario that tracks obstacles has moving discs, and only it has the
        // variables of the plan's own stop.
        debug_assert!(self.model.sweeps || self.discs.iter().all(|d| !d.moves()));
        self.discs.iter().map(move |d| {
            let m = &d.motion;
            let taken_s = if m.held { held_s } else { self.horizon_s };
            let rest_s = if m.hidden { 0.0 } else { rest_s };
            StopDisc::of(&d.at(taken_s), rest_s, escape || m.standing || m.hidden)
        })
    }

    /// The stop's duration from `speed`, s: `Ts + speed / a`.
    fn stop_s(&self, speed: f64) -> f64 {
        self.model.ts_s + speed / self.model.decel
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

    /// The row of `stop` built at the reference: the normal of the disc over the
    /// reference's stop, pointing (segment) at the closest point of the reference's
    /// stopping segment or (ball) at its start.
    fn disc_row(&self, stop: &StopDisc) -> DiscRow {
        let (p, w) = (self.reference_position(), self.reference_velocity());
        let speed = w[0].hypot(w[1]);
        let disc = stop.at(self.stop_s(match stop.own_stop {
            true => speed,
            false => self.max_speed,
        }));
        let (normal, beta, quadratic, c) = match self.model.form {
            BrakeForm::Ball => (self.unit_from_center(&disc, p), 0.0, 0.0, 1.0),
            BrakeForm::Segment => {
                let end = if speed > 0.0 {
                    let stop = self.model.stop_distance_bound(speed) / speed;
                    [p[0] + w[0] * stop, p[1] + w[1] * stop]
                } else {
                    p
                };
                let closest = protocol::closest_point_on_segment(p, end, disc.center);
                let normal = self.unit_from_center(&disc, closest);
                let approach = -(normal[0] * w[0] + normal[1] * w[1]);
                match approach > 0.0 {
                    true => (normal, 0.0, 1.0, (speed / approach).min(MAX_C)),
                    false => (normal, self.max_speed, 0.0, 1.0),
                }
            }
        };
        // Over the shortest stop, `Ts`, growing with the stop when it is the plan's own; the
        // decay floor's radius (a disc at rest is itself, exactly).
        let (shortest, support_rate, support_accel) = match stop.own_stop {
            true => (
                stop.at(self.model.ts_s),
                stop.support_rate(normal),
                stop.accel.max(0.0),
            ),
            false => (stop.at(self.stop_s(self.max_speed)), 0.0, 0.0),
        };
        DiscRow {
            normal,
            support: normal[0] * shortest.center[0]
                + normal[1] * shortest.center[1]
                + self.radius(&shortest),
            support_rate,
            support_accel,
            beta,
            quadratic,
            c,
        }
    }

    /// Columns of `tau` and `sigma`, when the rows sweep (`tau` is the ball's own).
    fn sweep_variables(&self) -> (Option<usize>, Option<usize>) {
        let after_e = self.first_variable + self.discs.len();
        match (self.model.form, self.model.sweeps) {
            (BrakeForm::Ball, sweeps) => (
                Some(self.first_variable),
                sweeps.then_some(self.first_variable + 1),
            ),
            (BrakeForm::Segment, true) => (Some(after_e), Some(after_e + 1)),
            (BrakeForm::Segment, false) => (None, None),
        }
    }

    /// The best values of the rows' variables for a last velocity `w_N`, in column order:
    /// `e = alpha+ = max(0, -n'w_N)` per disc (segment), `tau = |w_N|` (ball, or
    /// sweeping), `sigma = (Ts + tau / a)^2` (sweeping). At the reference the rows are
    /// exact with them.
    pub fn variables_at(&self, w: [f64; 2]) -> impl Iterator<Item = f64> + '_ {
        let speed = w[0].hypot(w[1]);
        let segment = (self.model.form == BrakeForm::Segment).then(|| {
            self.stop_discs().map(move |stop| {
                let n = self.disc_row(&stop).normal;
                (-(n[0] * w[0] + n[1] * w[1])).max(0.0)
            })
        });
        let (tau, sigma) = self.sweep_variables();
        let stop_s = self.stop_s(speed);
        segment
            .into_iter()
            .flatten()
            .chain(tau.map(|_| speed))
            .chain(sigma.map(|_| stop_s * stop_s))
    }

    /// Writes the rows of the nonnegative cone (segment: `e >= -n'w_N`, `e >= 0`).
    pub fn write_nonnegative(&self, asm: &mut Assembly) {
        if self.model.form != BrakeForm::Segment {
            return;
        }
        let [vx, vy] = self.velocity;
        for (j, stop) in self.stop_discs().enumerate() {
            let n = self.disc_row(&stop).normal;
            let e = self.first_variable + j;
            asm.row([(e, -1.0), (vx, -n[0]), (vy, -n[1])], 0.0);
            asm.row([(e, -1.0)], 0.0);
        }
    }

    /// Writes the cones (module docs for each form): `tau >= |w_N|` and
    /// `sigma >= (Ts + tau / a)^2` first, then one cone per disc, in which the disc's
    /// support grows with `tau` and `sigma` (the stop swept from the plan's own speed).
    pub fn write_cones(&self, asm: &mut Assembly) {
        let ([px, py], [vx, vy]) = (self.position, self.velocity);
        let (a, ts) = (self.model.decel, self.model.ts_s);
        let (tau, sigma) = self.sweep_variables();
        if let Some(tau) = tau {
            asm.row([(tau, -1.0)], 0.0);
            asm.row([(vx, -1.0)], 0.0);
            asm.row([(vy, -1.0)], 0.0);
        }
        if let (Some(tau), Some(sigma)) = (tau, sigma) {
            // (sigma + 1, sigma - 1, 2 (Ts + tau / a)).
            asm.row([(sigma, -1.0)], 1.0);
            asm.row([(sigma, -1.0)], -1.0);
            asm.row([(tau, -2.0 / a)], 2.0 * ts);
        }
        for (j, stop) in self.stop_discs().enumerate() {
            let row = self.disc_row(&stop);
            let n = row.normal;
            // t = 2a (n'p_N - support) - ..., the support growing by `rate tau / a` and
            // `accel (sigma - Ts^2)` when the rows sweep.
            let mut t = Terms::new([(px, -2.0 * a * n[0]), (py, -2.0 * a * n[1])]);
            let mut offset = 2.0 * a * row.support;
            let mut ball_tau = a * ts;
            if let (Some(tau), Some(sigma)) = (tau, sigma) {
                let tau_coefficient = 2.0 * row.support_rate;
                match self.model.form {
                    BrakeForm::Ball => ball_tau += tau_coefficient,
                    BrakeForm::Segment => t.push(tau, tau_coefficient),
                }
                t.push(sigma, 2.0 * a * row.support_accel);
                offset -= 2.0 * a * row.support_accel * ts * ts;
            }
            match self.model.form {
                BrakeForm::Ball => {
                    // (t + 1, t - 1, 2 w_N), t = 2a (n'p_N - support) - a Ts tau.
                    t.push(tau.expect("the ball has tau"), ball_tau);
                    asm.row(t.iter(), 1.0 - offset);
                    asm.row(t.iter(), -1.0 - offset);
                    asm.row([(vx, -2.0)], 0.0);
                    asm.row([(vy, -2.0)], 0.0);
                }
                BrakeForm::Segment => {
                    // (t + 1, t - 1, q sqrt(2c) e, q sqrt(2/c) w_N) with
                    // t = 2a (n'p_N - support) - (a Ts + beta) e.
                    let e = self.first_variable + j;
                    t.push(e, a * ts + row.beta);
                    asm.row(t.iter(), 1.0 - offset);
                    asm.row(t.iter(), -1.0 - offset);
                    asm.row([(e, -row.quadratic * (2.0 * row.c).sqrt())], 0.0);
                    let scale = row.quadratic * (2.0 / row.c).sqrt();
                    asm.row([(vx, -scale)], 0.0);
                    asm.row([(vy, -scale)], 0.0);
                }
            }
        }
    }

    /// Whether every row holds, with a margin, for every input sequence in `reach` (the
    /// input box, or about a plan): the smallest `n'p_N` against the largest right-hand
    /// side, with the speed `|w_N|` (and the approach speed, and the stop the discs are
    /// swept over) at their largest.
    pub fn implied(&self, reach: &PositionReach) -> bool {
        let speed = reach.max_terminal_speed();
        let horizon = reach.horizon();
        let a = self.model.decel;
        self.stop_discs().all(|stop| {
            let row = self.disc_row(&stop);
            let largest = match self.model.form {
                BrakeForm::Ball => self.model.stop_distance_bound(speed),
                BrakeForm::Segment => {
                    // With e = alpha+ <= |w_N| <= speed.
                    let quadratic = row.quadratic * (row.c + 1.0 / row.c) / 2.0;
                    let majorant = (row.beta + quadratic * speed) * speed;
                    majorant / (2.0 * a) + 0.5 * self.model.ts_s * speed
                }
            };
            let support = row.support_at(speed, &self.model);
            below(largest, reach.min_linear(horizon, row.normal) - support)
        })
    }

    /// Whether some disc's row fails for every input sequence in `reach` (the input box
    /// from `z_0`): the largest `n'p_N` over it below the row's least support (over the
    /// shortest stop when the stop is the plan's own, over the fastest for a walking
    /// track: [`TerminalRows::disc_row`]). Every cone of [`TerminalRows::write_cones`] asks
    /// `t = 2a (n'p_N - support) - ... >= 0`, the terms left out never negative (`e`,
    /// `tau`, `sigma - Ts^2`, and their coefficients), so no plan in the program
    /// exists: it is infeasible, proved without a solve. So it is when a walking track
    /// swept over the fastest stop covers everywhere the robot reaches (docs/fleet.md,
    /// "Another robot's stop sweep"), which clarabel takes 13 to 26 interior-point
    /// iterations to prove, twice a step with the relaxed program.
    pub fn impossible(&self, reach: &PositionReach) -> bool {
        let horizon = reach.horizon();
        self.stop_discs().any(|stop| {
            let row = self.disc_row(&stop);
            let largest = -reach.min_linear(horizon, row.normal.map(|x| -x));
            largest < row.support - IMPOSSIBLE_MARGIN_M
        })
    }
}

/// The terms of one row, without allocating: at most `p_N`, `tau`, `sigma` and `e`.
struct Terms {
    items: [(usize, f64); 5],
    len: usize,
}

impl Terms {
    fn new(first: [(usize, f64); 2]) -> Terms {
        let mut items = [(0, 0.0); 5];
        items[..2].copy_from_slice(&first);
        Terms { items, len: 2 }
    }

    fn push(&mut self, column: usize, value: f64) {
        self.items[self.len] = (column, value);
        self.len += 1;
    }

    fn iter(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.items[..self.len].iter().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A person 3 m ahead walking across, bounded: the disc grows by `kappa sigma_v` and
    /// `accel_max t^2 / 2`; a track that `standing`, held once the next tracks are due.
    fn person(standing: bool) -> Disc {
        Disc {
            motion: protocol::DiscMotion {
                velocity: [0.2, -0.5],
                radius_rate: 0.3,
                radius_accel: 0.25,
                hidden: false,
                standing,
                held: standing,
            },
            ..Disc::still([3.0, 0.5], 0.6)
        }
    }

    /// Rows of `form` keeping the stop from `p_N` (columns 0 and 2, `w_N` 1 and 3, the
    /// rows' own variables from 4) clear of `discs` swept over it, with `a` = 2 m/s^2,
    /// `Ts` = 0.1 s and speeds up to 5 m/s.
    fn sweeping_rows(discs: &[Disc], form: BrakeForm, prediction: Prediction) -> TerminalRows<'_> {
        TerminalRows {
            model: TerminalBrake {
                decel: 2.0,
                ts_s: 0.1,
                form,
                rest_lookahead_s: 0.5,
                sweeps: true,
            },
            discs,
            reference: [0.5, 1.0, 0.1, 0.2],
            p0: [-1.0, 0.0],
            position: [0, 2],
            velocity: [1, 3],
            first_variable: 4,
            max_speed: 5.0,
            floor_share: 0.0,
            horizon_s: 1.0,
            stand_s: 0.2,
            prediction,
        }
    }

    /// Row `r`'s slack `b - A x` in `asm` at `x`.
    fn slack_of(asm: &Assembly, x: &[f64], r: usize) -> f64 {
        let on_x: f64 = (asm.entries.iter())
            .filter(|e| e.0 == r)
            .map(|e| e.2 * x[e.1])
            .sum();
        asm.b[r] - on_x
    }

    #[test]
    fn discs_are_swept_over_the_own_or_fastest_stop_and_taken_at_the_next_tracks_or_stage_n() {
        let (a, ts, max_speed) = (2.0, 0.1, 5.0);
        // (prediction, standing, own stop, the disc's time taken: stage N's, 1 s, or the
        // next tracks', 0.2 s).
        let cases = [
            (Prediction::ConstantVelocity, false, true, 1.0),
            (Prediction::Bounded, true, true, 0.2),
            (Prediction::Bounded, false, false, 1.0),
        ];
        for (prediction, standing, own_stop, taken_s) in cases {
            let person = person(standing);
            let discs = [person];
            for form in [BrakeForm::Segment, BrakeForm::Ball] {
                let rows = sweeping_rows(&discs, form, prediction);
                let mut asm = Assembly::default();
                rows.write_cones(&mut asm);
                for (p, w) in [
                    ([0.4, 0.1], [0.0, 0.0]),
                    ([0.6, 0.2], [1.2, 0.3]),
                    ([1.0, -0.5], [2.5, -1.0]),
                ] {
                    let mut x = vec![p[0], w[0], p[1], w[1]];
                    x.extend(rows.variables_at(w));
                    let slack = |r: usize| slack_of(&asm, &x, r);
                    // sigma's cone is tight at sigma = (Ts + |w| / a)^2:
                    // (sigma + 1, sigma - 1, 2 stop).
                    let own_stop_s = ts + w[0].hypot(w[1]) / a;
                    let (s3, s4, s5) = (slack(3), slack(4), slack(5));
                    assert!((s5 - 2.0 * own_stop_s).abs() < 1e-12);
                    assert!((s3 * s3 - s4 * s4 - s5 * s5).abs() < 1e-9);
                    // The disc at stage N (or when the next tracks are due) swept over the
                    // stop and carried on for the rest lookahead.
                    let stop_s = match own_stop {
                        true => own_stop_s,
                        false => ts + max_speed / a,
                    };
                    let swept = person
                        .at(taken_s)
                        .swept(stop_s)
                        .carried_on([0.2, -0.5], 0.5);
                    let row = rows.disc_row(&rows.stop_discs().next().unwrap());
                    let n = row.normal;
                    let support = n[0] * swept.center[0] + n[1] * swept.center[1] + swept.radius;
                    let distance = n[0] * p[0] + n[1] * p[1] - support;
                    let t = slack(6) - 1.0;
                    let expected = match form {
                        BrakeForm::Ball => 2.0 * a * distance - a * ts * x[4],
                        BrakeForm::Segment => 2.0 * a * distance - (a * ts + row.beta) * x[4],
                    };
                    assert!(
                        (t - expected).abs() < 1e-9,
                        "{prediction:?}, standing {standing}, {form:?}, w {w:?}: t {t}, \
                         expected {expected}"
                    );
                }
            }
        }
    }

    #[test]
    fn no_cone_holds_where_the_last_position_is_below_the_rows_least_support() {
        // `impossible` rests on this: at any values of the rows' own variables their cones
        // admit (`tau >= |w_N|`, `sigma >= (Ts + tau / a)^2`, `e >= 0`), every disc's
        // cone head is `t <= 2a (n'p_N - support)`, and a cone needs `t >= 0`. Both
        // forms, sweeping; a walking track's stop the fastest, a standing one's the own.
        let a = 2.0;
        for (prediction, standing) in [
            (Prediction::ConstantVelocity, false),
            (Prediction::Bounded, true),
            (Prediction::Bounded, false),
        ] {
            let discs = [person(standing)];
            for form in [BrakeForm::Segment, BrakeForm::Ball] {
                let rows = sweeping_rows(&discs, form, prediction);
                let (tau, sigma) = rows.sweep_variables();
                let (tau, sigma) = (tau.unwrap(), sigma.unwrap());
                let row = rows.disc_row(&rows.stop_discs().next().unwrap());
                let mut asm = Assembly::default();
                rows.write_cones(&mut asm);
                for p in [[0.4, 0.1], [1.0, -0.5], [3.0, 0.5]] {
                    for w in [[0.0, 0.0], [1.2, 0.3], [-2.5, 1.0]] {
                        for extra in [0.0, 0.3, 2.0] {
                            let mut x = vec![p[0], w[0], p[1], w[1]];
                            x.extend(rows.variables_at(w));
                            x.iter_mut().skip(4).for_each(|v| *v += extra);
                            x[sigma] = (0.1 + x[tau] / a).powi(2) + extra;
                            let t = slack_of(&asm, &x, 6) - 1.0;
                            let n = row.normal;
                            let bound = 2.0 * a * (n[0] * p[0] + n[1] * p[1] - row.support);
                            assert!(
                                t <= bound + 1e-9,
                                "{prediction:?}, standing {standing}, {form:?}, p {p:?}, \
                                 w {w:?}, extra {extra}: t {t} above {bound}"
                            );
                            // At rest, at the variables' least, the bound is met: the
                            // proof leaves nothing out there.
                            if w == [0.0, 0.0] && extra == 0.0 && form == BrakeForm::Ball {
                                assert!((t - bound).abs() < 1e-9, "{t} against {bound}");
                            }
                        }
                    }
                }
            }
        }
    }
}
