//! Breaking a fleet's deadlocks (docs/fleet.md, "Deadlocks"): robots that keep clear of
//! each other can hold each other up for good, two face to face or eight meeting at a
//! circle's centre, each waiting for the others to move. Every robot applies one rule,
//! the same for all and decided from what each knows alone (its own state and the tracks
//! of the others), so the symmetry breaks the same way on every side: a robot held still
//! away from its goal with another robot close by ahead **gives way to its right**,
//! following a detour that passes the nearest such robot on its right-hand side (every
//! robot moving right, two that face each other pass left side to left side; a ring of
//! them turns like a roundabout). The detour is a route for the MPC to follow ([`crate::follow`]); no
//! safety row changes.
//!
//! With a route planner, "ahead", "right" and "nearer the goal" are taken along the
//! planner's route ([`Way`]): among shelves the way to the goal is the route's, not the
//! straight line, which may point into a shelf or away from where the robot drives.

use protocol::{
    ROBOT_STILL_SPEED_M_S, ROUTE_CAPACITY, Route, RouteStatus, Track, Tracks, distance,
};

/// Held still this long, a robot gives way, s.
pub const STILL_S: f64 = 1.0;
/// Another robot holds a robot up when their footprints are within this of each other, m.
pub const HOLD_UP_M: f64 = 1.0;
/// A detour passes the other robot's footprint this far off, m.
pub const PASSING_M: f64 = 0.4;
/// A detour ends when its waypoint is this near, m, or after [`DETOUR_S`].
pub const WAYPOINT_REACHED_M: f64 = 0.3;
/// The longest a detour lasts, s.
pub const DETOUR_S: f64 = 4.0;
/// A robot that has come less than [`CRAWL_M`] nearer its goal in this long crawls, and
/// is held up as if it held still, s.
pub const CRAWL_S: f64 = 2.0;
/// See [`CRAWL_S`], m: 0.1 m/s on average, a tenth of the built-in fleets' speed bound.
pub const CRAWL_M: f64 = 0.2;
/// On a route, the robot faces the route's point this far ahead of its closest point on
/// it, m ([`Way`]): about where another robot holds it up ([`HOLD_UP_M`]).
pub const AIM_M: f64 = 1.0;

/// Where a robot is headed, as the rule sees it: on a route (the planner's, newest), the
/// point [`AIM_M`] along it from the robot's closest point on it (the goal, when nearer),
/// the way left (from the robot to that closest point, then along the route to the goal,
/// m) and the route's points after that closest point's segment; without one, the goal
/// and the straight line to it.
#[derive(Debug, Clone, Copy)]
struct Way<'a> {
    aim: [f64; 2],
    left_m: f64,
    /// The route beyond the robot's segment, its last point the goal (`[goal]` without a
    /// route).
    beyond: &'a [[f64; 2]],
}

impl<'a> Way<'a> {
    fn of(position: [f64; 2], goal: &'a [f64; 2], route: Option<&'a Route>) -> Way<'a> {
        let Some(points) = route.filter(|r| r.is_ok()).map(Route::points) else {
            return Way {
                aim: *goal,
                left_m: distance(position, *goal),
                beyond: std::slice::from_ref(goal),
            };
        };
        let (segment, at, off_m) = protocol::closest_on_polyline(points, position);
        let beyond = &points[segment + 1..];
        let mut aim = beyond[beyond.len() - 1];
        let mut from = at;
        let mut to_go = AIM_M;
        for &next in beyond {
            let leg = distance(from, next);
            if leg >= to_go {
                let share = to_go / leg;
                aim = [0, 1].map(|a| from[a] + share * (next[a] - from[a]));
                break;
            }
            to_go -= leg;
            from = next;
        }
        Way {
            aim,
            left_m: off_m + distance(at, beyond[0]) + protocol::polyline_length(beyond),
            beyond,
        }
    }

    /// The vector from `position` to the aim, m.
    fn toward(&self, position: [f64; 2]) -> [f64; 2] {
        [self.aim[0] - position[0], self.aim[1] - position[1]]
    }

    /// The unit vector from `position` towards the aim (none at it).
    fn heading(&self, position: [f64; 2]) -> Option<[f64; 2]> {
        let way = self.toward(position);
        let length = way[0].hypot(way[1]);
        (length > 0.0).then(|| [way[0] / length, way[1] / length])
    }
}

/// One robot's rule: whether it holds still, and the detour it follows.
#[derive(Debug, Clone, PartialEq)]
pub struct GiveWay {
    radius_m: f64,
    /// Nearer the goal than this, a robot holding still is arriving, not held up, m.
    arriving_m: f64,
    still_since_s: Option<f64>,
    /// When the robot last came [`CRAWL_M`] nearer its goal (or a detour ended), and how
    /// far from it it was then along its way ([`Way`]), m ([`GiveWay::crawls`]).
    progress_mark: Option<(f64, f64)>,
    detour: Option<Detour>,
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
            radius_m: scenario.robot.radius_m,
            arriving_m: 2.0 * scenario.robot.goal_tolerance_m,
            still_since_s: None,
            progress_mark: None,
            detour: None,
        })
    }

    /// At time `t_s` for a robot at `position` going at `speed_m_s` to `goal`, along
    /// `route` if it has one (the planner's), with the other robots among `tracks`: the
    /// detour to follow, with the id of the robot given way to, if it gives way.
    pub fn detour(
        &mut self,
        t_s: f64,
        (position, speed_m_s): ([f64; 2], f64),
        goal: [f64; 2],
        route: Option<&Route>,
        tracks: Option<&Tracks>,
    ) -> Option<(Route, u32)> {
        let way = Way::of(position, &goal, route);
        let arriving = distance(position, goal) <= self.arriving_m;
        if let Some(d) = self.detour
            && (t_s >= d.until_s || distance(position, d.waypoint) < WAYPOINT_REACHED_M || arriving)
        {
            self.detour = None;
            self.still_since_s = None;
            // Also when it ends at its first step, before `crawls` saw it.
            self.progress_mark = None;
        }
        let holds_still = speed_m_s.abs() < ROBOT_STILL_SPEED_M_S && !arriving;
        self.still_since_s = match holds_still {
            true => Some(self.still_since_s.unwrap_or(t_s)),
            false => None,
        };
        let crawls = self.crawls(t_s, way.left_m, arriving);
        let held_up = crawls
            || self
                .still_since_s
                .is_some_and(|s| t_s - s >= STILL_S - 1e-9);
        if self.detour.is_none()
            && held_up
            && let Some(heading) = way.heading(position)
            && let Some(peer) = self.holding_up(position, way.toward(position), tracks)
        {
            self.detour = Some(Detour {
                peer: peer.obstacle - protocol::FIRST_PEER,
                waypoint: self.passing_right(heading, peer),
                until_s: t_s + DETOUR_S,
            });
        }
        let d = self.detour?;
        Some((route_via(position, d.waypoint, &way), d.peer))
    }

    /// Whether the robot, `left_m` from its goal at `t_s` (along its way, [`Way`]), has
    /// come less than [`CRAWL_M`] nearer it in the last [`CRAWL_S`] (since its mark; a
    /// detour or arriving sets none). A robot that crawls beside others, slower than
    /// [`ROBOT_STILL_SPEED_M_S`] at times and faster at others, is held up as surely as
    /// one that holds still. A new route that is longer than the last by more than the
    /// robot came (round a robot that stands, say) counts as no progress.
    fn crawls(&mut self, t_s: f64, left_m: f64, arriving: bool) -> bool {
        if self.detour.is_some() || arriving {
            self.progress_mark = None;
            return false;
        }
        match self.progress_mark {
            Some((_, mark_m)) if left_m <= mark_m - CRAWL_M => {
                self.progress_mark = Some((t_s, left_m));
                false
            }
            Some((since_s, _)) => t_s - since_s >= CRAWL_S - 1e-9,
            None => {
                self.progress_mark = Some((t_s, left_m));
                false
            }
        }
    }

    /// The nearest other robot ahead (on the side `toward` points to) within
    /// [`HOLD_UP_M`] of the robot's footprint.
    fn holding_up<'a>(
        &self,
        position: [f64; 2],
        toward: [f64; 2],
        tracks: Option<&'a Tracks>,
    ) -> Option<&'a Track> {
        let gap = |t: &Track| distance(position, t.center) - t.radius_m - self.radius_m;
        let ahead = |t: &Track| {
            let to = [0, 1].map(|a| t.center[a] - position[a]);
            toward[0] * to[0] + toward[1] * to[1] > 0.0
        };
        tracks?
            .tracks()
            .iter()
            .filter(|t| t.is_peer() && gap(t) < HOLD_UP_M && ahead(t))
            .min_by(|a, b| gap(a).total_cmp(&gap(b)))
    }

    /// The point [`PASSING_M`] beyond both footprints to the right of `peer`, as the robot
    /// faces `heading` (a unit vector).
    fn passing_right(&self, heading: [f64; 2], peer: &Track) -> [f64; 2] {
        let right = [heading[1], -heading[0]];
        let off = peer.radius_m + self.radius_m + PASSING_M;
        [
            peer.center[0] + right[0] * off,
            peer.center[1] + right[1] * off,
        ]
    }
}

/// The route from `position` through `waypoint`, then on along `way`: from the end of the
/// leg of the robot's route nearest the waypoint (its own leg to the route's next point
/// among them) to the goal; without a route, straight from the waypoint to the goal.
fn route_via(position: [f64; 2], waypoint: [f64; 2], way: &Way) -> Route {
    let beyond = way.beyond;
    let rejoin = match beyond.len() {
        1 => beyond,
        _ => {
            let first_leg_m = protocol::segment_distance(position, beyond[0], waypoint);
            match protocol::closest_on_polyline(beyond, waypoint) {
                (segment, _, off_m) if off_m < first_leg_m => &beyond[segment + 1..],
                _ => beyond,
            }
        }
    };
    // A route of every point the message holds, rejoined at its first leg, has one too
    // many: the first point after the waypoint is left out.
    let rest = &rejoin[(rejoin.len() + 2).saturating_sub(ROUTE_CAPACITY)..];
    let mut route = Route {
        status: RouteStatus::Ok as u32,
        count: (rest.len() + 2) as u32,
        ..Route::default()
    };
    route.waypoints[..2].copy_from_slice(&[position, waypoint]);
    route.waypoints[2..2 + rest.len()].copy_from_slice(rest);
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
    fn two_robots_face_to_face_each_give_way_to_its_right_and_pass_each_other() {
        let scenario = fleet();
        let (mut a, mut b) = (
            GiveWay::of(&scenario).unwrap(),
            GiveWay::of(&scenario).unwrap(),
        );
        let (pa, pb) = ([-0.7, 0.0], [0.7, 0.0]);
        let (ga, gb) = ([3.0, 0.0], [-3.0, 0.0]);
        let (ta, tb) = (peer(1, pb), peer(0, pa));
        for k in 0..20 {
            let t = k as f64 * 0.05;
            assert!(
                a.detour(t, (pa, 0.0), ga, None, Some(&ta)).is_none(),
                "not yet at {t} s"
            );
            assert!(b.detour(t, (pb, 0.0), gb, None, Some(&tb)).is_none());
        }
        let (route_a, given_a) = a
            .detour(1.0, (pa, 0.0), ga, None, Some(&ta))
            .expect("a gives way");
        let (route_b, given_b) = b
            .detour(1.0, (pb, 0.0), gb, None, Some(&tb))
            .expect("b gives way");
        assert_eq!((given_a, given_b), (1, 0));
        // Going +x, a's right is -y; going -x, b's is +y: they do not meet.
        assert!(route_a.points()[1][1] < -0.9 && route_b.points()[1][1] > 0.9);
        assert_eq!(route_a.points()[2], ga);
    }

    #[test]
    fn a_robot_crawling_beside_another_gives_way_though_it_never_holds_still() {
        let scenario = fleet();
        let mut rule = GiveWay::of(&scenario).unwrap();
        let goal = [3.0, 0.0];
        // At 0.1 m/s, twice the speed of holding still, with another robot just ahead.
        let at = |t: f64| [-1.0 + 0.05 * t, 0.0];
        let ahead = |t: f64| peer(1, [at(t)[0] + 0.8, 0.1]);
        let mut gave_way = None;
        for k in 0..80 {
            let t = k as f64 * 0.05;
            if let Some((_, to)) = rule.detour(t, (at(t), 0.1), goal, None, Some(&ahead(t))) {
                gave_way = Some((t, to));
                break;
            }
        }
        let (t, to) = gave_way.expect("never gave way");
        assert_eq!(to, 1);
        assert!(
            (CRAWL_S - 1e-9..CRAWL_S + 0.06).contains(&t),
            "gave way at {t} s"
        );
        // Coming CRAWL_M nearer its goal within CRAWL_S, it drives on.
        let mut driving = GiveWay::of(&scenario).unwrap();
        for k in 0..200 {
            let t = k as f64 * 0.05;
            let position = [-1.0 + 0.12 * t, 0.0];
            let ahead = peer(1, [position[0] + 0.8, 0.1]);
            assert!(
                driving
                    .detour(t, (position, 0.12), goal, None, Some(&ahead))
                    .is_none(),
                "at {t} s"
            );
        }
    }

    fn route(points: &[[f64; 2]]) -> Route {
        Route::through(points).unwrap()
    }

    #[test]
    fn on_a_route_a_robot_looks_along_the_route_not_the_straight_line_to_its_goal() {
        let scenario = fleet();
        // West first, round a shelf, then north-east to the goal: the straight line to the
        // goal points away from where the robot drives.
        let planned = route(&[[0.0, 0.0], [-2.0, 0.0], [-2.0, 3.0], [3.0, 3.0]]);
        let (position, goal) = ([-0.5, 0.0], [3.0, 3.0]);
        // Another robot on the route just ahead, behind the robot as the goal lies.
        let ahead_on_route = peer(1, [-1.3, 0.0]);
        let mut along = GiveWay::of(&scenario).unwrap();
        let mut straight = GiveWay::of(&scenario).unwrap();
        let mut given = None;
        for k in 0..=20 {
            let t = k as f64 * 0.05;
            let motion = (position, 0.0);
            given = along.detour(t, motion, goal, Some(&planned), Some(&ahead_on_route));
            assert!(
                (straight.detour(t, motion, goal, None, Some(&ahead_on_route))).is_none(),
                "the straight line has it behind"
            );
        }
        let (detour, to) = given.expect("gives way along its route");
        assert_eq!(to, 1);
        // Heading west, its right is north; then on along the planner's route.
        let points = detour.points();
        assert_eq!(points[0], position);
        assert!(
            (points[1][0] + 1.3).abs() < 1e-9 && points[1][1] > 0.9,
            "{points:?}"
        );
        assert_eq!(&points[2..], &[[-2.0, 3.0], [3.0, 3.0]]);

        // Driving west at 0.15 m/s with another robot beside it, ahead both ways, its
        // straight-line distance to the goal grows, yet it comes nearer along the route:
        // it does not crawl, and goes on.
        let (mut driving, mut crawling) = (
            GiveWay::of(&scenario).unwrap(),
            GiveWay::of(&scenario).unwrap(),
        );
        let mut straight_gave_way = false;
        for k in 0..120 {
            let t = k as f64 * 0.05;
            let position = [-1.0 - 0.15 * t, 0.0];
            let beside = peer(1, [position[0] - 0.2, 0.9]);
            let motion = (position, 0.15);
            let got = driving.detour(t, motion, goal, Some(&planned), Some(&beside));
            assert!(got.is_none(), "at {t} s, at {position:?}");
            straight_gave_way |= crawling
                .detour(t, motion, goal, None, Some(&beside))
                .is_some();
        }
        assert!(straight_gave_way, "the straight line would have it crawl");
    }

    #[test]
    fn a_robot_arriving_or_alone_does_not_give_way() {
        let scenario = fleet();
        let mut rule = GiveWay::of(&scenario).unwrap();
        let tracks = peer(1, [0.5, 0.0]);
        for k in 0..40 {
            let t = k as f64 * 0.05;
            // At its goal, held still beside another robot.
            assert!(
                rule.detour(t, ([0.0, 0.0], 0.0), [0.05, 0.0], None, Some(&tracks))
                    .is_none()
            );
            // Far from the others.
            let far = peer(1, [5.0, 0.0]);
            assert!(
                rule.detour(t, ([0.0, 0.0], 0.0), [-3.0, 0.0], None, Some(&far))
                    .is_none()
            );
        }
        assert!(GiveWay::of(&protocol::Scenario::default()).is_none());
    }
}
