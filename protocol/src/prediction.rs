//! What the tracks predict (docs/safety.md, "Moving obstacles"): the one rule by which
//! every consumer of the tracker (the MPC's constraints, the DFL's check) keeps the
//! newest track of each obstacle and grows its disc with the time since the track.

use crate::{Disc, DiscMotion, Plan, Scenario, Track, Tracks};

/// How a track's disc is predicted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Prediction {
    /// Grown by `accel_max t^2 / 2` (docs/safety.md): `perception.accel_max` for an
    /// obstacle, [`Scenario::peer_accel_max`] for another robot. Every plan and the DFL's
    /// safety check.
    Bounded,
    /// At the track's velocity, grown by its uncertainty alone: the MPC's escape plan when
    /// no plan keeps clear of the bounded predictions (`mpc::linear`), and how an evasion
    /// looks ahead (`dfl::evasion`).
    ConstantVelocity,
}

/// The track kept of each tracked obstacle heard of, with its time (s), and how its
/// predictions grow.
#[derive(Debug, Clone)]
pub struct KeptTracks {
    tracks: Vec<(Track, f64)>,
    /// `perception.accel_max`, m/s^2.
    accel_max: f64,
    /// The bound on another robot's acceleration, m/s^2 ([`Scenario::peer_accel_max`]).
    peer_accel_max: f64,
    /// `kappa`: standard deviations of a predicted position.
    uncertainty_sigmas: f64,
    /// `N Ts`, s: a track is judged by its disc at the end of the MPC's horizon.
    horizon_s: f64,
    /// Whether the tracks are the lidar's: each message holds every track the tracker
    /// has (an obstacle it lost is gone), so it replaces all kept.
    whole: bool,
    /// How long after their time the tracks stand, s ([`tracks_refresh_s`]).
    tracks_refresh_s: f64,
    /// How far the plans' timeline runs behind the clock, s
    /// ([`Scenario::command_lead_s`]): a track measured at `t` is kept as of `t - lead`,
    /// so that the disc it predicts at a plan's time is the one at the clock's.
    lead_s: f64,
}

impl KeptTracks {
    /// No track yet, for the tracked obstacles of `scenario`.
    pub fn of(scenario: &Scenario) -> KeptTracks {
        KeptTracks {
            tracks: Vec::with_capacity(crate::MAX_TRACKS),
            whole: scenario.sees_with_lidar(),
            accel_max: scenario.perception.accel_max,
            peer_accel_max: scenario.peer_accel_max(),
            uncertainty_sigmas: scenario.mpc.uncertainty_sigmas,
            horizon_s: scenario.mpc.horizon as f64 * scenario.timing.ts_s,
            tracks_refresh_s: tracks_refresh_s(scenario),
            lead_s: scenario.command_lead_s(),
        }
    }

    /// Takes the tracker's newest tracks: each replaces the one kept of its obstacle
    /// unless that one, predicted on, still gives the smaller disc at the end of the
    /// horizon. So a restarted tracker, which knows nothing of the velocities yet, takes
    /// over once its tracks are better than the last ones of the process before it.
    ///
    /// The lidar's tracks replace every track kept: a track is a group of points seen,
    /// not an obstacle of the scenario, and a restarted tracker's tracks are its own.
    pub fn take(&mut self, tracks: &Tracks) {
        let time_s = tracks.header.time_s - self.lead_s;
        if self.whole {
            self.tracks.clear();
            (self.tracks).extend(tracks.tracks().iter().map(|t| (*t, time_s)));
            return;
        }
        let judged_at = time_s + self.horizon_s;
        let (kappa, bounds) = (
            self.uncertainty_sigmas,
            (self.accel_max, self.peer_accel_max),
        );
        let growth = |(track, time): &(Track, f64)| {
            let accel_max = accel_of(track, Prediction::Bounded, bounds);
            prediction_growth_m(track, judged_at - time, kappa, accel_max)
        };
        for track in tracks.tracks() {
            let new = (*track, time_s);
            let new_growth = growth(&new);
            match self
                .tracks
                .iter()
                .position(|(k, _)| k.obstacle == track.obstacle)
            {
                Some(i) if new_growth <= growth(&self.tracks[i]) => self.tracks[i] = new,
                Some(_) => {}
                None => self.tracks.push(new),
            }
        }
    }

    /// The tracks kept, each with its time, s.
    pub fn tracks(&self) -> &[(Track, f64)] {
        &self.tracks
    }

    /// How long from `t_s` (absolute) the held discs ([`crate::DiscMotion::held`]: the
    /// phantoms, the tracks that stand still and are not overdue) stand for what they
    /// predict, s: until the next tracks replace them ([`tracks_refresh_s`] after their
    /// time; the soonest of them, as the tracks of one message share their time); 0 when
    /// the phantoms are overdue or there is none. A plan's stop from then on must end
    /// before anything hidden, or standing, could reach it.
    pub fn stand_for_s(&self, t_s: f64) -> f64 {
        let refresh = self.tracks_refresh_s;
        self.tracks
            .iter()
            .filter(|(track, time_s)| held(track, t_s - time_s, refresh))
            .map(|(_, time_s)| (time_s + refresh - t_s).max(0.0))
            .reduce(f64::min)
            .unwrap_or(0.0)
    }

    /// How long after their time the tracks stand, s ([`tracks_refresh_s`]).
    pub fn refresh_s(&self) -> f64 {
        self.tracks_refresh_s
    }

    /// The acceleration bound of `track`'s disc as `prediction` predicts it, m/s^2.
    pub fn accel_for(&self, track: &Track, prediction: Prediction) -> f64 {
        accel_of(track, prediction, (self.accel_max, self.peer_accel_max))
    }

    /// `kappa`.
    pub fn uncertainty_sigmas(&self) -> f64 {
        self.uncertainty_sigmas
    }

    /// What a track's disc grows by `age_s` after its time, m: `kappa sigma(t)`, at most
    /// `kappa (sigma_p + t sigma_v)` ([`Track::sigmas`]), and `accel_max t^2 / 2`.
    pub fn growth_m(&self, track: &Track, age_s: f64) -> f64 {
        let accel_max = self.accel_for(track, Prediction::Bounded);
        prediction_growth_m(track, age_s, self.uncertainty_sigmas, accel_max)
    }

    /// The disc of every track kept at time `t_s` (absolute), each obstacle's radius grown
    /// by `growth_m` and by its prediction ([`predicted_disc`]).
    pub fn discs_at(&self, t_s: f64, growth_m: f64) -> impl Iterator<Item = Disc> + '_ {
        self.discs_predicted(t_s, growth_m, Prediction::Bounded)
    }

    /// [`KeptTracks::discs_at`], each track predicted as `prediction` says.
    pub fn discs_predicted(
        &self,
        t_s: f64,
        growth_m: f64,
        prediction: Prediction,
    ) -> impl Iterator<Item = Disc> + '_ {
        self.tracks.iter().map(move |(track, time_s)| {
            predicted_disc(
                track,
                t_s - time_s,
                growth_m,
                self.uncertainty_sigmas,
                self.accel_for(track, prediction),
                self.tracks_refresh_s,
            )
        })
    }
}

/// How a fleet's robots predict each other from their plans (docs/fleet.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeerPrediction {
    /// `Ts`, s: a plan's stages are this far apart.
    pub ts_s: f64,
    /// The bound on a robot's acceleration, m/s^2 ([`Scenario::peer_accel_max`]).
    pub accel_max: f64,
    /// `kappa`: standard deviations of a predicted position (`mpc.uncertainty_sigmas`,
    /// positive in a fleet).
    pub kappa: f64,
}

impl PeerPrediction {
    pub fn of(scenario: &Scenario) -> PeerPrediction {
        PeerPrediction {
            ts_s: scenario.timing.ts_s,
            accel_max: scenario.peer_accel_max(),
            kappa: scenario.mpc.uncertainty_sigmas,
        }
    }

    /// Robot `robot` as a track to the others at time `t_s` (on the plans' timeline):
    /// where its newest solved `plan` puts it then, at the plan's velocity there
    /// ([`plan_state_at`]), its footprint `radius_m`. The plan is certain only at its own
    /// time, and only as its estimate was: `estimate_sigmas` are the standard deviations
    /// of the estimate's position (m) and of its velocity (m/s: the speed times the
    /// heading's). Since then the robot may have left the plan (braked, or flown another)
    /// accelerating up to `accel_max` against the plan's own `accel_max`. So after `d =
    /// t_s - plan time` its position may be off by `accel_max d^2` more and its velocity
    /// by `2 accel_max d`, which the track carries as `kappa` standard deviations; its disc
    /// then grows at `accel_max` ([`prediction_growth_m`]). Whatever the robot does within
    /// its input box, and short of `kappa` standard deviations off its estimate, it stays
    /// in the disc.
    pub fn track(
        &self,
        robot: usize,
        radius_m: f64,
        plan: &Plan,
        estimate_sigmas: [f64; 2],
        t_s: f64,
    ) -> Track {
        let since_s = (t_s - plan.sample as f64 * self.ts_s).max(0.0);
        let (center, velocity) = plan_state_at(plan, since_s, self.ts_s);
        let [estimate_p, estimate_v] = estimate_sigmas.map(|s| s.max(0.0));
        let [drift_p, drift_v] = self.drift_sigmas(since_s);
        let sigmas = [estimate_p + drift_p, estimate_v + drift_v];
        self.track_seen(robot, radius_m, (center, velocity), sigmas)
    }

    /// How far a robot may have left what was known of it `since_s` ago, accelerating up
    /// to `accel_max` against it, as `kappa` standard deviations: `[accel_max d^2,
    /// 2 accel_max d] / kappa` (position m, velocity m/s).
    pub fn drift_sigmas(&self, since_s: f64) -> [f64; 2] {
        let kappa = self.kappa.max(f64::MIN_POSITIVE);
        [
            self.accel_max * since_s * since_s / kappa,
            2.0 * self.accel_max * since_s / kappa,
        ]
    }

    /// Robot `robot` as a track where it is seen rather than planned: at `center` with
    /// `velocity`, both as uncertain as `sigmas` (`[position m, velocity m/s]`), its
    /// footprint `radius_m`; its disc grows from now at `accel_max`. The others go by its
    /// estimate until its first plan, and by what the world shows of it once its plans stop
    /// (`run::fleet`).
    pub fn track_seen(
        &self,
        robot: usize,
        radius_m: f64,
        (center, velocity): ([f64; 2], [f64; 2]),
        sigmas: [f64; 2],
    ) -> Track {
        let [var_p, var_v] = sigmas.map(|s| s * s);
        Track {
            obstacle: crate::FIRST_PEER + robot as u32,
            reserved: 0,
            radius_m,
            center,
            velocity,
            covariance: [var_p, 0.0, var_v, var_p, 0.0, var_v],
        }
    }
}

/// Where `plan` puts the robot `since_s` after the plan's time, and its velocity there,
/// m and m/s: on stage `i`'s constant acceleration between two stages (the DFL's linear
/// model, eq. 30), on at the last stage's velocity beyond the horizon.
pub fn plan_state_at(plan: &Plan, since_s: f64, ts_s: f64) -> ([f64; 2], [f64; 2]) {
    let horizon = (plan.horizon as usize).min(crate::MAX_HORIZON);
    let stage = ((since_s / ts_s).floor().max(0.0) as usize).min(horizon);
    let tau = since_s - stage as f64 * ts_s;
    let z = plan.z[stage];
    let a = match stage < horizon {
        true => plan.v[stage],
        false => [0.0; 2],
    };
    (
        [
            z[0] + z[1] * tau + 0.5 * a[0] * tau * tau,
            z[2] + z[3] * tau + 0.5 * a[1] * tau * tau,
        ],
        [z[1] + a[0] * tau, z[3] + a[1] * tau],
    )
}

/// [`KeptTracks::accel_for`], with `(perception.accel_max, the robots' bound)`.
fn accel_of(track: &Track, prediction: Prediction, (obstacles, peers): (f64, f64)) -> f64 {
    match (prediction, track.is_peer()) {
        (Prediction::ConstantVelocity, _) => 0.0,
        (Prediction::Bounded, true) => peers,
        (Prediction::Bounded, false) => obstacles,
    }
}

/// Whether `track`'s disc, `age_s` after its time, is held once the next tracks are due
/// ([`crate::DiscMotion::held`]): a phantom's always (an overdue one is held from now, and
/// the scan watchdog stops the robot), a standing track's until it is overdue (`refresh_s`
/// after its time: then nothing shows whether it set off, and it grows as a walking
/// one's).
fn held(track: &Track, age_s: f64, refresh_s: f64) -> bool {
    track.is_phantom() || (track.stands_still() && age_s < refresh_s)
}

/// How long after their time tracks stand for what they predict, s: until the next
/// tracks replace them, a perception period (`1 / lidar.rate_hz` with a lidar, else the
/// perception ticks') and a sample (the MPC and the DFL take tracks at sample starts).
/// Something that comes out of a shadow now, or an obstacle standing still that sets off
/// now, is seen by then, so the robot's stop need only be clear of where it could be
/// from there on (docs/safety.md).
pub fn tracks_refresh_s(scenario: &Scenario) -> f64 {
    let period = match &scenario.lidar {
        Some(lidar) => 1.0 / lidar.rate_hz,
        None => scenario.perception_ticks() as f64 * scenario.timing.dt_s(),
    };
    period + scenario.timing.ts_s
}

/// What `track`'s disc grows by `age_s` after its time, m: `kappa sigma(t)`, at most
/// `kappa (sigma_p + t sigma_v)` ([`Track::sigmas`]), and `accel_max t^2 / 2` (an obstacle
/// that changes its velocity by at most `accel_max`). A phantom's `kappa sigma_v` is
/// `perception.phantom_speed`, the fastest it comes out, so it grows by that alone.
pub fn prediction_growth_m(track: &Track, age_s: f64, kappa: f64, accel_max: f64) -> f64 {
    let age = age_s.max(0.0);
    let (sigma_p, sigma_v) = track.sigmas();
    let accel_max = bounded_accel(track, accel_max);
    kappa * (sigma_p + age * sigma_v) + 0.5 * accel_max * age * age
}

/// The acceleration bound of `track`'s prediction, m/s^2: `accel_max`, none for a phantom
/// (whose speed is bounded instead, [`prediction_growth_m`]).
fn bounded_accel(track: &Track, accel_max: f64) -> f64 {
    match track.is_phantom() {
        true => 0.0,
        false => accel_max,
    }
}

/// The disc `track` predicts `age_s` after its time (absolute): centred where the track's
/// velocity takes it, its radius the obstacle's grown by `growth_m` and by
/// [`prediction_growth_m`]. It moves on at the track's velocity and grows at the same rule
/// ([`Disc::at`]); held once the next tracks are due (`refresh_s` after the track's time,
/// [`held`]).
pub fn predicted_disc(
    track: &Track,
    age_s: f64,
    growth_m: f64,
    kappa: f64,
    accel_max: f64,
    refresh_s: f64,
) -> Disc {
    let age = age_s.max(0.0);
    let (_, sigma_v) = track.sigmas();
    let [vx, vy] = track.velocity;
    let accel_max = bounded_accel(track, accel_max);
    Disc {
        center: [track.center[0] + vx * age_s, track.center[1] + vy * age_s],
        radius: track.radius_m + growth_m + prediction_growth_m(track, age, kappa, accel_max),
        motion: DiscMotion {
            velocity: track.velocity,
            radius_rate: kappa * sigma_v + accel_max * age,
            radius_accel: 0.5 * accel_max,
            hidden: track.is_phantom(),
            standing: track.stands_still(),
            held: held(track, age, refresh_s),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn track(obstacle: u32, variance: f64) -> Track {
        Track {
            obstacle,
            radius_m: 0.3,
            center: [1.0, 2.0],
            velocity: [1.0, 0.0],
            covariance: [variance, 0.0, variance, variance, 0.0, variance],
            ..Track::default()
        }
    }

    fn tracks(time_s: f64, list: &[Track]) -> Tracks {
        let mut tracks = Tracks::default();
        tracks.header.time_s = time_s;
        tracks.count = list.len() as u32;
        tracks.tracks[..list.len()].copy_from_slice(list);
        tracks
    }

    #[test]
    fn a_new_track_replaces_the_kept_one_only_when_it_predicts_a_smaller_disc() {
        let mut kept = KeptTracks::of(&Scenario::default());
        kept.take(&tracks(0.0, &[track(0, 1e-4)]));
        // A restarted tracker's first track: far less certain, so the old one, predicted
        // on by 0.1 s, is kept.
        kept.take(&tracks(0.1, &[track(0, 1.0)]));
        assert_eq!(kept.tracks(), &[(track(0, 1e-4), 0.0)]);
        kept.take(&tracks(0.2, &[track(0, 1e-4), track(3, 1.0)]));
        assert_eq!(
            kept.tracks(),
            &[(track(0, 1e-4), 0.2), (track(3, 1.0), 0.2)]
        );
    }

    #[test]
    fn a_phantom_grows_at_its_speed_alone_is_passed_where_it_is_and_stands_until_the_next_scan() {
        let scenario = Scenario::default()
            .with_overrides(&["lidar.rate_hz=10".into(), "perception.phantoms=true".into()])
            .unwrap();
        let (kappa, speed): (f64, f64) = (3.0, 1.5);
        let phantom = Track {
            obstacle: crate::FIRST_PHANTOM,
            covariance: [
                0.0,
                0.0,
                (speed / kappa).powi(2),
                0.0,
                0.0,
                (speed / kappa).powi(2),
            ],
            velocity: [0.0; 2],
            ..track(0, 0.0)
        };
        // No acceleration term: `phantom_speed` bounds its speed.
        let disc = predicted_disc(&phantom, 0.4, 0.1, kappa, 2.0, 0.15);
        assert!((disc.radius - (0.3 + 0.1 + speed * 0.4)).abs() < 1e-12);
        assert!(disc.motion.hidden);
        assert!((disc.at(1.0).radius - disc.radius - speed).abs() < 1e-12);
        // A plan's stages pass it as it grows while it stands, where it is after; a
        // tracked obstacle's disc grows.
        assert_eq!(disc.staged(0.1, 0.15), disc.at(0.1));
        assert_eq!(
            disc.staged(1.0, 0.15),
            Disc::still(disc.center, disc.radius)
        );
        let person = predicted_disc(&track(0, 0.01), 0.4, 0.1, kappa, 2.0, 0.15);
        assert_eq!(person.staged(1.0, 0.15), person.at(1.0));
        // It stands a scan period and a sample after its scan's tracks.
        let mut kept = KeptTracks::of(&scenario);
        assert_eq!(kept.stand_for_s(0.0), 0.0, "no phantom");
        kept.take(&tracks(2.0, &[track(0, 0.01), phantom]));
        let refresh = 0.1 + scenario.timing.ts_s;
        assert!((kept.stand_for_s(2.0) - refresh).abs() < 1e-12);
        assert!((kept.stand_for_s(2.05) - (refresh - 0.05)).abs() < 1e-12);
        assert_eq!(kept.stand_for_s(3.0), 0.0, "overdue");
    }

    #[test]
    fn a_track_that_stands_still_grows_until_the_next_tracks_and_is_held_after_unless_overdue() {
        let scenario = Scenario::default()
            .with_overrides(&["perception.period_s=0.2".into(), "timing.ts_s=0.05".into()])
            .unwrap();
        let standing = Track {
            velocity: [0.05, 0.0],
            ..track(0, 1e-4)
        };
        assert!(standing.stands_still() && !track(1, 1e-4).stands_still());
        let disc = predicted_disc(&standing, 0.0, 0.1, 3.0, 0.5, 0.25);
        assert!(disc.motion.standing && disc.motion.held);
        // It grows and drifts as any track's until the next tracks are due, where it is
        // after (the next tracks take over).
        assert_eq!(disc.staged(0.1, 0.25), disc.at(0.1));
        assert!(disc.at(0.1).radius > disc.radius);
        assert_eq!(
            disc.staged(1.0, 0.25),
            Disc::still(disc.center, disc.radius)
        );
        // Without a lidar the next tracks are a perception period and a sample away; the
        // soonest of the held tracks sets how long they stand; a walking one holds none.
        let refresh = 0.2 + 0.05;
        assert!((tracks_refresh_s(&scenario) - refresh).abs() < 1e-12);
        let mut kept = KeptTracks::of(&scenario);
        kept.take(&tracks(2.0, &[track(1, 1e-4)]));
        assert_eq!(kept.stand_for_s(2.0), 0.0, "a walking track only");
        kept.take(&tracks(2.0, &[standing]));
        kept.take(&tracks(
            2.1,
            &[Track {
                obstacle: 2,
                ..standing
            }],
        ));
        assert!((kept.stand_for_s(2.05) - (refresh - 0.05)).abs() < 1e-12);
        // Once overdue (no next tracks came) nothing shows whether it set off: it grows as
        // a walking track's, and the other one's time decides.
        assert!(
            !predicted_disc(&standing, refresh, 0.1, 3.0, 0.5, refresh)
                .motion
                .held
        );
        assert!((kept.stand_for_s(2.3) - (2.1 + refresh - 2.3)).abs() < 1e-12);
    }

    #[test]
    fn a_predicted_disc_moves_with_the_track_and_grows_as_its_motion_says() {
        let t = track(0, 0.01);
        let (kappa, accel_max) = (2.0, 0.5);
        let at = |age: f64| predicted_disc(&t, age, 0.1, kappa, accel_max, 0.15);
        assert_eq!(at(0.0).radius, 0.3 + 0.1 + kappa * (0.1 + 0.0));
        for (from, by) in [(0.0, 1.0), (0.5, 0.25), (1.0, 2.0)] {
            let stepped = at(from).at(by);
            let direct = at(from + by);
            assert!((stepped.radius - direct.radius).abs() < 1e-12);
            assert!((stepped.center[0] - direct.center[0]).abs() < 1e-12);
            assert_eq!(stepped.center[1], direct.center[1]);
        }
    }

    #[test]
    fn a_robot_that_leaves_its_plan_within_its_input_box_stays_in_the_disc_the_others_keep_clear_of()
     {
        let mut scenario = Scenario::default();
        scenario.mpc.v_max = 1.0;
        let peers = PeerPrediction::of(&scenario);
        let kept = KeptTracks::of(&scenario);
        let ts = scenario.timing.ts_s;
        // A plan of sample 10 from 1 m/s along x, accelerating at one corner of the input
        // box, (1, 1) m/s^2; the robot leaves it for the opposite corner: the largest
        // difference there is.
        let mut plan = Plan {
            sample: 10,
            horizon: 8,
            ..Plan::default()
        };
        for i in 0..=8 {
            let t = i as f64 * ts;
            plan.z[i] = [t + 0.5 * t * t, 1.0 + t, 2.0 + 0.5 * t * t, t];
        }
        for v in plan.v.iter_mut().take(8) {
            *v = [1.0, 1.0];
        }
        let plan_s = 10.0 * ts;
        // The robot flew it for `flown` s, then accelerated at the box's corner against it.
        for flown in [0.0, 0.02, ts] {
            let corner = [-1.0, -1.0];
            let truth = |t: f64| {
                let (p, v) = plan_state_at(&plan, flown, ts);
                let s = t - flown;
                [0, 1].map(|a| p[a] + v[a] * s + 0.5 * corner[a] * s * s)
            };
            for told_after in [ts, 2.0 * ts] {
                let track = peers.track(3, 0.3, &plan, [0.0; 2], plan_s + told_after);
                assert!(track.is_peer());
                for k in 0..=40 {
                    let after = k as f64 * 0.02;
                    let t = told_after.max(flown) + after;
                    let age = t - told_after;
                    let center = [0, 1].map(|a| track.center[a] + track.velocity[a] * age);
                    let radius = kept.growth_m(&track, age) + 1e-12;
                    let off = crate::distance(truth(t), center);
                    assert!(
                        off <= radius,
                        "told {told_after} s after, flown {flown} s: {off} m off at {t} s, disc {radius} m"
                    );
                }
            }
        }
    }
}
