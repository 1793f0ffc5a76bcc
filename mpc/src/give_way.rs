//! Breaking a fleet's deadlocks (docs/fleet.md, "Deadlocks"): robots that keep clear of
//! each other can hold each other up for good, two face to face or eight meeting at a
//! circle's centre, each waiting for the others to move. Every robot applies one rule,
//! the same for all and decided from what each knows alone (its own state and the tracks
//! of the others), so the symmetry breaks the same way on every side: a robot held up
//! away from its goal (no nearer to it for a while) with another robot close by ahead
//! **gives way to its right**, following a detour that passes that robot on its
//! right-hand side. It gives way first to a robot of a lower id, and only after being held
//! up longer to one of a higher id: of two face to face the higher id makes room and the
//! lower goes on, and in a knot of several robots the lowest id goes on while the others
//! make room. The detour is a route for the MPC to follow ([`crate::follow`]); no safety
//! row changes.

use protocol::{Route, RouteStatus, Track, Tracks, distance};

/// A robot held up comes no nearer its goal than this in [`HELD_UP_S`], m: holding still,
/// crawling or backing away.
pub const PROGRESS_M: f64 = 0.1;
/// Held up this long, a robot gives way to a robot of a lower id, s.
pub const HELD_UP_S: f64 = 1.0;
/// Held up this long, a robot gives way to any robot, s: a robot of a lower id may be at
/// rest at its goal, or no longer plan, and will not make room.
pub const HELD_UP_LONG_S: f64 = 3.0;
/// Another robot holds a robot up when their footprints are within this of each other, m.
pub const HOLD_UP_M: f64 = 1.0;
/// A detour passes the other robot's footprint this far off, m.
pub const PASSING_M: f64 = 0.4;
/// A detour ends when its waypoint is this near, m, or after [`DETOUR_S`].
pub const WAYPOINT_REACHED_M: f64 = 0.3;
/// The longest a detour lasts, s.
pub const DETOUR_S: f64 = 4.0;

/// One robot's rule: whether it is held up, and the detour it follows.
#[derive(Debug, Clone, PartialEq)]
pub struct GiveWay {
    /// The robot's id in the fleet.
    id: u32,
    radius_m: f64,
    /// Nearer the goal than this, a robot is arriving, not held up, m.
    arriving_m: f64,
    /// The robot's last progress: since when, and its distance to its goal then, m.
    progress: Option<Progress>,
    detour: Option<Detour>,
}

/// Where a robot last came [`PROGRESS_M`] nearer its goal.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Progress {
    since_s: f64,
    to_goal_m: f64,
}

/// A detour round another robot.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Detour {
    /// The robot given way to.
    peer: u32,
    waypoint: [f64; 2],
    until_s: f64,
}

impl GiveWay {
    /// The rule of a fleet's robot (none for a robot alone).
    pub fn of(scenario: &protocol::Scenario) -> Option<GiveWay> {
        scenario.is_fleet().then_some(GiveWay {
            id: scenario.fleet_id.unwrap_or(0) as u32,
            radius_m: scenario.robot.radius_m,
            arriving_m: 2.0 * scenario.robot.goal_tolerance_m,
            progress: None,
            detour: None,
        })
    }

    /// At time `t_s` for a robot at `position` going to `goal`, with the other robots
    /// among `tracks`: the detour to follow, with the id of the robot given way to, if it
    /// gives way.
    pub fn detour(
        &mut self,
        t_s: f64,
        position: [f64; 2],
        goal: [f64; 2],
        tracks: Option<&Tracks>,
    ) -> Option<(Route, u32)> {
        let to_goal_m = distance(position, goal);
        let arriving = to_goal_m <= self.arriving_m;
        if let Some(d) = self.detour
            && (t_s >= d.until_s || distance(position, d.waypoint) < WAYPOINT_REACHED_M || arriving)
        {
            self.detour = None;
        }
        let progressed = self
            .progress
            .is_none_or(|p| to_goal_m < p.to_goal_m - PROGRESS_M);
        if progressed || arriving || self.detour.is_some() {
            self.progress = Some(Progress {
                since_s: t_s,
                to_goal_m,
            });
        }
        let held_up_s = self.progress.map_or(0.0, |p| t_s - p.since_s + 1e-9);
        if self.detour.is_none()
            && held_up_s >= HELD_UP_S
            && let Some(peer) = self.holding_up(position, goal, tracks, held_up_s >= HELD_UP_LONG_S)
        {
            self.detour = Some(Detour {
                peer: peer_id(peer),
                waypoint: self.passing_right(position, goal, peer),
                until_s: t_s + DETOUR_S,
            });
        }
        let d = self.detour?;
        Some((route_via(position, d.waypoint, goal), d.peer))
    }

    /// The nearest other robot ahead (towards `goal`) within [`HOLD_UP_M`] of the robot's
    /// footprint: of a lower id, or of `any` id.
    fn holding_up<'a>(
        &self,
        position: [f64; 2],
        goal: [f64; 2],
        tracks: Option<&'a Tracks>,
        any: bool,
    ) -> Option<&'a Track> {
        let gap = |t: &Track| distance(position, t.center) - t.radius_m - self.radius_m;
        let ahead = |t: &Track| {
            let (way, to) = (
                [0, 1].map(|a| goal[a] - position[a]),
                [0, 1].map(|a| t.center[a] - position[a]),
            );
            way[0] * to[0] + way[1] * to[1] > 0.0
        };
        tracks?
            .tracks()
            .iter()
            .filter(|t| t.is_peer() && (any || peer_id(t) < self.id))
            .filter(|t| gap(t) < HOLD_UP_M && ahead(t))
            .min_by(|a, b| gap(a).total_cmp(&gap(b)))
    }

    /// The point [`PASSING_M`] beyond both footprints to the right of `peer`, as the robot
    /// at `position` faces `goal`.
    fn passing_right(&self, position: [f64; 2], goal: [f64; 2], peer: &Track) -> [f64; 2] {
        let way = [goal[0] - position[0], goal[1] - position[1]];
        // Not 0: a robot this near its goal arrives, and gives way to none.
        let length = way[0].hypot(way[1]);
        let right = [way[1] / length, -way[0] / length];
        let off = peer.radius_m + self.radius_m + PASSING_M;
        [
            peer.center[0] + right[0] * off,
            peer.center[1] + right[1] * off,
        ]
    }
}

/// The id of the robot whose track `peer` is.
fn peer_id(peer: &Track) -> u32 {
    peer.obstacle - protocol::FIRST_PEER
}

/// The route from `position` through `waypoint` to `goal`.
fn route_via(position: [f64; 2], waypoint: [f64; 2], goal: [f64; 2]) -> Route {
    let mut route = Route {
        status: RouteStatus::Ok as u32,
        count: 3,
        ..Route::default()
    };
    route.waypoints[..3].copy_from_slice(&[position, waypoint, goal]);
    route
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fleet() -> protocol::Scenario {
        protocol::Scenario::from_toml(include_str!("../../scenarios/swap4.toml"), "swap4").unwrap()
    }

    fn peer(id: u32, center: [f64; 2]) -> Tracks {
        let mut tracks = Tracks::default();
        tracks.tracks[0] = Track {
            obstacle: protocol::FIRST_PEER + id,
            radius_m: 0.3,
            center,
            ..Track::default()
        };
        tracks.count = 1;
        tracks
    }

    #[test]
    fn of_two_face_to_face_the_higher_id_gives_way_to_its_right_and_the_lower_only_later() {
        let scenario = fleet();
        let (mut a, mut b) = (
            GiveWay::of(&scenario.member(0)).unwrap(),
            GiveWay::of(&scenario.member(1)).unwrap(),
        );
        let (pa, pb) = ([-0.7, 0.0], [0.7, 0.0]);
        let (ga, gb) = ([3.0, 0.0], [-3.0, 0.0]);
        let (ta, tb) = (peer(1, pb), peer(0, pa));
        let mut b_gave_way_s = None;
        for k in 0..=60 {
            let t = k as f64 * 0.05;
            let of_a = a.detour(t, pa, ga, Some(&ta));
            let of_b = b.detour(t, pb, gb, Some(&tb));
            if let Some((route, given)) = of_b.filter(|_| b_gave_way_s.is_none()) {
                b_gave_way_s = Some(t);
                assert_eq!(given, 0);
                // Going -x, b's right is +y.
                assert!(route.points()[1][1] > 0.9);
                assert_eq!(route.points()[2], gb);
            }
            assert_eq!(of_a.is_some(), t >= HELD_UP_LONG_S, "a at {t} s");
        }
        assert!((b_gave_way_s.unwrap() - HELD_UP_S).abs() < 1e-9);
        let (route, given) = a.detour(3.0, pa, ga, Some(&ta)).unwrap();
        // Still held up 3 s on, a gives way too, to its own right (-y).
        assert_eq!(given, 1);
        assert!(route.points()[1][1] < -0.9);
    }

    #[test]
    fn a_robot_crawling_round_another_is_held_up_and_one_coming_nearer_its_goal_is_not() {
        let scenario = fleet();
        let (mut crawling, mut coming) = (
            GiveWay::of(&scenario.member(1)).unwrap(),
            GiveWay::of(&scenario.member(1)).unwrap(),
        );
        let (goal, tracks) = ([3.0, 0.0], peer(0, [0.9, 0.0]));
        for k in 0..40 {
            let t = k as f64 * 0.05;
            // 0.2 m/s across the way to its goal.
            let across = crawling.detour(t, [0.0, 0.01 * k as f64], goal, Some(&tracks));
            assert_eq!(across.is_some(), t >= HELD_UP_S - 1e-9, "at {t} s");
            // 0.2 m/s towards its goal, behind the other robot.
            let towards = coming.detour(t, [-1.0 + 0.01 * k as f64, 0.0], goal, Some(&tracks));
            assert!(towards.is_none(), "at {t} s");
        }
    }

    #[test]
    fn a_robot_arriving_or_alone_does_not_give_way() {
        let scenario = fleet();
        let mut rule = GiveWay::of(&scenario.member(1)).unwrap();
        let tracks = peer(0, [0.5, 0.0]);
        for k in 0..40 {
            let t = k as f64 * 0.05;
            // At its goal, held still beside another robot.
            assert!(
                rule.detour(t, [0.0, 0.0], [0.05, 0.0], Some(&tracks))
                    .is_none()
            );
            // Far from the others.
            let far = peer(0, [5.0, 0.0]);
            assert!(
                rule.detour(t, [0.0, 0.0], [-3.0, 0.0], Some(&far))
                    .is_none()
            );
        }
        assert!(GiveWay::of(&protocol::Scenario::default()).is_none());
    }
}
