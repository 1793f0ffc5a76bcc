//! The plots of one run, `path` and `clearance` (written by `scmpc run`, and so for a
//! replayed fuzz world too): drawn to be read without the docs (docs/running.md, "The
//! plots of a run").
//!
//! - `path`: the obstacles at rest to scale, each with its boundary grown by the robot's
//!   footprint and the fixed margins (dashed: the centre of a robot on it has its edge at
//!   the margin); the robot's footprint at the start, every [`TRACE_LABEL_S`] and at its
//!   end; a moving obstacle as its disc at those times, beside the robot's footprint at
//!   the same time in the same colour, each with its time written; the MPC's predictions,
//!   the routes and, with a lidar, what it could see; start and goal on top; the legend
//!   in the corner it covers least of.
//! - `clearance`: the clearance named for what it is (from the robot's edge, or its
//!   centre for a point robot, to the nearest obstacle's surface), the contact line, the
//!   margin line, and every contact marked.

use super::{Figure, Marker, Ring, Series, Trajectory};
use protocol::{ObstacleGrowth, PlantKind, Scenario};
use rand::SeedableRng;
use record::schema::Table;
use std::path::Path;

/// Seconds between two times the path shows where the robot (and a moving obstacle) was.
const TRACE_LABEL_S: f64 = 2.0;

/// `path` and `clearance` of the run in `dir` (written by `scmpc run`).
pub fn run_plots(dir: &Path, scenario: &Scenario) -> anyhow::Result<()> {
    let t = Trajectory::read(dir)?;
    path_figure(dir, scenario, &t)?.write(dir)?;
    clearance_figure(scenario, &t).write(dir)?;
    Ok(())
}

fn series(label: &str, points: Vec<(f64, f64)>) -> Series {
    Series {
        label: label.to_string(),
        points,
        ..Series::default()
    }
}

fn path_figure(dir: &Path, scenario: &Scenario, t: &Trajectory) -> anyhow::Result<Figure> {
    let mut path = vec![series("robot", t.path())];
    // The MPC's prediction every second (N Ts ahead of the robot), under the routes.
    for (i, predicted) in (polylines(dir, "predictions.csv", "sample")?.into_iter()).enumerate() {
        let label = if i == 0 {
            "MPC prediction, every 1 s"
        } else {
            ""
        };
        path.push(Series {
            color: 7,
            ..series(label, predicted)
        });
    }
    // The first route, then the later plans faint (one legend entry for them all).
    for (i, route) in polylines(dir, "route.csv", "plan")?.into_iter().enumerate() {
        let label = ["route (first plan)", "later routes"].get(i).unwrap_or(&"");
        path.push(Series {
            dashed: true,
            faint: i > 0,
            color: if i == 0 { 2 } else { 4 },
            ..series(label, route)
        });
    }
    path.extend(moving_paths(scenario, t));
    path.extend(scan_dots(scenario, t));
    let mut rings = grown_boundaries(scenario);
    rings.extend(where_when(scenario, t));
    let [sx, sy, _] = scenario.robot.start;
    let [gx, gy] = scenario.robot.goal.position;
    let marker = |label: &str, at, color| Marker {
        label: label.into(),
        at,
        color,
    };
    Ok(Figure {
        stem: "path".into(),
        title: format!("{}: path", scenario.name),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series: path,
        discs: (scenario.obstacles.iter())
            .filter(|o| !o.moves())
            .map(|o| (o.x, o.y, o.radius))
            .collect(),
        rings,
        markers: vec![marker("start", (sx, sy), 3), marker("goal", (gx, gy), 1)],
        equal_axes: true,
        legend_auto: true,
        ..Figure::default()
    })
}

/// Each obstacle at rest grown by the robot's footprint and the fixed margins
/// ([`ObstacleGrowth::fixed_m`]), dashed; none when they add nothing (the paper's point
/// robot). The growth `kappa sigma` by the estimate's uncertainty changes sample by
/// sample and is not drawn.
fn grown_boundaries(scenario: &Scenario) -> Vec<Ring> {
    let growth = ObstacleGrowth::of(scenario).fixed_m;
    if growth <= 0.0 {
        return Vec::new();
    }
    let label = format!("grown by footprint and margin ({growth:.2} m)");
    (scenario.obstacles.iter().filter(|o| !o.moves()))
        .enumerate()
        .map(|(i, o)| Ring {
            at: (o.x, o.y),
            radius: o.radius + growth,
            color: 5,
            dashed: true,
            label: if i == 0 { label.clone() } else { String::new() },
            ..Ring::default()
        })
        .collect()
}

/// The times the path shows: every [`TRACE_LABEL_S`] from 0, and the end of the run.
fn shown_times(robot: &Trajectory) -> Vec<f64> {
    let end_s = robot.t.last().copied().unwrap_or(0.0);
    let mut times: Vec<f64> = (0..=(end_s / TRACE_LABEL_S) as usize)
        .map(|i| i as f64 * TRACE_LABEL_S)
        .collect();
    if times.last().is_some_and(|&t| end_s - t > 0.5) {
        times.push(end_s);
    }
    times
}

/// Where the robot and every moving obstacle were at the [`shown_times`]: the robot's
/// footprint (a ring of 0.1 m for a point robot), and a moving obstacle's disc, both in
/// the colour of the time and with the time written beside them; one legend entry each
/// for the robot and the moving obstacles. Without a moving obstacle only the robot's
/// footprint at the start and the end, if it has one.
fn where_when(scenario: &Scenario, robot: &Trajectory) -> Vec<Ring> {
    let moving: Vec<_> = scenario.obstacles.iter().filter(|o| o.moves()).collect();
    let footprint = scenario.robot.radius_m;
    let mut times = shown_times(robot);
    if moving.is_empty() {
        if footprint <= 0.0 {
            return Vec::new();
        }
        times = vec![0.0, robot.t.last().copied().unwrap_or(0.0)];
    }
    let mut rings = Vec::new();
    for (k, &t) in times.iter().enumerate() {
        let Some(i) = robot.t.iter().position(|&rt| rt >= t - 1e-9) else {
            continue;
        };
        let color = (k % 7) + 1;
        let text = if moving.is_empty() {
            String::new()
        } else {
            format!("{t:.0} s")
        };
        rings.push(Ring {
            at: (robot.x[i], robot.y[i]),
            radius: footprint.max(0.1),
            color,
            label: match (k, moving.is_empty()) {
                (0, true) => "robot's footprint at the start and the end".into(),
                (0, false) => "robot (footprint) at the times written".into(),
                _ => String::new(),
            },
            text: text.clone(),
            ..Ring::default()
        });
        for (j, o) in moving.iter().enumerate() {
            let [x, y] = o.center_at(t);
            rings.push(Ring {
                at: (x, y),
                radius: o.radius,
                color,
                filled: true,
                label: if k == 0 && j == 0 {
                    "moving obstacle at the same times".into()
                } else {
                    String::new()
                },
                text: text.clone(),
                ..Ring::default()
            });
        }
    }
    rings
}

/// The path of every moving obstacle's centre over the run, dashed, one legend entry.
fn moving_paths(scenario: &Scenario, robot: &Trajectory) -> Vec<Series> {
    let end_s = robot.t.last().copied().unwrap_or(0.0);
    let steps = (end_s / 0.1).ceil() as usize;
    (scenario.obstacles.iter().filter(|o| o.moves()))
        .enumerate()
        .map(|(i, o)| Series {
            label: if i == 0 {
                "moving obstacles' centres".into()
            } else {
                String::new()
            },
            points: (0..=steps)
                .map(|k| o.center_at(k as f64 * 0.1))
                .map(|[x, y]| (x, y))
                .collect(),
            dashed: true,
            color: 5,
            ..Series::default()
        })
        .collect()
}

/// With a simulated lidar, every [`TRACE_LABEL_S`], its returns from where the robot
/// truly was (`robot`: the trajectory), ray-cast again against the true world without
/// noise or dropouts: what it could see then (the run's own scans are in `scan.csv` and
/// `run.mcap`). Nothing without one, or for a robot's own lidar.
fn scan_dots(scenario: &Scenario, robot: &Trajectory) -> Option<Series> {
    let config = (scenario.lidar.as_ref()).filter(|_| scenario.plant.kind == PlantKind::Sim)?;
    let sensor = lidar::Lidar {
        noise_std_m: 0.0,
        dropout: 0.0,
        ..lidar::Lidar::of(config)
    };
    let (first, step) = sensor.angles();
    let end_s = robot.t.last().copied().unwrap_or(0.0);
    let mut ranges = vec![0.0_f32; sensor.beams];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let mut points = Vec::new();
    for i in 0..=(end_s / TRACE_LABEL_S) as usize {
        let t = i as f64 * TRACE_LABEL_S;
        let Some(k) = robot.t.iter().position(|&rt| rt >= t - 1e-9) else {
            continue;
        };
        let pose = [robot.x[k], robot.y[k], robot.theta[k]];
        let discs: Vec<lidar::Disc> = (scenario.obstacles.iter())
            .map(|o| (o.center_at(t), o.radius))
            .collect();
        sensor.scan(pose, &discs, &mut rng, &mut ranges);
        let [lx, ly, heading] = sensor.pose_on(pose);
        for (beam, &r) in ranges.iter().enumerate().filter(|(_, r)| r.is_finite()) {
            let angle = heading + first + step * beam as f64;
            let r = f64::from(r);
            points.push((lx + r * angle.cos(), ly + r * angle.sin()));
        }
    }
    Some(Series {
        label: format!("lidar returns, every {TRACE_LABEL_S:.0} s"),
        points,
        dots: true,
        color: 6,
        ..Series::default()
    })
}

/// The clearance over time, named for what `trajectory.csv` holds, with the contact and
/// margin lines and the contacts marked.
fn clearance_figure(scenario: &Scenario, t: &Trajectory) -> Figure {
    let n = scenario.obstacles.len();
    let (nearest, title) = match n {
        0 => (
            "any obstacle".to_string(),
            "clearance (no obstacle)".to_string(),
        ),
        1 => (
            "the obstacle's surface".to_string(),
            "clearance to the obstacle".to_string(),
        ),
        n => (
            "the nearest obstacle's surface".to_string(),
            format!("clearance to the nearest of {n} obstacles"),
        ),
    };
    let from = if scenario.robot.radius_m > 0.0 {
        format!(
            "robot's edge (footprint {:.2} m) to {nearest}",
            scenario.robot.radius_m
        )
    } else {
        format!("robot (a point) to {nearest}")
    };
    let margin = ObstacleGrowth::of(scenario).fixed_m - scenario.robot.radius_m;
    let mut levels = vec![(0.0, "contact (0 m)".to_string())];
    if margin > 0.0 {
        levels.push((margin, format!("margin the MPC keeps ({margin:.2} m)")));
    }
    let contacts: Vec<(f64, f64)> = (t.clearance().into_iter())
        .filter(|(_, c)| *c < 0.0)
        .collect();
    let mut curves = vec![series(&from, t.clearance())];
    if !contacts.is_empty() {
        curves.push(Series {
            dots: true,
            color: 1,
            ..series(&format!("in contact ({} ticks)", contacts.len()), contacts)
        });
    }
    Figure {
        stem: "clearance".into(),
        title: format!("{}: {title}", scenario.name),
        x_label: "t (s)".into(),
        y_label: "clearance (m)".into(),
        series: curves,
        levels,
        legend_auto: true,
        ..Figure::default()
    }
}

/// The polylines of `file` in `dir`: rows of `x` and `y`, one polyline per run of equal
/// `key` values (none if the file does not exist).
fn polylines(dir: &Path, file: &str, key: &str) -> anyhow::Result<Vec<Vec<(f64, f64)>>> {
    let file = dir.join(file);
    if !file.exists() {
        return Ok(Vec::new());
    }
    let table = Table::read(&file)?;
    let (plan, x, y) = (
        table.numbers(key)?,
        table.numbers("x")?,
        table.numbers("y")?,
    );
    let mut routes: Vec<(f64, Vec<(f64, f64)>)> = Vec::new();
    for (p, point) in plan.into_iter().zip(x.into_iter().zip(y)) {
        match routes.last_mut() {
            Some((last, points)) if *last == p => points.push(point),
            _ => routes.push((p, vec![point])),
        }
    }
    Ok(routes.into_iter().map(|(_, points)| points).collect())
}
