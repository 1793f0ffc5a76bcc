//! What the orchestrator receives from the roles, filed by tick as it arrives, and recorded
//! once a tick is whole: every tick's row with the hop latencies, the plans and the
//! deadline verdicts in sample order, the routes.

use super::session::Session;
use protocol::graph::{Graph, Rate, Topic};
use protocol::{
    Actuation, Data, DeadlineVerdict, Estimate, GroundTruth, Measurement, Plan, Route, Timing,
    Tracks,
};
use record::judge::Outcome;
use record::{Event, Latencies, ProcessReport, Recorder};
use runtime::clock::RunMode;
use std::collections::BTreeMap;

/// Everything received for one tick.
#[derive(Default)]
pub(super) struct TickSlot {
    pub truth: Option<GroundTruth>,
    pub measurement: Option<Measurement>,
    pub estimate: Option<Estimate>,
    /// With the orchestrator's own receipt latency, ns.
    pub actuation: Option<(Actuation, u64)>,
}

impl TickSlot {
    /// Whether every sample of the tick has come (of the tick after the last, only the
    /// truth is needed).
    fn complete(&self, last: bool) -> bool {
        self.truth.is_some()
            && (last
                || (self.measurement.is_some()
                    && self.estimate.is_some()
                    && self.actuation.is_some()))
    }

    /// Whether the plant was commanded at the tick (an estimate may be missing: the DFL
    /// braked on its own while the estimator was silent).
    fn commanded(&self) -> bool {
        self.truth.is_some() && self.measurement.is_some() && self.actuation.is_some()
    }

    /// The topics whose sample of the tick never came, as the `record_gap` event names
    /// them: which process was silent.
    fn missing(&self) -> Vec<&'static str> {
        [
            ("truth", self.truth.is_none()),
            ("measurement", self.measurement.is_none()),
            ("estimate", self.estimate.is_none()),
            ("actuation", self.actuation.is_none()),
        ]
        .into_iter()
        .filter_map(|(topic, missing)| missing.then_some(topic))
        .collect()
    }
}

/// The slot of `tick`, unless the tick is already recorded (`tick < cursor`).
fn slot(slots: &mut BTreeMap<u64, TickSlot>, cursor: u64, tick: u64) -> Option<&mut TickSlot> {
    (tick >= cursor).then(|| slots.entry(tick).or_default())
}

/// The samples received and not recorded yet, and the counts of what was recorded.
pub(super) struct Intake {
    timing: Timing,
    /// The run's ticks: samples of later ticks (the roles' answers to the last grant) are
    /// not part of the run.
    ticks: u64,
    mode: RunMode,
    /// The plant is a ROS 2 robot: a measurement's input latency is its odometry's age.
    robot: bool,
    /// The wheels' geometry, for the wheel speeds of a tick the plant's watchdog drove.
    wheels: protocol::WheelGeometry,
    /// What the plant's watchdog did over the last tick recorded
    /// ([`GroundTruth::watchdog`]: 1 braking, 2 ramping to the commands that came again).
    watchdog: u32,
    slots: BTreeMap<u64, TickSlot>,
    plans: BTreeMap<u64, Plan>,
    verdicts: BTreeMap<u64, DeadlineVerdict>,
    /// Routes received and not recorded yet, in arrival order.
    routes: Vec<Route>,
    /// Tracks received and not recorded yet, in arrival order.
    tracks: Vec<Tracks>,
    /// Messages of the topics recorded as [`Data`] ([`Graph::recorded`]) received and
    /// not recorded yet, in arrival order.
    recorded: Vec<Data>,
    /// Each of those topics, with the newest tick received: an older or equal one is a
    /// replay (not recorded again), and lockstep waits for those published every tick or
    /// every sample ([`Rate`]).
    newest_recorded: Vec<(&'static Topic, Option<u64>)>,
    /// The newest tick whose truth has come.
    pub newest_truth: Option<u64>,
    /// Next tick to record (every earlier one is recorded).
    pub cursor: u64,
    /// Newest sample whose plan is recorded.
    last_plan: Option<u64>,
    latencies: Latencies,
    record_gaps: u64,
    ticks_without_estimate: u64,
}

impl Intake {
    pub fn new(scenario: &protocol::Scenario, mode: RunMode) -> Intake {
        Intake {
            timing: scenario.timing.clone(),
            ticks: scenario.tick_count(),
            mode,
            robot: scenario.plant.kind == protocol::PlantKind::Ros2,
            wheels: scenario.plant.wheel_geometry(),
            watchdog: 0,
            slots: BTreeMap::new(),
            plans: BTreeMap::new(),
            verdicts: BTreeMap::new(),
            routes: Vec::new(),
            tracks: Vec::new(),
            recorded: Vec::new(),
            newest_recorded: (Graph::of(scenario).recorded())
                .map(|topic| (topic, None))
                .collect(),
            newest_truth: None,
            cursor: 0,
            last_plan: None,
            latencies: Latencies::default(),
            record_gaps: 0,
            ticks_without_estimate: 0,
        }
    }

    /// Files everything the data topics hold by tick, after clearing their wake-ups (so
    /// none is missed). Ticks already recorded come again only as replays: skipped.
    pub fn take(&mut self, session: &Session) -> anyhow::Result<()> {
        for input in session.inputs() {
            input.clear_wakeups();
        }
        self.take_from_memory(session)
    }

    /// [`Intake::take`] straight from shared memory, without a system call: the wake-ups
    /// stay, so the caller takes with [`Intake::take`] before it blocks.
    pub fn take_from_memory(&mut self, session: &Session) -> anyhow::Result<()> {
        for (_, input) in &session.data {
            input.take_data(&mut |data, latency| self.file(data, latency))?;
        }
        Ok(())
    }

    /// Files a sample: a tick's by its tick (unless the tick is recorded already: a
    /// replay), the others to be recorded (unless after the run's last tick: the roles'
    /// answers to the last grant), `latency` with the command.
    fn file(&mut self, data: Data, latency: u64) {
        let tick = data.header().tick;
        let cursor = self.cursor;
        let in_run = tick < self.ticks;
        match data {
            Data::Truth(m) => {
                self.newest_truth = self.newest_truth.max(Some(tick));
                if let Some(s) = slot(&mut self.slots, cursor, tick) {
                    s.truth = Some(m);
                }
            }
            Data::Measurement(m) => {
                if let Some(s) = slot(&mut self.slots, cursor, tick) {
                    s.measurement = Some(m);
                }
            }
            Data::Estimate(m) => {
                if let Some(s) = slot(&mut self.slots, cursor, tick) {
                    s.estimate = Some(m);
                }
            }
            Data::Actuation(m) => {
                if let Some(s) = slot(&mut self.slots, cursor, tick) {
                    s.actuation = Some((m, latency));
                }
            }
            Data::Plan(p) if in_run => {
                self.plans.insert(p.sample, p);
            }
            Data::Deadline(v) if in_run => {
                self.verdicts.insert(v.sample, v);
            }
            Data::Route(r) if in_run => self.routes.push(r),
            Data::Tracks(t) if in_run => self.tracks.push(t),
            other => {
                let topic = other.topic();
                let Some((_, newest)) =
                    (self.newest_recorded.iter_mut()).find(|(t, _)| t.name == topic)
                else {
                    return;
                };
                if newest.is_some_and(|n| tick <= n) {
                    return;
                }
                *newest = Some(tick);
                if in_run {
                    self.recorded.push(other);
                }
            }
        }
    }

    /// Lockstep: whether tick `tick` is whole, with the plan of its sample when it starts
    /// one.
    pub fn has_whole(&self, tick: u64) -> bool {
        let last = tick == self.ticks;
        let plan_due = !last && self.timing.starts_sample(tick);
        self.slots.get(&tick).is_some_and(|s| s.complete(last))
            && (!plan_due || self.plans.contains_key(&self.timing.sample_of(tick)))
            && (last
                || self.newest_recorded.iter().all(|(topic, newest)| {
                    let due = match topic.rate {
                        Rate::Tick => true,
                        Rate::Sample => self.timing.starts_sample(tick),
                        Rate::PerceptionTick | Rate::Verdict => false,
                    };
                    !due || newest.is_some_and(|n| n >= tick)
                }))
    }

    /// How many samples (of any tick) are filed: it grows while the roles make progress.
    pub fn filed(&self) -> usize {
        self.slots.len() + self.plans.len()
    }

    /// Real time: the next tick to record, if it is whole or overdue (its truth is two
    /// samples old): a tick lost is counted as a record gap, and recorded as one, when
    /// there is a `recorder` (a fleet's robot whose record has ended has none).
    pub fn next_due(
        &mut self,
        recorder: Option<&mut Recorder>,
    ) -> anyhow::Result<Option<TickSlot>> {
        let tick = self.cursor;
        let overdue = self
            .newest_truth
            .is_some_and(|t| t >= tick + 2 * self.timing.ticks_per_sample());
        let complete = self
            .slots
            .get(&tick)
            .is_some_and(|s| s.complete(tick == self.ticks));
        // The truth of the tick after tells how the plant drove this one. After a tick its
        // watchdog drove, the next may be driven too though the DFL commanded it (the base
        // ramping to the commands that came again): it waits for that truth.
        let after = self.slots.get(&(tick + 1)).and_then(|s| s.truth);
        let waits_for_after = self.watchdog != 0 && after.is_none() && tick < self.ticks;
        if (!complete || waits_for_after) && !overdue {
            return Ok(None);
        }
        let mut slot = self.take_slot(tick);
        let before = self.watchdog;
        self.watchdog = after.map_or(before, |t| t.watchdog);
        // What the base's own watchdog applied stands for the DFL's command, if one came:
        // the base did not apply that one.
        if let Some(driven) =
            (after.zip(slot.truth)).and_then(|(after, truth)| self.watchdog_command(&truth, &after))
        {
            slot.actuation = Some((driven, 0));
        }
        let Some(recorder) = recorder.filter(|_| tick < self.ticks) else {
            return Ok(Some(slot));
        };
        if self.watchdog == 1 && before != 1 {
            recorder.event(Event::CommandTimeout { tick })?;
        }
        if !complete && !slot.commanded() {
            self.record_gaps += 1;
            recorder.event(Event::RecordGap {
                tick,
                missing: slot.missing().into_iter().map(String::from).collect(),
            })?;
        }
        Ok(Some(slot))
    }

    /// Real time: the command of the tick of `truth` when the plant drove it on its own
    /// watchdog (`plant.command_timeout_s`: no DFL commanded it, or the base ramped to
    /// the commands that came again), as the truth of the tick `after` tells: what the
    /// base applied, in [`CommandMode::Watchdog`].
    fn watchdog_command(&self, truth: &GroundTruth, after: &GroundTruth) -> Option<Actuation> {
        let at = truth.header;
        (after.watchdog != 0).then(|| Actuation {
            header: protocol::Header {
                tick: at.tick,
                time_s: at.time_s,
                run_id: at.run_id,
                robot: at.robot,
                ..protocol::Header::default()
            },
            u1: after.applied[0],
            u2: after.applied[1],
            wheels: self.wheels.wheel_speeds(after.applied),
            zeta: after.applied[0],
            mode: protocol::CommandMode::Watchdog as u32,
            ..Actuation::default()
        })
    }

    /// Takes the slot of `tick` (empty if nothing came); the cursor moves past it.
    pub fn take_slot(&mut self, tick: u64) -> TickSlot {
        self.cursor = tick + 1;
        self.slots.remove(&tick).unwrap_or_default()
    }

    /// Records the tick of `slot` if the plant was commanded at it; returns the outcome
    /// when the tick ends the run.
    // Never inlined: tests/instructions.rs counts this step's instructions by its name (a
    // change elsewhere in the crate once let the compiler inline it).
    #[inline(never)]
    pub fn record(
        &mut self,
        slot: TickSlot,
        recorder: &mut Recorder,
    ) -> anyhow::Result<Option<Outcome>> {
        let (Some(truth), Some(measurement), Some((act, own_latency))) =
            (slot.truth, slot.measurement, slot.actuation)
        else {
            return Ok(None);
        };
        // A tick is recorded with an estimate of NaN when it has none.
        let estimate = slot.estimate.unwrap_or(Estimate {
            state: [f64::NAN; 4],
            ..Estimate::default()
        });
        // A tick the plant's watchdog drove: no DFL commanded it, no hop to measure.
        if act.mode() != Some(protocol::CommandMode::Watchdog) {
            self.measure_hops(&slot, &measurement, &act, own_latency);
        }
        Ok(recorder.tick(&truth, Some(&measurement), &estimate, &act)?)
    }

    /// The hop latencies of a tick the DFL commanded with `act`.
    fn measure_hops(
        &mut self,
        slot: &TickSlot,
        measurement: &Measurement,
        act: &Actuation,
        own_latency: u64,
    ) {
        let l = &mut self.latencies;
        let plant_input_ns = u64::from(measurement.header.input_latency_ns);
        if self.robot {
            l.odometry_age(plant_input_ns);
        } else {
            l.hop("control_to_plant", plant_input_ns);
        }
        // A tick the DFL commanded without an estimate: estimator silent, DFL braking.
        self.ticks_without_estimate += u64::from(slot.estimate.is_none());
        if let Some(estimate) = &slot.estimate {
            l.hop(
                "measurement_to_estimator",
                u64::from(estimate.header.input_latency_ns),
            );
            l.hop("estimate_to_dfl", u64::from(act.header.input_latency_ns));
        }
        if self.mode == RunMode::Lockstep {
            // In real time the orchestrator drains its buffers periodically: not a hop.
            l.hop("actuation_to_orchestrator", own_latency);
        }
        if !self.timing.starts_sample(measurement.header.tick) && slot.estimate.is_some() {
            let ns = act
                .header
                .publish_ns
                .saturating_sub(measurement.header.publish_ns);
            l.sensor_to_actuator(ns);
        }
    }

    /// Records every route and plan received, then every deadline verdict (the DFL judges
    /// sample k at the start of sample k + 1, after plan(k) was published). Returns the
    /// outcome when a route ends the run.
    pub fn record_plans(&mut self, recorder: &mut Recorder) -> anyhow::Result<Option<Outcome>> {
        let mut no_route = None;
        for route in std::mem::take(&mut self.routes) {
            no_route = no_route.or(recorder.route(&route)?);
        }
        for tracks in std::mem::take(&mut self.tracks) {
            recorder.tracks(&tracks)?;
        }
        for data in std::mem::take(&mut self.recorded) {
            recorder.data(&data)?;
        }
        while let Some((sample, plan)) = self.plans.pop_first() {
            // A replay repeats a plan already recorded.
            if self.last_plan.is_some_and(|last| sample <= last) {
                continue;
            }
            self.last_plan = Some(sample);
            self.latencies
                .hop("estimate_to_mpc", u64::from(plan.header.input_latency_ns));
            recorder.plan(&plan)?;
        }
        while let Some((_, v)) = self.verdicts.pop_first() {
            recorder.verdict(&v)?;
        }
        Ok(no_route)
    }

    /// Drops every route, plan and verdict received (a fleet's robot whose record has
    /// ended drives on unrecorded).
    pub fn drop_plans(&mut self) {
        self.routes.clear();
        self.tracks.clear();
        self.recorded.clear();
        self.plans.clear();
        self.verdicts.clear();
    }

    /// The counts of what was received, for the summary.
    pub fn report(&self, report: &mut ProcessReport) {
        self.latencies.report(report);
        report.record_gaps = self.record_gaps;
        report.ticks_without_estimate = self.ticks_without_estimate;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{CommandMode, Header};

    fn header(tick: u64, dt_s: f64) -> Header {
        Header {
            tick,
            time_s: tick as f64 * dt_s,
            ..Header::default()
        }
    }

    /// Ticks before `silent_from` commanded by the DFL at 0.5 m/s; then none until
    /// `resumed_from`, and from there commands at rest again. The plant's watchdog braked the
    /// ticks from `watchdog_from` on, slowing by 0.01 m/s a tick, and from `resumed_from`
    /// it ramps to the commands (the same slowing) until at rest.
    fn file_ticks(
        intake: &mut Intake,
        dt_s: f64,
        ticks: u64,
        [silent_from, watchdog_from, resumed_from]: [u64; 3],
    ) {
        for tick in 0..ticks {
            let driven = tick
                .checked_sub(1)
                .filter(|before| *before >= watchdog_from);
            let slowed = |before: u64| (0.5 - 0.01 * (before - watchdog_from + 1) as f64).max(0.0);
            let (applied, watchdog) = match driven {
                None => ([0.5, 0.1], 0),
                Some(before) if before < resumed_from => ([slowed(before), 0.0], 1),
                Some(before) if slowed(before) > 0.0 => ([slowed(before), 0.0], 2),
                Some(_) => ([0.0; 2], 0),
            };
            let truth = GroundTruth {
                header: header(tick, dt_s),
                applied,
                watchdog,
                ..GroundTruth::default()
            };
            intake.file(Data::Truth(truth), 0);
            let measurement = Measurement {
                header: header(tick, dt_s),
                ..Measurement::default()
            };
            intake.file(Data::Measurement(measurement), 0);
            if tick < silent_from || tick >= resumed_from {
                let estimate = Estimate {
                    header: header(tick, dt_s),
                    ..Estimate::default()
                };
                intake.file(Data::Estimate(estimate), 0);
                let act = Actuation {
                    header: header(tick, dt_s),
                    u1: if tick < silent_from { 0.5 } else { 0.0 },
                    ..Actuation::default()
                };
                intake.file(Data::Actuation(act), 0);
            }
        }
    }

    #[test]
    fn ticks_the_plants_watchdog_drove_are_recorded_in_its_mode_after_one_command_timeout() {
        let scenario = protocol::Scenario::paper();
        let dt_s = scenario.timing.dt_s();
        let dir = tempfile::tempdir().unwrap();
        let mut recorder =
            Recorder::create(dir.path(), &scenario, &[record::sink::EventsFile::open]).unwrap();
        let mut intake = Intake::new(&scenario, RunMode::Realtime);
        // Braked from 0.5 m/s at 0.01 m/s a tick from 80: at 0.2 m/s when commands come
        // again at 110, ramped to their rest by 129, the first tick commanded again.
        file_ticks(&mut intake, dt_s, 200, [50, 80, 110]);
        let mut commands = Vec::new();
        while let Some(slot) = intake.next_due(Some(&mut recorder)).unwrap() {
            commands.push(slot.actuation.map(|(act, _)| act));
        }
        drop(recorder);
        assert!(commands.len() > 160, "{} ticks due", commands.len());
        for (tick, act) in commands.iter().enumerate() {
            let mode = act.and_then(|a| a.mode());
            match tick {
                0..50 => assert_eq!(mode, Some(CommandMode::Nominal), "tick {tick}"),
                50..80 => assert_eq!(mode, None, "tick {tick}: held, not commanded"),
                // Braked, then ramped to the DFL's commands at rest: what the base applied,
                // not what the DFL commanded.
                80..129 => {
                    let act = act.expect("driven by the watchdog");
                    assert_eq!(mode, Some(CommandMode::Watchdog), "tick {tick}");
                    assert_eq!(act.header.tick, tick as u64);
                    let slowed = 0.5 - 0.01 * (tick - 79) as f64;
                    assert!((act.u1 - slowed).abs() < 1e-12, "tick {tick}: {act:?}");
                    assert_eq!((act.zeta, act.u2), (act.u1, 0.0));
                }
                _ => assert_eq!(mode, Some(CommandMode::Nominal), "tick {tick}"),
            }
        }
        let events = std::fs::read_to_string(dir.path().join("events.jsonl")).unwrap();
        let timeouts: Vec<&str> = events
            .lines()
            .filter(|l| l.contains("command_timeout"))
            .collect();
        assert_eq!(timeouts.len(), 1, "{events}");
        assert!(timeouts[0].contains("\"tick\":80"), "{}", timeouts[0]);
        assert_eq!(events.matches("record_gap").count(), 30, "{events}");
    }

    #[test]
    fn a_tick_commanded_while_the_base_ramps_after_its_watchdog_waits_for_the_truth_after_it() {
        let scenario = protocol::Scenario::paper();
        let dt_s = scenario.timing.dt_s();
        let mut intake = Intake::new(&scenario, RunMode::Realtime);
        // Braked from tick 51, commanded again from 53, the base ramping until about 100:
        // tick 79 is whole, but only the truth of 80 tells whether the base applied its
        // command.
        file_ticks(&mut intake, dt_s, 80, [50, 51, 53]);
        let mut due = Vec::new();
        while let Some(slot) = intake.next_due(None).unwrap() {
            due.push(slot.truth.map(|t| t.header.tick));
        }
        assert_eq!(due.last(), Some(&Some(78)), "{} ticks due", due.len());
    }
}
