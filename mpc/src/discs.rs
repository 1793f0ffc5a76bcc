//! The obstacles as the MPC's constraints see them: grown by the one rule every consumer
//! uses ([`protocol::ObstacleGrowth`]), by what the MPC keeps for what follows the solver
//! ([`PlanMargin`]) and by the inter-sample chord, in goal-relative coordinates.

pub use protocol::Prediction;
use protocol::{Disc, KeptTracks, ObstacleGrowth, Plan};

/// What the MPC keeps clear beyond the obstacles grown by the robot's radius, `m` and
/// `kappa sigma`, for what happens to a plan after the solver: it is met only to the
/// solver's tolerance (about a micrometre), and the DFL realizes it on the robot to a few
/// micrometres more.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanMargin {
    /// The paper's formulation (no safety layer): none.
    None,
    /// Braking-safe plans without the DFL's check: [`protocol::COMMIT_MARGIN_M`] (without
    /// it 10 of 1000 noise-free fuzz worlds touched an obstacle, by up to 11 um).
    Realization,
    /// The DFL checks the plans (`dfl.gatekeeper`): the check's commit margin
    /// ([`protocol::commit_margin_m`]) and a millimetre more, so that the check passes
    /// the MPC's own plans.
    Checked,
}

impl PlanMargin {
    /// The margin of the scenario's safety layers.
    pub fn of(scenario: &protocol::Scenario) -> Self {
        if scenario.dfl.gatekeeper {
            Self::Checked
        } else if scenario.mpc.terminal_safety != protocol::TerminalSafety::None {
            Self::Realization
        } else {
            Self::None
        }
    }

    /// The margin for an estimate with position standard deviation `sigma_m`, m.
    pub fn m(self, sigma_m: f64) -> f64 {
        match self {
            Self::None => 0.0,
            Self::Realization => protocol::COMMIT_MARGIN_M,
            Self::Checked => protocol::commit_margin_m(sigma_m) + 1e-3,
        }
    }
}

/// What every obstacle's radius grows by in the MPC's constraints, m, before the
/// inter-sample term: the one growth of every consumer ([`ObstacleGrowth`]: the robot's
/// radius, the safety margin `m`, `kappa sigma` for an estimate with position standard
/// deviation `sigma_m`), then the [`PlanMargin`].
pub fn obstacle_growth_m(growth: &ObstacleGrowth, sigma_m: f64, plan_margin: PlanMargin) -> f64 {
    growth.total_m(sigma_m) + plan_margin.m(sigma_m)
}

/// Fills `discs` with the constraint discs of one step: `obstacles` in coordinates
/// relative to `goal`, each radius inflated by `margin_m` (the safety margin and the
/// uncertainty term, [`obstacle_growth_m`]) and by the inter-sample dip. The CBF holds at the sample instants;
/// between two of them the robot moves along a chord of at most
/// `d = |speed| Ts + accel_max Ts^2 / 2`. A segment of length `d` whose end points lie
/// outside radius `R` comes no closer to the centre than `sqrt(R^2 - d^2 / 4)`, so the
/// radius `R = sqrt(r^2 + d^2 / 4)` keeps the path between samples out of radius `r`
/// too: about `r + d^2 / (8 r)` for a large obstacle (0.2 mm at 1 m/s in the paper's
/// scenario), `d / 2` for a point.
pub fn constraint_discs(
    obstacles: &[protocol::Obstacle],
    goal: [f64; 2],
    margin_m: f64,
    speed_m_s: f64,
    ts_s: f64,
    accel_max: f64,
    discs: &mut Vec<Disc>,
) {
    let chord = chord_m(speed_m_s, ts_s, accel_max);
    discs.clear();
    discs.extend(obstacles.iter().map(|o| {
        let grown = Disc::around(o, margin_m);
        Disc::still(
            [grown.center[0] - goal[0], grown.center[1] - goal[1]],
            grown.radius.hypot(chord / 2.0),
        )
    }));
}

/// The longest chord the robot moves along between two samples, m:
/// `|speed| Ts + accel_max Ts^2 / 2` ([`constraint_discs`]).
pub fn chord_m(speed_m_s: f64, ts_s: f64, accel_max: f64) -> f64 {
    speed_m_s.abs() * ts_s + 0.5 * accel_max * ts_s * ts_s
}

/// What every disc of one step grows by, and where the goal is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepGrowth {
    /// The goal, m: the discs are goal-relative.
    pub goal: [f64; 2],
    /// The growth of every obstacle ([`obstacle_growth_m`]), m.
    pub margin_m: f64,
    /// The robot's speed, m/s, and the bound on its acceleration, m/s^2 (the
    /// inter-sample chord, [`chord_m`]).
    pub speed_m_s: f64,
    pub accel_max: f64,
    pub ts_s: f64,
    /// `kappa`: standard deviations of a predicted position.
    pub uncertainty_sigmas: f64,
}

/// The obstacles the MPC keeps clear of: those known from the scenario
/// ([`protocol::Scenario::known_obstacles`]) and the track kept of each tracked one
/// ([`KeptTracks`]).
#[derive(Debug, Clone)]
pub struct World {
    known: Vec<protocol::Obstacle>,
    /// Whether any obstacle is tracked (none are with `fault.mpc_ignore_obstacles`).
    tracking: bool,
    tracks: KeptTracks,
    /// With a lidar: the most tracks' discs a step keeps ([`protocol::MAX_SEEN_DISCS`],
    /// and in a fleet one more for each other robot: the nearest of the seen and the
    /// others' together, [`protocol::Scenario::max_obstacle_discs`]).
    seen_most: Option<usize>,
}

impl World {
    pub fn of(scenario: &protocol::Scenario) -> World {
        World {
            known: scenario.known_obstacles().cloned().collect(),
            tracking: scenario.takes_tracks(),
            tracks: KeptTracks::of(scenario),
            seen_most: scenario
                .sees_with_lidar()
                .then_some(protocol::MAX_SEEN_DISCS + scenario.robot_count() - 1),
        }
    }

    /// The obstacles known from the scenario (absolute, true radii).
    pub fn known(&self) -> &[protocol::Obstacle] {
        &self.known
    }

    /// Takes the tracker's newest tracks ([`KeptTracks::take`]).
    pub fn set_tracks(&mut self, tracks: &protocol::Tracks) {
        if self.tracking {
            self.tracks.take(tracks);
        }
    }

    /// How long from `t_s` the phantoms and standing tracks kept stand, s
    /// ([`KeptTracks::stand_for_s`]).
    pub fn stand_for_s(&self, t_s: f64) -> f64 {
        self.tracks.stand_for_s(t_s)
    }

    /// Whether any track is kept (the step's discs move).
    pub fn has_tracks(&self) -> bool {
        !self.tracks.tracks().is_empty()
    }

    /// Whether some kept track is another robot's, whose plans are known
    /// ([`protocol::Track::is_peer`]).
    pub fn has_peers(&self) -> bool {
        self.tracks.tracks().iter().any(|(t, _)| t.is_peer())
    }

    /// Whether some kept track that moves is another robot's ([`World::has_peers`]).
    pub fn peers_move(&self) -> bool {
        (self.tracks.tracks().iter()).any(|(t, _)| t.is_peer() && !t.stands_still())
    }

    /// Fills `discs` with the step's constraint discs at the sample's time `t_s` for the
    /// robot at `position` (goal-relative, m): the known obstacles' ([`constraint_discs`]),
    /// then each track's predicted one ([`predicted_disc`]) as `prediction` says (with a
    /// lidar the nearest `seen_most`, [`keep_nearest`]).
    pub fn discs(
        &self,
        g: StepGrowth,
        t_s: f64,
        prediction: Prediction,
        position: [f64; 2],
        discs: &mut Vec<Disc>,
    ) {
        let chord = chord_m(g.speed_m_s, g.ts_s, g.accel_max);
        constraint_discs(
            &self.known,
            g.goal,
            g.margin_m,
            g.speed_m_s,
            g.ts_s,
            g.accel_max,
            discs,
        );
        discs.extend(self.tracks.tracks().iter().map(|(track, time_s)| {
            let age_s = t_s - time_s;
            let accel_max = self.tracks.accel_for(track, prediction);
            predicted_disc(track, age_s, &g, chord, accel_max, self.tracks.refresh_s())
        }));
        if let Some(most) = self.seen_most {
            keep_nearest(discs, self.known.len(), position, most);
        }
    }
}

/// Keeps of `discs[first..]` the `most` nearest to `position` (by the distance to their
/// edge; all of them when they are no more), in that order.
pub fn keep_nearest(discs: &mut Vec<Disc>, first: usize, position: [f64; 2], most: usize) {
    if discs.len() <= first + most {
        return;
    }
    let gap = |d: &Disc| (d.center[0] - position[0]).hypot(d.center[1] - position[1]) - d.radius;
    discs[first..].sort_unstable_by(|a, b| gap(a).total_cmp(&gap(b)));
    discs.truncate(first + most);
}

/// The disc `track` predicts `age_s` after the track's time, as a constraint
/// (docs/safety.md, "Moving obstacles"): [`protocol::predicted_disc`] grown by the step's
/// margin, in goal-relative coordinates, and grown by the inter-sample chord of the robot
/// (`chord`, m) and the obstacle together as in [`constraint_discs`].
fn predicted_disc(
    track: &protocol::Track,
    age_s: f64,
    g: &StepGrowth,
    chord: f64,
    accel_max: f64,
    refresh_s: f64,
) -> Disc {
    let kappa = g.uncertainty_sigmas;
    let disc = protocol::predicted_disc(track, age_s, g.margin_m, kappa, accel_max, refresh_s);
    let [vx, vy] = track.velocity;
    let chord = chord + vx.hypot(vy) * g.ts_s + 0.5 * accel_max * g.ts_s * g.ts_s;
    Disc {
        center: [disc.center[0] - g.goal[0], disc.center[1] - g.goal[1]],
        radius: disc.radius.hypot(chord / 2.0),
        motion: disc.motion,
    }
}

/// The smallest slack of the paper's (nonconvex) CBF inequality over a plan:
/// `min_i H(p_{i+1}) - (1 - gamma) H(p_i)` over stages and discs (eq. 54), m^2.
pub fn barrier_slack(plan: &Plan, discs_absolute: &[Disc], gamma: f64) -> f64 {
    let mut slack = f64::INFINITY;
    for disc in discs_absolute {
        for i in 0..plan.horizon as usize {
            let h = |z: [f64; 4]| disc.barrier([z[0], z[2]]);
            slack = slack.min(h(plan.z[i + 1]) - (1.0 - gamma) * h(plan.z[i]));
        }
    }
    slack
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn another_robots_track_is_told_from_a_persons_and_a_phantoms() {
        // A scenario with a tracked person, so that the world takes tracks.
        let scenario = protocol::Scenario {
            obstacles: vec![protocol::Obstacle {
                velocity: [1.0, 0.0],
                ..protocol::Obstacle::fixed(3.0, 0.0, 0.3)
            }],
            ..protocol::Scenario::default()
        };
        let track = |obstacle: u32, velocity: [f64; 2]| protocol::Track {
            obstacle,
            radius_m: 0.3,
            velocity,
            ..protocol::Track::default()
        };
        let walking = [1.0, 0.0];
        let peer = protocol::FIRST_PEER + 1;
        let phantom = track(protocol::FIRST_PHANTOM, [0.0; 2]);
        let peers = |tracks: &[protocol::Track]| {
            let mut all = protocol::Tracks::default();
            all.tracks[..tracks.len()].copy_from_slice(tracks);
            all.count = tracks.len() as u32;
            let mut world = World::of(&scenario);
            world.set_tracks(&all);
            (world.has_peers(), world.peers_move())
        };
        assert_eq!(peers(&[]), (false, false), "no track");
        assert_eq!(
            peers(&[track(peer, [0.0; 2])]),
            (true, false),
            "a robot at rest"
        );
        assert_eq!(peers(&[track(0, walking), phantom]), (false, false));
        let mixed = [track(0, walking), track(peer, walking), phantom];
        assert_eq!(peers(&mixed), (true, true));
    }

    #[test]
    fn the_plan_margin_follows_the_safety_layers() {
        let with = |sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            PlanMargin::of(&protocol::Scenario::default().with_overrides(&sets).unwrap())
        };
        let paper = with(&["mpc.terminal_safety=none", "dfl.gatekeeper=false"]);
        assert_eq!(paper, PlanMargin::None);
        assert_eq!(paper.m(0.02), 0.0, "the paper's formulation exactly");
        let unchecked = with(&["dfl.gatekeeper=false"]);
        assert_eq!(unchecked, PlanMargin::Realization);
        assert_eq!(unchecked.m(0.02), protocol::COMMIT_MARGIN_M);
        for sets in [&[][..], &["mpc.terminal_safety=none"][..]] {
            let checked = with(sets);
            assert_eq!(checked, PlanMargin::Checked);
            // Outside the check's commit margin, so the check passes the MPC's own plans.
            assert!(checked.m(0.02) > protocol::commit_margin_m(0.02));
        }
    }

    #[test]
    fn no_chord_between_two_samples_outside_the_constraint_disc_enters_the_obstacle() {
        for radius in [0.0, 0.05, 1.5] {
            for speed in [0.0, 0.5, 3.0] {
                let (ts, accel_max) = (0.05, 4.0);
                let chord = speed * ts + 0.5 * accel_max * ts * ts;
                let obstacle = protocol::Obstacle::fixed(1.0, 2.0, radius);
                let mut discs = Vec::new();
                constraint_discs(&[obstacle], [0.0; 2], 0.0, speed, ts, accel_max, &mut discs);
                let disc = discs[0];
                // Segments of the longest length with both ends on the constraint circle
                // (the deepest any chord of at most that length reaches), all directions.
                for k in 0..360 {
                    let phi = f64::from(k).to_radians();
                    let half_angle = (chord / (2.0 * disc.radius)).min(1.0).asin();
                    let end = |a: f64| {
                        let r = disc.radius;
                        [disc.center[0] + r * a.cos(), disc.center[1] + r * a.sin()]
                    };
                    let (a, b) = (end(phi - half_angle), end(phi + half_angle));
                    let closest = (0..=100)
                        .map(|t| {
                            let t = f64::from(t) / 100.0;
                            let p = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
                            (p[0] - disc.center[0]).hypot(p[1] - disc.center[1])
                        })
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        closest >= radius - 1e-12,
                        "r {radius}, speed {speed}: a chord reaches {closest} m from the centre"
                    );
                }
            }
        }
    }

    #[test]
    fn linearized_barrier_is_tight_at_the_reference_and_below_elsewhere() {
        let disc = Disc::still([3.0, 3.5], 1.5);
        let p_bar = [5.0, 1.0];
        let (g, c) = disc.linearized_barrier(p_bar);
        let l = |p: [f64; 2]| g[0] * p[0] + g[1] * p[1] + c;
        assert!((l(p_bar) - disc.barrier(p_bar)).abs() < 1e-12);
        for p in [[0.0, 0.0], [3.0, 3.5], [10.0, -4.0], [5.1, 1.2]] {
            assert!(l(p) <= disc.barrier(p) + 1e-12);
        }
    }
}
