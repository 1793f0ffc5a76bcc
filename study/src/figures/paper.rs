//! The paper's figure set (`scmpc figures`): the runs of its study in the paper's
//! formulation, Fig. 4 (a)-(d), the figures over time and the solve-time comparison.

use super::{Figure, Series, Trajectory, ensure_font, obstacle_discs};
use anyhow::{Context, anyhow};
use std::path::{Path, PathBuf};

/// The γ values of the paper's Fig. 4 (a).
pub const GAMMAS: [f64; 6] = [0.1, 0.3, 0.5, 0.7, 0.9, 1.0];
/// The (γ, N) pairs of Fig. 4 (b).
pub const GAMMA_HORIZON_PAIRS: [(f64, usize); 4] = [(0.1, 9), (0.3, 10), (0.5, 12), (0.9, 14)];
/// Horizons of the solve-time comparison.
pub const HORIZONS: [usize; 5] = [8, 9, 10, 12, 14];

/// What [`paper_set`] produced.
#[derive(Debug)]
pub struct FigureSet {
    pub files: Vec<PathBuf>,
    pub solve_times: Vec<crate::solve_times::SolveTimes>,
}

/// The paper's figure set, from scratch: runs every scenario it needs in process (on
/// `threads` threads, into `out/runs`), measures the solve times of both formulations,
/// and draws every figure into `out`.
pub fn paper_set(
    out: &Path,
    threads: usize,
    stop: &std::sync::atomic::AtomicBool,
) -> anyhow::Result<FigureSet> {
    ensure_font()?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (base, noisy) = (paper_scenario("paper")?, paper_scenario("paper-noisy")?);
    let specs = study_runs(&base, &noisy, out)?;
    let results = crate::sweep::run_all(&specs, threads, true, false, stop);
    run::stop::check(stop)?;
    let mut runs = StudyRuns::default();
    for (s, r) in specs.iter().zip(results) {
        r.with_context(|| format!("run {}", s.values[0]))?;
        runs.0
            .insert(s.values[0].clone(), Trajectory::read(&s.dir)?);
    }
    let mut figures = path_figures(&runs, obstacle_discs(&base))?;
    figures.extend(time_figures(&runs, base.robot.goal.position)?);
    let mut solve_times = Vec::new();
    for n in HORIZONS {
        run::stop::check(stop)?;
        let dir = out.join("runs").join(format!("solve-time-n-{n}"));
        solve_times.push(crate::solve_times::compare_solve_times(
            &base, n, &dir, stop,
        )?);
    }
    figures.push(solve_time_figure(&solve_times, base.timing.ts_s));
    let mut files = Vec::new();
    for f in &figures {
        run::stop::check(stop)?;
        files.extend(f.write(out)?);
    }
    crate::solve_times::write_csv(&out.join("solve_times.csv"), &solve_times)?;
    Ok(FigureSet { files, solve_times })
}

/// A built-in scenario in the paper's formulation: the paper's study is of it, without the
/// safety layers added since (docs/safety.md).
fn paper_scenario(name: &str) -> anyhow::Result<protocol::Validated> {
    let paper = [
        "mpc.terminal_safety=none".to_string(),
        "dfl.gatekeeper=false".to_string(),
    ];
    run::scenarios::load(Some(name), &paper)
        .map_err(|e| anyhow!("the built-in {name} scenario: {e}"))
}

/// The runs of the paper's study, each named after what it varies: every γ of Fig. 4 (a)
/// and (γ, N) pair of (b), the Euclidean constraint, and the noisy runs with the EKF and
/// with the raw measurement (`κ = 0`).
fn study_runs(
    base: &protocol::Validated,
    noisy: &protocol::Validated,
    out: &Path,
) -> anyhow::Result<Vec<crate::sweep::RunSpec>> {
    let spec = |name: String, scenario: &protocol::Validated, sets: &[String]| {
        let scenario = scenario
            .with_overrides(sets, &name)
            .map_err(|e| anyhow!("{name}: {e}"))?;
        Ok::<_, anyhow::Error>(crate::sweep::RunSpec {
            values: vec![name.clone()],
            combination: 0,
            scenario,
            dir: out.join("runs").join(name),
        })
    };
    let mut specs = Vec::new();
    for g in GAMMAS {
        specs.push(spec(
            format!("gamma-{g}"),
            base,
            &[format!("mpc.gamma={g}")],
        )?);
    }
    for (g, n) in GAMMA_HORIZON_PAIRS {
        let sets = [format!("mpc.gamma={g}"), format!("mpc.horizon={n}")];
        specs.push(spec(format!("gamma-{g}-n-{n}"), base, &sets)?);
    }
    specs.push(spec(
        "euclidean".into(),
        base,
        &["mpc.constraint=euclidean".into()],
    )?);
    specs.push(spec("noisy-ekf".into(), noisy, &[])?);
    let passthrough = [
        "estimator.kind=passthrough".to_string(),
        "mpc.uncertainty_sigmas=0".to_string(),
    ];
    specs.push(spec("noisy-passthrough".into(), noisy, &passthrough)?);
    Ok(specs)
}

/// The trajectories of [`study_runs`] by name.
#[derive(Default)]
struct StudyRuns(std::collections::BTreeMap<String, Trajectory>);

impl StudyRuns {
    fn get(&self, name: &str) -> anyhow::Result<&Trajectory> {
        self.0
            .get(name)
            .ok_or_else(|| anyhow!("run {name} missing"))
    }

    /// One series per γ of Fig. 4 (a) (N = 8), `f` of its run.
    fn per_gamma(&self, f: &dyn Fn(&Trajectory) -> Vec<(f64, f64)>) -> anyhow::Result<Vec<Series>> {
        GAMMAS
            .iter()
            .enumerate()
            .map(|(i, g)| {
                let run = self.get(&format!("gamma-{g}"))?;
                Ok(series(format!("γ = {g}, N = 8"), f(run), i, false))
            })
            .collect()
    }
}

fn series(label: String, points: Vec<(f64, f64)>, color: usize, faint: bool) -> Series {
    Series {
        label,
        points,
        faint,
        color,
        ..Series::default()
    }
}

/// Fig. 4 (a)-(d): the paths for several γ, for several (γ, N), of the CBF against the
/// Euclidean constraint, and with noisy feedback.
fn path_figures(runs: &StudyRuns, discs: Vec<(f64, f64, f64)>) -> anyhow::Result<Vec<Figure>> {
    let paths = |stem: &str, title: &str, series: Vec<Series>| Figure {
        stem: stem.into(),
        title: title.into(),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series,
        discs: discs.clone(),
        equal_axes: true,
        ..Figure::default()
    };
    let pair_paths = GAMMA_HORIZON_PAIRS
        .iter()
        .enumerate()
        .map(|(i, (g, n))| {
            let run = runs.get(&format!("gamma-{g}-n-{n}"))?;
            Ok(series(format!("γ = {g}, N = {n}"), run.path(), i, false))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let nominal = runs.get("gamma-0.1")?;
    Ok(vec![
        paths(
            "paths_gamma",
            "(a) paths for several γ, N = 8",
            runs.per_gamma(&Trajectory::path)?,
        ),
        paths(
            "paths_gamma_horizon",
            "(b) paths for several (γ, N)",
            pair_paths,
        ),
        paths(
            "paths_cbf_euclidean",
            "(c) CBF against the Euclidean constraint, N = 8",
            vec![
                series("CBF, γ = 0.1".into(), nominal.path(), 0, false),
                series(
                    "Euclidean distance".into(),
                    runs.get("euclidean")?.path(),
                    1,
                    false,
                ),
            ],
        ),
        paths(
            "paths_noise",
            "(d) nominal against noisy feedback (variance 0.05)",
            vec![
                series("nominal".into(), nominal.path(), 0, false),
                series("noisy, EKF".into(), runs.get("noisy-ekf")?.path(), 1, false),
                series(
                    "noisy, passthrough (κ = 0)".into(),
                    runs.get("noisy-passthrough")?.path(),
                    3,
                    false,
                ),
            ],
        ),
    ])
}

/// The figures over time: the forward speed ζ and the clearance for every γ, and the
/// extended state `z` converging to the goal (nominal and noisy).
fn time_figures(runs: &StudyRuns, goal: [f64; 2]) -> anyhow::Result<Vec<Figure>> {
    let over_time = |stem: &str, title: &str, y_label: &str, series: Vec<Series>| Figure {
        stem: stem.into(),
        title: title.into(),
        x_label: "t (s)".into(),
        y_label: y_label.into(),
        series,
        ..Figure::default()
    };
    let mut distance = runs.per_gamma(&Trajectory::clearance)?;
    distance.push(series(
        "Euclidean, N = 8".into(),
        runs.get("euclidean")?.clearance(),
        7,
        false,
    ));
    let names = ["x", "ẋ", "y", "ẏ"];
    let (nominal, noisy) = (runs.get("gamma-0.1")?, runs.get("noisy-ekf")?);
    let convergence =
        (names.iter().enumerate())
            .map(|(c, name)| series(format!("{name}, nominal"), nominal.flat(c, goal), c, false))
            .chain((names.iter().enumerate()).map(|(c, name)| {
                series(format!("{name}, noisy (EKF)"), noisy.flat(c, goal), c, true)
            }))
            .collect();
    Ok(vec![
        over_time(
            "velocity",
            "linear velocity ζ",
            "ζ (m/s)",
            runs.per_gamma(&Trajectory::speed)?,
        ),
        over_time(
            "distance",
            "distance to the obstacle",
            "clearance (m)",
            distance,
        ),
        over_time(
            "convergence",
            "the extended state z converging to the origin",
            "z (m, m/s)",
            convergence,
        ),
    ])
}

/// The solve time of both formulations against the horizon, with `Ts` for scale.
fn solve_time_figure(solve_times: &[crate::solve_times::SolveTimes], ts_s: f64) -> Figure {
    let curve =
        |label: &str, color, faint, f: &dyn Fn(&crate::solve_times::SolveTimes) -> f64| Series {
            label: label.into(),
            points: solve_times
                .iter()
                .map(|s| (s.horizon as f64, f(s) / 1e3))
                .collect(),
            faint,
            color,
            ..Series::default()
        };
    Figure {
        stem: "solve_time".into(),
        title: "solve time per sample against N".into(),
        x_label: "prediction horizon N".into(),
        y_label: "solve time (ms, log scale)".into(),
        series: vec![
            curve("linear (DFL), median", 0, false, &|s| s.linear_us.p50),
            curve("linear (DFL), p99", 0, true, &|s| s.linear_us.p99),
            curve("nonlinear (SCNMPC), median", 1, false, &|s| {
                s.nonlinear_us.p50
            }),
            curve("nonlinear (SCNMPC), p99", 1, true, &|s| s.nonlinear_us.p99),
        ],
        levels: vec![(ts_s * 1e3, format!("Ts = {:.0} ms", ts_s * 1e3))],
        log_y: true,
        ..Figure::default()
    }
}
