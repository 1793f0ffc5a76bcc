//! `scmpc fuzz`: random valid worlds, each run in process on all cores, to measure the
//! safety property (docs/safety.md) on worlds nobody tuned for.
//!
//! The distribution (every draw independent, uniform unless said otherwise; seeded, so
//! `--seed` draws the same worlds, and every world runs the same unless a step of its
//! MPC takes longer than `Ts`: such a plan counts as late by its measured time, as in
//! lockstep (docs/design.md), so the world can end otherwise on a slower or busier
//! machine; see docs/safety.md):
//!
//! | what | drawn from |
//! |---|---|
//! | start, goal | anywhere in the position box (the paper's, ±10 m) at least [`EDGE_M`] inside its edges, at least 1 m apart (so up to its diagonal) |
//! | start heading | any, −π to π |
//! | `robot.zeta0` | at rest in half the worlds, else 0–1 m/s (already moving, whichever way it faces) |
//! | `robot.radius_m` | 0–0.3 m |
//! | obstacles | 1–6; centre at 20–80 % of the way from start to goal, up to 1.5 m to either side of the line; radius 0.2–1.5 m; redrawn while the start or the goal is within 0.3 m of its edge grown by the robot's radius |
//! | `timing.ts_s` | 0.02–0.1 s (`M` = 10) |
//! | `mpc.horizon` | 8–20 |
//! | `mpc.gamma` | 0.05–1 |
//! | `mpc.v_max` | 1–5 m/s² (the brake's deceleration follows: `auto`) |
//! | wheel saturation | off in half the worlds, else `plant.max_wheel_speed_rad_s` 12–40 rad/s |
//! | output noise | `plant.noise_variance` 0–0.01 (`--set plant.noise_variance=...` forces one) |
//! | `plant.disturbance_std` | none in half the worlds, else 0–0.02 |
//! | `duration_s` | 40 s, plus 4 s per metre of start–goal distance beyond 9 m; `seed` (noise) the world's index |
//! | moving obstacles | in a share of the worlds (`--people`, [`PEOPLE`] by default) 1–2 more, radius 0.2–0.4 m (people), each one of: *crossing* the line at 0.5–1.5 m/s, level with it at 30–70 % of the way at 2 s + 1 s per metre of the way; *oncoming* along the line from 80–120 % of the way at 0.3–1 m/s, up to 0.5 m aside; *stepping into the way* from 1.5–3 m aside at 1–6 s, at up to 0.5–1.2 m/s (speeding up and slowing down at 0.5 m/s², a path point every 0.1 s), and standing there; `perception.noise_std` 0.02 m in half of those worlds, else 0. Drawn last, from a stream of their own; obstacles at rest are solid to them: one who would walk through one stops short of it, braking at 0.5 m/s² (one stepping in steps only as far as they can, and one without room stands where they are, an obstacle at rest), or is left out when they cannot ([`solid`]) |
//! | `--perception lidar` | the default `[lidar]` (360 beams, 8 m, 10 Hz) in every world; each obstacle at rest of radius up to 0.6 m a box not in the map (`known = false`) with probability one half (from a stream of its own: the worlds are otherwise the same); the larger ones stay in the map, and hide what is behind them. In half the worlds, from the same stream, two obstacles more: a pillar in the map at 30–70 % of the way, radius 0.5–1 m, its edge 0.3–1 m (and the robot's radius) to either side, and a person of radius 0.2–0.35 m standing behind it, hidden from where a robot at 0.4–1.2 m/s would be when they leave, and far enough along the way to step out past it with 0.1 m to spare; they leave so as to reach the way about when that robot reaches the pillar, step out across the way to 1 m past it, speeding up and slowing down at 0.5 m/s² to at most 0.8–1.5 m/s, and stand there ([`occluders`]); the pillar is solid to the people too ([`solid`]) |
//!
//! Every other key is the paper's. The `--set` overrides are applied on top of every world
//! (a user fuzzes their own tuning), and the world is validated: one the overrides make
//! invalid (a start inside a grown obstacle, say) is drawn again.

use crate::sweep::{self, RunSpec};
use anyhow::Context;
use protocol::distance;
use protocol::{NoiseVariance, Obstacle, Scenario, ScenarioErrors, Validated};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use record::judge::{Outcome, StallReason};
use record::{Percentiles, Summary};
use std::f64::consts::PI;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

mod occluders;
mod solid;

/// Start and goal are drawn at least this far inside the position box's edges, m (a robot
/// at an edge, already moving outwards, may have no way to stay in the box).
pub const EDGE_M: f64 = 0.5;

/// The share of the worlds with people on the way (moving obstacles) by default.
pub const PEOPLE: f64 = 0.5;

/// Draws of a world that its overrides make invalid before giving up.
const MAX_DRAWS: usize = 100;

/// One generated world.
#[derive(Debug, Clone)]
pub struct World {
    pub index: usize,
    pub scenario: Validated,
}

/// World `index` of the batch `seed`: the distribution of the module docs, `overrides`
/// applied on top, validated.
pub fn world(
    seed: u64,
    index: usize,
    draws: Draws,
    overrides: &[String],
) -> Result<World, ScenarioErrors> {
    let stream = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(stream);
    // Boxes not in the map from a stream of their own: the worlds are the same otherwise.
    let mut boxes = ChaCha8Rng::seed_from_u64(stream ^ 0x6c_6964_6172);
    let mut last_error = None;
    for _ in 0..MAX_DRAWS {
        let mut scenario = draw(&mut rng, index, draws.people);
        if draws.lidar {
            seen_through_a_lidar(&mut scenario, &mut boxes);
        }
        let scenario = scenario.with_overrides(overrides)?;
        match scenario.validated(&format!("fuzz world {index}")) {
            Ok(scenario) => return Ok(World { index, scenario }),
            Err(e) => last_error = Some(e),
        }
    }
    Err(last_error.unwrap_or_else(|| ScenarioErrors(Vec::new())))
}

/// What a batch draws beyond the obstacles at rest: the share of its worlds with people
/// on the way, and whether the robot sees through a lidar (`--perception lidar`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Draws {
    pub people: f64,
    pub lidar: bool,
}

impl Default for Draws {
    fn default() -> Self {
        Draws {
            people: PEOPLE,
            lidar: false,
        }
    }
}

/// The largest radius of a box not in the map, m: a larger obstacle at rest is a pillar
/// or a wall, which a map holds.
pub const BOX_RADIUS_M: f64 = 0.6;

/// The world `s` seen through the default lidar (`--perception lidar`, module docs): each
/// obstacle at rest of radius up to [`BOX_RADIUS_M`] is, in half the worlds' draws, a box
/// not in the map; the larger ones stay in it and hide what is behind them; in half the
/// worlds a pillar hides a person who steps out ([`occluders::pillar_and_person`]).
fn seen_through_a_lidar(s: &mut Scenario, rng: &mut ChaCha8Rng) {
    s.lidar = Some(protocol::LidarConfig::default());
    for obstacle in s.obstacles.iter_mut().filter(|o| !o.moves()) {
        let unmapped = rng.random_bool(0.5);
        if obstacle.radius <= BOX_RADIUS_M && unmapped {
            obstacle.known = Some(false);
        }
    }
    let [x, y, _] = s.robot.start;
    let way = Way::between([x, y], s.robot.goal.position);
    if let Some(occluded) = occluders::pillar_and_person(rng, &way, s.robot.radius_m) {
        s.obstacles.extend(occluded);
    }
    solid::keep_people_out(s);
}

/// One draw from the distribution (before overrides).
fn draw(rng: &mut ChaCha8Rng, index: usize, people: f64) -> Scenario {
    let mut s = Scenario {
        name: format!("fuzz-{index:04}"),
        seed: index as u64 + 1,
        duration_s: 40.0,
        ..Scenario::default()
    };
    let c = &s.mpc;
    let (lo, hi) = (c.position_min, c.position_max);
    let mut anywhere = || [0, 1].map(|a| rng.random_range(lo[a] + EDGE_M..hi[a] - EDGE_M));
    let goal = anywhere();
    let start = loop {
        let p = anywhere();
        if distance(p, goal) >= 1.0 {
            break p;
        }
    };
    let span = distance(start, goal);
    s.duration_s = 40.0 + 4.0 * (span - 9.0).max(0.0);
    s.robot.start = [start[0], start[1], rng.random_range(-PI..PI)];
    s.robot.goal.position = goal;
    s.robot.zeta0 = if rng.random_bool(0.5) {
        0.0
    } else {
        rng.random_range(0.0..1.0)
    };
    s.robot.radius_m = rng.random_range(0.0..0.3);
    s.timing.ts_s = rng.random_range(0.02..0.1);
    s.mpc.horizon = rng.random_range(8..=20);
    s.mpc.gamma = rng.random_range(0.05..=1.0);
    s.mpc.v_max = rng.random_range(1.0..5.0);
    s.plant.noise_variance = NoiseVariance::Uniform(rng.random_range(0.0..0.01));
    s.plant.disturbance_std = if rng.random_bool(0.5) {
        0.0
    } else {
        rng.random_range(0.0..0.02)
    };
    s.plant.max_wheel_speed_rad_s = if rng.random_bool(0.5) {
        rng.random_range(12.0..40.0)
    } else {
        0.0
    };
    let count = rng.random_range(1..=6);
    let way = Way::between(start, goal);
    let (along_line, normal) = (way.along, way.normal);
    let footprint = s.robot.radius_m;
    s.obstacles = (0..count)
        .map(|_| {
            loop {
                let along = span * rng.random_range(0.2..0.8);
                let aside = rng.random_range(-1.5..1.5);
                let radius = rng.random_range(0.2..1.5);
                let x = start[0] + along * along_line[0] + aside * normal[0];
                let y = start[1] + along * along_line[1] + aside * normal[1];
                let clear = |p: [f64; 2]| distance(p, [x, y]) > radius + footprint + 0.3;
                if clear(start) && clear(goal) {
                    break Obstacle::fixed(x, y, radius);
                }
            }
        })
        .collect();
    let mut moving = ChaCha8Rng::seed_from_u64(rng.random::<u64>() ^ 0x6d6f_7669_6e67);
    if moving.random_bool(people.clamp(0.0, 1.0)) {
        add_people(&mut s, &mut moving, &[way]);
    }
    s
}

/// One or two people on `ways` (each on one of them, drawn when there are several: a
/// fleet's robots' ways) added to `s` ([`moving_obstacle`]), measured with noise half the
/// time, and kept out of the obstacles at rest ([`solid::keep_people_out`]).
pub(crate) fn add_people(s: &mut Scenario, rng: &mut ChaCha8Rng, ways: &[Way]) {
    let count = rng.random_range(1..=2);
    let at_rest = s.obstacles.clone();
    for _ in 0..count {
        let way = match ways.len() {
            1 => &ways[0],
            n => &ways[rng.random_range(0..n)],
        };
        s.obstacles.push(moving_obstacle(rng, way, &at_rest));
    }
    s.perception.noise_std = if rng.random_bool(0.5) { 0.02 } else { 0.0 };
    solid::keep_people_out(s);
}

/// The straight way from the start to the goal: where it starts, its unit direction and
/// normal, its length, m.
pub(crate) struct Way {
    start: [f64; 2],
    along: [f64; 2],
    normal: [f64; 2],
    span: f64,
}

impl Way {
    /// The way from `start` to `goal` (m), at least 1 m apart.
    pub(crate) fn between(start: [f64; 2], goal: [f64; 2]) -> Way {
        let span = distance(start, goal);
        let along = [(goal[0] - start[0]) / span, (goal[1] - start[1]) / span];
        Way {
            start,
            along,
            normal: [-along[1], along[0]],
            span,
        }
    }

    /// The point `along_m` along the way and `aside_m` to its left.
    fn at(&self, along_m: f64, aside_m: f64) -> [f64; 2] {
        [0, 1].map(|a| self.start[a] + along_m * self.along[a] + aside_m * self.normal[a])
    }
}

/// A person on the way (module docs): crossing it, coming along it, or stepping into it
/// (as far as the obstacles `at_rest` let them, [`solid::room_m`]) and standing.
fn moving_obstacle(rng: &mut ChaCha8Rng, way: &Way, at_rest: &[Obstacle]) -> Obstacle {
    let radius = rng.random_range(0.2..0.4);
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    match rng.random_range(0..3) {
        0 => {
            let speed = rng.random_range(0.5..1.5);
            let level_at_s = 2.0 + way.span;
            let [x, y] = way.at(way.span * rng.random_range(0.3..0.7), 0.0);
            let v = way.normal.map(|n| side * speed * n);
            Obstacle {
                velocity: v,
                ..Obstacle::fixed(x - v[0] * level_at_s, y - v[1] * level_at_s, radius)
            }
        }
        1 => {
            let speed = rng.random_range(0.3..1.0);
            let from = way.span * rng.random_range(0.8..1.2);
            let [x, y] = way.at(from, side * rng.random_range(0.0..0.5));
            Obstacle {
                velocity: way.along.map(|a| -speed * a),
                ..Obstacle::fixed(x, y, radius)
            }
        }
        _ => {
            let along = way.span * rng.random_range(0.3..0.7);
            let aside = side * rng.random_range(1.5..3.0);
            let leaves_s = rng.random_range(1.0..6.0);
            let speed = rng.random_range(0.5..1.2);
            let from = way.at(along, aside);
            let towards = way.normal.map(|n| -side * n);
            let room = solid::room_m(from, towards, radius, at_rest).min(aside.abs());
            if room < STEP_IN_LEAST_M {
                // Never moving, an obstacle at rest like any other (in the map unless a
                // lidar world draws it out of it).
                return walking(radius, vec![[0.0, from[0], from[1]]]);
            }
            let path = step_in(room, speed, leaves_s)
                .map(|(t, d)| {
                    let [x, y] = way.at(along, side * (aside.abs() - d));
                    [t, x, y]
                })
                .collect();
            walking(radius, path)
        }
    }
}

/// A person of `radius` (m) who walks `path` (`[t, x, y]` points, s and m).
fn walking(radius: f64, path: Vec<[f64; 3]>) -> Obstacle {
    Obstacle {
        x: f64::NAN,
        y: f64::NAN,
        radius,
        velocity: [0.0; 2],
        path,
        known: None,
    }
}

/// A person with less room than this to step into the way stands where they are, m.
const STEP_IN_LEAST_M: f64 = 0.1;

/// Acceleration of a person stepping into the way, m/s^2: within the tracker's default
/// bound (`perception.accel_max`), the assumption of passive safety (docs/safety.md).
const STEP_IN_ACCEL: f64 = 0.5;

/// `(t, distance walked)` every 0.1 s of a walk of `distance_m` from rest to rest,
/// leaving at `leaves_s`: accelerating at [`STEP_IN_ACCEL`] up to `speed_m_s` (or half way),
/// on at that speed, braking the same to stop there; from rest at `(0, 0)`.
fn step_in(distance_m: f64, speed_m_s: f64, leaves_s: f64) -> impl Iterator<Item = (f64, f64)> {
    let a = STEP_IN_ACCEL;
    let top = speed_m_s.min((a * distance_m).sqrt());
    let ramp_s = top / a;
    let cruise_s = (distance_m - top * ramp_s) / top;
    let walk_s = 2.0 * ramp_s + cruise_s;
    let walked = move |t: f64| {
        if t <= ramp_s {
            0.5 * a * t * t
        } else if t <= ramp_s + cruise_s {
            0.5 * top * ramp_s + top * (t - ramp_s)
        } else {
            let left = (walk_s - t).max(0.0);
            distance_m - 0.5 * a * left * left
        }
    };
    // Every 0.1 s to the first such time at rest, so that each segment is as long and
    // the path keeps the bound at its points too (`protocol::PATH_CORNER_S`).
    let steps = (walk_s / 0.1).ceil() as usize;
    std::iter::once((0.0, 0.0)).chain((0..=steps).map(move |k| {
        let t = k as f64 * 0.1;
        (leaves_s + t, walked(t))
    }))
}

/// A robot that goes farther than this from its goal after coming within 0.2 m of it
/// wandered (Nav2's default goal tolerance), m.
pub const WANDERED_BEYOND_M: f64 = 0.25;

/// A batch of worlds: its seed (the same seed draws the same worlds), how many, and what
/// they draw beyond the obstacles at rest ([`Draws`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    pub seed: u64,
    pub count: usize,
    pub draws: Draws,
}

/// The outcome of a batch.
pub struct Report {
    pub worlds: Vec<World>,
    pub results: Vec<anyhow::Result<Summary>>,
}

impl Report {
    /// Worlds per outcome, in a fixed order (errors last).
    pub fn counts(&self) -> Vec<(&'static str, usize)> {
        let outcomes = [
            Outcome::Reached,
            Outcome::Collided,
            Outcome::Stalled,
            Outcome::Timeout,
            Outcome::Interrupted,
            Outcome::Aborted,
            Outcome::NoRoute,
        ];
        let mut counts: Vec<(&'static str, usize)> = outcomes
            .iter()
            .map(|o| {
                let n = self
                    .results
                    .iter()
                    .filter(|r| r.as_ref().is_ok_and(|s| s.outcome == *o))
                    .count();
                (o.as_str(), n)
            })
            .collect();
        counts.push(("error", self.results.iter().filter(|r| r.is_err()).count()));
        counts
    }

    /// Worlds that ended with `outcome`.
    pub fn count(&self, outcome: Outcome) -> usize {
        self.results
            .iter()
            .filter(|r| r.as_ref().is_ok_and(|s| s.outcome == outcome))
            .count()
    }

    /// Worlds that stalled or timed out for `reason`.
    pub fn stall_count(&self, reason: StallReason) -> usize {
        self.results
            .iter()
            .filter(|r| r.as_ref().is_ok_and(|s| s.stall_reason == Some(reason)))
            .count()
    }

    pub fn collisions(&self) -> usize {
        self.count(Outcome::Collided)
    }

    /// Share of the worlds with a route (all but those ending `no_route`) that reached
    /// the goal.
    pub fn reach_of_routable(&self) -> f64 {
        let routable = self.results.len() - self.count(Outcome::NoRoute);
        self.count(Outcome::Reached) as f64 / routable.max(1) as f64
    }

    /// The table printed at the end: each outcome's count and rate, and the safety
    /// layers' activity.
    pub fn table(&self) -> String {
        let total = self.results.len().max(1);
        let mut out = String::new();
        for (name, n) in self.counts().into_iter().filter(|(_, n)| *n > 0) {
            out += &format!(
                "  {name:<12} {n:>5}  {:>5.1} %\n",
                100.0 * n as f64 / total as f64
            );
        }
        for reason in StallReason::ALL {
            let n = self.stall_count(reason);
            if n > 0 {
                out += &format!("    {:<24} {n:>5}\n", reason.as_str());
            }
        }
        let summaries = self.results.iter().filter_map(|r| r.as_ref().ok());
        let (interventions, failures) = summaries.fold((0, 0), |(i, f), s| {
            (i + s.safety_interventions, f + s.solver_failures)
        });
        out += &format!(
            "  {} worlds; safety interventions {interventions}, solver failures {failures}\n",
            self.results.len()
        );
        let at_rest = self
            .results
            .iter()
            .filter(|r| r.as_ref().is_ok_and(|s| s.contacts_at_rest > 0))
            .count();
        if at_rest > 0 {
            out += &format!("  contacts at rest in {at_rest} worlds\n");
        }
        let seen = (self.results.iter()).filter_map(|r| r.as_ref().ok()?.perception);
        let (seeing, false_tracks, missed) = seen.fold((0, 0, 0), |(n, f, m), p| {
            (n + 1, f + p.false_tracks, m + p.missed_obstacles)
        });
        if seeing > 0 {
            out += &format!(
                "  perception: {false_tracks} false tracks, {missed} obstacles missed in {seeing} worlds\n"
            );
        }
        if self.count(Outcome::NoRoute) > 0 {
            out += &format!(
                "  reached {:.1} % of the worlds with a route\n",
                100.0 * self.reach_of_routable()
            );
        }
        out + &self.arrival_table()
    }

    /// The final approaches ([`record::ArrivalReport`]) of the worlds that came within
    /// 0.2 m of their goal: the largest distance after that, and the time to rest.
    pub fn arrivals(&self) -> Vec<record::ArrivalReport> {
        let summaries = self.results.iter().filter_map(|r| r.as_ref().ok());
        summaries.filter_map(|s| s.arrival).collect()
    }

    /// The table's lines on the final approaches: percentiles over the worlds that came
    /// within 0.2 m, and how many went out beyond [`WANDERED_BEYOND_M`] or ended
    /// without coming to rest.
    fn arrival_table(&self) -> String {
        let arrivals = self.arrivals();
        if arrivals.is_empty() {
            return String::new();
        }
        let farthest: Vec<f64> = arrivals
            .iter()
            .map(|a| a.largest_distance_after_m)
            .collect();
        // A world that ended without coming to rest counts as never (infinite).
        let to_rest: Vec<f64> = arrivals
            .iter()
            .map(|a| a.time_to_rest_s.unwrap_or(f64::INFINITY))
            .collect();
        let never = to_rest.iter().filter(|t| t.is_infinite()).count();
        let beyond = farthest.iter().filter(|&&d| d > WANDERED_BEYOND_M).count();
        let (f, r) = (Percentiles::of(&farthest), Percentiles::of(&to_rest));
        let rest_m = arrivals.iter().map(|a| a.rest_within_m).fold(0.0, f64::max);
        let mut out = format!(
            "  after coming within 0.2 m ({} worlds): distance to the goal p50 {:.3}, p99 {:.3}, max {:.3} m; beyond {WANDERED_BEYOND_M} m in {beyond} ({:.1} %)\n",
            arrivals.len(),
            f.p50,
            f.p99,
            f.max,
            100.0 * beyond as f64 / arrivals.len() as f64
        );
        let s = |t: f64| {
            if t.is_finite() {
                format!("{t:.2} s")
            } else {
                "never".to_string()
            }
        };
        out += &format!(
            "  then to rest within {rest_m} m: p50 {}, p99 {}, max {}; not at rest at the end in {never}\n",
            s(r.p50),
            s(r.p99),
            s(r.max),
        );
        out
    }
}

/// Runs `count` worlds of batch `seed` on `threads` threads into `out`: `fuzz.csv`, a
/// scenario file under `out/failed/` for every world that did not reach the goal or
/// touched an obstacle on the way (at rest), and no run directories (such a world replays
/// with `scmpc run FILE`).
pub fn run(
    Batch { seed, count, draws }: Batch,
    overrides: &[String],
    out: &Path,
    threads: usize,
    progress: bool,
    stop: &AtomicBool,
) -> anyhow::Result<Report> {
    let mut worlds = (0..count)
        .map(|i| world(seed, i, draws, overrides))
        .collect::<Result<Vec<_>, _>>()?;
    let runs: Vec<RunSpec> = worlds
        .iter()
        .map(|w| RunSpec {
            values: Vec::new(),
            combination: w.index,
            scenario: w.scenario.clone(),
            dir: out.join("runs").join(format!("{:04}", w.index)),
        })
        .collect();
    let results = sweep::run_all(&runs, threads, progress, false, stop);
    worlds.truncate(results.len()); // interrupted: the worlds that ran
    let report = Report { worlds, results };
    let _ = std::fs::remove_dir_all(out.join("runs"));
    write_csv(&report, out).with_context(|| format!("writing {}", out.display()))?;
    Ok(report)
}

/// Where the scenario of a world that did not reach the goal, or touched an obstacle, is
/// kept.
fn failed_file(out: &Path, index: usize) -> PathBuf {
    out.join("failed").join(format!("{index:04}.toml"))
}

/// `fuzz.csv`, and the scenario file of every world that did not reach the goal or
/// touched an obstacle.
fn write_csv(report: &Report, out: &Path) -> anyhow::Result<()> {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.3}"));
    std::fs::create_dir_all(out.join("failed"))?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(out.join("fuzz.csv"))?);
    writeln!(
        f,
        "world,obstacles,moving,ts_s,horizon,gamma,v_max,noise_variance,disturbance_std,max_wheel_speed_rad_s,robot_radius_m,zeta0,start_distance_m,outcome,stall_reason,min_clearance_m,min_static_clearance_m,final_distance_m,time_to_goal_s,within_0_2_m_s,largest_distance_after_m,time_to_rest_s,safety_interventions,solver_failures,deadline_misses,contacts_at_rest,false_tracks,missed_obstacles,file"
    )?;
    for (world, result) in report.worlds.iter().zip(&report.results) {
        let s = &world.scenario;
        let [x, y, _] = s.robot.start;
        let params = format!(
            "{},{},{},{:.4},{},{:.4},{:.3},{},{:.4},{:.2},{:.3},{:.3},{:.3}",
            world.index,
            s.obstacles.len(),
            s.obstacles.iter().filter(|o| o.moves()).count(),
            s.timing.ts_s,
            s.mpc.horizon,
            s.mpc.gamma,
            s.mpc.v_max,
            s.plant.noise_variance.per_axis()[0],
            s.plant.disturbance_std,
            s.plant.max_wheel_speed_rad_s,
            s.robot.radius_m,
            s.robot.zeta0,
            (x - s.robot.goal.position[0]).hypot(y - s.robot.goal.position[1]),
        );
        let clean = (result.as_ref())
            .is_ok_and(|r| r.outcome == Outcome::Reached && r.contacts_at_rest == 0);
        let file = if clean {
            String::new()
        } else {
            let path = failed_file(out, world.index);
            std::fs::write(&path, s.to_toml())?;
            path.display().to_string()
        };
        match result {
            Ok(r) => writeln!(
                f,
                "{params},{},{},{:.6},{},{:.3},{},{},{},{},{},{},{},{},{},{},{file}",
                r.outcome.as_str(),
                r.stall_reason.map_or("", |reason| reason.as_str()),
                r.min_clearance_m,
                r.min_static_clearance_m
                    .map_or(String::new(), |v| format!("{v:.6}")),
                r.final_distance_to_goal_m,
                opt(r.time_to_goal_s),
                opt(r.arrival.map(|a| a.within_0_2_m_s)),
                opt(r.arrival.map(|a| a.largest_distance_after_m)),
                opt(r.arrival.and_then(|a| a.time_to_rest_s)),
                r.safety_interventions,
                r.solver_failures,
                r.deadline_misses,
                r.contacts_at_rest,
                r.perception
                    .map_or(String::new(), |p| p.false_tracks.to_string()),
                r.perception
                    .map_or(String::new(), |p| p.missed_obstacles.to_string()),
            )?,
            Err(e) => writeln!(
                f,
                "{params},error: {},,,,,,,,,,,,,,,{file}",
                format!("{e:#}").replace(',', ";")
            )?,
        }
    }
    Ok(f.flush()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_is_the_same_for_a_seed_and_differs_across_seeds() {
        let a = world(7, 3, Draws::default(), &[]).unwrap().scenario;
        assert_eq!(a, world(7, 3, Draws::default(), &[]).unwrap().scenario);
        assert_ne!(a, world(8, 3, Draws::default(), &[]).unwrap().scenario);
        assert_ne!(a, world(7, 4, Draws::default(), &[]).unwrap().scenario);
    }

    #[test]
    fn a_lidar_batch_draws_the_same_worlds_with_a_lidar_and_small_obstacles_half_unmapped() {
        let lidar = Draws {
            lidar: true,
            ..Draws::default()
        };
        let (mut unmapped, mut small, mut with_occluder) = (0, 0, 0);
        for i in 0..200 {
            let seen = world(5, i, lidar, &[]).unwrap().scenario.into_inner();
            let mut plain = world(5, i, Draws::default(), &[])
                .unwrap()
                .scenario
                .into_inner();
            assert_eq!(seen.lidar, Some(protocol::LidarConfig::default()));
            // The obstacles at rest first, as drawn, some unmapped.
            let at_rest = plain.obstacles.iter().filter(|o| !o.moves()).count();
            for (a, b) in seen
                .obstacles
                .iter()
                .zip(&mut plain.obstacles)
                .take(at_rest)
            {
                assert!(a.known.is_none() || (a.radius <= BOX_RADIUS_M && !a.moves()));
                small += usize::from(a.radius <= BOX_RADIUS_M && !a.moves());
                unmapped += usize::from(a.known == Some(false));
                b.known = a.known;
            }
            // Then the people, and in some worlds the occluder and its person after them:
            // the same world, its people kept out of the pillar too.
            let occluder = seen.obstacles.iter().skip(at_rest).position(|o| !o.moves());
            if let Some(k) = occluder {
                let occluded = &seen.obstacles[at_rest + k..];
                assert!(occluded.len() <= 2, "{occluded:?}");
                assert!(occluded[0].known.is_none() && occluded.iter().skip(1).all(|o| o.moves()));
                plain.obstacles.extend_from_slice(occluded);
                solid::keep_people_out(&mut plain);
                for o in &mut plain.obstacles {
                    // As a world's file has them: a path's obstacle where it is at t = 0
                    // (a person who brakes at once started before the run).
                    if !o.path.is_empty() {
                        [o.x, o.y] = o.center_at(0.0);
                    }
                }
                with_occluder += 1;
            }
            plain.lidar = seen.lidar.clone();
            assert_eq!(seen, plain, "world {i} is the same world");
        }
        let share = unmapped as f64 / small as f64;
        assert!(
            (0.4..0.6).contains(&share),
            "{unmapped} of {small} small obstacles unmapped"
        );
        assert!(
            (60..140).contains(&with_occluder),
            "{with_occluder} of 200 occluded"
        );
    }

    #[test]
    fn every_world_is_valid_and_within_the_documented_distribution() {
        let (mut far, mut moving, mut noisy, mut disturbed) = (0, 0, 0, 0);
        let mut with_people = 0;
        for i in 0..300 {
            let s = world(1, i, Draws::default(), &[]).unwrap().scenario;
            let [x, y, heading] = s.robot.start;
            let goal = s.robot.goal.position;
            let span = distance([x, y], goal);
            assert!(span >= 1.0, "{span}");
            for p in [[x, y], goal] {
                for (a, value) in p.into_iter().enumerate() {
                    assert!(value >= s.mpc.position_min[a] + EDGE_M);
                    assert!(value <= s.mpc.position_max[a] - EDGE_M);
                }
            }
            assert!((-PI..PI).contains(&heading));
            assert!((0.0..1.0).contains(&s.robot.zeta0));
            assert!((0.0..0.3).contains(&s.robot.radius_m));
            let people = s.obstacles.iter().filter(|o| o.moves()).count();
            assert!((1..=6).contains(&(s.obstacles.len() - people)));
            assert!(people <= 2);
            with_people += usize::from(people > 0);
            assert!((0.02..0.1).contains(&s.timing.ts_s));
            assert!((8..=20).contains(&s.mpc.horizon));
            assert!((0.05..=1.0).contains(&s.mpc.gamma));
            assert!((1.0..5.0).contains(&s.mpc.v_max));
            let wheels = s.plant.max_wheel_speed_rad_s;
            assert!(wheels == 0.0 || (12.0..40.0).contains(&wheels), "{wheels}");
            let noise = s.plant.noise_variance.per_axis()[0];
            assert!((0.0..0.01).contains(&noise));
            assert!((0.0..0.02).contains(&s.plant.disturbance_std));
            assert_eq!(s.duration_s, 40.0 + 4.0 * (span - 9.0).max(0.0));
            for o in s.obstacles.iter().filter(|o| o.moves()) {
                assert!((0.2..0.4).contains(&o.radius));
                // A person stepping in, or stopping short of an obstacle, speeds up and
                // slows down within the tracker's bound, at the points of the path too.
                let end_s = o.path.last().map_or(0.0, |p| p[0] + 0.2);
                for k in 0..(end_s / 0.01) as usize {
                    let (t, h) = (k as f64 * 0.01, 1e-4);
                    let (v0, v1) = (o.velocity_at(t), o.velocity_at(t + h));
                    let turn = (v1[0] - v0[0]).hypot(v1[1] - v0[1]) / h;
                    assert!(turn <= STEP_IN_ACCEL + 1e-6, "{turn} m/s^2 at {t} s");
                }
            }
            for o in s.obstacles.iter().filter(|o| !o.moves()) {
                assert!((0.2..1.5).contains(&o.radius));
                let room = o.radius + s.robot.radius_m + 0.3;
                assert!(distance([o.x, o.y], [x, y]) > room);
                assert!(distance([o.x, o.y], goal) > room);
            }
            far += usize::from(span > 15.0);
            moving += usize::from(s.robot.zeta0 > 0.0);
            noisy += usize::from(noise > 0.0);
            disturbed += usize::from(s.plant.disturbance_std > 0.0);
        }
        // Each part of the distribution is drawn.
        for (what, n) in [
            ("with people", with_people),
            ("far", far),
            ("moving", moving),
            ("noisy", noisy),
            ("disturbed", disturbed),
        ] {
            assert!(n > 30, "{n} {what} worlds of 300");
        }
    }

    #[test]
    fn overrides_apply_to_every_world_and_a_world_they_invalidate_is_drawn_again() {
        let overrides = [
            "mpc.gamma=0.2".to_string(),
            "robot.radius_m=0.4".to_string(),
        ];
        for i in 0..50 {
            let s = world(3, i, Draws::default(), &overrides).unwrap().scenario;
            assert_eq!((s.mpc.gamma, s.robot.radius_m), (0.2, 0.4));
        }
        let unknown = world(3, 0, Draws::default(), &["mpc.gama=0.2".to_string()]).unwrap_err();
        assert_eq!(unknown.0[0].key, "mpc.gama");
    }
}
