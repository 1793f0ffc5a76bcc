//! What a run leaves, and the judge of how it ends.
//!
//! The [`Recorder`] is the one path both executors record through: it is handed every
//! sample and event of the run, keeps the summary's statistics, asks the [`Judge`]
//! whether the run ends, derives the events a sample tells of (a deadline miss, a safety
//! intervention, no route), and hands everything on to the run's [`Sink`]s: the run
//! directory's files ([`sink::RunDirectory`], with `summary.json`), `events.jsonl`
//! ([`sink::EventsFile`]), the CSV files ([`csv::CsvFiles`], columns in [`schema`]),
//! `run.mcap` ([`Encoded::open_mcap`]), and whatever a run adds (its status line): the list is
//! `run::sinks::Recording::sinks`.
//!
//! Whatever ends the run, the records hold what happened up to [`FLUSH_PERIOD`] before
//! the end, in whole lines ([`lines::Lines`]), and a run that did not end in a summary
//! says so: its directory keeps the [`INCOMPLETE`] file written when the run started.

pub use crate::event::{Event, EventLine};
use crate::judge::{Judge, Outcome, clearance_m};
use protocol::{
    CommandMode, DeadlineVerdict, GroundTruth, Intervention, Obstacle, ObstacleGrowth, Plan,
    ReplanReason, Route, Scenario,
};
use std::collections::{BTreeMap, VecDeque};

pub mod csv;
pub mod event;
pub mod fleet;
pub mod goals;
pub mod judge;
pub mod perception;
pub mod run_dir;
pub mod schema;
pub mod sink;

mod json;
mod lines;
pub mod mcap;
mod summary;
pub use lines::FLUSH_PERIOD;
pub use mcap::{Channels, Encoded};
pub use sink::{INCOMPLETE, OpenSink, RunStart, Sample, Sink, TickSample};
pub use summary::{
    ArrivalReport, Latencies, LinkReport, ModeCounts, Percentiles, ProcessReport, Scheduling,
    Summary,
};

/// Records a run through its sinks and keeps the summary's statistics (module docs). It
/// decides nothing itself: how the run ends is the [`Judge`]'s.
pub struct Recorder {
    sinks: Vec<Box<dyn Sink>>,
    judge: Judge,
    created: std::time::Instant,
    /// For the clearance of each tick: the obstacles and the robot's footprint.
    obstacles: Vec<Obstacle>,
    footprint: ObstacleGrowth,
    solve_us: Vec<f64>,
    iterations: Vec<f64>,
    /// Each solved plan's position one sample on, `(t_s, [x_m, y_m])`, waiting for the
    /// tick at that time ([`Summary::plan_following_mm`]), oldest first.
    planned_next: VecDeque<(f64, [f64; 2])>,
    /// How far the robot was from it, mm, plan by plan.
    plan_following_mm: Vec<f64>,
    /// `Ts`, the inner tick and how far the plans' timeline runs behind the clock
    /// ([`protocol::Scenario::command_lead_s`]), s.
    ts_s: f64,
    dt_s: f64,
    lead_s: f64,
    deadline_misses: u64,
    miss_streak: u64,
    longest_miss_streak: u64,
    /// Newest sample judged (a replayed verdict is not counted twice).
    last_judged: Option<u64>,
    solver_failures: u64,
    /// The largest count of safety interventions each DFL (by producer epoch) reported:
    /// its own count, which a tick with two interventions raises by two.
    safety_interventions: BTreeMap<u32, u32>,
    commands: ModeCounts,
    /// In a fleet: whom the newest plan gives way to ([`Plan::gives_way`]), and how many
    /// detours began (each a `gave_way` event).
    gives_way: u32,
    deadlocks_broken: u64,
    /// The newest route plan recorded: the planner's epoch and its plan count.
    last_route_plan: Option<(u32, u32)>,
    route_plans: u64,
    route_length_m: Option<f64>,
    ticks: u64,
    last_time_s: f64,
    /// Since when the DFL has commanded the robot to stand (no forward speed, ζ = 0), s.
    commanded_rest_since_s: Option<f64>,
    /// How well a run with a simulated lidar saw.
    perception: Option<perception::PerceptionJudge>,
    /// Goals a sink took from outside (a live view's client), not set yet; `None` once
    /// the record takes no more ([`Recorder::stop_taking_goals`]).
    goals: Option<std::sync::mpsc::Receiver<protocol::Goal>>,
    /// Where they are sent: handed to a sink opened elsewhere ([`Recorder::goal_inbox`]);
    /// its board shows the sinks the goal in force and the one waiting.
    goals_to: goals::GoalInbox,
    /// The newest of those, waiting for [`Recorder::goal_interval_s`] to pass.
    pending_goal: Option<protocol::Goal>,
    /// When the last goal was set, s.
    goal_set_at_s: Option<f64>,
    /// The shortest time between two goals set: [`MIN_GOAL_INTERVAL_S`], or four samples if
    /// longer (a goal waits up to two samples for its first tick, and the control messages
    /// carry two goals: the one in force and the newest).
    goal_interval_s: f64,
}

/// The shortest time between two goals set while the run drives, s: each one has the MPC
/// build its program anew.
pub const MIN_GOAL_INTERVAL_S: f64 = 1.0;

impl Recorder {
    /// Creates `dir` (and parents) and opens the sinks of `open` in order
    /// (`run::sinks::Recording::sinks`). A sink that cannot open undoes nothing the
    /// others wrote: the directory keeps [`INCOMPLETE`].
    pub fn create(
        dir: &std::path::Path,
        scenario: &protocol::Scenario,
        open: &[OpenSink],
    ) -> std::io::Result<Recorder> {
        std::fs::create_dir_all(dir)?;
        let (sent, goals) = std::sync::mpsc::channel();
        let board = goals::GoalBoard::new(scenario.robot.goal.position);
        let inbox = goals::GoalInbox::new(sent, board);
        let run = RunStart {
            dir,
            scenario,
            goals: inbox.clone(),
        };
        let mut sinks = Vec::with_capacity(open.len());
        for open in open {
            sinks.extend(open(&run)?);
        }
        Ok(Recorder {
            goals: Some(goals),
            goals_to: inbox,
            pending_goal: None,
            goal_set_at_s: None,
            goal_interval_s: MIN_GOAL_INTERVAL_S.max(4.0 * scenario.timing.ts_s),
            sinks,
            judge: Judge::new(scenario),
            perception: perception::PerceptionJudge::of(scenario),
            created: std::time::Instant::now(),
            obstacles: scenario.obstacles.clone(),
            footprint: ObstacleGrowth::footprint(scenario),
            solve_us: Vec::new(),
            iterations: Vec::new(),
            planned_next: VecDeque::new(),
            plan_following_mm: Vec::new(),
            ts_s: scenario.timing.ts_s,
            dt_s: scenario.timing.dt_s(),
            lead_s: scenario.command_lead_s(),
            deadline_misses: 0,
            miss_streak: 0,
            longest_miss_streak: 0,
            last_judged: None,
            solver_failures: 0,
            safety_interventions: BTreeMap::new(),
            commands: ModeCounts::default(),
            gives_way: 0,
            deadlocks_broken: 0,
            last_route_plan: None,
            route_plans: 0,
            route_length_m: None,
            ticks: 0,
            last_time_s: 0.0,
            commanded_rest_since_s: None,
        })
    }

    /// Adds a sink opened elsewhere, after those of [`Recorder::create`] (so it closes
    /// first): one that several records share, as a fleet's live view is.
    pub fn with_sink(mut self, sink: Box<dyn Sink>) -> Recorder {
        self.sinks.push(sink);
        self
    }

    /// Where a sink opened elsewhere ([`Recorder::with_sink`]) hands the goals it takes
    /// from outside, as [`RunStart::goals`].
    pub fn goal_inbox(&self) -> goals::GoalInbox {
        self.goals_to.clone()
    }

    /// The newest goal a sink took from outside that is not set yet, once the last one
    /// set is [`MIN_GOAL_INTERVAL_S`] old (the ones between are passed over).
    pub fn requested_goal(&mut self) -> Option<protocol::Goal> {
        if let Some(newest) = (self.goals.as_ref()).and_then(|goals| goals.try_iter().last()) {
            self.pending_goal = Some(newest);
        }
        let due =
            (self.goal_set_at_s).is_none_or(|at| self.last_time_s - at >= self.goal_interval_s);
        if due { self.pending_goal.take() } else { None }
    }

    /// Takes no more goals from outside: the record has its outcome, and a fleet's robot
    /// drives on as a track to the others. A sink's send fails from now on, so its client
    /// is told.
    pub fn stop_taking_goals(&mut self) {
        (self.goals, self.pending_goal) = (None, None);
        self.goals_to.board.closed();
    }

    /// `change` is set (the executor told every role): the judge measures the run against
    /// it from the newest tick recorded on, and it is an event.
    pub fn goal_set(&mut self, change: &protocol::task::GoalChange) -> std::io::Result<()> {
        self.goal_set_at_s = Some(self.last_time_s);
        self.goals_to.board.set(change.goal.position);
        self.judge.retarget(change.goal);
        let [x, y] = change.goal.position;
        self.event(Event::Goal {
            serial: change.serial,
            from_tick: change.from_tick,
            x,
            y,
            heading: change.goal.yaw_rad,
            from: "live".into(),
        })
    }

    /// An event, handed to every sink at the simulated time of the last recorded tick.
    pub fn event(&mut self, event: Event) -> std::io::Result<()> {
        let line = EventLine {
            wall_s: self.created.elapsed().as_secs_f64(),
            t: self.last_time_s,
            event,
        };
        let json = line.to_json().map_err(std::io::Error::other)?;
        self.sinks
            .iter_mut()
            .try_for_each(|s| s.event(&line, &json))
    }

    fn hand_on(&mut self, sample: Sample<'_>) -> std::io::Result<()> {
        self.sinks.iter_mut().try_for_each(|s| s.sample(&sample))
    }

    /// How long, up to the last recorded tick, the DFL has commanded the robot to stand
    /// (a braked robot: no forward speed, ζ = 0), s.
    pub fn commanded_rest_for_s(&self) -> f64 {
        self.commanded_rest_since_s
            .map_or(0.0, |since| self.last_time_s - since)
    }

    /// One inner tick: the truth at `t_j`, the plant's measurement when the executor has
    /// it, the estimate used, and the command applied over `[t_j, t_j+1)`. Returns the
    /// judge's outcome when the tick ends the run.
    pub fn tick(
        &mut self,
        truth: &GroundTruth,
        measurement: Option<&protocol::Measurement>,
        estimate: &protocol::Estimate,
        act: &protocol::Actuation,
    ) -> std::io::Result<Option<Outcome>> {
        let t = truth.header.time_s;
        let mode = act.mode().unwrap_or(CommandMode::Brake);
        self.commands.count(mode);
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
        if act.u1 == 0.0 && act.zeta == 0.0 {
            self.commanded_rest_since_s.get_or_insert(t);
        } else {
            self.commanded_rest_since_s = None;
        }
        if let Some(perception) = &mut self.perception {
            perception.robot_at(t, truth.pose);
        }
        let [x, y, _] = truth.pose;
        while let Some(&(due_s, [px, py])) = self.planned_next.front()
            && t >= due_s - 0.5 * self.dt_s
        {
            self.planned_next.pop_front();
            if t <= due_s + 0.5 * self.dt_s {
                self.plan_following_mm.push(1e3 * (x - px).hypot(y - py));
            }
        }
        self.hand_on(Sample::Tick(TickSample {
            truth,
            measurement,
            estimate,
            actuation: act,
            clearance_m: clearance_m(&self.obstacles, &self.footprint, t, [x, y]),
        }))?;
        Ok(self.judge.tick(truth, act))
    }

    /// The end of a run that reached its last tick: `truth`, after that tick (when there
    /// is one), ends the run's simulated time and is judged too.
    pub fn end_of_run(&mut self, truth: Option<&GroundTruth>) -> Outcome {
        if let Some(truth) = truth {
            self.last_time_s = truth.header.time_s;
        }
        self.judge.end_of_run(truth)
    }

    /// A route as the planner publishes it (every sample): a new plan is counted and
    /// handed on; none found is an event, and ends the run.
    pub fn route(&mut self, route: &Route) -> std::io::Result<Option<Outcome>> {
        let plan = (route.header.epoch, route.plans);
        if self.last_route_plan == Some(plan) {
            return Ok(None);
        }
        self.last_route_plan = Some(plan);
        self.route_plans += 1;
        if !route.is_ok() {
            let reason =
                ReplanReason::from_code(route.reason).map_or("unknown", ReplanReason::as_str);
            self.event(Event::NoRoute {
                sample: route.planned_sample,
                reason: reason.into(),
            })?;
        } else if self.route_length_m.is_none() {
            self.route_length_m = Some(route.length_m);
        }
        self.hand_on(Sample::Route(route))?;
        Ok(self.judge.route(route))
    }

    /// The tracker's tracks, as published after each measurement.
    pub fn tracks(&mut self, tracks: &protocol::Tracks) -> std::io::Result<()> {
        if let Some(perception) = &mut self.perception {
            perception.tracks(tracks);
        }
        self.judge.peers(tracks);
        self.hand_on(Sample::Tracks(tracks))
    }

    /// A message of a topic the record has no place of its own for ([`Sample::Data`]):
    /// one of [`protocol::graph::Graph::recorded`], whose type names what to record (the
    /// executors hand on no other).
    pub fn data(&mut self, data: &protocol::Data) -> std::io::Result<()> {
        debug_assert!(!protocol::Data::recorded_names(data.topic()).is_empty());
        self.hand_on(Sample::Data(data))
    }

    /// A plan as it is published.
    pub fn plan(&mut self, plan: &Plan) -> std::io::Result<()> {
        if !plan.is_solved() {
            self.solver_failures += 1;
        }
        if plan.gives_way != self.gives_way {
            self.gives_way = plan.gives_way;
            if plan.gives_way != 0 {
                self.deadlocks_broken += 1;
                self.event(Event::GaveWay {
                    sample: plan.sample,
                    to_robot: plan.gives_way - 1,
                })?;
            }
        }
        self.solve_us.push(plan.solve_ns as f64 / 1e3);
        self.iterations.push(f64::from(plan.iterations));
        if plan.is_solved() && plan.horizon > 0 {
            let [x, _, y, _] = plan.z[1];
            let due_s = (plan.sample + 1) as f64 * self.ts_s + self.lead_s;
            self.planned_next.push_back((due_s, [x, y]));
        }
        self.hand_on(Sample::Plan(plan))
    }

    /// The deadlocks this robot broke so far, setting out on a detour round another robot
    /// of its fleet (each a `gave_way` event).
    pub fn deadlocks_broken(&self) -> u64 {
        self.deadlocks_broken
    }

    /// The deadlines missed so far (each a `deadline_miss` event).
    pub fn deadline_misses(&self) -> u64 {
        self.deadline_misses
    }

    /// The DFL's deadline verdict on a sample (a replay is dropped): a miss is counted
    /// and is a `deadline_miss` event.
    pub fn verdict(&mut self, v: &DeadlineVerdict) -> std::io::Result<()> {
        if self.last_judged.is_some_and(|last| v.sample <= last) {
            return Ok(());
        }
        self.last_judged = Some(v.sample);
        self.hand_on(Sample::Verdict(v))?;
        if v.met != 0 {
            self.miss_streak = 0;
        } else {
            self.deadline_misses += 1;
            self.miss_streak += 1;
            self.longest_miss_streak = self.longest_miss_streak.max(self.miss_streak);
            self.event(Event::DeadlineMiss {
                sample: v.sample,
                status: csv::verdict_status(v).into(),
                production_us: (v.status != protocol::PLAN_MISSING)
                    .then(|| v.production_ns as f64 / 1e3),
                arrival_ms: csv::arrival_ms(v),
                fallback: csv::fallback(v).into(),
            })?;
        }
        Ok(())
    }

    /// Ends the run: the `end` event (with, for a run interrupted, the stop signal that
    /// ended it: `run::stop::received`), the summary with the judge's findings, and every
    /// sink closed with it, the last opened first. Every sink is closed whatever another
    /// one's error; after one failed, the rest are told the record is not whole (the run
    /// directory then keeps `INCOMPLETE` and writes no summary). The first error is
    /// returned.
    pub fn finish(
        mut self,
        scenario: &Scenario,
        mode: &str,
        outcome: Outcome,
        wall_s: f64,
        processes: Option<ProcessReport>,
        signal: Option<&'static str>,
    ) -> std::io::Result<Summary> {
        // A goal handed on and not set yet never will be (a fleet robot's pipeline drives
        // on to the goal in force).
        self.stop_taking_goals();
        let interrupted_by = signal.filter(|_| outcome == Outcome::Interrupted);
        self.event(Event::End {
            outcome,
            signal: interrupted_by.map(String::from),
        })?;
        let summary = self.summary(scenario, mode, outcome, wall_s, processes, interrupted_by);
        let mut failed = None;
        while let Some(sink) = self.sinks.pop() {
            if let Err(e) = sink.end(&summary, failed.is_none()) {
                failed.get_or_insert(e);
            }
        }
        failed.map_or(Ok(summary), Err)
    }

    fn summary(
        &self,
        scenario: &Scenario,
        mode: &str,
        outcome: Outcome,
        wall_s: f64,
        processes: Option<ProcessReport>,
        interrupted_by: Option<&'static str>,
    ) -> Summary {
        let m = &self.judge;
        Summary {
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
            min_static_clearance_m: m
                .min_static_clearance_m
                .is_finite()
                .then_some(m.min_static_clearance_m),
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
            plan_following_mm: Percentiles::of(&self.plan_following_mm),
            commands: self.commands,
            replans: self.route_plans.saturating_sub(1),
            route_length_m: self.route_length_m,
            robot: summary::RobotReport::of(scenario),
            perception: self.perception.as_ref().map(|p| p.report()),
            processes,
        }
    }
}

#[cfg(test)]
mod tests;
