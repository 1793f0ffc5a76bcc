//! `scmpc sweep`: every combination of a parameter grid (times noise seeds), run in
//! process on all cores, one row per run in `sweep.csv`; with seeds, the Monte Carlo
//! statistics per combination in `monte_carlo.csv`. [`run_all`] runs any list of scenarios
//! so (`fuzz` and `figures` too).

use anyhow::Context;
use protocol::{ScenarioError, ScenarioErrors, Validated};
use record::Summary;
use record::judge::Outcome;
use run::inprocess;
use run::sinks::Recording;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// One axis of a sweep: a dotted scenario key and the values it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    pub key: String,
    pub values: Vec<String>,
}

impl Axis {
    /// Parses `key=v1,v2,...`.
    pub fn parse(text: &str) -> Result<Axis, ScenarioErrors> {
        let fail = |key: &str, message: &str| {
            ScenarioErrors(vec![ScenarioError {
                origin: "--grid".into(),
                key: key.into(),
                message: message.into(),
            }])
        };
        let (key, values) = text
            .split_once('=')
            .ok_or_else(|| fail(text, "expected KEY=V1,V2,..."))?;
        let values: Vec<String> = values.split(',').map(|v| v.trim().to_string()).collect();
        if values.iter().any(String::is_empty) {
            return Err(fail(key.trim(), "an empty value"));
        }
        Ok(Axis {
            key: key.trim().to_string(),
            values,
        })
    }
}

/// One run of a sweep.
#[derive(Debug, Clone)]
pub struct RunSpec {
    /// The grid values of this run, in axis order.
    pub values: Vec<String>,
    /// Index of the grid combination (runs with other seeds share it).
    pub combination: usize,
    pub scenario: Validated,
    pub dir: PathBuf,
}

/// Every combination of `axes` applied to `base`, `seeds` noise seeds each (seeds
/// `1..=seeds`; with `seeds == 0` the scenario's own seed). Every combination is
/// validated before anything runs.
pub fn plan_runs(
    base: &Validated,
    axes: &[Axis],
    seeds: u64,
    out: &Path,
) -> Result<Vec<RunSpec>, ScenarioErrors> {
    let mut combinations: Vec<Vec<String>> = vec![Vec::new()];
    for axis in axes {
        combinations = combinations
            .into_iter()
            .flat_map(|c| {
                axis.values.iter().map(move |v| {
                    let mut next = c.clone();
                    next.push(v.clone());
                    next
                })
            })
            .collect();
    }
    let seed_list: Vec<Option<u64>> = if seeds == 0 {
        vec![None]
    } else {
        (1..=seeds).map(Some).collect()
    };
    let mut runs = Vec::new();
    for (combination, values) in combinations.into_iter().enumerate() {
        let overrides: Vec<String> = axes
            .iter()
            .zip(&values)
            .map(|(a, v)| format!("{}={v}", a.key))
            .collect();
        let origin = format!("--grid {}", overrides.join(" "));
        let scenario = base.with_overrides(&overrides, &origin)?;
        for seed in &seed_list {
            let scenario = match seed {
                Some(seed) => scenario.with_overrides(&[format!("seed={seed}")], &origin)?,
                None => scenario.clone(),
            };
            let dir = out.join("runs").join(format!("{:04}", runs.len()));
            runs.push(RunSpec {
                values: values.clone(),
                combination,
                scenario,
                dir,
            });
        }
    }
    Ok(runs)
}

/// Runs every spec in process on `threads` threads; results in spec order. Shows progress
/// on stderr when `progress`: a bar on a terminal, else a line every
/// [`progress_every`](run::status_line::progress_every) (the count, the time taken and the
/// time left). Writes each run's `run.mcap` when `mcap`.
/// Once `stop` is set no run starts (those going on end `interrupted`): the results are
/// then those of the first specs only, as many as had started.
pub fn run_all(
    runs: &[RunSpec],
    threads: usize,
    progress: bool,
    mcap: bool,
    stop: &AtomicBool,
) -> Vec<anyhow::Result<Summary>> {
    let bar = if progress {
        indicatif::ProgressBar::new(runs.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} runs, {elapsed} (eta {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let lines = Progress {
        shown: progress && !std::io::stderr().is_terminal(),
        every: run::status_line::progress_every(),
        printed: Mutex::new(std::time::Instant::now()),
    };
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<anyhow::Result<Summary>>>> =
        Mutex::new((0..runs.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                while !stop.load(Ordering::Relaxed) {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(spec) = runs.get(i) else { break };
                    let result =
                        inprocess::run(&spec.scenario, &spec.dir, Recording::files(mcap), stop);
                    if let Ok(mut r) = results.lock() {
                        r[i] = Some(result);
                    }
                    bar.inc(1);
                    lines.tick(&bar);
                }
            });
        }
    });
    bar.finish_and_clear();
    // Indices are taken in order and every one taken is run: the runs not started are the
    // last ones.
    results
        .into_inner()
        .unwrap_or_default()
        .into_iter()
        .map_while(|r| r)
        .collect()
}

/// Progress lines where the bar cannot be drawn (stderr no terminal).
struct Progress {
    shown: bool,
    every: std::time::Duration,
    printed: Mutex<std::time::Instant>,
}

impl Progress {
    /// A line with the bar's count, time taken and time left, if one is due.
    fn tick(&self, bar: &indicatif::ProgressBar) {
        let Ok(mut printed) = self.printed.lock() else {
            return;
        };
        if !self.shown || printed.elapsed() < self.every {
            return;
        }
        *printed = std::time::Instant::now();
        eprintln!(
            "{}/{} runs, {:.0} s, about {:.0} s left",
            bar.position(),
            bar.length().unwrap_or(0),
            bar.elapsed().as_secs_f64(),
            bar.eta().as_secs_f64()
        );
    }
}

/// Writes `sweep.csv`: one row per run, the grid values then the summary's numbers.
pub fn write_sweep_csv(
    path: &Path,
    axes: &[Axis],
    runs: &[RunSpec],
    results: &[anyhow::Result<Summary>],
) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    let keys: Vec<&str> = axes.iter().map(|a| a.key.as_str()).collect();
    writeln!(
        f,
        "run,{}{}seed,outcome,min_clearance_m,deviation_time_s,time_to_goal_s,final_distance_to_goal_m,deadline_misses,solver_failures,solve_us_p50,solve_us_p99,solve_us_max,dir",
        keys.join(","),
        if keys.is_empty() { "" } else { "," }
    )?;
    let opt = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.3}"));
    for (i, (spec, result)) in runs.iter().zip(results).enumerate() {
        let values = spec.values.join(",");
        let sep = if keys.is_empty() { "" } else { "," };
        match result {
            Ok(s) => writeln!(
                f,
                "{i},{values}{sep}{},{},{:.6},{},{},{:.4},{},{},{:.1},{:.1},{:.1},{}",
                s.seed,
                s.outcome.as_str(),
                s.min_clearance_m,
                opt(s.deviation_time_s),
                opt(s.time_to_goal_s),
                s.final_distance_to_goal_m,
                s.deadline_misses,
                s.solver_failures,
                s.solve_us.p50,
                s.solve_us.p99,
                s.solve_us.max,
                spec.dir.display()
            )?,
            Err(e) => writeln!(
                f,
                "{i},{values}{sep}{},error: {},,,,,,,,,,{}",
                spec.scenario.seed,
                format!("{e:#}").replace(',', ";"),
                spec.dir.display()
            )?,
        }
    }
    Ok(f.flush()?)
}

/// The Monte Carlo statistics of one grid combination.
#[derive(Debug, Clone, PartialEq)]
pub struct SeedStats {
    pub values: Vec<String>,
    pub runs: usize,
    pub collisions: usize,
    pub reached: usize,
    /// Minimum clearance over the seeds: min, 5th percentile, median, m.
    pub clearance_min_m: f64,
    pub clearance_p5_m: f64,
    pub clearance_p50_m: f64,
}

impl SeedStats {
    pub fn collision_rate(&self) -> f64 {
        self.collisions as f64 / self.runs.max(1) as f64
    }
}

/// Statistics over the seeds of every combination, in combination order.
pub fn seed_stats(runs: &[RunSpec], results: &[anyhow::Result<Summary>]) -> Vec<SeedStats> {
    let combinations = runs.iter().map(|r| r.combination + 1).max().unwrap_or(0);
    (0..combinations)
        .map(|c| {
            let summaries: Vec<&Summary> = runs
                .iter()
                .zip(results)
                .filter(|(r, _)| r.combination == c)
                .filter_map(|(_, s)| s.as_ref().ok())
                .collect();
            let mut clearances: Vec<f64> = summaries.iter().map(|s| s.min_clearance_m).collect();
            clearances.sort_by(f64::total_cmp);
            let rank = |p: f64| {
                clearances
                    .get(((p * clearances.len() as f64).ceil() as usize).max(1) - 1)
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            SeedStats {
                values: runs
                    .iter()
                    .find(|r| r.combination == c)
                    .map(|r| r.values.clone())
                    .unwrap_or_default(),
                runs: summaries.len(),
                collisions: summaries
                    .iter()
                    .filter(|s| s.outcome == Outcome::Collided)
                    .count(),
                reached: summaries
                    .iter()
                    .filter(|s| s.outcome == Outcome::Reached)
                    .count(),
                clearance_min_m: clearances.first().copied().unwrap_or(f64::NAN),
                clearance_p5_m: rank(0.05),
                clearance_p50_m: rank(0.5),
            }
        })
        .collect()
}

/// Writes `monte_carlo.csv`.
pub fn write_seed_stats(path: &Path, axes: &[Axis], stats: &[SeedStats]) -> anyhow::Result<()> {
    let mut text = String::new();
    let keys: Vec<&str> = axes.iter().map(|a| a.key.as_str()).collect();
    text.push_str(&keys.join(","));
    if !keys.is_empty() {
        text.push(',');
    }
    text.push_str(
        "runs,collisions,collision_rate,reached,clearance_min_m,clearance_p5_m,clearance_p50_m\n",
    );
    for s in stats {
        text.push_str(&s.values.join(","));
        if !keys.is_empty() {
            text.push(',');
        }
        text.push_str(&format!(
            "{},{},{:.4},{},{:.4},{:.4},{:.4}\n",
            s.runs,
            s.collisions,
            s.collision_rate(),
            s.reached,
            s.clearance_min_m,
            s.clearance_p5_m,
            s.clearance_p50_m
        ));
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn header(axes: &[Axis]) -> String {
    axes.iter()
        .map(|a| a.key.as_str())
        .collect::<Vec<_>>()
        .join(" ")
}

/// The end-of-sweep table: one line per run.
pub fn run_table(axes: &[Axis], runs: &[RunSpec], results: &[anyhow::Result<Summary>]) -> String {
    let mut text = format!(
        "{:<40} {:<9} {:>10} {:>10} {:>10} {:>10}\n",
        header(axes),
        "outcome",
        "clear (m)",
        "swerve (s)",
        "goal (s)",
        "solve p50"
    );
    for (spec, result) in runs.iter().zip(results) {
        let values = spec.values.join(" ");
        text.push_str(&match result {
            Ok(s) => format!(
                "{values:<40} {:<9} {:>10.4} {:>10} {:>10} {:>7.0} µs\n",
                s.outcome.as_str(),
                s.min_clearance_m,
                s.deviation_time_s.map_or("-".into(), |t| format!("{t:.3}")),
                s.time_to_goal_s.map_or("-".into(), |t| format!("{t:.2}")),
                s.solve_us.p50
            ),
            Err(e) => format!("{values:<40} error: {e:#}\n"),
        });
    }
    text
}

/// The end-of-sweep table with seeds: one line per combination.
pub fn seed_table(axes: &[Axis], stats: &[SeedStats]) -> String {
    let mut text = format!(
        "{:<40} runs  collisions  reached  clearance min / p5 / p50 (m)\n",
        header(axes)
    );
    for s in stats {
        text.push_str(&format!(
            "{:<40} {:>4}  {:>4} ({:>5.1} %)  {:>4}  {:.4} / {:.4} / {:.4}\n",
            s.values.join(" "),
            s.runs,
            s.collisions,
            100.0 * s.collision_rate(),
            s.reached,
            s.clearance_min_m,
            s.clearance_p5_m,
            s.clearance_p50_m
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_expands_to_every_combination_times_the_seeds() {
        let axes = [
            Axis::parse("mpc.gamma=0.1,0.5").unwrap(),
            Axis::parse("mpc.horizon=8,10,12").unwrap(),
        ];
        let paper = protocol::Scenario::default().validated("test").unwrap();
        let runs = plan_runs(&paper, &axes, 2, Path::new("/tmp/x")).unwrap();
        assert_eq!(runs.len(), 12);
        assert_eq!(runs[0].values, ["0.1", "8"]);
        assert_eq!((runs[1].scenario.seed, runs[1].combination), (2, 0));
        assert_eq!(runs[11].scenario.mpc.horizon, 12);
        assert_eq!(runs[11].scenario.mpc.gamma, 0.5);
    }

    #[test]
    fn a_bad_grid_value_is_refused_with_its_key() {
        let axes = [Axis::parse("mpc.gamma=0.1,2").unwrap()];
        let paper = protocol::Scenario::default().validated("test").unwrap();
        let err = plan_runs(&paper, &axes, 0, Path::new("/tmp/x")).unwrap_err();
        assert!(err.to_string().contains("mpc.gamma"), "{err}");
        assert!(Axis::parse("mpc.gamma").is_err());
        assert!(Axis::parse("mpc.gamma=0.1,").is_err());
    }
}
