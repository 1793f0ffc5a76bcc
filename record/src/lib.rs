//! The run directory: `trajectory.csv` (one row per inner tick), `plans.csv` (one row per
//! MPC sample), `route.csv` (every route planned), `predictions.csv` (a plan's predicted
//! positions every second; their columns in [`crate::schema`]),
//! `events.jsonl` and `summary.json` (with the table printed at the end of a run:
//! [`summary`]).
//!
//! Whatever ends the run, the records hold what happened up to [`FLUSH_PERIOD`] before
//! the end, in whole lines ([`Lines`]), and a run that did not end in a summary says so:
//! its directory keeps the [`INCOMPLETE`] file written when the run started.

pub use crate::event::{Event, EventLine};
use crate::judge::{Judge, Outcome, clearance_m};
use lines::{FlushClock, Lines};
use protocol::{
    Actuation, CommandMode, DeadlineVerdict, Estimate, GroundTruth, Intervention, Obstacle,
    ObstacleGrowth, PLAN_MISSING, Plan, PlanStatus, ReplanReason, Route, RouteSwitch, Scenario,
    Tracks,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The file of a run directory whose run has not written `summary.json`: it is going on,
/// or it died (its orchestrator's pid, in the file, is gone). Removed with the summary.
pub const INCOMPLETE: &str = "INCOMPLETE";

pub mod event;
pub mod judge;
pub mod run_dir;
pub mod schema;

mod json;
mod lines;
mod mcap;
mod summary;
pub use lines::FLUSH_PERIOD;
pub use mcap::McapLog;
pub use summary::{
    ArrivalReport, Latencies, LinkReport, ModeCounts, Percentiles, ProcessReport, Scheduling,
    Summary,
};

/// Streams the run's records to its directory and accumulates the summary's statistics.
/// It decides nothing: how the run ends is the [`Judge`]'s.
pub struct Recorder {
    dir: PathBuf,
    trajectory: Lines,
    plans: Lines,
    predictions: Lines,
    /// Simulated time from which the next solved plan goes to `predictions.csv`, s.
    next_prediction_s: f64,
    events: Lines,
    created: std::time::Instant,
    /// For the clearance column: the obstacles and the robot's footprint.
    obstacles: Vec<Obstacle>,
    footprint: ObstacleGrowth,
    solve_us: Vec<f64>,
    iterations: Vec<f64>,
    deadline_misses: u64,
    miss_streak: u64,
    longest_miss_streak: u64,
    /// Newest sample judged (a replayed verdict is not counted twice).
    last_judged: Option<u64>,
    solver_failures: u64,
    /// The largest count of safety interventions each DFL (by producer epoch) reported:
    /// its own count, which a tick with two interventions raises by two.
    safety_interventions: BTreeMap<u32, u32>,
    /// Plans published but not judged yet, by sample.
    pending_plans: BTreeMap<u64, Plan>,
    commands: ModeCounts,
    /// `route.csv`, opened at the first route.
    routes: Option<Lines>,
    /// `tracks.csv`, opened at the first tracks.
    tracks: Option<Lines>,
    /// The newest route plan recorded: the planner's epoch and its plan count.
    last_route_plan: Option<(u32, u32)>,
    route_plans: u64,
    route_length_m: Option<f64>,
    ticks: u64,
    last_time_s: f64,
    /// The DFL's zeta at the start of the next tick.
    zeta: f64,
    /// Clearance and command mode of the newest tick recorded.
    last_clearance_m: Option<f64>,
    last_mode: Option<CommandMode>,
    /// Since when the DFL has commanded the robot to stand (no forward speed, ζ = 0), s.
    commanded_rest_since_s: Option<f64>,
    /// `run.mcap`, when asked for ([`Recorder::record_mcap`]).
    mcap: Option<McapLog>,
    flush: FlushClock,
}

impl Recorder {
    /// Creates `dir` (and parents) and the record files.
    pub fn create(dir: &Path, scenario: &Scenario) -> std::io::Result<Recorder> {
        std::fs::create_dir_all(dir)?;
        std::fs::write(
            dir.join(INCOMPLETE),
            format!(
                "This run has not written summary.json: it is going on, or its orchestrator \
                 (pid {}) died.\nIts records hold what happened up to {} ms before that, in \
                 whole lines; run.mcap is read by a reader that scans records in order.\n",
                std::process::id(),
                FLUSH_PERIOD.as_millis()
            ),
        )?;
        std::fs::write(dir.join("scenario.toml"), scenario.to_toml())?;
        let trajectory = csv_file(&dir.join("trajectory.csv"), &schema::TRAJECTORY_COLUMNS)?;
        let plans = csv_file(&dir.join("plans.csv"), &schema::PLANS_COLUMNS)?;
        let predictions = csv_file(&dir.join("predictions.csv"), &schema::PREDICTION_COLUMNS)?;
        let events = Lines::create(&dir.join("events.jsonl"))?;
        Ok(Recorder {
            dir: dir.to_path_buf(),
            trajectory,
            plans,
            predictions,
            next_prediction_s: 0.0,
            events,
            created: std::time::Instant::now(),
            obstacles: scenario.obstacles.clone(),
            footprint: ObstacleGrowth::footprint(scenario),
            solve_us: Vec::new(),
            iterations: Vec::new(),
            deadline_misses: 0,
            miss_streak: 0,
            longest_miss_streak: 0,
            last_judged: None,
            solver_failures: 0,
            safety_interventions: BTreeMap::new(),
            pending_plans: BTreeMap::new(),
            commands: ModeCounts::default(),
            routes: None,
            tracks: None,
            last_route_plan: None,
            route_plans: 0,
            route_length_m: None,
            ticks: 0,
            last_time_s: 0.0,
            zeta: scenario.robot.zeta0,
            last_clearance_m: None,
            last_mode: None,
            commanded_rest_since_s: None,
            mcap: None,
            flush: FlushClock::new(),
        })
    }

    /// Records the run into `run.mcap` too, from now on.
    pub fn record_mcap(&mut self, scenario: &Scenario) -> std::io::Result<()> {
        self.mcap = Some(McapLog::create(&self.dir.join("run.mcap"), scenario)?);
        Ok(())
    }

    /// One line of `events.jsonl` ([`EventLine`]), at the simulated time of the last
    /// recorded tick.
    pub fn event(&mut self, event: Event) -> std::io::Result<()> {
        let line = EventLine {
            wall_s: self.created.elapsed().as_secs_f64(),
            t: self.last_time_s,
            event,
        };
        let json = line.to_json().map_err(std::io::Error::other)?;
        // Events are rare: flush each, so a live run can be followed in the file.
        writeln!(self.events, "{json}")?;
        if let Some(mcap) = &mut self.mcap {
            mcap.event(line, json);
        }
        self.events.flush()
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Simulated time of the newest tick recorded, s.
    pub fn simulated_s(&self) -> f64 {
        self.last_time_s
    }

    /// Deadline misses so far.
    pub fn deadline_misses(&self) -> u64 {
        self.deadline_misses
    }

    /// The robot's clearance at the newest tick recorded, m.
    pub fn last_clearance_m(&self) -> Option<f64> {
        self.last_clearance_m
    }

    /// The command mode of the newest tick recorded.
    pub fn last_mode(&self) -> Option<CommandMode> {
        self.last_mode
    }

    /// How long, up to the last recorded tick, the DFL has commanded the robot to stand
    /// (a braked robot: no forward speed, ζ = 0), s.
    pub fn commanded_rest_for_s(&self) -> f64 {
        self.commanded_rest_since_s
            .map_or(0.0, |since| self.last_time_s - since)
    }

    /// One inner tick: the truth at `t_j`, the estimate used, and the command applied over
    /// `[t_j, t_j+1)`.
    pub fn tick(
        &mut self,
        truth: &GroundTruth,
        estimate: &Estimate,
        act: &Actuation,
    ) -> std::io::Result<()> {
        let [x, y, theta] = truth.pose;
        // The DFL's zeta at t_j: where the previous command left it.
        let zeta = std::mem::replace(&mut self.zeta, act.zeta);
        let t = truth.header.time_s;
        let mode = act.mode().unwrap_or(CommandMode::Brake);
        match mode {
            CommandMode::Nominal => self.commands.nominal += 1,
            CommandMode::Shifted => self.commands.shifted += 1,
            CommandMode::Brake => self.commands.brake += 1,
            CommandMode::ZetaGuard => self.commands.zeta_guard += 1,
            CommandMode::SafetyBrake => self.commands.safety_brake += 1,
            CommandMode::Hold => self.commands.hold += 1,
        }
        let count = self
            .safety_interventions
            .entry(act.header.epoch)
            .or_default();
        *count = (*count).max(act.safety_interventions);
        if let Some(reason) = act.intervention().filter(|i| *i != Intervention::None) {
            self.event(Event::SafetyIntervention {
                tick: truth.header.tick,
                reason: reason.as_str().into(),
                command: mode.as_str().into(),
                plan_sample: act.intervention_plan,
                clearance_m: act.intervention_clearance_m,
                dfl_count: act.safety_interventions,
            })?;
        }
        self.ticks += 1;
        self.last_time_s = t;
        let clearance = clearance_m(&self.obstacles, &self.footprint, t, [x, y]);
        self.last_clearance_m = Some(clearance);
        self.last_mode = Some(mode);
        if act.u1 == 0.0 && act.zeta == 0.0 {
            self.commanded_rest_since_s.get_or_insert(t);
        } else {
            self.commanded_rest_since_s = None;
        }
        if let Some(mcap) = &mut self.mcap {
            mcap.tick(truth, estimate, act);
        }
        let e = &estimate.state;
        writeln!(
            self.trajectory,
            "{t:.4},{x},{y},{theta},{zeta},{},{},{},{},{},{},{},{},{},{},{},{},{clearance}",
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
        )?;
        if self.flush.due() {
            self.flush_files()?;
        }
        Ok(())
    }

    /// Hands every CSV file's buffered lines to the file system.
    fn flush_files(&mut self) -> std::io::Result<()> {
        self.trajectory.flush()?;
        self.plans.flush()?;
        self.predictions.flush()?;
        for file in [&mut self.routes, &mut self.tracks].into_iter().flatten() {
            file.flush()?;
        }
        Ok(())
    }

    /// The truth after the last tick: the run's simulated time ends there.
    pub fn final_truth(&mut self, truth: &GroundTruth) {
        self.last_time_s = truth.header.time_s;
    }

    /// A route as the planner publishes it (every sample): a new plan is written to
    /// `route.csv` and counted; none found is an event.
    pub fn route(&mut self, route: &Route) -> std::io::Result<()> {
        let plan = (route.header.epoch, route.plans);
        if self.last_route_plan == Some(plan) {
            return Ok(());
        }
        self.last_route_plan = Some(plan);
        self.route_plans += 1;
        let reason = ReplanReason::from_code(route.reason).map_or("unknown", ReplanReason::as_str);
        let switch = RouteSwitch::from_code(route.switch).map_or("unknown", RouteSwitch::as_str);
        if !route.is_ok() {
            return self.event(Event::NoRoute {
                sample: route.planned_sample,
                reason: reason.into(),
            });
        }
        if self.route_length_m.is_none() {
            self.route_length_m = Some(route.length_m);
        }
        if let Some(mcap) = &mut self.mcap {
            mcap.route(route);
        }
        let routes = opened(
            &mut self.routes,
            &self.dir.join("route.csv"),
            &schema::ROUTE_COLUMNS,
        )?;
        for [x, y] in route.points() {
            writeln!(
                routes,
                "{},{},{reason},{switch},{x},{y}",
                self.route_plans, route.planned_sample
            )?;
        }
        Ok(())
    }

    /// The tracker's tracks, as published after each measurement: a `tracks.csv` row per
    /// track, with the obstacle's true centre beside it, and the tracks in `run.mcap`.
    pub fn tracks(&mut self, tracks: &Tracks) -> std::io::Result<()> {
        if let Some(mcap) = &mut self.mcap {
            mcap.tracks(tracks);
        }
        let file = opened(
            &mut self.tracks,
            &self.dir.join("tracks.csv"),
            &schema::TRACK_COLUMNS,
        )?;
        let t = tracks.header.time_s;
        for track in tracks.tracks() {
            let truth = self
                .obstacles
                .get(track.obstacle as usize)
                .map_or([f64::NAN; 2], |o| o.center_at(t));
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

    /// A plan as it is published; its `plans.csv` row waits for the DFL's verdict.
    pub fn plan(&mut self, plan: &Plan) -> std::io::Result<()> {
        if let Some(mcap) = &mut self.mcap {
            mcap.plan(plan);
        }
        if !plan.is_solved() {
            self.solver_failures += 1;
        }
        self.solve_us.push(plan.solve_ns as f64 / 1e3);
        self.iterations.push(f64::from(plan.iterations));
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

    /// The DFL's deadline verdict on a sample: writes the sample's `plans.csv` row, and on a
    /// miss counts it and writes a `deadline_miss` event.
    pub fn verdict(&mut self, v: &DeadlineVerdict) -> std::io::Result<()> {
        if self.last_judged.is_some_and(|last| v.sample <= last) {
            return Ok(());
        }
        self.last_judged = Some(v.sample);
        if let Some(mcap) = &mut self.mcap {
            mcap.verdict(v);
        }
        let met = v.met != 0;
        let fallback = CommandMode::from_code(v.fallback).map_or("unknown", CommandMode::as_str);
        let status = match v.status {
            PLAN_MISSING => "missing",
            code => PlanStatus::from_code(code).map_or("unknown", PlanStatus::as_str),
        };
        let arrival_ms = (v.arrival_ns != u64::MAX).then(|| v.arrival_ns as f64 / 1e6);
        if met {
            self.miss_streak = 0;
        } else {
            self.deadline_misses += 1;
            self.miss_streak += 1;
            self.longest_miss_streak = self.longest_miss_streak.max(self.miss_streak);
            self.event(Event::DeadlineMiss {
                sample: v.sample,
                status: status.into(),
                production_us: (v.status != PLAN_MISSING).then(|| v.production_ns as f64 / 1e3),
                arrival_ms,
                fallback: fallback.into(),
            })?;
        }
        let plan = self.pending_plans.remove(&v.sample);
        self.plan_row(
            v.sample,
            plan.as_ref(),
            status,
            arrival_ms,
            Some(met),
            fallback,
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

    /// Flushes the records and writes `summary.json`, with the judge's findings and, for a
    /// run interrupted, the stop signal that ended it (`run::stop::received`).
    pub fn finish(
        mut self,
        scenario: &Scenario,
        mode: &str,
        (outcome, judge): (Outcome, &Judge),
        wall_s: f64,
        processes: Option<ProcessReport>,
        signal: Option<&'static str>,
    ) -> std::io::Result<Summary> {
        // Plans the run ended before the DFL could judge.
        for (sample, plan) in std::mem::take(&mut self.pending_plans) {
            let status = plan.status().map_or("unknown", |s| s.as_str());
            self.plan_row(sample, Some(&plan), status, None, None, "")?;
        }
        self.flush_files()?;
        let interrupted_by = signal.filter(|_| outcome == Outcome::Interrupted);
        self.event(Event::End {
            outcome,
            signal: interrupted_by.map(String::from),
        })?;
        self.events.flush()?;
        if let Some(mcap) = self.mcap.take() {
            mcap.finish()?;
        }
        let m = judge;
        let summary = Summary {
            scenario: scenario.name.clone(),
            seed: scenario.seed,
            mode: mode.to_string(),
            outcome,
            stall_reason: m.reason(
                outcome,
                (self.solve_us.len() as u64).saturating_sub(self.solver_failures),
                self.route_plans > 0,
            ),
            interrupted_by,
            min_clearance_m: m.min_clearance_m,
            min_moving_clearance_m: m
                .min_moving_clearance_m
                .is_finite()
                .then_some(m.min_moving_clearance_m),
            contacts_moving: m.contacts_moving,
            contacts_at_rest: m.contacts_at_rest,
            deviation_time_s: m.deviation_time_s,
            time_to_goal_s: if outcome == Outcome::Reached {
                m.inside_goal_since_s
            } else {
                None
            },
            final_distance_to_goal_m: m.last_distance_to_goal_m,
            final_heading_error_rad: m.last_heading_error_rad,
            arrival: ArrivalReport::of(&m.arrival),
            deadline_misses: self.deadline_misses,
            longest_miss_streak: self.longest_miss_streak,
            solver_failures: self.solver_failures,
            safety_interventions: self
                .safety_interventions
                .values()
                .map(|&n| u64::from(n))
                .sum(),
            faults: scenario.fault.describe(),
            steps: self.solve_us.len() as u64,
            ticks: self.ticks,
            simulated_s: self.last_time_s,
            wall_s,
            solve_us: Percentiles::of(&self.solve_us),
            iterations: Percentiles::of(&self.iterations),
            commands: self.commands,
            replans: self.route_plans.saturating_sub(1),
            route_length_m: self.route_length_m,
            robot: summary::RobotReport::of(scenario),
            processes,
        };
        let json = serde_json::to_string_pretty(&summary).map_err(std::io::Error::other)?;
        std::fs::write(self.dir.join("summary.json"), json + "\n")?;
        std::fs::remove_file(self.dir.join(INCOMPLETE))?;
        Ok(summary)
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_counts_each_dfls_interventions_once_however_they_arrive() {
        let dir = std::env::temp_dir().join(format!("scmpc-record-{}", std::process::id()));
        let scenario = Scenario::default();
        let mut recorder = Recorder::create(&dir, &scenario).unwrap();
        let truth = GroundTruth {
            pose: [7.0, 7.0, 0.0],
            ..GroundTruth::default()
        };
        let estimate = Estimate::default();
        // The first DFL: a tick with two interventions (a plan refused and the committed
        // trajectory given up), then a replay of that tick; a restarted DFL (epoch 1)
        // counts from zero again.
        for (epoch, count, intervention) in [
            (0, 0, Intervention::None),
            (0, 2, Intervention::CommittedUnsafe),
            (0, 2, Intervention::CommittedUnsafe),
            (1, 1, Intervention::PlanRefused),
        ] {
            let mut act = Actuation {
                safety_interventions: count,
                intervention: intervention as u32,
                ..Actuation::default()
            };
            act.header.epoch = epoch;
            recorder.tick(&truth, &estimate, &act).unwrap();
        }
        let summary = recorder
            .finish(
                &scenario,
                "test",
                (Outcome::Timeout, &Judge::new(&scenario)),
                0.0,
                None,
                None,
            )
            .unwrap();
        assert_eq!(summary.safety_interventions, 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn percentiles_use_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(
            Percentiles::of(&v),
            Percentiles {
                p50: 50.0,
                p99: 99.0,
                max: 100.0
            }
        );
        assert_eq!(Percentiles::of(&[]), Percentiles::default());
    }
}
