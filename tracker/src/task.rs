//! The tracker role as a task ([`protocol::task`]). At every perception tick it publishes
//! its tracks:
//! - measuring the tracked obstacles from the plant's truth at that tick's time;
//! - or, with a lidar, from the scan of that tick, put into the world with the estimate of
//!   the tick it was taken at (`age_ticks` before: a robot's scan; the same tick for the
//!   simulated lidar), waited for until a quarter of an inner tick after the scan's time
//!   (in lockstep until it comes; once that is past, the newest estimate before it).
//!
//! It takes every perception tick in order, so in process and in lockstep a run's tracks
//! do not depend on when its inputs arrive (in real time a scan whose estimate is late is
//! placed with the newest before it; estimates kept are the last [`POSES_KEPT`]).
//!
//! In a fleet it adds the other robots to every perception tick's tracks, from their
//! truths, estimates and plans ([`Peers`]); its lidar's returns on them are left out
//! ([`Peers::footprints`]).

use crate::lidar::Circle;
use crate::{Peers, Perception, Tracker};
use protocol::task::{Context, Due, PerceptionTicks, Publish, Task, TaskError};
use protocol::topics::{ESTIMATE, SCAN, TRUTH};
use protocol::{Data, Estimate, FaultConfig, GroundTruth, Header, Role, Scan, Tracks, Validated};
use std::collections::VecDeque;

/// What the tracker takes: with a lidar its scans and the estimates, else the plant's
/// truth, its clock (the obstacles' true positions are the scenario's motion at the
/// truth's time).
#[derive(Debug, Clone, Copy)]
#[allow(clippy::large_enum_variant)] // handed over by value, like `Data`, which holds a scan
pub enum TrackerInput {
    Scan(Scan),
    Estimate(Estimate),
    Truth(GroundTruth),
}
protocol::task_input!(TrackerInput: Scan, Estimate, Truth);

/// How the tracker perceives the world.
enum Sense {
    /// It measures the tracked obstacles from the truth.
    Truth(Tracker),
    /// It sees with the lidar: its perception, the scans waiting, and the newest estimates
    /// heard (`(tick, pose)`).
    Lidar {
        perception: Perception,
        scans: VecDeque<Scan>,
        poses: VecDeque<(u64, [f64; 3])>,
    },
}

/// Estimates kept to place a scan with (more than a sample's inner ticks).
const POSES_KEPT: usize = 64;

/// Scans kept waiting for their estimate (the oldest is dropped beyond).
const SCANS_KEPT: usize = 4;

/// How long after a scan's time its estimate is waited for, in inner ticks (real time).
const POSE_GRACE_TICKS: f64 = 0.25;

/// The tracker with the perception ticks waiting for it.
pub struct TrackerTask {
    sense: Sense,
    perception: PerceptionTicks,
    ticks_per_sample: u64,
    /// Whether every perception tick starts a sample.
    perceives_at_sample_starts: bool,
    dt_s: f64,
    faults: FaultConfig,
    /// Perception ticks heard and not measured yet, with their times, s (of the truth).
    pending: VecDeque<(u64, f64)>,
    dropped: u32,
    /// The other robots of a fleet.
    peers: Option<Peers>,
    /// The other robots' footprints at a scan's time (kept to allocate once).
    footprints: Vec<Circle>,
}

impl Task for TrackerTask {
    const ROLE: Role = Role::Tracker;
    type Input = TrackerInput;
    type Output = Tracks;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<TrackerTask, TaskError> {
        let sense = if scenario.sees_with_lidar() {
            Sense::Lidar {
                perception: Perception::new(scenario),
                scans: VecDeque::with_capacity(SCANS_KEPT),
                poses: VecDeque::with_capacity(POSES_KEPT),
            }
        } else {
            Sense::Truth(Tracker::new(scenario))
        };
        Ok(TrackerTask {
            sense,
            perception: PerceptionTicks::of(scenario),
            ticks_per_sample: scenario.timing.inner_steps as u64,
            perceives_at_sample_starts: scenario
                .perception_ticks()
                .is_multiple_of(scenario.timing.ticks_per_sample()),
            dt_s: scenario.timing.dt_s(),
            faults: scenario.fault.clone(),
            pending: VecDeque::with_capacity(8),
            dropped: 0,
            peers: Peers::of(scenario),
            footprints: Vec::with_capacity(scenario.robot_count()),
        })
    }

    /// The scans and the estimates with a lidar; else the truth.
    fn takes(&self, topic: &str) -> bool {
        match self.sense {
            Sense::Truth(_) => topic == TRUTH,
            Sense::Lidar { .. } => topic == SCAN || topic == ESTIMATE,
        }
    }

    /// The truths at perception ticks, if each starts a sample (with a lidar, its scans
    /// wake it, and the estimates of every tick: a robot's scan may be of any tick).
    fn woken_at_sample_starts(&self, topic: &str) -> bool {
        matches!(self.sense, Sense::Truth(_)) && topic == TRUTH && self.perceives_at_sample_starts
    }

    /// In a fleet, another robot's truth, estimate or plan.
    fn hear_peer(&mut self, data: &Data) {
        if let Some(peers) = &mut self.peers {
            peers.hear(data);
        }
    }

    /// A truth or a scan at a perception tick newer than the last is queued; an estimate
    /// is kept.
    fn hear(&mut self, input: TrackerInput, _latency_ns: u64, _context: &impl Context) {
        let header = match (&mut self.sense, input) {
            (Sense::Truth(_), TrackerInput::Truth(truth)) => truth.header,
            (Sense::Lidar { scans, .. }, TrackerInput::Scan(scan)) => {
                if self.perception.is_past(scan.header.tick) {
                    return;
                }
                if scans.len() == SCANS_KEPT {
                    scans.pop_front();
                }
                scans.push_back(scan);
                scan.header
            }
            (Sense::Lidar { poses, .. }, TrackerInput::Estimate(estimate)) => {
                let [x, y, theta, _] = estimate.state;
                if poses.back().is_none_or(|(t, _)| estimate.header.tick > *t) {
                    if poses.len() == POSES_KEPT {
                        poses.pop_front();
                    }
                    poses.push_back((estimate.header.tick, [x, y, theta]));
                }
                return;
            }
            _ => return,
        };
        if self.perception.take(header.tick) {
            self.pending.push_back((header.tick, header.time_s));
        }
    }

    /// The next perception tick's truth or scan is expected; with a scan waiting for its
    /// estimate, the step is due when the wait for it is over.
    fn next(&self) -> Due {
        if let (Sense::Lidar { .. }, Some(&(_, time_s))) = (&self.sense, self.pending.front()) {
            return Due::Wait(Some(time_s + POSE_GRACE_TICKS * self.dt_s));
        }
        Due::Expect(Some(self.perception.next_s()))
    }

    /// The tracks after the oldest perception tick waiting (measured, or predicted to it
    /// when its sample is in `fault.tracker_drop_samples`), held `fault.tracker_delay_ms`.
    // Never inlined: tests/instructions.rs counts this step's instructions by its name.
    #[inline(never)]
    fn step(&mut self, context: &impl Context) -> Option<Publish<Tracks>> {
        let &(tick, time_s) = self.pending.front()?;
        let dropped = (self.faults.tracker_drop_samples).contains(tick / self.ticks_per_sample);
        let mut tracks = Tracks {
            header: Header {
                tick,
                time_s,
                ..Header::default()
            },
            ..Tracks::default()
        };
        match &mut self.sense {
            Sense::Truth(tracker) => {
                if dropped {
                    tracker.predict_to(time_s);
                } else {
                    tracker.measure(time_s);
                }
                tracker.tracks(&mut tracks);
            }
            Sense::Lidar {
                perception,
                scans,
                poses,
            } => {
                let heard = poses.back().is_some_and(|(t, _)| *t >= tick);
                if !heard && !context.is_past(time_s + POSE_GRACE_TICKS * self.dt_s) {
                    return None; // the estimate of the scan's tick is on its way
                }
                let scan = scans.iter().position(|s| s.header.tick == tick);
                let taken = scan.map_or(tick, |i| scans[i].taken_tick());
                let pose = poses.iter().rev().find(|(t, _)| *t <= taken);
                match (scan, pose) {
                    (Some(i), Some((_, pose))) if !dropped && scans[i].beams > 0 => {
                        let footprints = &mut self.footprints;
                        if let Some(peers) = &self.peers {
                            peers.footprints(taken, taken as f64 * self.dt_s, footprints);
                        }
                        perception.take(&scans[i], *pose, footprints)
                    }
                    _ => perception.predict_to(time_s),
                }
                scans.retain(|s| s.header.tick > tick);
                perception.tracks(&mut tracks);
            }
        }
        if let Some(peers) = &mut self.peers {
            peers.tracks(tick, time_s, &mut tracks);
        }
        self.pending.pop_front();
        self.dropped += u32::from(dropped);
        tracks.dropped = self.dropped;
        Some(Publish {
            output: tracks,
            hold_ns: (self.faults.tracker_delay_ms * 1e6) as u64,
        })
    }
}
