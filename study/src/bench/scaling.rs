//! How the MPC step's cost grows with the horizon `N` and the number of obstacles: the
//! paper's robot driven through random fields ([`super::planning_field`], a fixed seed per
//! size, the first seed whose field has a route) along the planner's route, in process,
//! for [`SIMULATED_S`] each; the step's percentiles per `(N, obstacles)`, as a table in
//! `bench.json` and the figure `scaling.svg`/`.png`. And what moving obstacles cost
//! ([`moving_cost`]): the step with five people crossing the way against the same five
//! frozen where they start.

use super::{PLANNING_START, planning_field};
use crate::figures::{Figure, Series};
use anyhow::{Context, anyhow};
use protocol::{Obstacle, PlannerKind, Scenario, Validated};
use record::Percentiles;
use run::sinks::Recording;
use serde::Serialize;
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// The horizons and the obstacle counts of the table.
pub const HORIZONS: [usize; 3] = [8, 16, 30];
pub const OBSTACLES: [usize; 4] = [1, 5, 12, 20];
/// Simulated length of each run, s.
pub const SIMULATED_S: f64 = 10.0;

/// One cell of the table.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingPoint {
    pub horizon: usize,
    pub obstacles: usize,
    /// MPC step (update, every solve) over the run's samples, µs.
    pub step_us: Percentiles,
}

/// Runs every `(N, obstacles)` pair into `out` (one run directory each, without
/// `run.mcap`) and draws the figure there.
pub fn measure(out: &Path, stop: &AtomicBool) -> anyhow::Result<Vec<ScalingPoint>> {
    let mut points = Vec::new();
    for obstacles in OBSTACLES {
        let field = routable_field(obstacles)?;
        for horizon in HORIZONS {
            let scenario = field_scenario(&field, horizon)?;
            let dir = out.join(format!("n{horizon}-obstacles{obstacles}"));
            let summary = run::inprocess::run(&scenario, &dir, Recording::files(false), stop)?;
            run::stop::check(stop)?;
            points.push(ScalingPoint {
                horizon,
                obstacles,
                step_us: summary.solve_us,
            });
        }
    }
    figure(&points)
        .write(out)
        .context("drawing the scaling figure")?;
    Ok(points)
}

/// The first field of `n` discs (seeds from 1) through which the planner finds a route.
fn routable_field(n: usize) -> anyhow::Result<Vec<Obstacle>> {
    let mut graph = planner::TangentGraph::with_capacity(n);
    let bounds = [[-10.0, 10.0], [-10.0, 10.0]];
    (1..100)
        .map(|seed| planning_field(seed, n))
        .find(|discs| {
            graph
                .shortest_path(PLANNING_START, [0.0, 0.0], discs, bounds)
                .is_ok()
        })
        .map(|discs| {
            let obstacle = |d: &planner::Disc| Obstacle::fixed(d.center[0], d.center[1], d.radius);
            discs.iter().map(obstacle).collect()
        })
        .ok_or_else(|| anyhow!("no field of {n} discs with a route in 99 seeds"))
}

/// The paper's robot from [`PLANNING_START`] to the origin through `field` along the
/// planner's route, with horizon `horizon`.
fn field_scenario(field: &[Obstacle], horizon: usize) -> anyhow::Result<Validated> {
    let mut s = Scenario {
        name: format!("scaling-n{horizon}-obstacles{}", field.len()),
        duration_s: SIMULATED_S,
        obstacles: field.to_vec(),
        ..Scenario::paper()
    };
    s.robot.start = [
        PLANNING_START[0],
        PLANNING_START[1],
        -0.75 * std::f64::consts::PI,
    ];
    s.robot.goal.position = [0.0, 0.0];
    s.mpc.horizon = horizon;
    s.planner.kind = PlannerKind::Route;
    s.validated("the scaling benchmark")
        .map_err(|e| anyhow!("{e}"))
}

/// Step p50 and p99 against `N`, one pair of curves per obstacle count.
fn figure(points: &[ScalingPoint]) -> Figure {
    let curve = |obstacles: usize, color: usize, p99: bool| Series {
        label: format!(
            "{obstacles} obstacle{}, {}",
            if obstacles == 1 { "" } else { "s" },
            if p99 { "p99" } else { "median" }
        ),
        points: (points.iter())
            .filter(|p| p.obstacles == obstacles)
            .map(|p| {
                let us = if p99 { p.step_us.p99 } else { p.step_us.p50 };
                (p.horizon as f64, us / 1e3)
            })
            .collect(),
        faint: p99,
        color,
        ..Series::default()
    };
    Figure {
        stem: "scaling".into(),
        title: "MPC step against N and the obstacles (random fields)".into(),
        x_label: "prediction horizon N".into(),
        y_label: "MPC step (ms, log scale)".into(),
        series: (OBSTACLES.iter().enumerate())
            .flat_map(|(i, &n)| [curve(n, i, false), curve(n, i, true)])
            .collect(),
        log_y: true,
        legend_left: true,
        ..Figure::default()
    }
}

/// How many times the step's p50 grows from the shortest horizon of [`HORIZONS`] to the
/// longest with `obstacles` obstacles (linear in `N` would be 30 / 8 = 3.75).
pub fn growth(points: &[ScalingPoint], obstacles: usize) -> Option<f64> {
    let p50 = |horizon| {
        points
            .iter()
            .find(|p| p.horizon == horizon && p.obstacles == obstacles)
            .map(|p| p.step_us.p50)
    };
    Some(p50(HORIZONS[HORIZONS.len() - 1])? / p50(HORIZONS[0])?.max(1e-9))
}

/// The step of the built-in `field` (13 discs along a planned route) at `N` = 30, in
/// process, the whole run.
pub fn field_n30(out: &Path, stop: &AtomicBool) -> anyhow::Result<Percentiles> {
    let field = run::scenarios::load(Some("field"), &["mpc.horizon=30".to_owned()])
        .map_err(|e| anyhow!("{e}"))?;
    let summary = run::inprocess::run(&field, out, Recording::files(false), stop)?;
    run::stop::check(stop)?;
    Ok(summary.solve_us)
}

/// The table as `scmpc bench` prints it, with each obstacle count's [`growth`].
pub fn table(points: &[ScalingPoint]) -> String {
    let mut out = String::from("  MPC step p50 / p99 (µs)");
    for n in HORIZONS {
        out += &format!("{:>20}", format!("N = {n}"));
    }
    out += "   growth of p50\n";
    for obstacles in OBSTACLES {
        out += &format!("  {obstacles:>2} obstacles            ");
        for horizon in HORIZONS {
            let cell = points
                .iter()
                .find(|p| p.horizon == horizon && p.obstacles == obstacles)
                .map_or(String::from("-"), |p| {
                    format!("{:.0} / {:.0}", p.step_us.p50, p.step_us.p99)
                });
            out += &format!("{cell:>20}");
        }
        let grown = growth(points, obstacles).map_or(String::from("-"), |g| format!("{g:.1}×"));
        out += &format!("{grown:>18}\n");
    }
    out
}

/// The people of [`moving_cost`]: `(x, y, vy)` at t = 0 (m, m/s), radius 0.3 m, each
/// crossing the way from (-4, 0) to (9, 0).
pub const PEOPLE: [(f64, f64, f64); 5] = [
    (0.0, -3.0, 0.8),
    (1.5, -4.0, 1.0),
    (3.0, 3.0, -0.6),
    (4.5, 4.0, -0.9),
    (6.0, -5.0, 0.7),
];

/// The MPC step with the [`PEOPLE`] moving (tracked every sample) and frozen where they
/// start (obstacles at rest, no tracker), in process, [`SIMULATED_S`] each.
#[derive(Debug, Clone, Serialize)]
pub struct MovingCost {
    pub moving_step_us: Percentiles,
    pub frozen_step_us: Percentiles,
    /// `moving_step_us.p50 / frozen_step_us.p50`.
    pub ratio_p50: f64,
}

/// Runs the two worlds of [`MovingCost`] into `out`.
pub fn moving_cost(out: &Path, stop: &AtomicBool) -> anyhow::Result<MovingCost> {
    let step_us = |name: &str, moving: bool| -> anyhow::Result<Percentiles> {
        let mut s = Scenario {
            name: format!("people-{name}"),
            duration_s: SIMULATED_S,
            obstacles: (PEOPLE.iter())
                .map(|&(x, y, vy)| Obstacle {
                    velocity: [0.0, if moving { vy } else { 0.0 }],
                    ..Obstacle::fixed(x, y, 0.3)
                })
                .collect(),
            ..Scenario::paper()
        };
        s.robot.start = [-4.0, 0.0, 0.0];
        s.robot.goal.position = [9.0, 0.0];
        let s = s
            .validated("the moving-obstacle benchmark")
            .map_err(|e| anyhow!("{e}"))?;
        let summary = run::inprocess::run(&s, &out.join(name), Recording::files(false), stop)?;
        run::stop::check(stop)?;
        Ok(summary.solve_us)
    };
    let moving_step_us = step_us("moving", true)?;
    let frozen_step_us = step_us("frozen", false)?;
    Ok(MovingCost {
        ratio_p50: moving_step_us.p50 / frozen_step_us.p50.max(1e-9),
        moving_step_us,
        frozen_step_us,
    })
}
