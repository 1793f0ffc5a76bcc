//! A fleet in process (`[[robots]]`, docs/fleet.md): one [`ClosedLoop`] per robot, each
//! the pipeline of the scenario's member for that robot ([`protocol::Scenario::member`]),
//! stepped tick by tick in one world. After every tick each robot's truth, estimate and
//! plan go to every other robot's tracker, which tells its MPC and DFL of them
//! ([`tracker::Peers`]) from what came before its tick only, so that no robot's plan
//! depends on the order the robots are stepped in. Each robot has its own record
//! (`robot<id>/`, as a run of one robot); the fleet's judge measures the robots against
//! each other, and `summary.json` holds the fleet's line and each robot's.
//!
//! Across processes each tracker takes the other robots' topics itself
//! ([`crate::multiproc`]); in process the executor hands them over, as it plays the world.

use crate::closed_loop::{ClosedLoop, Ended};
use crate::inprocess::{record_tick, set_requested_goal};
use crate::sinks::Recording;
use crate::status_line::FleetStatus;
use anyhow::Context as _;
use protocol::{Data, Validated};
use record::Recorder;
use record::event::Event;
use record::fleet::{FleetJudge, FleetSummary};
use record::judge::Outcome;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// One robot of the fleet: its pipeline, its record until its outcome, and what the others
/// hear of it.
struct Member {
    scenario: Validated,
    /// `None` once the pipeline ended (a role refused with no restart left): the robot
    /// stays where it is and falls silent.
    closed_loop: Option<ClosedLoop>,
    /// `None` once its outcome is recorded (it goes on driving, a track to the others).
    recorder: Option<Recorder>,
    summary: Option<record::Summary>,
    /// What it published in its last tick, stamped with its id, for the others.
    published: Vec<Data>,
    /// Its true position now.
    position: [f64; 2],
    radius_m: f64,
    /// The detours it set out on while its record ran (each a `gave_way` event).
    deadlocks_broken: u64,
    /// When its record began, for its summary's wall time.
    started: Instant,
    /// The goals set from outside so far (a live view's client).
    goals_set: u32,
}

/// Runs the fleet to its end (every robot's outcome, the duration, or `stop`) and writes
/// `out`: the fleet's `scenario.toml` (as a run across processes does), `robot<id>/` for
/// each robot and the fleet's `summary.json`.
pub fn run(
    scenario: &Validated,
    out: &Path,
    recording: Recording,
    stop: &AtomicBool,
) -> anyhow::Result<FleetSummary> {
    let started = Instant::now();
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let scenario_file = out.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml())
        .with_context(|| format!("writing {}", scenario_file.display()))?;
    let view = crate::sinks::fleet_view(scenario, recording)?;
    let mut members = (0..scenario.robot_count())
        .map(|id| Member::new(scenario, id, out, recording, view.as_ref()))
        .collect::<anyhow::Result<Vec<_>>>()?;
    view.iter().for_each(live::FleetView::announce);
    let radii = members.iter().map(|m| m.radius_m).collect();
    let mut judge = FleetJudge::new(radii);
    let timing = &scenario.timing;
    let mut tick = 0;
    let mut interrupted = false;
    let mut positions = Vec::with_capacity(members.len());
    let mut status = FleetStatus::of(recording.status_line, scenario.duration_s, members.len());
    let mut pace = crate::pace::Pace::of(scenario, recording);
    while members.iter().any(|m| m.recorder.is_some()) && tick < scenario.tick_count() {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        if let Some(pace) = &mut pace {
            pace.wait(tick);
        }
        for member in &mut members {
            member.step()?;
        }
        hear_each_other(&mut members);
        positions.clear();
        positions.extend(members.iter().map(|m| m.position));
        judge.tick(&positions, timing.dt_s());
        tick += 1;
        if let Some(status) = &mut status {
            let outcomes = members
                .iter()
                .map(|m| m.summary.as_ref().map(|s| s.outcome));
            let misses = members.iter().map(Member::deadline_misses);
            status.show(timing.tick_time_s(tick), outcomes, misses, &judge);
        }
    }
    drop(status);
    let wall_s = started.elapsed().as_secs_f64();
    let mut summaries = Vec::with_capacity(members.len());
    for member in &mut members {
        summaries.push(member.finish(interrupted)?);
    }
    if let Some(view) = view {
        view.finish().context("closing the fleet's live view")?;
    }
    let deadlocks: Vec<u64> = members.iter().map(|m| m.deadlocks_broken).collect();
    let simulated_s = timing.tick_time_s(tick);
    let summary = FleetSummary::of(&summaries, &judge, &deadlocks, simulated_s, wall_s);
    summary.write(out)?;
    crate::sinks::merge_fleet_mcap(out, scenario.robot_count());
    Ok(summary)
}

/// After a tick: what each robot published in it goes to every other robot's pipeline.
fn hear_each_other(members: &mut [Member]) {
    for from in 0..members.len() {
        let published = std::mem::take(&mut members[from].published);
        for (to, member) in members.iter_mut().enumerate() {
            if let (true, Some(closed_loop)) = (to != from, &mut member.closed_loop) {
                published
                    .iter()
                    .for_each(|data| closed_loop.hear_peer(data));
            }
        }
        members[from].published = published;
    }
}

impl Member {
    fn new(
        fleet: &Validated,
        id: usize,
        out: &Path,
        recording: Recording,
        view: Option<&live::FleetView>,
    ) -> anyhow::Result<Self> {
        let scenario = fleet
            .member(id)
            .validated(&format!("robot {id} of the fleet"))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let dir = out.join(format!("robot{id}"));
        let recorder = crate::sinks::member_recorder(&scenario, id, &dir, recording, view)?;
        let closed_loop = ClosedLoop::new(&scenario)?;
        let [x, y, _] = scenario.robot.start;
        Ok(Member {
            published: Vec::with_capacity(3),
            position: [x, y],
            radius_m: scenario.robot.radius_m,
            scenario,
            closed_loop: Some(closed_loop),
            recorder: Some(recorder),
            summary: None,
            deadlocks_broken: 0,
            started: Instant::now(),
            goals_set: 0,
        })
    }

    /// One tick of its pipeline, recorded until its outcome.
    fn step(&mut self) -> anyhow::Result<()> {
        let Some(closed_loop) = &mut self.closed_loop else {
            return Ok(());
        };
        if let Some(recorder) = &mut self.recorder {
            set_requested_goal(recorder, closed_loop, &mut self.goals_set)?;
        }
        let tick = match closed_loop.step() {
            Ok(tick) => tick,
            Err(Ended::Aborted { role, topic }) => {
                self.closed_loop = None;
                if let Some(recorder) = &mut self.recorder {
                    recorder.event(Event::Aborted {
                        role,
                        reason: format!("{topic} refused, no restart left"),
                    })?;
                }
                return self.end(Outcome::Aborted);
            }
            Err(stalled) => return Err(stalled.into()),
        };
        let [x, y, _] = tick.truth.pose;
        self.position = [x, y];
        let id = self.scenario.fleet_id.unwrap_or_default() as u32;
        let published = [Data::Truth(tick.truth), Data::Estimate(tick.estimate)];
        self.published.clear();
        for mut data in published.into_iter().chain(tick.plan.map(Data::Plan)) {
            data.header_mut().robot = id;
            self.published.push(data);
        }
        let Some(recorder) = &mut self.recorder else {
            return Ok(());
        };
        if let Some(outcome) = record_tick(recorder, &tick)? {
            self.end(outcome)?;
        }
        Ok(())
    }

    /// Ends its record with `outcome`; its pipeline drives on.
    fn end(&mut self, outcome: Outcome) -> anyhow::Result<()> {
        if let Some(recorder) = self.recorder.take() {
            self.deadlocks_broken = recorder.deadlocks_broken();
            let wall_s = self.started.elapsed().as_secs_f64();
            let summary =
                recorder.finish(&self.scenario, "in-process", outcome, wall_s, None, None)?;
            self.summary = Some(summary);
        }
        Ok(())
    }

    /// The deadlines its record counted as missed so far (all of them once it ended).
    fn deadline_misses(&self) -> u64 {
        match (&self.recorder, &self.summary) {
            (Some(recorder), _) => recorder.deadline_misses(),
            (None, Some(summary)) => summary.deadline_misses,
            (None, None) => 0,
        }
    }

    /// Its summary: the one recorded at its outcome, or now at the end of the run.
    fn finish(&mut self, interrupted: bool) -> anyhow::Result<record::Summary> {
        if let Some(mut recorder) = self.recorder.take() {
            self.deadlocks_broken = recorder.deadlocks_broken();
            let final_truth = (self.closed_loop.as_mut()).and_then(ClosedLoop::final_truth);
            let outcome = match interrupted {
                true => Outcome::Interrupted,
                false => recorder.end_of_run(final_truth.as_ref()),
            };
            let signal = crate::stop::received();
            let wall_s = self.started.elapsed().as_secs_f64();
            let summary =
                recorder.finish(&self.scenario, "in-process", outcome, wall_s, None, signal)?;
            self.summary = Some(summary);
        }
        self.summary
            .clone()
            .context("a robot of the fleet without a summary")
    }
}
