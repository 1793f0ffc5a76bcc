//! A fleet in process (`[[robots]]`, docs/fleet.md): one [`ClosedLoop`] per robot, each
//! the pipeline of the scenario's member for that robot ([`protocol::Scenario::member`]),
//! stepped tick by tick in one world. At every sample boundary each robot's MPC and DFL
//! hear the other robots as tracks ([`Member::track`]), all made from what the robots
//! published up to the tick before, so that no robot's plan depends on the order the
//! robots are stepped in. Each robot has its own record (`robot<id>/`, as a run of one
//! robot); the fleet's judge measures the robots against each other, and `summary.json`
//! holds the fleet's line and each robot's.
//!
//! Across processes a robot's tracker would take this part (docs/fleet.md, "Left out");
//! in process the executor plays it, as it plays the world.

use crate::closed_loop::{ClosedLoop, Ended};
use crate::inprocess::record_tick;
use crate::sinks::Recording;
use anyhow::Context as _;
use protocol::{Data, Estimate, Header, PeerPrediction, Plan, Track, Tracks, Validated};
use record::Recorder;
use record::event::Event;
use record::fleet::{FleetJudge, FleetSummary};
use record::judge::Outcome;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// A robot whose newest solved plan is older than this many samples has stopped
/// publishing plans: the others go by what the world shows of it ([`Member::track`]).
pub const SILENT_SAMPLES: u64 = 4;

/// What a robot's estimate tells the others: its state `[x, y, theta, zeta]` and the
/// standard deviations of its position (m) and of its velocity (m/s, the speed times the
/// heading's).
#[derive(Debug, Clone, Copy)]
struct Estimated {
    state: [f64; 4],
    sigmas: [f64; 2],
}

impl Estimated {
    fn of(estimate: &Estimate) -> Estimated {
        let theta_sigma = estimate.covariance[8].max(0.0).sqrt();
        Estimated {
            state: estimate.state,
            sigmas: [
                estimate.position_sigma(),
                estimate.state[3].abs() * theta_sigma,
            ],
        }
    }
}

/// One robot of the fleet: its pipeline, its record until its outcome, and what the others
/// know of it.
struct Member {
    scenario: Validated,
    /// `None` once the pipeline ended (a role refused with no restart left): the robot
    /// stays where it is, a disc to the others.
    closed_loop: Option<ClosedLoop>,
    /// `None` once its outcome is recorded (it goes on driving, a disc to the others).
    recorder: Option<Recorder>,
    summary: Option<record::Summary>,
    /// Its newest solved plan, with its estimate then.
    plan: Option<(Plan, Estimated)>,
    /// Its newest estimate (at first its start), which the others go by before its first
    /// plan.
    estimate: Estimated,
    /// Its true position now, and at the last sample's start.
    position: [f64; 2],
    sampled_at: [f64; 2],
    radius_m: f64,
    /// The detours it set out on while its record ran (each a `gave_way` event), and
    /// the one of its last plan ([`Plan::gives_way`]).
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
    let mut positions = Vec::with_capacity(members.len());
    while members.iter().any(|m| m.recorder.is_some()) && tick < scenario.tick_count() {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        if timing.starts_sample(tick) {
            let t_s = timing.tick_time_s(tick);
            hear_each_other(&mut members, &peers, (tick, timing.sample_of(tick)), t_s);
        }
        for member in &mut members {
            member.step()?;
        }
        positions.clear();
        positions.extend(members.iter().map(|m| m.position));
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
    let path = out.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(summary)
}

/// At the start of sample `sample` (inner tick `tick`, time `t_s`): each robot hears
/// every other as a track ([`Member::track`]). (A fleet has no command delay, so the
/// plans' timeline is the clock's.)
fn hear_each_other(
    members: &mut [Member],
    peers: &PeerPrediction,
    (tick, sample): (u64, u64),
    t_s: f64,
) {
    let tracks: Vec<Track> = (members.iter().enumerate())
        .map(|(id, m)| m.track(id, peers, sample, t_s))
        .collect();
    for (id, member) in members.iter_mut().enumerate() {
        member.sampled_at = member.position;
        let mut heard = Tracks {
            header: Header {
                tick,
                time_s: t_s,
                robot: id as u32,
                ..Header::default()
            },
            ..Tracks::default()
        };
        for (_, track) in tracks.iter().enumerate().filter(|(other, _)| *other != id) {
            heard.tracks[heard.count as usize] = *track;
            heard.count += 1;
        }
        if let Some(closed_loop) = &mut member.closed_loop {
            closed_loop.hear_from_outside(Data::Tracks(heard));
        }
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
        let recorder =
            crate::sinks::recorder(&scenario, &out.join(format!("robot{id}")), recording)?;
        let closed_loop = ClosedLoop::new(&scenario)?;
        let [x, y, theta] = scenario.robot.start;
        Ok(Member {
            estimate: Estimated {
                state: [x, y, theta, scenario.robot.zeta0],
                sigmas: [0.0; 2],
            },
            position: [x, y],
            sampled_at: [x, y],
            radius_m: scenario.robot.radius_m,
            scenario,
            closed_loop: Some(closed_loop),
            recorder: Some(recorder),
            summary: None,
            plan: None,
            deadlocks_broken: 0,
            gives_way: 0,
            started: Instant::now(),
        })
    }

    /// It as a track to the others at sample `sample`, time `t_s`:
    /// - predicted from its newest solved plan ([`PeerPrediction::track`]);
    /// - before its first, where its estimate (at first its start) puts it;
    /// - once its plans have stopped for [`SILENT_SAMPLES`] (its MPC fails), where the
    ///   world shows it, as a tracker measuring it would: its true position, at the
    ///   velocity of its last sample, uncertain by `perception.noise_std` and by the half
    ///   sample of acceleration that velocity is behind by;
    /// - once its pipeline ended, at rest where it stopped.
    fn track(&self, id: usize, peers: &PeerPrediction, sample: u64, t_s: f64) -> Track {
        if self.closed_loop.is_none() {
            let sigmas = [self.scenario.perception.noise_std, 0.0];
            return peers.track_seen(id, self.radius_m, (self.position, [0.0; 2]), sigmas);
        }
        match &self.plan {
            Some((plan, estimated)) if plan.sample + SILENT_SAMPLES >= sample => {
                peers.track(id, self.radius_m, plan, estimated.sigmas, t_s)
            }
            Some(_) => {
                let ts = peers.ts_s;
                let velocity = [0, 1].map(|a| (self.position[a] - self.sampled_at[a]) / ts);
                let kappa = peers.kappa.max(f64::MIN_POSITIVE);
                let sigmas = [
                    self.scenario.perception.noise_std,
                    0.5 * peers.accel_max * ts / kappa,
                ];
                peers.track_seen(id, self.radius_m, (self.position, velocity), sigmas)
            }
            None => {
                let [x, y, theta, zeta] = self.estimate.state;
                let seen = ([x, y], [zeta * theta.cos(), zeta * theta.sin()]);
                peers.track_seen(id, self.radius_m, seen, self.estimate.sigmas)
            }
        }
    }

    /// One tick of its pipeline, recorded until its outcome.
    fn step(&mut self) -> anyhow::Result<()> {
        let Some(closed_loop) = &mut self.closed_loop else {
            return Ok(());
        };
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
        self.estimate = Estimated::of(&tick.estimate);
        if let Some(plan) = tick.plan.filter(Plan::is_solved) {
            self.plan = Some((plan, self.estimate));
        }
        let Some(recorder) = &mut self.recorder else {
            return Ok(());
        };
        if let Some(plan) = &tick.plan
            && plan.gives_way != self.gives_way
        {
            self.gives_way = plan.gives_way;
            if plan.gives_way != 0 {
                self.deadlocks_broken += 1;
                recorder.event(Event::GaveWay {
                    sample: plan.sample,
                    to_robot: plan.gives_way - 1,
                })?;
            }
        }
        if let Some(outcome) = record_tick(recorder, &tick)? {
            self.end(outcome)?;
        }
        Ok(())
    }

    /// Ends its record with `outcome`; its pipeline drives on.
    fn end(&mut self, outcome: Outcome) -> anyhow::Result<()> {
        if let Some(recorder) = self.recorder.take() {
            let wall_s = self.started.elapsed().as_secs_f64();
            let summary =
                recorder.finish(&self.scenario, "in-process", outcome, wall_s, None, None)?;
            self.summary = Some(summary);
        }
        Ok(())
    }

    /// Its summary: the one recorded at its outcome, or now at the end of the run.
    fn finish(&mut self, interrupted: bool) -> anyhow::Result<record::Summary> {
        if let Some(mut recorder) = self.recorder.take() {
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
