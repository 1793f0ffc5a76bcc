//! The record's CSV files, a [`Sink`]: `trajectory.csv` (a row per inner tick),
//! `plans.csv` (a row per MPC sample, written when the DFL judged it), `predictions.csv`
//! (a plan's predicted positions every second), `route.csv` and `tracks.csv` (opened at
//! the first route or tracks). Their columns are in [`crate::schema`].

use crate::Summary;
use crate::lines::{FlushClock, Lines};
use crate::schema;
use crate::sink::{RunStart, Sample, Sink, TickSample};
use protocol::{
    CommandMode, DeadlineVerdict, Obstacle, PLAN_MISSING, Plan, PlanStatus, ReplanReason, Route,
    RouteSwitch, Tracks,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The CSV files of a run (module docs).
pub struct CsvFiles {
    dir: PathBuf,
    trajectory: Lines,
    plans: Lines,
    predictions: Lines,
    /// `route.csv`, opened at the first route.
    routes: Option<Lines>,
    /// `tracks.csv`, opened at the first tracks.
    tracks: Option<Lines>,
    /// `<topic>.csv` of each topic recorded as [`Sample::Data`], opened at its first
    /// message, with the values its type names after its time and tick.
    data: BTreeMap<&'static str, Lines>,
    /// Reused for a message's values.
    values: Vec<f64>,
    /// Simulated time from which the next solved plan goes to `predictions.csv`, s.
    next_prediction_s: f64,
    /// Plans published but not judged yet, by sample.
    pending_plans: BTreeMap<u64, Plan>,
    /// Newest sample judged.
    last_judged: Option<u64>,
    /// Routes planned so far (a route's `plan` column).
    route_plans: u64,
    /// The DFL's zeta at the start of the next tick.
    zeta: f64,
    /// The obstacles, for the true centre beside each track.
    obstacles: Vec<Obstacle>,
    /// Whether the tracks are the lidar's (a track is then no obstacle's by index).
    lidar_tracks: bool,
    flush: FlushClock,
}

impl CsvFiles {
    pub fn open(run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
        let dir = run.dir;
        Ok(Some(Box::new(CsvFiles {
            dir: dir.to_path_buf(),
            trajectory: csv_file(&dir.join("trajectory.csv"), &schema::TRAJECTORY_COLUMNS)?,
            plans: csv_file(&dir.join("plans.csv"), &schema::PLANS_COLUMNS)?,
            predictions: csv_file(&dir.join("predictions.csv"), &schema::PREDICTION_COLUMNS)?,
            routes: None,
            tracks: None,
            data: BTreeMap::new(),
            values: Vec::new(),
            next_prediction_s: 0.0,
            pending_plans: BTreeMap::new(),
            last_judged: None,
            route_plans: 0,
            zeta: run.scenario.robot.zeta0,
            obstacles: run.scenario.obstacles.clone(),
            lidar_tracks: run.scenario.sees_with_lidar(),
            flush: FlushClock::new(),
        })))
    }

    fn tick(&mut self, tick: &TickSample<'_>) -> std::io::Result<()> {
        let (truth, act) = (tick.truth, tick.actuation);
        let [x, y, theta] = truth.pose;
        // The DFL's zeta at t_j: where the previous command left it.
        let zeta = std::mem::replace(&mut self.zeta, act.zeta);
        let t = truth.header.time_s;
        let mode = act.mode().unwrap_or(CommandMode::Brake);
        let e = &tick.estimate.state;
        writeln!(
            self.trajectory,
            "{t:.4},{x},{y},{theta},{zeta},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            e[0],
            e[1],
            e[2],
            e[3],
            act.v[0],
            act.v[1],
            act.u1,
            act.u2,
            act.wheels[0],
            act.wheels[1],
            mode.as_str(),
            act.plan_sample,
            tick.clearance_m,
        )?;
        if self.flush.due() {
            self.flush_files()?;
        }
        Ok(())
    }

    /// Hands every file's buffered lines to the file system.
    fn flush_files(&mut self) -> std::io::Result<()> {
        self.trajectory.flush()?;
        self.plans.flush()?;
        self.predictions.flush()?;
        for file in [&mut self.routes, &mut self.tracks].into_iter().flatten() {
            file.flush()?;
        }
        for file in self.data.values_mut() {
            file.flush()?;
        }
        Ok(())
    }

    /// A plan as it is published: its `plans.csv` row waits for the DFL's verdict; the
    /// first solved plan of every second goes to `predictions.csv`.
    fn plan(&mut self, plan: &Plan) -> std::io::Result<()> {
        // A plan that comes after the DFL judged its sample (missing, over a slow link) has
        // its row already.
        if self.last_judged.is_none_or(|last| plan.sample > last) {
            self.pending_plans.insert(plan.sample, *plan);
        }
        if plan.is_solved() && plan.header.time_s >= self.next_prediction_s {
            self.next_prediction_s = plan.header.time_s.floor() + 1.0;
            let n = (plan.horizon as usize).min(protocol::MAX_HORIZON);
            for (i, z) in plan.z[..=n].iter().enumerate() {
                writeln!(self.predictions, "{},{i},{},{}", plan.sample, z[0], z[2])?;
            }
        }
        Ok(())
    }

    fn verdict(&mut self, v: &DeadlineVerdict) -> std::io::Result<()> {
        self.last_judged = Some(v.sample);
        let plan = self.pending_plans.remove(&v.sample);
        self.plan_row(
            v.sample,
            plan.as_ref(),
            verdict_status(v),
            arrival_ms(v),
            Some(v.met != 0),
            fallback(v),
        )
    }

    fn plan_row(
        &mut self,
        sample: u64,
        plan: Option<&Plan>,
        status: &str,
        arrival_ms: Option<f64>,
        met: Option<bool>,
        fallback: &str,
    ) -> std::io::Result<()> {
        let opt = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:.3}"));
        let p = plan.copied().unwrap_or_default();
        // Which MPC made the plan (it changes with a swap or a restart).
        let producer = plan.map_or(String::from(","), |p| {
            format!("{},{}", p.horizon, p.header.epoch)
        });
        writeln!(
            self.plans,
            "{sample},{:.4},{status},{:.1},{:.1},{},{},{},{},{fallback},{},{},{producer}",
            p.header.time_s,
            p.solve_ns as f64 / 1e3,
            p.injected_delay_ns as f64 / 1e3,
            p.iterations,
            p.solves,
            opt(arrival_ms),
            met.map_or(String::new(), |m| m.to_string()),
            p.v[0][0],
            p.v[0][1]
        )
    }

    /// A new route: a `route.csv` row per waypoint (none found writes none).
    fn route(&mut self, route: &Route) -> std::io::Result<()> {
        self.route_plans += 1;
        if !route.is_ok() {
            return Ok(());
        }
        let reason = ReplanReason::from_code(route.reason).map_or("unknown", ReplanReason::as_str);
        let switch = RouteSwitch::from_code(route.switch).map_or("unknown", RouteSwitch::as_str);
        let plan = self.route_plans;
        let routes = opened(
            &mut self.routes,
            &self.dir.join("route.csv"),
            &schema::ROUTE_COLUMNS,
        )?;
        for [x, y] in route.points() {
            writeln!(
                routes,
                "{plan},{},{reason},{switch},{x},{y}",
                route.planned_sample
            )?;
        }
        Ok(())
    }

    /// A `tracks.csv` row per track, with the obstacle's true centre beside it.
    fn tracks(&mut self, tracks: &Tracks) -> std::io::Result<()> {
        let file = opened(
            &mut self.tracks,
            &self.dir.join("tracks.csv"),
            &schema::TRACK_COLUMNS,
        )?;
        let t = tracks.header.time_s;
        for track in tracks.tracks() {
            let truth = if track.is_phantom() {
                [f64::NAN; 2]
            } else if self.lidar_tracks {
                nearest_unknown(&self.obstacles, track.center, t)
            } else {
                (self.obstacles.get(track.obstacle as usize))
                    .map_or([f64::NAN; 2], |o| o.center_at(t))
            };
            let (sigma_p, sigma_v) = track.sigmas();
            writeln!(
                file,
                "{t:.4},{},{},{},{},{},{},{sigma_p},{sigma_v},{},{}",
                tracks.header.tick,
                track.obstacle,
                track.center[0],
                track.center[1],
                track.velocity[0],
                track.velocity[1],
                truth[0],
                truth[1],
            )?;
        }
        Ok(())
    }
}

impl CsvFiles {
    /// A `<topic>.csv` row: the message's time and tick, then the values its type names.
    fn data(&mut self, data: &protocol::Data) -> std::io::Result<()> {
        let topic = data.topic();
        let file = match self.data.entry(topic) {
            std::collections::btree_map::Entry::Occupied(file) => file.into_mut(),
            std::collections::btree_map::Entry::Vacant(slot) => {
                let columns = [&["t", "tick"], protocol::Data::recorded_names(topic)].concat();
                slot.insert(csv_file(&self.dir.join(format!("{topic}.csv")), &columns)?)
            }
        };
        self.values.clear();
        data.recorded(&mut self.values);
        let header = data.header();
        write!(file, "{:.4},{}", header.time_s, header.tick)?;
        for value in &self.values {
            write!(file, ",{value}")?;
        }
        writeln!(file)
    }
}

impl Sink for CsvFiles {
    fn sample(&mut self, sample: &Sample<'_>) -> std::io::Result<()> {
        match sample {
            Sample::Tick(tick) => self.tick(tick),
            Sample::Plan(plan) => self.plan(plan),
            Sample::Verdict(v) => self.verdict(v),
            Sample::Route(route) => self.route(route),
            Sample::Tracks(tracks) => self.tracks(tracks),
            Sample::Data(data) => self.data(data),
        }
    }

    /// Plans the run ended before the DFL could judge get their rows; everything is
    /// flushed.
    fn end(mut self: Box<Self>, _summary: &Summary, _whole: bool) -> std::io::Result<()> {
        for (sample, plan) in std::mem::take(&mut self.pending_plans) {
            let status = plan.status().map_or("unknown", |s| s.as_str());
            self.plan_row(sample, Some(&plan), status, None, None, "")?;
        }
        self.flush_files()
    }
}

/// The solver's status of the plan a verdict judged, or `missing`.
pub(crate) fn verdict_status(v: &DeadlineVerdict) -> &'static str {
    match v.status {
        PLAN_MISSING => "missing",
        code => PlanStatus::from_code(code).map_or("unknown", PlanStatus::as_str),
    }
}

/// The command mode the DFL fell back to on a verdict's sample.
pub(crate) fn fallback(v: &DeadlineVerdict) -> &'static str {
    CommandMode::from_code(v.fallback).map_or("unknown", CommandMode::as_str)
}

/// When a verdict's plan arrived, ms after its sample (`None`: it never did).
pub(crate) fn arrival_ms(v: &DeadlineVerdict) -> Option<f64> {
    (v.arrival_ns != u64::MAX).then(|| v.arrival_ns as f64 / 1e6)
}

/// The true centre at `t_s` of the obstacle not known to the pipeline nearest to
/// `centre` (NaN when every obstacle is known): what a lidar track is judged against.
fn nearest_unknown(obstacles: &[Obstacle], centre: [f64; 2], t_s: f64) -> [f64; 2] {
    (obstacles.iter().filter(|o| !o.is_known()))
        .map(|o| o.center_at(t_s))
        .min_by(|a, b| {
            let d = |p: &[f64; 2]| (p[0] - centre[0]).hypot(p[1] - centre[1]);
            d(a).total_cmp(&d(b))
        })
        .unwrap_or([f64::NAN; 2])
}

/// A new CSV file at `path` with the header line of `columns`, on disk at once.
fn csv_file(path: &Path, columns: &[&str]) -> std::io::Result<Lines> {
    let mut file = Lines::create(path)?;
    writeln!(file, "{}", schema::header(columns))?;
    file.flush()?;
    Ok(file)
}

/// The CSV file in `slot`, created at `path` with `columns` the first time it is needed.
fn opened<'a>(
    slot: &'a mut Option<Lines>,
    path: &Path,
    columns: &[&str],
) -> std::io::Result<&'a mut Lines> {
    match slot {
        Some(file) => Ok(file),
        None => Ok(slot.insert(csv_file(path, columns)?)),
    }
}
