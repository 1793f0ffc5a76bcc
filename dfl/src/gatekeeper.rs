//! The DFL's safety check (docs/safety.md): a gatekeeper in the sense of Agrawal and
//! Panagou (2024), with the Simplex idea of a verified fallback.
//!
//! The DFL flies only a *committed trajectory*: a plan followed, from its last state, by the
//! fallback brake (`U2 = 0`, zeta to zero at the braking deceleration). A plan is committed
//! only if that trajectory, rolled out from the current estimate, stays outside every
//! obstacle disc grown by the robot's radius, `mpc.safety_margin_m`, `kappa sigma` and
//! [`protocol::commit_margin_m`]. Otherwise the trajectory already committed goes on, and
//! its brake follows: today's shifted-plan fallback, but checked. On every tick the
//! committed trajectory is checked again from the new estimate, against the same discs
//! without that last margin; if it would enter one, the DFL brakes at once, unless braking
//! touches too: then it takes the least unsafe choice (`dfl::least_unsafe`), for which the
//! check tells contacts while the robot moves from those at rest ([`Verdict`]).
//! A robot already inside a grown disc (its uncertainty grew, say) is checked against the
//! disc through its position: it may move, but not deeper. The margin
//! between the two checks keeps the estimate's jitter and the robot's small departures
//! from its linearized model (the zeta guard, commands held over an inner tick) from
//! giving up trajectories that are safe; `kappa sigma` stays in both, since the estimate
//! the trajectory is flown from is that far from the truth. None of this depends on where a plan came from, so a swapped-in MPC
//! that ignores the obstacles cannot drive the robot into one while the model holds.
//!
//! The check is exact and closed form. Under the linearizing law the robot is two double
//! integrators (paper eq. mobile46-1), so between samples, with the plan's `v` held, its
//! position is a parabolic arc `p + w t + v t^2 / 2`; the closest point of an arc to a
//! disc's centre is at an end or where `(q(t) - o) . q'(t) = 0`, a cubic in `t`. The brake
//! moves the robot straight along its velocity for [`protocol::stopping_distance`]. A
//! cheap lower bound (the chord's distance less the arc's largest departure from it,
//! `|v| T^2 / 8`) settles almost every arc; only arcs close to a disc solve the cubic.

use protocol::{Disc, KeptTracks, ObstacleGrowth, Plan, Prediction, Scenario, Tracks};

/// The checks of one DFL: the obstacles, the braking model, the clock.
#[derive(Debug, Clone)]
pub struct Gatekeeper {
    /// The obstacles known from the scenario (absolute, m) grown by the fixed part of the
    /// growth, before the uncertainty term.
    discs: Vec<Disc>,
    /// The tracked obstacles' tracks, when any obstacle is tracked: checked as discs that
    /// move and grow as predicted (docs/safety.md, "Moving obstacles").
    tracks: Option<KeptTracks>,
    growth: ObstacleGrowth,
    /// The fallback brake's deceleration, m/s^2.
    brake_decel: f64,
    ts_s: f64,
    inner_tick_s: f64,
    /// `N Ts`, s: how long from now every choice is checked against a moving disc, the
    /// robot at rest after its brake included ([`Gatekeeper::moving_brake_verdict`]).
    horizon_s: f64,
}

/// How far ahead, and how, a check foresees the tracked obstacles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Foresight {
    /// How long from now a moving disc is checked against the robot at rest after the
    /// trajectory's brake, s (the trajectory and its brake are checked whole).
    pub window_s: f64,
    /// How each tracked obstacle is foreseen: changing its velocity by up to its bound for
    /// the safety check, going on as it goes for an evasion's look ahead.
    pub prediction: Prediction,
}

/// When a check starts: `into_sample_s` into sample `sample`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moment {
    pub sample: u64,
    pub into_sample_s: f64,
}

impl Gatekeeper {
    /// The checks against the obstacles known from the scenario and, once tracks come
    /// ([`Gatekeeper::set_tracks`]), against the discs the tracks predict.
    pub fn new(scenario: &Scenario) -> Gatekeeper {
        let growth = ObstacleGrowth::of(scenario);
        Gatekeeper {
            discs: scenario
                .known_obstacles()
                .map(|o| Disc::around(o, growth.fixed_m))
                .collect(),
            tracks: scenario.takes_tracks().then(|| KeptTracks::of(scenario)),
            growth,
            brake_decel: scenario.brake_decel(),
            ts_s: scenario.timing.ts_s,
            inner_tick_s: scenario.timing.dt_s(),
            horizon_s: scenario.mpc.horizon as f64 * scenario.timing.ts_s,
        }
    }

    /// Takes the tracker's newest tracks ([`KeptTracks::take`]).
    pub fn set_tracks(&mut self, tracks: &Tracks) {
        if let Some(kept) = &mut self.tracks {
            kept.take(tracks);
        }
    }

    /// How the safety check foresees the tracked obstacles: each checked against the
    /// robot until `N Ts` from now, changing its velocity by up to its bound
    /// ([`Prediction::Bounded`]).
    pub fn foresight(&self) -> Foresight {
        Foresight {
            window_s: self.horizon_s,
            prediction: Prediction::Bounded,
        }
    }

    /// How much the re-check of a committed trajectory grows every disc beyond the robot's
    /// radius and the safety margin, for an estimate with position standard deviation
    /// `sigma_m`: `kappa sigma`, m.
    pub fn keep_growth(&self, sigma_m: f64) -> f64 {
        self.growth.uncertainty_m(sigma_m)
    }

    /// How much the commit check grows every disc: [`Gatekeeper::keep_growth`] and
    /// [`protocol::commit_margin_m`], m.
    pub fn commit_growth(&self, sigma_m: f64) -> f64 {
        self.keep_growth(sigma_m) + protocol::commit_margin_m(sigma_m)
    }

    /// Checks the trajectory that flies `plan` from the state `z = [x, xdot, y, ydot]`
    /// (absolute coordinates) at `now`, and then brakes, against every disc grown by
    /// `grow` (m). Returns `None` when the trajectory stays outside them, else its deepest
    /// entry found (negative clearance, m).
    pub fn check(&self, plan: &Plan, now: Moment, z: [f64; 4], grow: f64) -> Option<f64> {
        self.verdict(plan, now, z, grow).deepest()
    }

    /// [`Gatekeeper::check`], with its contacts told apart by whether the robot still
    /// moves at them ([`Verdict`]).
    pub fn verdict(&self, plan: &Plan, now: Moment, z: [f64; 4], grow: f64) -> Verdict {
        self.verdict_within(plan, now, z, grow, self.foresight())
    }

    /// [`Gatekeeper::verdict`] with the tracked obstacles foreseen as `foresight` says
    /// rather than as the safety check does ([`Gatekeeper::foresight`]).
    pub fn verdict_within(
        &self,
        plan: &Plan,
        now: Moment,
        z: [f64; 4],
        grow: f64,
        foresight: Foresight,
    ) -> Verdict {
        let window_s = foresight.window_s;
        let start = [z[0], z[2]];
        let velocity = [z[1], z[3]];
        let first = crate::covering_element(plan, now.sample);
        // The plan's stages from now: (acceleration, duration) of each.
        let stages = || {
            first.into_iter().flat_map(move |first| {
                (first..plan.horizon as usize).map(move |i| {
                    let duration = if i == first {
                        (self.ts_s - now.into_sample_s).max(0.0)
                    } else {
                        self.ts_s
                    };
                    (plan.v[i], duration)
                })
            })
        };
        let mut found = Verdict::default();
        // Disc by disc, so that each disc's checked radius is computed once.
        for &Disc { center, radius, .. } in &self.discs {
            let radius = checked_radius(start, center, radius + grow);
            let (mut p, mut w) = (start, velocity);
            for (acc, duration) in stages() {
                // An obstacle at rest never comes to the robot: a contact with it is one
                // the robot makes, however slowly.
                found.note(arc_clearance(p, w, acc, duration, center, radius), false);
                advance(&mut p, &mut w, acc, duration);
            }
        }
        let stand_s = self.stand_for_s(now);
        for disc in self.moving_discs(start, now, grow, foresight.prediction) {
            if disc.motion.held {
                let held = self.held_verdict(&disc, stages(), (start, velocity), stand_s, window_s);
                found.add(held);
                continue;
            }
            let (mut p, mut w, mut elapsed) = (start, velocity, 0.0);
            for (acc, duration) in stages() {
                let clearance = moving_arc_clearance(p, w, acc, duration, &disc.at(elapsed));
                found.note(clearance, at_rest(w, acc, duration));
                advance(&mut p, &mut w, acc, duration);
                elapsed += duration;
            }
            found.add(self.moving_brake_verdict(p, w, &disc, elapsed, window_s));
        }
        let (mut p, mut w) = (start, velocity);
        for (acc, duration) in stages() {
            advance(&mut p, &mut w, acc, duration);
        }
        if let Some(clearance) = self.brake_clearance(p, w, grow, start) {
            found.note(clearance, false);
        }
        found
    }

    /// Checks braking at once from the state `z = [x, xdot, y, ydot]` at `now` against
    /// every disc grown by `grow` (m), as [`Gatekeeper::check`] does.
    pub fn brake_check(&self, z: [f64; 4], now: Moment, grow: f64) -> Option<f64> {
        self.brake_verdict(z, now, grow).deepest()
    }

    /// [`Gatekeeper::brake_check`], with its contacts told apart by whether the robot
    /// still moves at them ([`Verdict`]).
    pub fn brake_verdict(&self, z: [f64; 4], now: Moment, grow: f64) -> Verdict {
        self.brake_verdict_within(z, now, grow, self.foresight())
    }

    /// [`Gatekeeper::brake_verdict`] with the tracked obstacles foreseen as `foresight`
    /// says ([`Gatekeeper::verdict_within`]).
    pub fn brake_verdict_within(
        &self,
        z: [f64; 4],
        now: Moment,
        grow: f64,
        foresight: Foresight,
    ) -> Verdict {
        let window_s = foresight.window_s;
        let (p, w) = ([z[0], z[2]], [z[1], z[3]]);
        let mut found = Verdict::default();
        if let Some(clearance) = self.brake_clearance(p, w, grow, p) {
            found.note(clearance, false);
        }
        for disc in self.moving_discs(p, now, grow, foresight.prediction) {
            let mut verdict = self.moving_brake_verdict(p, w, &disc, 0.0, window_s);
            if disc.motion.held {
                // At rest, a phantom or an obstacle that stands still touches the robot
                // only by walking into it.
                verdict.resting = None;
            }
            found.add(verdict);
        }
        found
    }

    /// The check of a trajectory from `start` with `velocity`, flown over `stages`
    /// (acceleration, duration), against a phantom's or a standing track's `disc`
    /// ([`protocol::DiscMotion::held`]) that stands for `stand_s` from now
    /// (docs/safety.md, "What the lidar cannot see"). Until then something may have come
    /// out of the shadow, or set off, unseen: every stage keeps clear of the disc as it
    /// grows. Then it is seen: the stop from where the robot is then (from the plan's end,
    /// if sooner) must end before the growing disc reaches the robot, and the later
    /// stages keep clear of the disc held as it is now (the next tracks judge them), as
    /// the MPC's CBF rows do ([`Disc::staged`]). Only contacts while the robot moves
    /// count: a robot at rest is touched by a phantom, or by an obstacle that stands
    /// still, only if something walks into it.
    fn held_verdict(
        &self,
        disc: &Disc,
        stages: impl Iterator<Item = ([f64; 2], f64)>,
        (start, velocity): ([f64; 2], [f64; 2]),
        stand_s: f64,
        window_s: f64,
    ) -> Verdict {
        let (mut p, mut w, mut elapsed) = (start, velocity, 0.0);
        let mut found = Verdict::default();
        let mut stop_checked = false;
        for (acc, duration) in stages {
            if !stop_checked && elapsed + duration >= stand_s {
                let (mut q, mut u) = (p, w);
                advance(&mut q, &mut u, acc, stand_s - elapsed);
                found.add(self.moving_brake_verdict(q, u, disc, stand_s, window_s));
                stop_checked = true;
            }
            let staged = disc.staged(elapsed, stand_s);
            found.note(
                moving_arc_clearance(p, w, acc, duration, &staged),
                at_rest(w, acc, duration),
            );
            advance(&mut p, &mut w, acc, duration);
            elapsed += duration;
        }
        if !stop_checked {
            found.add(self.moving_brake_verdict(p, w, disc, elapsed, window_s));
        }
        Verdict {
            moving: found.moving,
            resting: None,
        }
    }

    /// How long from `now` the phantoms and standing tracks kept stand, s
    /// ([`KeptTracks::stand_for_s`]).
    fn stand_for_s(&self, now: Moment) -> f64 {
        let now_s = now.sample as f64 * self.ts_s + now.into_sample_s;
        self.tracks
            .as_ref()
            .map_or(0.0, |kept| kept.stand_for_s(now_s))
    }

    /// The discs the tracks predict at `now` as `prediction` says, grown by the fixed part
    /// and `grow` (m), as a trajectory from `start` is checked against them
    /// ([`checked_radius`]): none before the first track.
    fn moving_discs(
        &self,
        start: [f64; 2],
        now: Moment,
        grow: f64,
        prediction: Prediction,
    ) -> impl Iterator<Item = Disc> + '_ {
        let now_s = now.sample as f64 * self.ts_s + now.into_sample_s;
        let growth = self.growth.fixed_m + grow;
        self.tracks
            .iter()
            .flat_map(move |kept| kept.discs_predicted(now_s, growth, prediction))
            .map(move |disc| Disc {
                radius: checked_radius(start, disc.center, disc.radius),
                ..disc
            })
    }

    /// The clearance of braking from position `p` with velocity `w`, if the brake path
    /// enters a disc grown by `grow` (m) as a trajectory from `start` is checked
    /// ([`checked_radius`]).
    fn brake_clearance(&self, p: [f64; 2], w: [f64; 2], grow: f64, start: [f64; 2]) -> Option<f64> {
        let speed = w[0].hypot(w[1]);
        let stop = protocol::stopping_distance(speed, self.brake_decel, self.inner_tick_s);
        let end = if speed > 0.0 {
            [p[0] + w[0] / speed * stop, p[1] + w[1] / speed * stop]
        } else {
            p
        };
        self.discs
            .iter()
            .map(|&Disc { center, radius, .. }| {
                let radius = checked_radius(start, center, radius + grow);
                protocol::segment_distance(p, end, center) - radius
            })
            .filter(|c| *c < 0.0)
            .reduce(f64::min)
    }

    /// The contacts of braking, `elapsed_s` after now, from position `p` with velocity
    /// `w` with a moving `disc` (as it is now), m; then of the robot at rest until
    /// `window_s` after now. (Against a disc at rest, resting adds nothing;
    /// against one coming at the robot it makes staying one choice among others, not a
    /// safe one: the DFL can then take a plan out of the obstacle's way.) The brake is
    /// taken as the arc of constant deceleration that stops in
    /// [`protocol::stopping_distance`] (the held inner-tick commands stop a little later
    /// than the continuous brake; the arc covers that distance, over a longer time).
    fn moving_brake_verdict(
        &self,
        p: [f64; 2],
        w: [f64; 2],
        disc: &Disc,
        elapsed_s: f64,
        window_s: f64,
    ) -> Verdict {
        let speed = w[0].hypot(w[1]);
        let stop = protocol::stopping_distance(speed, self.brake_decel, self.inner_tick_s);
        let (acc, duration) = if speed == 0.0 || stop == 0.0 {
            ([0.0; 2], 0.0)
        } else {
            let decel = speed * speed / (2.0 * stop);
            (
                [-decel * w[0] / speed, -decel * w[1] / speed],
                2.0 * stop / speed,
            )
        };
        let mut found = Verdict::default();
        let braking = moving_arc_clearance(p, w, acc, duration, &disc.at(elapsed_s));
        found.note(braking, at_rest(w, acc, duration));
        let rest_s = window_s - elapsed_s - duration;
        if rest_s <= 0.0 {
            return found;
        }
        let mut at_rest = p;
        advance(&mut at_rest, &mut w.clone(), acc, duration);
        let resting = moving_arc_clearance(
            at_rest,
            [0.0; 2],
            [0.0; 2],
            rest_s,
            &disc.at(elapsed_s + duration),
        );
        found.note(resting, true);
        found
    }
}

/// What the check of a trajectory found: its deepest entry into a grown disc while the
/// robot moves, and after it has come to rest (negative clearances, m), if any. A robot
/// that enters no disc while it moves is at rest at its first contact, if any comes: a
/// contact the obstacle makes, not the robot (passive safety, docs/safety.md).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Verdict {
    pub moving: Option<f64>,
    pub resting: Option<f64>,
}

impl Verdict {
    /// The deepest entry of either kind, if any (negative clearance, m).
    pub fn deepest(self) -> Option<f64> {
        match (self.moving, self.resting) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Whether the trajectory enters no grown disc at all.
    pub fn clear(self) -> bool {
        self.deepest().is_none()
    }

    /// Whether every contact found comes with the robot at rest (or none comes): the
    /// robot has come to rest before its first predicted contact and does not move into
    /// one after it (a contact at rest followed by a move into another counts as moving).
    pub fn rests_before_contact(self) -> bool {
        self.moving.is_none()
    }

    /// Notes a clearance found (m) with the robot moving or `resting`.
    fn note(&mut self, clearance: f64, resting: bool) {
        if clearance < 0.0 {
            let kind = if resting {
                &mut self.resting
            } else {
                &mut self.moving
            };
            *kind = Some(kind.map_or(clearance, |d| d.min(clearance)));
        }
    }

    /// Notes what another part of the same trajectory found.
    fn add(&mut self, other: Verdict) {
        for (clearance, resting) in [(other.moving, false), (other.resting, true)] {
            if let Some(clearance) = clearance {
                self.note(clearance, resting);
            }
        }
    }
}

/// Whether the robot is at rest over an arc from velocity `w` at constant acceleration
/// `acc` for `duration` (s): slower than [`protocol::REST_SPEED_M_S`] at both ends (its
/// speed is largest at an end).
fn at_rest(w: [f64; 2], acc: [f64; 2], duration: f64) -> bool {
    let end = [w[0] + acc[0] * duration, w[1] + acc[1] * duration];
    w[0].hypot(w[1]) < protocol::REST_SPEED_M_S && end[0].hypot(end[1]) < protocol::REST_SPEED_M_S
}

/// Moves position `p` and velocity `w` on by `duration` (s) at constant acceleration `acc`.
fn advance(p: &mut [f64; 2], w: &mut [f64; 2], acc: [f64; 2], duration: f64) {
    for k in 0..2 {
        p[k] += w[k] * duration + 0.5 * acc[k] * duration * duration;
        w[k] += acc[k] * duration;
    }
}

/// The radius a trajectory from `start` is checked against for a disc at `center` of
/// radius `grown` (m): the grown radius, or, when `start` is inside it (the uncertainty
/// grew, say), the robot's distance from the centre now, less a nanometre against rounding.
/// A robot inside a grown disc may move, but not deeper; it never reaches the obstacle it
/// is not already in.
fn checked_radius(start: [f64; 2], center: [f64; 2], grown: f64) -> f64 {
    let now = (start[0] - center[0]).hypot(start[1] - center[1]);
    grown.min(now - 1e-9)
}

/// The smallest distance from `center` to the arc `q(t) = p + w t + acc t^2 / 2`,
/// `t in [0, duration]`, less `radius` (m): negative when the arc enters the disc. Exact;
/// a lower bound is returned instead when that bound already shows the arc outside.
pub fn arc_clearance(
    p: [f64; 2],
    w: [f64; 2],
    acc: [f64; 2],
    duration: f64,
    center: [f64; 2],
    radius: f64,
) -> f64 {
    let t = duration;
    let end = [
        p[0] + w[0] * t + 0.5 * acc[0] * t * t,
        p[1] + w[1] * t + 0.5 * acc[1] * t * t,
    ];
    // The arc departs from its chord by `acc t (t - T) / 2`, at most `|acc| T^2 / 8`.
    let bulge = acc[0].hypot(acc[1]) * t * t / 8.0;
    let lower_bound = protocol::segment_distance(p, end, center) - bulge - radius;
    if lower_bound >= 0.0 {
        return lower_bound;
    }
    arc_min_distance(p, w, acc, duration, center) - radius
}

/// The smallest distance from `center` to the arc `q(t) = p + w t + acc t^2 / 2`,
/// `t in [0, duration]`, m. The squared distance is a quartic in `t`; its stationary
/// points are the roots of the cubic `g(t) = (q(t) - o) . (w + acc t)`
/// ([`cubic_roots_within`]).
pub fn arc_min_distance(
    p: [f64; 2],
    w: [f64; 2],
    acc: [f64; 2],
    duration: f64,
    center: [f64; 2],
) -> f64 {
    let d = [p[0] - center[0], p[1] - center[1]];
    // g(t) = c3 t^3 + c2 t^2 + c1 t + c0.
    let (c3, c2, c1, c0) = (
        0.5 * dot(acc, acc),
        1.5 * dot(acc, w),
        dot(w, w) + dot(d, acc),
        dot(d, w),
    );
    let distance = |t: f64| {
        let q = [
            d[0] + w[0] * t + 0.5 * acc[0] * t * t,
            d[1] + w[1] * t + 0.5 * acc[1] * t * t,
        ];
        q[0].hypot(q[1])
    };
    cubic_roots_within([c3, c2, c1, c0], duration)
        .map(distance)
        .fold(distance(0.0).min(distance(duration)), f64::min)
}

/// The clearance of the arc `q(t) = p + w t + acc t^2 / 2`, `t in [0, duration]`, from a
/// disc that moves and grows (`disc` as it is at the arc's start, [`Disc::at`]), m: the
/// least `|q(t) - c(t)| - R(t)` found, negative when the arc enters the disc. Relative to
/// the centre, which moves at a constant velocity, the arc is again a parabola, so
/// `f(t) = |q(t) - c(t)|^2 - R(t)^2` is a quartic; where it is least on `[0, T]` (an end,
/// or a root of its cubic derivative, [`cubic_roots_within`]) the clearance is taken. It
/// is negative exactly where `f` is, so the arc enters the disc exactly when the
/// clearance returned is negative. As for a disc at rest ([`arc_clearance`]), a lower
/// bound is returned when it already shows the arc outside: the relative chord's
/// distance less the arc's bulge and the radius at the end (the largest: the disc only
/// grows).
pub fn moving_arc_clearance(
    p: [f64; 2],
    w: [f64; 2],
    acc: [f64; 2],
    duration: f64,
    disc: &Disc,
) -> f64 {
    let m = &disc.motion;
    let d = [p[0] - disc.center[0], p[1] - disc.center[1]];
    let u = [w[0] - m.velocity[0], w[1] - m.velocity[1]];
    let (r0, r1, r2) = (disc.radius, m.radius_rate, m.radius_accel);
    let radius = |t: f64| r0 + r1 * t + r2 * t * t;
    let relative = |t: f64| {
        [
            d[0] + u[0] * t + 0.5 * acc[0] * t * t,
            d[1] + u[1] * t + 0.5 * acc[1] * t * t,
        ]
    };
    let clearance = |t: f64| {
        let q = relative(t);
        q[0].hypot(q[1]) - radius(t)
    };
    let t = duration;
    let bulge = acc[0].hypot(acc[1]) * t * t / 8.0;
    let lower_bound = protocol::segment_distance(d, relative(t), [0.0; 2]) - bulge - radius(t);
    if lower_bound >= 0.0 {
        return lower_bound;
    }
    // f(t) = e4 t^4 + e3 t^3 + e2 t^2 + e1 t + e0; f'(t) = 4 e4 t^3 + 3 e3 t^2 + ...
    let e4 = 0.25 * dot(acc, acc) - r2 * r2;
    let e3 = dot(u, acc) - 2.0 * r1 * r2;
    let e2 = dot(u, u) + dot(d, acc) - r1 * r1 - 2.0 * r0 * r2;
    let e1 = 2.0 * dot(d, u) - 2.0 * r0 * r1;
    cubic_roots_within([4.0 * e4, 3.0 * e3, 2.0 * e2, e1], duration)
        .map(clearance)
        .fold(clearance(0.0).min(clearance(duration)), f64::min)
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// The roots in `(0, duration)` of the cubic `g(t) = c3 t^3 + c2 t^2 + c1 t + c0`
/// (`c = [c3, c2, c1, c0]`) where it changes sign, found by bisection on the intervals
/// where `g` is monotone (split at the roots of `g'`); roots at the ends are left out
/// (the callers count the ends anyway).
fn cubic_roots_within(c: [f64; 4], duration: f64) -> impl Iterator<Item = f64> {
    let [c3, c2, c1, c0] = c;
    let g = move |t: f64| ((c3 * t + c2) * t + c1) * t + c0;
    // Split [0, T] where g' = 3 c3 t^2 + 2 c2 t + c1 vanishes.
    let mut bounds = [0.0, duration, duration, duration];
    let mut count = 1;
    for root in quadratic_roots(3.0 * c3, 2.0 * c2, c1) {
        if root > 0.0 && root < duration {
            bounds[count] = root;
            count += 1;
        }
    }
    bounds[count] = duration;
    bounds[..=count].sort_by(f64::total_cmp);
    (0..count).filter_map(move |i| {
        let (mut lo, mut hi) = (bounds[i], bounds[i + 1]);
        let (g_lo, g_hi) = (g(lo), g(hi));
        if g_lo == 0.0 || g_hi == 0.0 || (g_lo < 0.0) == (g_hi < 0.0) {
            return None;
        }
        let rising = g_hi > 0.0;
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if (g(mid) > 0.0) == rising {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(0.5 * (lo + hi))
    })
}

/// The real roots of `a t^2 + b t + c` (none, or up to two; a linear equation when `a`
/// vanishes).
fn quadratic_roots(a: f64, b: f64, c: f64) -> impl Iterator<Item = f64> {
    let roots: [Option<f64>; 2] = if a == 0.0 {
        [(b != 0.0).then(|| -c / b), None]
    } else {
        let discriminant = b * b - 4.0 * a * c;
        if discriminant < 0.0 {
            [None, None]
        } else {
            // The stable form: no cancellation between -b and the root.
            let q = -0.5 * (b + b.signum() * discriminant.sqrt());
            if q == 0.0 {
                [Some(0.0), None]
            } else {
                [Some(q / a), Some(c / q)]
            }
        }
    };
    roots.into_iter().flatten()
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Obstacle, PlanStatus};

    /// The smallest distance over a fine grid of the arc, for comparison.
    fn sampled_min_distance(
        p: [f64; 2],
        w: [f64; 2],
        acc: [f64; 2],
        duration: f64,
        center: [f64; 2],
    ) -> f64 {
        (0..=100_000)
            .map(|k| {
                let t = duration * f64::from(k) / 100_000.0;
                let q = [
                    p[0] + w[0] * t + 0.5 * acc[0] * t * t - center[0],
                    p[1] + w[1] * t + 0.5 * acc[1] * t * t - center[1],
                ];
                q[0].hypot(q[1])
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// A deterministic sequence in [-1, 1].
    fn sequence(seed: f64) -> impl FnMut() -> f64 {
        let mut x = seed;
        move || {
            x = (x * 3.99 * (1.0 - x)).clamp(1e-6, 1.0 - 1e-6);
            2.0 * x - 1.0
        }
    }

    #[test]
    fn the_closest_point_of_an_arc_is_found_exactly() {
        let mut next = sequence(0.31);
        for _ in 0..2_000 {
            let p = [2.0 * next(), 2.0 * next()];
            let w = [3.0 * next(), 3.0 * next()];
            let acc = [5.0 * next(), 5.0 * next()];
            let duration = 0.05 + 0.5 * next().abs();
            let center = [next(), next()];
            let exact = arc_min_distance(p, w, acc, duration, center);
            let sampled = sampled_min_distance(p, w, acc, duration, center);
            // The grid's points are at most |q'| T / 2e5 from the true closest point.
            assert!(
                exact <= sampled + 1e-12 && sampled - exact < 1e-4,
                "p {p:?} w {w:?} acc {acc:?} T {duration}: {exact} vs sampled {sampled}"
            );
        }
    }

    #[test]
    fn the_quick_bound_never_calls_an_arc_safe_that_enters_the_disc() {
        let mut next = sequence(0.77);
        let (mut quick, mut exact) = (0, 0);
        for _ in 0..5_000 {
            let p = [next(), next()];
            let w = [2.0 * next(), 2.0 * next()];
            let acc = [4.0 * next(), 4.0 * next()];
            let (duration, center, radius) = (0.1, [0.3 * next(), 0.3 * next()], 0.5);
            let clearance = arc_clearance(p, w, acc, duration, center, radius);
            let truth = arc_min_distance(p, w, acc, duration, center) - radius;
            assert!(clearance <= truth + 1e-12, "bound above the truth");
            assert_eq!(clearance < 0.0, truth < 0.0, "p {p:?} w {w:?} acc {acc:?}");
            if clearance == truth {
                exact += 1
            } else {
                quick += 1
            }
        }
        assert!(quick > 100 && exact > 100, "{quick} quick, {exact} exact");
    }

    fn at(sample: u64, into_sample_s: f64) -> Moment {
        Moment {
            sample,
            into_sample_s,
        }
    }

    #[test]
    fn an_arc_enters_a_moving_growing_disc_exactly_when_the_clearance_found_is_negative() {
        let mut next = sequence(0.43);
        let (mut entering, mut clear) = (0, 0);
        for _ in 0..3_000 {
            let (p, w, acc) = (
                [2.0 * next(), 2.0 * next()],
                [3.0 * next(), 3.0 * next()],
                [5.0 * next(), 5.0 * next()],
            );
            let duration = 0.05 + next().abs();
            let disc = Disc {
                center: [next(), next()],
                radius: 0.2 + 0.5 * next().abs(),
                motion: protocol::DiscMotion {
                    velocity: [2.0 * next(), 2.0 * next()],
                    radius_rate: next().abs(),
                    radius_accel: 0.25 * next().abs(),
                    hidden: false,
                    standing: false,
                    held: false,
                },
            };
            let found = moving_arc_clearance(p, w, acc, duration, &disc);
            let sampled = (0..=20_000)
                .map(|k| {
                    let t = duration * f64::from(k) / 20_000.0;
                    let at = disc.at(t);
                    let q = [
                        p[0] + w[0] * t + 0.5 * acc[0] * t * t - at.center[0],
                        p[1] + w[1] * t + 0.5 * acc[1] * t * t - at.center[1],
                    ];
                    q[0].hypot(q[1]) - at.radius
                })
                .fold(f64::INFINITY, f64::min);
            if sampled.abs() < 1e-3 {
                continue; // grazing: within the grid's resolution
            }
            assert_eq!(found < 0.0, sampled < 0.0, "p {p:?} w {w:?} {disc:?}");
            if sampled < 0.0 {
                entering += 1;
                // A clearance the arc has at some time: no deeper than the deepest.
                assert!(found >= sampled - 1e-9, "{found} vs {sampled}");
            } else {
                clear += 1;
            }
        }
        assert!(
            entering > 300 && clear > 300,
            "{entering} entering, {clear} clear"
        );
    }

    /// The gatekeeper of a scenario whose only obstacle (0.3 m) starts at `(x, y)` and
    /// moves at `velocity`, before any track.
    fn tracking(x: f64, y: f64, velocity: [f64; 2]) -> Gatekeeper {
        Gatekeeper::new(&Scenario {
            obstacles: vec![Obstacle {
                velocity,
                ..Obstacle::fixed(x, y, 0.3)
            }],
            ..Scenario::default()
        })
    }

    #[test]
    fn running_into_where_a_moving_obstacle_will_be_fails_and_braking_short_of_it_passes() {
        // At 1 m/s along x from 1.5 m short of the crossing; the obstacle crosses the way
        // at 1 m/s, reaching it at t = 1.5 s.
        let mut g = tracking(0.0, -1.5, [0.0, 1.0]);
        let z = [-1.5, 1.0, 0.0, 0.0];
        let coasting = plan(0, 20, [0.0, 0.0]);
        assert_eq!(g.check(&coasting, at(0, 0.0), z, 0.0), None, "no track yet");
        g.set_tracks(&crate::tests::one_track(0.0, [0.0, -1.5], [0.0, 1.0]));
        assert!(g.check(&coasting, at(0, 0.0), z, 0.0).is_some());
        assert_eq!(g.brake_check(z, at(0, 0.0), 0.0), None);
        // Frozen where it is now, it would be far from the robot's way.
        let frozen = Gatekeeper::new(&scenario_with_obstacle(0.0, -1.5, 0.3));
        assert_eq!(frozen.check(&coasting, at(0, 0.0), z, 0.0), None);
        // Tracked 2 s later, past the way and walking on, it leaves the coasting clear.
        g.set_tracks(&crate::tests::one_track(2.0, [0.0, 0.5], [0.0, 1.0]));
        assert_eq!(g.check(&plan(40, 20, [0.0; 2]), at(40, 0.0), z, 0.0), None);
    }

    /// The gatekeeper of a robot with a lidar of `rate_hz` and phantoms that has been
    /// given one phantom (0.3 m, coming out at up to 1.5 m/s) at `center`, at `time_s`.
    fn seeing_a_phantom(center: [f64; 2], time_s: f64, rate_hz: f64) -> Gatekeeper {
        let sets = [
            format!("lidar.rate_hz={rate_hz}"),
            "perception.phantoms=true".to_string(),
        ];
        let scenario = Scenario::default().with_overrides(&sets).unwrap();
        let mut g = Gatekeeper::new(&scenario);
        let mut tracks = crate::tests::one_track(time_s, center, [0.0; 2]);
        let sigma_v = scenario.perception.phantom_speed / scenario.mpc.uncertainty_sigmas;
        tracks.tracks[0].obstacle = protocol::FIRST_PHANTOM;
        tracks.tracks[0].covariance = [0.0, 0.0, sigma_v.powi(2), 0.0, 0.0, sigma_v.powi(2)];
        g.set_tracks(&tracks);
        g
    }

    #[test]
    fn a_phantom_is_passed_slowly_enough_to_stop_before_anything_hidden_could_reach_the_robot() {
        // The way along x, 1 m from a shadow's edge whose phantom is at (0, 1); the robot
        // coasts for the plan's 0.4 s, then brakes at 3 m/s^2.
        let coasting = |g: &Gatekeeper, speed: f64| {
            let z = [-1.0, speed, 0.0, 0.0];
            g.verdict(&plan(0, 8, [0.0; 2]), at(0, 0.0), z, 0.0)
        };
        let g = seeing_a_phantom([0.0, 1.0], 0.0, 10.0);
        // At 1 m/s: a person stepping out now is seen by the next scan's phantoms, 0.15 s
        // on; braking from there, the robot is at rest 1.21 m from the phantom's place
        // when the person could be 1.05 m out.
        assert!(coasting(&g, 1.0).clear(), "{:?}", coasting(&g, 1.0));
        // At 3 m/s the stop takes a second, by when that person could be on the way.
        let fast = coasting(&g, 3.0);
        assert!(fast.moving.is_some(), "{fast:?}");
        // With a lidar at 1 Hz the phantoms stand for 1.05 s, longer than the plan: the
        // stop is checked from the plan's end, 0.4 m further on, and fails.
        let slow_lidar = seeing_a_phantom([0.0, 1.0], 0.0, 1.0);
        let late = coasting(&slow_lidar, 1.0);
        assert!(late.moving.is_some(), "{late:?}");
    }

    #[test]
    fn a_track_that_stands_still_may_be_crept_up_to_but_not_braked_at_late_nor_once_overdue() {
        // A box (0.3 m) seen standing still at (1, 0) at t = 0, on the robot's way along
        // x, its velocity known to 0.1 m/s: until the next scan, 0.15 s on, it may set off
        // at 0.5 m/s^2 from a velocity within 3 sigma; the next scan shows it if it does.
        let sets = [
            "lidar.rate_hz=10".to_string(),
            "perception.phantoms=false".to_string(),
        ];
        let mut g = Gatekeeper::new(&Scenario::default().with_overrides(&sets).unwrap());
        let mut tracks = crate::tests::one_track(0.0, [1.0, 0.0], [0.0; 2]);
        tracks.tracks[0].covariance = [1e-4, 0.0, 1e-2, 1e-4, 0.0, 1e-2];
        assert!(tracks.tracks[0].stands_still());
        g.set_tracks(&tracks);
        // Creeping at 0.1 m/s for a plan of 1 s, to 0.5 m from the box's centre, checked
        // at the track's time and 0.07 s after it: at rest before anything that set off
        // could reach it.
        let (x, speed, end_s) = (0.4, 0.1, 20.0 * g.ts_s);
        let creeping = |now: Moment| {
            g.verdict(
                &plan(now.sample, 20, [0.0; 2]),
                now,
                [x, speed, 0.0, 0.0],
                0.0,
            )
        };
        for now in [at(0, 0.0), at(1, 0.02)] {
            assert!(
                creeping(now).moving.is_none(),
                "{now:?}: {:?}",
                creeping(now)
            );
        }
        // Grown over the whole plan, as a walking track's is, the disc would have met the
        // robot while it still moves, at the plan's end.
        let grown = g
            .moving_discs([x, 0.0], at(0, 0.0), 0.0, g.foresight().prediction)
            .next()
            .unwrap()
            .at(end_s);
        assert!(1.0 - grown.radius < x + speed * end_s, "{grown:?}");
        // So it is once the track is overdue (0.2 s old, no next scan came): nothing shows
        // whether it set off.
        let overdue = creeping(at(4, 0.0));
        assert!(overdue.moving.is_some(), "{overdue:?}");
        // Braking from 3 m/s at 3 m/s^2 to rest at the same place: what set off could
        // reach the robot before it is at rest.
        let braking = g.verdict(
            &plan(0, 20, [-3.0, 0.0]),
            at(0, 0.0),
            [-1.0, 3.0, 0.0, 0.0],
            0.0,
        );
        assert!(braking.moving.is_some(), "{braking:?}");
    }

    #[test]
    fn a_plan_keeps_clear_of_where_a_phantom_is_and_a_robot_at_rest_is_never_touched_by_one() {
        // Driving through the phantom's place is a contact the robot makes.
        let g = seeing_a_phantom([0.0, 0.0], 0.0, 10.0);
        let z = [-0.6, 1.0, 0.0, 0.0];
        let through = g.verdict(&plan(0, 8, [0.0; 2]), at(0, 0.0), z, 0.0);
        assert!(through.moving.is_some(), "{through:?}");
        // A robot at rest 0.5 m from a phantom, whose disc grows over it: something
        // hidden could reach it there, but only by walking into it. So for a phantom of
        // this very sample (its stop checked 0.15 s on) and one 2 s old (overdue).
        let rest = [0.0, 0.0, 0.0, 0.0];
        for time_s in [1.0, -1.0] {
            let g = seeing_a_phantom([0.0, 0.5], time_s, 10.0);
            let staying = g.verdict(&plan(20, 8, [0.0; 2]), at(20, 0.0), rest, 0.0);
            assert!(staying.clear(), "{time_s}: {staying:?}");
            assert!(g.brake_verdict(rest, at(20, 0.0), 0.0).clear(), "{time_s}");
        }
        // A tracked person there whose velocity is uncertain to 0.5 m/s (not standing
        // still: they may walk at the robot) is another matter: the robot at rest is
        // judged touched.
        let mut person = seeing_a_phantom([0.0, 0.5], -1.0, 10.0);
        let mut tracks = crate::tests::one_track(-1.0, [0.0, 0.5], [0.0; 2]);
        tracks.tracks[0].covariance = [0.0, 0.0, 0.25, 0.0, 0.0, 0.25];
        person.set_tracks(&tracks);
        let judged = person.verdict(&plan(20, 8, [0.0; 2]), at(20, 0.0), rest, 0.0);
        assert!(
            judged.resting.is_some() && judged.moving.is_none(),
            "{judged:?}"
        );
    }

    fn scenario_with_obstacle(x: f64, y: f64, radius: f64) -> Scenario {
        Scenario {
            obstacles: vec![Obstacle::fixed(x, y, radius)],
            ..Scenario::default()
        }
    }

    fn plan(sample: u64, horizon: u32, v: [f64; 2]) -> Plan {
        let mut p = Plan {
            sample,
            horizon,
            status: PlanStatus::Solved as u32,
            ..Plan::default()
        };
        for i in 0..horizon as usize {
            p.v[i] = v;
        }
        p
    }

    #[test]
    fn inside_a_grown_disc_a_trajectory_may_move_away_but_not_deeper() {
        // 0.2 m from the edge, with a margin of 0.3 m: inside the grown disc, at rest.
        let mut s = scenario_with_obstacle(1.5, 0.0, 0.5);
        s.mpc.safety_margin_m = 0.3;
        let g = Gatekeeper::new(&s);
        let z = [0.8, 0.0, 0.0, 0.0];
        assert_eq!(
            g.check(&plan(0, 8, [-1.0, 0.0]), at(0, 0.0), z, 0.0),
            None,
            "away"
        );
        assert_eq!(
            g.check(&plan(0, 8, [0.0, 0.0]), at(0, 0.0), z, 0.0),
            None,
            "staying"
        );
        assert!(
            g.check(&plan(0, 8, [0.5, 0.0]), at(0, 0.0), z, 0.0)
                .is_some(),
            "deeper"
        );
    }

    #[test]
    fn braking_short_of_an_obstacle_passes_and_braking_into_it_fails() {
        // At 1 m/s towards an obstacle whose edge is 0.3 m ahead, braking at 3 m/s^2
        // stops in 1/6 m; at 2 m/s it needs 2/3 m.
        let s = scenario_with_obstacle(1.3, 0.0, 1.0);
        let g = Gatekeeper::new(&s);
        let coasting = plan(0, 0, [0.0; 2]);
        assert_eq!(
            g.check(&coasting, at(0, 0.0), [0.0, 1.0, 0.0, 0.0], 0.0),
            None
        );
        let depth = g
            .check(&coasting, at(0, 0.0), [0.0, 2.0, 0.0, 0.0], 0.0)
            .unwrap();
        let expected = 0.3 - protocol::stopping_distance(2.0, 3.0, s.timing.dt_s());
        assert!((depth - expected).abs() < 1e-12, "{depth} vs {expected}");
    }

    #[test]
    fn a_plan_that_turns_away_in_time_passes_and_one_that_keeps_going_fails() {
        // Moving at 1 m/s along x towards an obstacle whose edge is 1.0 m ahead.
        let s = scenario_with_obstacle(0.5, 0.0, 0.5);
        let g = Gatekeeper::new(&s);
        let z = [-1.0, 1.0, 0.0, 0.0];
        // Decelerating at 2 m/s^2 over 8 samples (0.4 s): 0.24 m, speed 0.2 m/s left,
        // stopping in 7 mm: clear.
        assert_eq!(g.check(&plan(0, 8, [-2.0, 0.0]), at(0, 0.0), z, 0.0), None);
        // Accelerating at 2 m/s^2: 0.56 m in 0.4 s at 1.8 m/s, 0.54 m more to stop.
        assert!(
            g.check(&plan(0, 8, [2.0, 0.0]), at(0, 0.0), z, 0.0)
                .is_some()
        );
        // Checked later in their lives, 0.19 m from the edge: only the last 0.025 s of
        // each is flown, then the brake: 0.210 m accelerating, 0.175 m decelerating.
        let z = [-0.19, 1.0, 0.0, 0.0];
        assert!(
            g.check(&plan(0, 8, [2.0, 0.0]), at(7, 0.025), z, 0.0)
                .is_some()
        );
        assert_eq!(
            g.check(&plan(0, 8, [-2.0, 0.0]), at(7, 0.025), z, 0.0),
            None
        );
    }

    #[test]
    fn the_commit_check_grows_every_disc_by_the_uncertainty_and_the_margin() {
        // From rest 1.0 m from the edge, creeping towards it at 0.5 m/s^2 for 0.4 s: 4 cm,
        // then the brake from 0.2 m/s.
        let mut s = scenario_with_obstacle(1.5, 0.0, 0.5);
        let z = [0.0, 0.0, 0.0, 0.0];
        let creep = plan(0, 8, [0.5, 0.0]);
        let reach = 0.04 + protocol::stopping_distance(0.2, 3.0, s.timing.dt_s());
        let g = Gatekeeper::new(&s);
        // kappa = 3: sigma 0.23 m grows the disc by 0.69 m, the commit margin by a sigma
        // and 1 mm more (0.921 m); sigma 0.24 m by 0.961 m, into which the creep reaches.
        assert_eq!(g.check(&creep, at(0, 0.0), z, g.commit_growth(0.23)), None);
        let depth = g
            .check(&creep, at(0, 0.0), z, g.commit_growth(0.24))
            .unwrap();
        let expected = 1.0 - reach - g.commit_growth(0.24);
        assert!((depth - expected).abs() < 1e-9, "{depth} vs {expected}");
        assert_eq!(
            g.check(&creep, at(0, 0.0), z, g.keep_growth(0.24)),
            None,
            "re-check"
        );
        // The robot's radius grows the disc too.
        s.robot.radius_m = 0.96;
        let depth = Gatekeeper::new(&s)
            .check(&creep, at(0, 0.0), z, 0.0)
            .unwrap();
        assert!((depth - (1.0 - reach - 0.96)).abs() < 1e-9, "{depth}");
    }
}
