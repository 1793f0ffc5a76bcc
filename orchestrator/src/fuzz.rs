//! `scmpc fuzz`: random valid worlds, each run in process on all cores, to measure the
//! safety property (docs/safety.md) on worlds nobody tuned for.
//!
//! The distribution (every draw independent, uniform unless said otherwise; seeded, so
//! `--seed` reproduces a batch exactly):
//!
//! | what | drawn from |
//! |---|---|
//! | goal | the origin |
//! | start | 4-9 m from the goal in any direction, heading towards the goal +- 90 degrees, at rest |
//! | obstacles | 1-6; centre at 20-80 % of the way from start to goal, up to 1.5 m to either side of the line; radius 0.2-1.5 m; redrawn while the start or the goal is within 0.3 m of its edge |
//! | `timing.ts_s` | 0.02-0.1 s (`M` = 10) |
//! | `mpc.horizon` | 8-20 |
//! | `mpc.gamma` | 0.05-1 |
//! | `mpc.v_max` | 1-5 m/s^2 (the brake's deceleration follows: `auto`) |
//! | wheel saturation | off in half the worlds, else `plant.max_wheel_speed_rad_s` 15-40 rad/s |
//! | output noise | none (`--set plant.noise_variance=...` adds it) |
//! | `duration_s` | 40 s; `seed` (noise) the world's index |
//!
//! Every other key is the paper's. The `--set` overrides are applied on top of every world
//! (a user fuzzes their own tuning), and the world is validated: one the overrides make
//! invalid (a start inside a grown obstacle, say) is drawn again.

use crate::judge::Outcome;
use crate::record::Summary;
use crate::sweep::{self, RunSpec};
use anyhow::Context;
use protocol::{NoiseVariance, Obstacle, Scenario, ScenarioErrors, Validated};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

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
pub fn world(seed: u64, index: usize, overrides: &[String]) -> Result<World, ScenarioErrors> {
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index as u64);
    let mut last_error = None;
    for _ in 0..MAX_DRAWS {
        let scenario = draw(&mut rng, index).with_overrides(overrides)?;
        match scenario.validated(&format!("fuzz world {index}")) {
            Ok(scenario) => return Ok(World { index, scenario }),
            Err(e) => last_error = Some(e),
        }
    }
    Err(last_error.unwrap_or_else(|| ScenarioErrors(Vec::new())))
}

/// One draw from the distribution (before overrides).
fn draw(rng: &mut ChaCha8Rng, index: usize) -> Scenario {
    let mut s = Scenario {
        name: format!("fuzz-{index:04}"),
        seed: index as u64 + 1,
        duration_s: 40.0,
        ..Scenario::default()
    };
    let distance = rng.random_range(4.0..9.0);
    let bearing = rng.random_range(-PI..PI);
    let start = [distance * bearing.cos(), distance * bearing.sin()];
    let towards_goal = (-start[1]).atan2(-start[0]);
    let heading = protocol::wrap_angle(towards_goal + rng.random_range(-FRAC_PI_2..FRAC_PI_2));
    s.robot.start = [start[0], start[1], heading];
    s.robot.goal = [0.0, 0.0];
    s.timing.ts_s = rng.random_range(0.02..0.1);
    s.mpc.horizon = rng.random_range(8..=20);
    s.mpc.gamma = rng.random_range(0.05..=1.0);
    s.mpc.v_max = rng.random_range(1.0..5.0);
    s.plant.noise_variance = NoiseVariance::Uniform(0.0);
    s.plant.max_wheel_speed_rad_s = if rng.random_bool(0.5) {
        rng.random_range(15.0..40.0)
    } else {
        0.0
    };
    let count = rng.random_range(1..=6);
    let normal = [-start[1] / distance, start[0] / distance];
    s.obstacles = (0..count)
        .map(|_| {
            loop {
                let along = rng.random_range(0.2..0.8);
                let aside = rng.random_range(-1.5..1.5);
                let radius = rng.random_range(0.2..1.5);
                let x = start[0] * (1.0 - along) + aside * normal[0];
                let y = start[1] * (1.0 - along) + aside * normal[1];
                let clear = |p: [f64; 2]| (p[0] - x).hypot(p[1] - y) > radius + 0.3;
                if clear(start) && clear([0.0, 0.0]) {
                    break Obstacle { x, y, radius };
                }
            }
        })
        .collect();
    s
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
        let summaries = self.results.iter().filter_map(|r| r.as_ref().ok());
        let (interventions, failures) = summaries.fold((0, 0), |(i, f), s| {
            (i + s.safety_interventions, f + s.solver_failures)
        });
        out += &format!(
            "  {} worlds; safety interventions {interventions}, solver failures {failures}\n",
            self.results.len()
        );
        if self.count(Outcome::NoRoute) > 0 {
            out += &format!(
                "  reached {:.1} % of the worlds with a route\n",
                100.0 * self.reach_of_routable()
            );
        }
        out
    }
}

/// Runs `count` worlds of batch `seed` on `threads` threads into `out`: `fuzz.csv`, a
/// scenario file under `out/failed/` for every world that did not reach the goal, and no
/// run directories (a failed world replays with `scmpc run FILE`).
pub fn run(
    seed: u64,
    count: usize,
    overrides: &[String],
    out: &Path,
    threads: usize,
    progress: bool,
    stop: &AtomicBool,
) -> anyhow::Result<Report> {
    let worlds = (0..count)
        .map(|i| world(seed, i, overrides))
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
    let report = Report { worlds, results };
    let _ = std::fs::remove_dir_all(out.join("runs"));
    write_csv(&report, out).with_context(|| format!("writing {}", out.display()))?;
    Ok(report)
}

/// Where the scenario of a world that did not reach the goal is kept.
fn failed_file(out: &Path, index: usize) -> PathBuf {
    out.join("failed").join(format!("{index:04}.toml"))
}

/// `fuzz.csv`, and the scenario file of every world that did not reach the goal.
fn write_csv(report: &Report, out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out.join("failed"))?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(out.join("fuzz.csv"))?);
    writeln!(
        f,
        "world,obstacles,ts_s,horizon,gamma,v_max,noise_variance,max_wheel_speed_rad_s,start_distance_m,outcome,min_clearance_m,final_distance_m,time_to_goal_s,safety_interventions,solver_failures,deadline_misses,file"
    )?;
    for (world, result) in report.worlds.iter().zip(&report.results) {
        let s = &world.scenario;
        let [x, y, _] = s.robot.start;
        let params = format!(
            "{},{},{:.4},{},{:.4},{:.3},{},{:.2},{:.3}",
            world.index,
            s.obstacles.len(),
            s.timing.ts_s,
            s.mpc.horizon,
            s.mpc.gamma,
            s.mpc.v_max,
            s.plant.noise_variance.per_axis()[0],
            s.plant.max_wheel_speed_rad_s,
            (x - s.robot.goal[0]).hypot(y - s.robot.goal[1]),
        );
        let reached = result.as_ref().is_ok_and(|r| r.outcome == Outcome::Reached);
        let file = if reached {
            String::new()
        } else {
            let path = failed_file(out, world.index);
            std::fs::write(&path, s.to_toml())?;
            path.display().to_string()
        };
        match result {
            Ok(r) => writeln!(
                f,
                "{params},{},{:.6},{:.3},{},{},{},{},{file}",
                r.outcome.as_str(),
                r.min_clearance_m,
                r.final_distance_to_goal_m,
                r.time_to_goal_s
                    .map_or(String::new(), |t| format!("{t:.3}")),
                r.safety_interventions,
                r.solver_failures,
                r.deadline_misses,
            )?,
            Err(e) => writeln!(
                f,
                "{params},error: {},,,,,,,{file}",
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
        let a = world(7, 3, &[]).unwrap().scenario;
        assert_eq!(a, world(7, 3, &[]).unwrap().scenario);
        assert_ne!(a, world(8, 3, &[]).unwrap().scenario);
        assert_ne!(a, world(7, 4, &[]).unwrap().scenario);
    }

    #[test]
    fn every_world_is_valid_and_within_the_documented_distribution() {
        for i in 0..300 {
            let s = world(1, i, &[]).unwrap().scenario;
            let [x, y, _] = s.robot.start;
            let distance = x.hypot(y);
            assert!((4.0..9.0).contains(&distance), "{distance}");
            assert!((1..=6).contains(&s.obstacles.len()));
            assert!((0.02..0.1).contains(&s.timing.ts_s));
            assert!((8..=20).contains(&s.mpc.horizon));
            assert!((0.05..=1.0).contains(&s.mpc.gamma));
            for o in &s.obstacles {
                assert!((0.2..1.5).contains(&o.radius));
                assert!((o.x - x).hypot(o.y - y) > o.radius + 0.3);
                assert!(o.x.hypot(o.y) > o.radius + 0.3);
            }
        }
    }

    #[test]
    fn overrides_apply_to_every_world_and_a_world_they_invalidate_is_drawn_again() {
        let overrides = [
            "mpc.gamma=0.2".to_string(),
            "robot.radius_m=0.4".to_string(),
        ];
        for i in 0..50 {
            let s = world(3, i, &overrides).unwrap().scenario;
            assert_eq!((s.mpc.gamma, s.robot.radius_m), (0.2, 0.4));
        }
        let unknown = world(3, 0, &["mpc.gama=0.2".to_string()]).unwrap_err();
        assert_eq!(unknown.0[0].key, "mpc.gama");
    }
}
