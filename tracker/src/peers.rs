//! The other robots of a fleet as tracks (docs/fleet.md): a robot's tracker takes every
//! other robot's truth, estimate and plan, and at each perception tick `j` tells its MPC
//! and DFL where each of them may be, from what they published before `j` only. So in
//! process and in lockstep its tracks do not depend on whether another robot's process
//! has already stepped tick `j` (lockstep grants `j` only once every robot's `j - 1` is
//! whole, so that much has always come).

use protocol::task::Recent;
use protocol::{Data, Estimate, Header, PeerPrediction, Plan, Track, Tracks, Validated};

/// A robot whose newest solved plan is older than this many samples has stopped
/// publishing plans: the others go by what the world shows of it ([`Peers::tracks`]).
pub const SILENT_SAMPLES: u64 = 4;

/// The most another robot's footprint is grown by its estimate's uncertainty where its
/// lidar returns are left out ([`Peers::footprints`]), m: a robot whose estimate has
/// drifted is seen by the lidar beyond it (its plans still track it) rather than hide
/// what stands near it.
pub const FOOTPRINT_GROWTH_MAX_M: f64 = 0.1;

/// A robot's solved plans kept ([`Recent`]): one a sample.
const PLANS_KEPT: usize = 4;

/// What a robot's estimate tells the others: its state `[x, y, theta, zeta]` and the
/// standard deviations of its position (m) and of its velocity (m/s: the speed times the
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

/// Another robot as heard.
#[derive(Debug, Clone)]
struct Peer {
    id: usize,
    radius_m: f64,
    /// Where it starts: what the others go by before its first estimate.
    start: Estimated,
    truths: Recent<[f64; 2]>,
    estimates: Recent<Estimated>,
    /// Its solved plans.
    plans: Recent<Plan>,
    /// Its true position at the last perception tick (the tick of that truth, and it).
    seen_at: Option<(u64, [f64; 2])>,
}

/// Every other robot of the fleet, and how they are predicted.
#[derive(Debug, Clone)]
pub struct Peers {
    prediction: PeerPrediction,
    peers: Vec<Peer>,
    noise_std: f64,
    ticks_per_sample: u64,
    dt_s: f64,
}

impl Peers {
    /// The other robots of `scenario`'s fleet, seen by its member ([`Scenario::member`]);
    /// `None` for a robot alone.
    ///
    /// [`Scenario::member`]: protocol::Scenario::member
    pub fn of(scenario: &Validated) -> Option<Peers> {
        scenario.fleet_id?;
        let ticks_per_sample = scenario.timing.inner_steps;
        let peers = (scenario.other_robots())
            .map(|(id, [x, y, theta], radius_m)| Peer {
                id,
                radius_m,
                start: Estimated {
                    state: [x, y, theta, scenario.robot.zeta0],
                    sigmas: [0.0; 2],
                },
                truths: Recent::of_two_samples(ticks_per_sample),
                estimates: Recent::of_two_samples(ticks_per_sample),
                plans: Recent::new(PLANS_KEPT),
                seen_at: None,
            })
            .collect();
        Some(Peers {
            prediction: PeerPrediction::of(scenario),
            peers,
            noise_std: scenario.perception.noise_std,
            ticks_per_sample: ticks_per_sample as u64,
            dt_s: scenario.timing.dt_s(),
        })
    }

    /// A sample of robot `data.header().robot`: its truth, its estimate, or its plan (kept
    /// when solved). Samples of robots not in the fleet are ignored.
    pub fn hear(&mut self, data: &Data) {
        let header: &Header = data.header();
        let Some(peer) = self
            .peers
            .iter_mut()
            .find(|p| p.id == header.robot as usize)
        else {
            return;
        };
        match data {
            Data::Truth(truth) => {
                let [x, y, _] = truth.pose;
                peer.truths.push(header.tick, [x, y]);
            }
            Data::Estimate(estimate) => peer.estimates.push(header.tick, Estimated::of(estimate)),
            Data::Plan(plan) if plan.is_solved() => peer.plans.push(header.tick, *plan),
            _ => {}
        }
    }

    /// Every other robot's footprint at tick `tick` (time `t_s`), as its lidar's returns
    /// on it are left out ([`crate::Perception::take`]): where the robot says it is, its
    /// newest estimate before `tick` moved on to `t_s` at the estimate's velocity, its
    /// radius grown by `kappa` standard deviations of the estimate's position, at most by
    /// [`FOOTPRINT_GROWTH_MAX_M`]. An estimate more than a sample old (its estimator fell
    /// silent) is not moved on: the footprint is where the world shows the robot, its
    /// newest true position before `tick` ([`Recent::position_at`]), as its track then is
    /// ([`Peers::tracks`]), else where it was last estimated, or before anything is heard
    /// of it its start.
    pub fn footprints(&self, tick: u64, t_s: f64, footprints: &mut Vec<crate::lidar::Circle>) {
        let sample_s = self.ticks_per_sample as f64 * self.dt_s;
        footprints.clear();
        footprints.extend(self.peers.iter().map(|peer| {
            let newest = (peer.estimates.newest_before(tick))
                .map(|(heard, estimate)| (t_s - heard as f64 * self.dt_s, estimate));
            match newest.filter(|(age_s, _)| *age_s <= sample_s) {
                Some((age_s, estimate)) => {
                    let [x, y, theta, zeta] = estimate.state;
                    let ahead_s = age_s.max(0.0);
                    let centre = [
                        x + zeta * theta.cos() * ahead_s,
                        y + zeta * theta.sin() * ahead_s,
                    ];
                    let grown = self.prediction.kappa * estimate.sigmas[0];
                    (centre, peer.radius_m + grown.min(FOOTPRINT_GROWTH_MAX_M))
                }
                None => {
                    let [x, y, ..] = newest.map_or(peer.start, |(_, e)| e).state;
                    let seen = peer.truths.position_at(tick, t_s, self.dt_s);
                    (seen.unwrap_or([x, y]), peer.radius_m)
                }
            }
        }));
    }

    /// Appends every other robot to `tracks`, as it may be at perception tick `tick`
    /// (time `t_s`), from what it published before `tick`:
    /// - predicted from its newest solved plan ([`PeerPrediction::track`]), uncertain by
    ///   its newest estimate's error;
    /// - before its first, where its newest estimate puts it; before any is heard, at its
    ///   start, uncertain by all it may have done since (at `t_s = 0`, nothing);
    /// - once its plans have stopped for [`SILENT_SAMPLES`] (its MPC fails or is gone), where
    ///   the world shows it, as a tracker measuring it would: its true position, at the
    ///   velocity it had since the last perception tick, uncertain by
    ///   `perception.noise_std` and by the half sample of acceleration that velocity is
    ///   behind by.
    pub fn tracks(&mut self, tick: u64, t_s: f64, tracks: &mut Tracks) {
        let sample = tick / self.ticks_per_sample;
        for peer in &mut self.peers {
            let heard = peer.estimates.newest_before(tick);
            let estimate = heard.map_or(peer.start, |(_, e)| e);
            let seen = peer.truths.newest_before(tick);
            let track = match peer.plans.newest_before(tick) {
                Some((_, plan)) if plan.sample.saturating_add(SILENT_SAMPLES) >= sample => {
                    let sigmas = estimate.sigmas;
                    self.prediction
                        .track(peer.id, peer.radius_m, &plan, sigmas, t_s)
                }
                Some(_) => {
                    let (now, position) =
                        seen.unwrap_or((tick, [estimate.state[0], estimate.state[1]]));
                    let velocity = match peer.seen_at {
                        Some((then, before)) if now > then => {
                            let elapsed_s = (now - then) as f64 * self.dt_s;
                            [0, 1].map(|a| (position[a] - before[a]) / elapsed_s)
                        }
                        _ => [0.0; 2],
                    };
                    let prediction = &self.prediction;
                    let kappa = prediction.kappa.max(f64::MIN_POSITIVE);
                    let sigmas = [
                        self.noise_std,
                        0.5 * prediction.accel_max * prediction.ts_s / kappa,
                    ];
                    prediction.track_seen(peer.id, peer.radius_m, (position, velocity), sigmas)
                }
                None if heard.is_none() => {
                    // Nothing heard of it yet: where it may be since it started, by the
                    // time now (a tracker restarted mid-run has heard nothing).
                    let [x, y, theta, zeta] = peer.start.state;
                    let seen = ([x, y], [zeta * theta.cos(), zeta * theta.sin()]);
                    let sigmas = self.prediction.drift_sigmas(t_s);
                    (self.prediction).track_seen(peer.id, peer.radius_m, seen, sigmas)
                }
                None => {
                    let [x, y, theta, zeta] = estimate.state;
                    let seen = ([x, y], [zeta * theta.cos(), zeta * theta.sin()]);
                    (self.prediction).track_seen(peer.id, peer.radius_m, seen, estimate.sigmas)
                }
            };
            if seen.is_some() {
                peer.seen_at = seen;
            }
            push(tracks, track);
        }
    }
}

/// Appends `track` to `tracks` if there is room ([`protocol::MAX_TRACKS`] is above a
/// fleet's robots and its tracked obstacles together: the validator's
/// `check_planner_and_obstacles`).
fn push(tracks: &mut Tracks, track: Track) {
    if let Some(slot) = tracks.tracks.get_mut(tracks.count as usize) {
        *slot = track;
        tracks.count += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::GroundTruth;

    fn truth(robot: u32, tick: u64, x: f64) -> Data {
        Data::Truth(GroundTruth {
            header: Header {
                robot,
                tick,
                ..Header::default()
            },
            pose: [x, 0.0, 0.0],
            ..GroundTruth::default()
        })
    }

    fn estimate(robot: u32, tick: u64, state: [f64; 4], variance: f64) -> Data {
        Data::Estimate(Estimate {
            header: Header {
                robot,
                tick,
                ..Header::default()
            },
            state,
            covariance: [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, 0.0],
            ahead: state,
        })
    }

    #[test]
    fn a_footprint_is_where_the_newest_estimate_before_the_tick_puts_the_robot_grown_a_little() {
        let toml = include_str!("../../scenarios/swap4.toml");
        let fleet = protocol::Scenario::from_toml(toml, "swap4").unwrap();
        let member = fleet.member(0).validated("robot 0").unwrap();
        let (dt, kappa) = (member.timing.dt_s(), member.mpc.uncertainty_sigmas);
        let ticks = member.timing.inner_steps as u64;
        let mut peers = Peers::of(&member).unwrap();
        let mut footprints = Vec::new();
        peers.footprints(0, 0.0, &mut footprints);
        let start = member.robots[1].start;
        assert_eq!(
            footprints[0],
            ([start[0], start[1]], 0.3),
            "before anything: its start"
        );

        // Robot 1 at (1, 0) heading along x at 2 m/s, its position 1 cm uncertain; an
        // estimate of the tick being scanned is not yet its to use.
        peers.hear(&estimate(1, 9, [1.0, 0.0, 0.0, 2.0], 1e-4));
        peers.hear(&estimate(1, 10, [9.0, 9.0, 0.0, 2.0], 1e-4));
        peers.footprints(10, 10.0 * dt, &mut footprints);
        let (centre, radius) = footprints[0];
        assert!((centre[0] - (1.0 + 2.0 * dt)).abs() < 1e-12 && centre[1] == 0.0);
        assert!((radius - (0.3 + kappa * 0.01)).abs() < 1e-12, "{radius}");
        // A diverged estimate grows it by FOOTPRINT_GROWTH_MAX_M at most.
        peers.hear(&estimate(1, 11, [1.0, 0.0, 0.0, 2.0], 100.0));
        peers.footprints(12, 12.0 * dt, &mut footprints);
        assert_eq!(footprints[0].1, 0.3 + FOOTPRINT_GROWTH_MAX_M);

        // Its estimates stop; two samples on, the footprint is not moved on along the old
        // heading but where the world shows the robot.
        let late = 11 + 2 * ticks;
        peers.footprints(late, late as f64 * dt, &mut footprints);
        assert_eq!(
            footprints[0].0,
            [1.0, 0.0],
            "no truth: where last estimated"
        );
        peers.hear(&truth(1, late - 1, 1.5));
        peers.footprints(late, late as f64 * dt, &mut footprints);
        assert_eq!(footprints[0], ([1.5, 0.0], 0.3));
    }

    #[test]
    fn a_robot_that_never_planned_is_where_it_was_seen_and_one_silent_moves_as_it_was_seen() {
        let toml = include_str!("../../scenarios/swap4.toml");
        let fleet = protocol::Scenario::from_toml(toml, "swap4").unwrap();
        let member = fleet.member(0).validated("robot 0").unwrap();
        let mut peers = Peers::of(&member).unwrap();
        let mut tracks = Tracks::default();
        peers.tracks(0, 0.0, &mut tracks);
        assert_eq!(tracks.count, 3, "every other robot, from its start");
        let start = member.robots[1].start;
        assert_eq!(tracks.tracks[0].center, [start[0], start[1]]);

        // Robot 1 planned at sample 0, then fell silent; the world shows it moving +x at
        // 1 m/s (truths 10 ticks = one sample apart).
        let plan = Plan {
            header: Header {
                robot: 1,
                ..Header::default()
            },
            status: protocol::PlanStatus::Solved as u32,
            ..Plan::default()
        };
        peers.hear(&Data::Plan(plan));
        let dt = member.timing.dt_s();
        let ticks = member.timing.inner_steps as u64;
        let late = (SILENT_SAMPLES + 2) * ticks;
        peers.hear(&truth(1, late - ticks - 1, 0.0));
        peers.hear(&truth(9, late - ticks - 1, 5.0)); // no such robot: ignored
        let mut tracks = Tracks::default();
        peers.tracks(late - ticks, (late - ticks) as f64 * dt, &mut tracks);
        peers.hear(&truth(1, late - 1, ticks as f64 * dt));
        peers.hear(&truth(1, late, 99.0)); // of the tick being tracked: not yet
        let mut tracks = Tracks::default();
        peers.tracks(late, late as f64 * dt, &mut tracks);
        let seen = tracks.tracks[0];
        assert_eq!(seen.center, [ticks as f64 * dt, 0.0]);
        assert!((seen.velocity[0] - 1.0).abs() < 1e-9, "{:?}", seen.velocity);
    }
}
