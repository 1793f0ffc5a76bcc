//! `scmpc fuzz --robots A..B`: random fleets (docs/fleet.md, "Fuzz"). Each world draws
//! `A` to `B` robots with their starts, goals and radii in the middle of the position box (two
//! robots' starts, and two goals, at least their radii and half a metre apart), up to four
//! obstacles at rest clear of them all, the noise and the input box; the fleet runs in
//! process, and the batch reports every robot's outcome, contacts between robots (moving
//! and at rest) and the deadlocks broken. With `--perception lidar` every world has the
//! default `[lidar]`, and each obstacle of radius up to [`crate::fuzz::BOX_RADIUS_M`] is a
//! box not in the map with probability one half (drawn from a stream of its own, so the
//! worlds are otherwise the same): the robots see it only through their lidars. With
//! `--people SHARE` that share of the worlds has one or two people on robots' ways, as
//! the worlds of one robot have on its way ([`crate::fuzz::add_people`]; a stream of their
//! own too): the robots track them from the truth, or see them through their lidars.

use anyhow::Context as _;
use protocol::{FleetRobot, Goal, NoiseVariance, Obstacle, Scenario, Validated, distance};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use record::fleet::FleetSummary;
use record::judge::Outcome;
use std::f64::consts::PI;
use std::io::Write;
use std::ops::RangeInclusive;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Room kept between two robots' starts (or goals) beyond their radii, and between an
/// obstacle and any start or goal beyond the footprint, m.
pub const ROOM_M: f64 = 0.5;
/// Draws of one world before the batch gives up on it.
const MAX_DRAWS: usize = 100;

/// The seed of the draws of the boxes not in the map beside a world's (`"boxes"` in
/// ASCII).
const BOXES_STREAM: u64 = 0x62_6f78_6573;
/// The seed of the draws of the people beside a world's (`"people"` in ASCII).
const PEOPLE_STREAM: u64 = 0x7065_6f70_6c65;

/// What a batch's worlds hold beside the robots and the obstacles at rest (module docs).
#[derive(Debug, Clone, Copy, Default)]
pub struct Extras {
    /// Every world seen through the default lidar.
    pub lidar: bool,
    /// The share of the worlds with people on the robots' ways, 0 to 1.
    pub people: f64,
}

/// World `index` of batch `seed` with `robots` robots at most and at least, with the
/// `extras` (module docs), `overrides` applied: the first draw the validator accepts. The
/// people are drawn for the first fleet it accepts, and drawn again (from their own
/// stream) until it accepts them too, so that a batch's fleets are the same with and
/// without people.
pub fn world(
    seed: u64,
    index: usize,
    robots: &RangeInclusive<usize>,
    extras: Extras,
    overrides: &[String],
) -> anyhow::Result<Validated> {
    let world_seed = seed.wrapping_mul(0x9e37_79b9) ^ index as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(world_seed);
    let mut boxes = ChaCha8Rng::seed_from_u64(world_seed ^ BOXES_STREAM);
    let mut people = ChaCha8Rng::seed_from_u64(world_seed ^ PEOPLE_STREAM);
    let mut last = String::new();
    let validated = |drawn: &Scenario, last: &mut String| -> anyhow::Result<Option<Validated>> {
        let scenario = drawn.clone().with_overrides(overrides)?;
        match scenario.validated(&format!("fleet world {index}")) {
            Ok(valid) if robots.contains(&valid.robots.len()) => return Ok(Some(valid)),
            Ok(valid) => *last = format!("{} robots placed", valid.robots.len()),
            Err(e) => *last = e.to_string(),
        }
        Ok(None)
    };
    let fleet = 'fleet: {
        for _ in 0..MAX_DRAWS {
            let mut drawn = draw(&mut rng, index, robots);
            if extras.lidar {
                seen_through_a_lidar(&mut drawn, &mut boxes);
            }
            if let Some(valid) = validated(&drawn, &mut last)? {
                break 'fleet (drawn, valid);
            }
        }
        anyhow::bail!("fleet world {index}: no valid draw in {MAX_DRAWS}: {last}");
    };
    let (drawn, valid) = fleet;
    if !people.random_bool(extras.people.clamp(0.0, 1.0)) {
        return Ok(valid);
    }
    let ways: Vec<_> = (drawn.robots.iter())
        .map(|r| crate::fuzz::Way::between([r.start[0], r.start[1]], r.goal.position))
        .collect();
    for _ in 0..MAX_DRAWS {
        let mut among_people = drawn.clone();
        crate::fuzz::add_people(&mut among_people, &mut people, &ways);
        if let Some(valid) = validated(&among_people, &mut last)? {
            return Ok(valid);
        }
    }
    anyhow::bail!("fleet world {index}: no valid draw of its people in {MAX_DRAWS}: {last}")
}

/// The world `s` seen through the default lidar: each obstacle of radius up to
/// [`crate::fuzz::BOX_RADIUS_M`] is a box not in the map with probability one half.
fn seen_through_a_lidar(s: &mut Scenario, boxes: &mut ChaCha8Rng) {
    s.lidar = Some(protocol::LidarConfig::default());
    for obstacle in &mut s.obstacles {
        let unmapped = boxes.random_bool(0.5);
        if obstacle.radius <= crate::fuzz::BOX_RADIUS_M && unmapped {
            obstacle.known = Some(false);
        }
    }
}

fn draw(rng: &mut ChaCha8Rng, index: usize, robots: &RangeInclusive<usize>) -> Scenario {
    let mut s = Scenario {
        name: format!("fleet-fuzz-{index:04}"),
        seed: index as u64 + 1,
        duration_s: 60.0,
        ..Scenario::default()
    };
    let (lo, hi) = (s.mpc.position_min, s.mpc.position_max);
    let edge = crate::fuzz::EDGE_M;
    // The middle 60 % of the box: the robots meet more often than across all of it.
    let anywhere =
        |rng: &mut ChaCha8Rng| [0, 1].map(|a| rng.random_range(lo[a] + edge..hi[a] - edge) * 0.6);
    let count = rng.random_range(robots.clone());
    let mut fleet: Vec<FleetRobot> = Vec::with_capacity(count);
    // Robots packed too close to place one more in many tries: the world has fewer, and
    // [`world`] draws again if they are fewer than the range asks.
    for _ in 0..MAX_DRAWS * count {
        if fleet.len() == count {
            break;
        }
        let radius = rng.random_range(0.1..0.4);
        let (start, goal) = (anywhere(rng), anywhere(rng));
        let apart = |p: [f64; 2], q: [f64; 2], r: Option<f64>| {
            distance(p, q) > radius + r.unwrap_or(0.0) + ROOM_M
        };
        let clear = fleet.iter().all(|o| {
            apart(start, [o.start[0], o.start[1]], o.radius_m)
                && apart(goal, o.goal.position, o.radius_m)
        });
        if clear && distance(start, goal) >= 1.0 {
            fleet.push(FleetRobot {
                radius_m: Some(radius),
                ..FleetRobot::between(
                    [start[0], start[1], rng.random_range(-PI..PI)],
                    Goal::at(goal),
                )
            });
        }
    }
    let obstacles = rng.random_range(0..=4);
    s.obstacles = (0..obstacles)
        .filter_map(|_| {
            let (center, radius) = (anywhere(rng), rng.random_range(0.2..1.0));
            let clear = |p: [f64; 2], r: Option<f64>| {
                distance(p, center) > radius + r.unwrap_or(0.0) + ROOM_M
            };
            let free = fleet.iter().all(|o| {
                clear([o.start[0], o.start[1]], o.radius_m) && clear(o.goal.position, o.radius_m)
            });
            free.then(|| Obstacle::fixed(center[0], center[1], radius))
        })
        .collect();
    s.robots = fleet;
    s.mpc.v_max = rng.random_range(0.5..2.0);
    s.plant.noise_variance = NoiseVariance::Uniform(rng.random_range(0.0..0.01));
    s
}

/// A fleet world's outcome.
pub struct FleetWorld {
    pub index: usize,
    pub scenario: Validated,
    pub summary: anyhow::Result<FleetSummary>,
}

/// The outcome of a batch.
pub struct FleetReport {
    pub worlds: Vec<FleetWorld>,
}

impl FleetReport {
    /// Every robot's line of every world that ran.
    fn robots(&self) -> impl Iterator<Item = &record::fleet::FleetMember> {
        (self.worlds.iter())
            .filter_map(|w| w.summary.as_ref().ok())
            .flat_map(|s| &s.robots)
    }

    /// Robots that moved into another robot.
    pub fn contacts_moving(&self) -> u64 {
        self.robots().map(|r| r.robot_contacts_moving).sum()
    }

    /// Robots that moved into an obstacle ([`Outcome::Collided`]).
    pub fn collided(&self) -> usize {
        (self.robots())
            .filter(|r| r.outcome == Outcome::Collided)
            .count()
    }

    /// Robots that reached their goal, and all robots.
    pub fn reached(&self) -> (usize, usize) {
        let reached = self
            .robots()
            .filter(|r| r.outcome == Outcome::Reached)
            .count();
        (reached, self.robots().count())
    }

    /// Worlds whose run failed (an error, not an outcome).
    pub fn errors(&self) -> usize {
        self.worlds.iter().filter(|w| w.summary.is_err()).count()
    }

    pub fn table(&self) -> String {
        let (reached, robots) = self.reached();
        let mut by_outcome = std::collections::BTreeMap::<String, usize>::new();
        for r in self.robots().filter(|r| r.outcome != Outcome::Reached) {
            let reason = r
                .stall_reason
                .map_or(String::new(), |s| format!(" ({})", s.as_str()));
            *by_outcome
                .entry(format!("{}{reason}", r.outcome.as_str()))
                .or_default() += 1;
        }
        let mut out = format!(
            "fleet fuzz: {} worlds, {robots} robots: {reached} reached ({:.1} %)\n",
            self.worlds.len(),
            100.0 * reached as f64 / robots.max(1) as f64
        );
        for (what, n) in by_outcome {
            out += &format!("  {what}: {n}\n");
        }
        let at_rest: u64 = self.robots().map(|r| r.robot_contacts_at_rest).sum();
        let deadlocks: u64 = self.robots().map(|r| r.deadlocks_broken).sum();
        out += &format!(
            "  contacts between robots: {} moving, {at_rest} at rest; deadlocks broken: {deadlocks}; errors: {}\n",
            self.contacts_moving(),
            self.errors()
        );
        let people = (self.worlds.iter())
            .filter(|w| w.scenario.obstacles.iter().any(Obstacle::moves))
            .count();
        if people > 0 {
            let walked_into: u64 = self.robots().map(|r| r.contacts_at_rest).sum();
            out += &format!(
                "  worlds with people: {people}; times a person walked into a robot at rest: {walked_into}\n"
            );
        }
        out
    }
}

/// Runs `count` fleet worlds of batch `seed` on `threads` threads into `out`:
/// `fleet_fuzz.csv`, and under `out/failed/` the scenario of every world in which a robot
/// did not reach its goal, two robots touched or a person walked into a robot
/// (`scmpc run FILE --in-process` replays it).
pub fn run(
    (seed, count): (u64, usize),
    robots: RangeInclusive<usize>,
    extras: Extras,
    overrides: &[String],
    out: &Path,
    threads: usize,
    stop: &AtomicBool,
) -> anyhow::Result<FleetReport> {
    let scenarios = (0..count)
        .map(|i| world(seed, i, &robots, extras, overrides))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let next = AtomicUsize::new(0);
    let results = Mutex::new(Vec::with_capacity(count));
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                while !stop.load(Ordering::Relaxed) {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    let Some(scenario) = scenarios.get(index) else {
                        break;
                    };
                    let summary = run_one(
                        scenario,
                        &out.join("runs").join(format!("{index:04}")),
                        stop,
                    );
                    if let Ok(mut results) = results.lock() {
                        results.push((index, summary));
                    }
                }
            });
        }
    });
    let mut results = results.into_inner().unwrap_or_default();
    results.sort_by_key(|(index, _)| *index);
    let worlds = results
        .into_iter()
        .map(|(index, summary)| FleetWorld {
            index,
            scenario: scenarios[index].clone(),
            summary,
        })
        .collect();
    let report = FleetReport { worlds };
    let _ = std::fs::remove_dir_all(out.join("runs"));
    write_csv(&report, out).with_context(|| format!("writing {}", out.display()))?;
    Ok(report)
}

fn run_one(scenario: &Validated, dir: &Path, stop: &AtomicBool) -> anyhow::Result<FleetSummary> {
    let recording = run::sinks::Recording {
        mcap: false,
        status_line: false,
        live: false,
    };
    let summary = run::fleet::run(scenario, dir, recording, stop);
    let _ = std::fs::remove_dir_all(dir);
    summary
}

fn write_csv(report: &FleetReport, out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out.join("failed"))?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(out.join("fleet_fuzz.csv"))?);
    writeln!(
        f,
        "world,robot,robots,obstacles,unmapped,people,v_max,radius_m,outcome,stall_reason,time_to_goal_s,robot_contacts_moving,robot_contacts_at_rest,person_contacts_at_rest,deadlocks_broken,min_robot_clearance_m,file"
    )?;
    for world in &report.worlds {
        let s = &world.scenario;
        let Ok(summary) = &world.summary else {
            continue;
        };
        let walked_into = summary.robots.iter().any(|r| r.contacts_at_rest > 0);
        let failed = !summary.all_reached() || walked_into;
        let file = match failed {
            true => {
                let path = out.join("failed").join(format!("{:04}.toml", world.index));
                std::fs::write(&path, s.to_toml())?;
                path.display().to_string()
            }
            false => String::new(),
        };
        let at_rest = s.obstacles.iter().filter(|o| !o.moves());
        for r in &summary.robots {
            writeln!(
                f,
                "{},{},{},{},{},{},{:.3},{:.3},{},{},{},{},{},{},{},{:.4},{file}",
                world.index,
                r.id,
                summary.robots.len(),
                at_rest.clone().count(),
                at_rest.clone().filter(|o| !o.is_known()).count(),
                s.obstacles.len() - at_rest.clone().count(),
                s.mpc.v_max,
                s.radius_of(r.id),
                r.outcome.as_str(),
                r.stall_reason.map_or("", |s| s.as_str()),
                r.time_to_goal_s
                    .map_or(String::new(), |t| format!("{t:.2}")),
                r.robot_contacts_moving,
                r.robot_contacts_at_rest,
                r.contacts_at_rest,
                r.deadlocks_broken,
                summary.min_robot_clearance_m,
            )?;
        }
    }
    Ok(())
}
