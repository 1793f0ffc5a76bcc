//! A fleet in process (`[[robots]]`, docs/fleet.md): one [`ClosedLoop`] per robot, each
//! the pipeline of the scenario's member for that robot ([`protocol::Scenario::member`]),
//! stepped tick by tick in one world. At every sample boundary each robot's MPC and DFL
//! hear the other robots as tracks predicted from their newest solved plans
//! ([`PeerPrediction::track`]), all made from the plans of the sample before, so that no
//! robot's plan depends on the order the robots are stepped in. Each robot has its own
//! record (`robot<id>/`, as a run of one robot); the fleet's judge measures the robots
//! against each other, and `summary.json` holds the fleet's line and each robot's.

use crate::closed_loop::{ClosedLoop, Ended, Tick};
use crate::sinks::Recording;
use anyhow::Context as _;
use protocol::{Data, Header, PeerPrediction, Plan, Tracks, Validated};
use record::Recorder;
use record::event::Event;
use record::fleet::{FleetJudge, FleetSummary};
use record::judge::Outcome;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// One robot of the fleet: its pipeline, its record until its outcome, and what the others
/// know of it.
struct Member {
    scenario: Validated,
    closed_loop: ClosedLoop,
    /// `None` once its outcome is recorded (it goes on driving, a disc to the others).
    recorder: Option<Recorder>,
    summary: Option<record::Summary>,
    /// Its newest solved plan, and the larger variance of its estimate's position then.
    plan: Option<(Plan, f64)>,
    /// Its newest estimate's state and the larger variance of its position (at first its
    /// start), which the others go by until it has a plan.
    estimate: ([f64; 4], f64),
    position: [f64; 2],
    radius_m: f64,
    /// Deadlocks it broke: the detours it set out on ([`Plan::gives_way`]), and the one
    /// of its last plan.
    deadlocks_broken: u64,
    gives_way: u32,
    /// When its record began, for its summary's wall time.
    started: Instant,
}

/// Runs the fleet to its end (every robot's outcome, the duration, or `stop`) and writes
/// `out`: `robot<id>/` for each robot and the fleet's `summary.json`.
pub fn run(
    scenario: &Validated,
    out: &Path,
    recording: Recording,
    stop: &AtomicBool,
) -> anyhow::Result<FleetSummary> {
    let started = Instant::now();
    let mut members = (0..scenario.robot_count())
        .map(|id| Member::new(scenario, id, out, recording))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let radii = members.iter().map(|m| m.radius_m).collect();
    let mut judge = FleetJudge::new(radii);
    let timing = &scenario.timing;
    let peers = PeerPrediction::of(scenario);
    let mut tick = 0;
    let mut interrupted = false;
    while members.iter().any(|m| m.recorder.is_some()) && tick < scenario.tick_count() {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        if timing.starts_sample(tick) {
            hear_each_other(&mut members, &peers, tick, timing.tick_time_s(tick));
        }
        for member in &mut members {
            member.step()?;
        }
        let positions: Vec<[f64; 2]> = members.iter().map(|m| m.position).collect();
        judge.tick(&positions, timing.dt_s());
        tick += 1;
    }
    let wall_s = started.elapsed().as_secs_f64();
    let mut summaries = Vec::with_capacity(members.len());
    for member in &mut members {
        summaries.push(member.finish(interrupted)?);
    }
    let deadlocks: Vec<u64> = members.iter().map(|m| m.deadlocks_broken).collect();
    let simulated_s = timing.tick_time_s(tick);
    let summary = FleetSummary::of(&summaries, &judge, &deadlocks, simulated_s, wall_s);
    let json = serde_json::to_string_pretty(&summary)?;
    std::fs::write(out.join("summary.json"), json + "\n")
        .with_context(|| format!("writing {}", out.join("summary.json").display()))?;
    Ok(summary)
}

/// At the sample starting at `tick`: each robot hears every other as a track predicted
/// from its newest solved plan (from its estimate before its first).
fn hear_each_other(members: &mut [Member], peers: &PeerPrediction, tick: u64, t_s: f64) {
    let tracks: Vec<_> = (members.iter().enumerate())
        .map(|(id, m)| match &m.plan {
            Some((plan, variance)) => peers.track(id, m.radius_m, plan, *variance, t_s),
            None => peers.track_of_estimate(id, m.radius_m, m.estimate.0, m.estimate.1),
        })
        .enumerate()
        .collect();
    for (id, member) in members.iter_mut().enumerate() {
        let mut heard = Tracks {
            header: Header {
                tick,
                time_s: t_s,
                robot: id as u32,
                ..Header::default()
            },
            ..Tracks::default()
        };
        for (_, track) in tracks.iter().filter(|(other, _)| *other != id) {
            heard.tracks[heard.count as usize] = *track;
            heard.count += 1;
        }
        member.closed_loop.hear_from_outside(Data::Tracks(heard));
    }
}

impl Member {
    fn new(fleet: &Validated, id: usize, out: &Path, recording: Recording) -> anyhow::Result<Self> {
        let scenario = fleet
            .member(id)
            .validated(&format!("robot {id} of the fleet"))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let recording = Recording {
            status_line: false,
            live: false,
            ..recording
        };
        let dir = out.join(format!("robot{id}"));
        let recorder = crate::sinks::recorder(&scenario, &dir, recording)?;
        let closed_loop = ClosedLoop::new(&scenario)?;
        let [x, y, theta] = scenario.robot.start;
        Ok(Member {
            estimate: ([x, y, theta, scenario.robot.zeta0], 0.0),
            radius_m: scenario.robot.radius_m,
            scenario,
            closed_loop,
            recorder: Some(recorder),
            summary: None,
            plan: None,
            position: [x, y],
            deadlocks_broken: 0,
            gives_way: 0,
            started: Instant::now(),
        })
    }

    /// One tick of its pipeline, recorded until its outcome.
    fn step(&mut self) -> anyhow::Result<()> {
        let tick = match self.closed_loop.step() {
            Ok(tick) => tick,
            Err(Ended::Aborted { role, topic }) => {
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
        let c = &tick.estimate.covariance;
        self.estimate = (tick.estimate.state, c[0].max(c[4]));
        if let Some(plan) = &tick.plan {
            if plan.is_solved() {
                self.plan = Some((*plan, self.estimate.1));
            }
            if plan.gives_way != 0 && plan.gives_way != self.gives_way {
                self.deadlocks_broken += 1;
                if let Some(recorder) = &mut self.recorder {
                    recorder.event(Event::GaveWay {
                        sample: plan.sample,
                        to_robot: plan.gives_way - 1,
                    })?;
                }
            }
            self.gives_way = plan.gives_way;
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
            let wall_s = 0.0;
            let summary =
                recorder.finish(&self.scenario, "in-process", outcome, wall_s, None, None)?;
            self.summary = Some(summary);
        }
        Ok(())
    }

    /// Its summary: the one recorded at its outcome, or now at the end of the run.
    fn finish(&mut self, interrupted: bool) -> anyhow::Result<record::Summary> {
        if let Some(mut recorder) = self.recorder.take() {
            let outcome = match interrupted {
                true => Outcome::Interrupted,
                false => recorder.end_of_run(self.closed_loop.final_truth().as_ref()),
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

/// Records one tick of a robot's pipeline: its outcome, if the tick ends its run.
fn record_tick(recorder: &mut Recorder, tick: &Tick) -> anyhow::Result<Option<Outcome>> {
    if let Some(plan) = &tick.plan {
        recorder.plan(plan)?;
    }
    if let Some(verdict) = &tick.verdict {
        recorder.verdict(verdict)?;
    }
    let mut no_route = None;
    if let Some(route) = &tick.route {
        no_route = recorder.route(route)?;
    }
    for data in &tick.recorded {
        recorder.data(data)?;
    }
    let outcome = recorder.tick(&tick.truth, None, &tick.estimate, &tick.actuation)?;
    Ok(outcome.or(no_route))
}
