//! The route planner (docs/planner.md): a collision-free route from the robot to
//! the goal around the obstacles, grown as the MPC grows them and by `planner.clearance_m`
//! more, which the MPC follows ([`Route`]). No IPC here: the `scmpc planner` process
//! ([`process`]) and the in-process loop both step a [`Planner`].
//!
//! The route is the shortest path in the tangent visibility graph ([`tangent_graph`]):
//! exact for circles. Its arcs are written as waypoints on polygons circumscribed about
//! their circles, so that every segment of the route, and not only its corners, keeps
//! outside the grown obstacles.

pub mod task;
pub use task::PlannerTask;
pub mod tangent_graph;

pub use protocol::Disc;
use protocol::{
    Estimate, ObstacleGrowth, ROUTE_CAPACITY, ReplanReason, Route, RouteStatus, RouteSwitch,
    Validated, closest_on_polyline, distance, polyline_length,
};
pub use tangent_graph::{Bounds, Leg, NoRoute, TangentGraph};

/// The robot counts as stalled when it has moved less than this ...
pub const STALL_DISTANCE_M: f64 = 0.05;
/// ... for this long, away from the goal.
pub const STALL_WINDOW_S: f64 = 1.0;

/// A periodic replan takes a new route that goes round the obstacles the same way as the
/// current one only if it is shorter than what is left of the current one by this much,
/// m (or the current one is blocked now); one that goes another way, only if it is
/// shorter by `planner.switch_margin` of it, and at least by this ([`Planner::switch`]).
pub const SWITCH_GAIN_M: f64 = 0.25;

/// Widest turn of an arc between two waypoints, rad (30 degrees: the polygon's corners
/// stand `R (1 / cos 15° - 1)`, 3.5 % of the radius, off the circle). Doubled while a
/// route would not fit in [`ROUTE_CAPACITY`] waypoints.
const ARC_STEP_RAD: f64 = std::f64::consts::PI / 6.0;

/// Each replan on a stall keeps this much more room from the obstacles than the last
/// (at least; [`Planner::extra_clearance_m`]), m: a route the robot could not follow (a
/// bend too tight for it, a gap its grown discs close) is not planned again as it was.
pub const STALL_CLEARANCE_STEP_M: f64 = 0.2;
/// Stall replans that widen the clearance, at most.
pub const MAX_CLEARANCE_STEPS: u32 = 3;
/// A robot this far from where it last stalled has made way: the clearance is the
/// configured one again, m.
pub const CLEARANCE_RESET_M: f64 = 1.0;

/// How far inside its true radius a disc holding the start or the goal is shrunk to free
/// them, m.
const FREE_END_M: f64 = 1e-6;

/// The planner's state across samples: the newest route and what decides the next plan.
pub struct Planner {
    graph: TangentGraph,
    /// The obstacles at rest known from the scenario: the route goes round them; the
    /// tracked ones are the MPC's (docs/planner.md).
    obstacles: Vec<protocol::Obstacle>,
    /// With a lidar: the tracks that stand still, obstacles at rest the map did not hold
    /// (a box on the floor); the route goes round them too.
    standing: Vec<protocol::Obstacle>,
    discs: Vec<Disc>,
    goal: [f64; 2],
    goal_tolerance_m: f64,
    bounds: Bounds,
    /// How every obstacle grows (before the clearance).
    growth: ObstacleGrowth,
    clearance_m: f64,
    period_s: f64,
    stray_m: f64,
    /// `planner.switch_margin`: the share of the route left by which a route going
    /// another way round must be shorter to replace it.
    switch_margin: f64,
    ts_s: f64,
    /// The route published.
    route: Route,
    /// The newest route planned (taken as `route`, or not: [`SWITCH_GAIN_M`]).
    candidate: Route,
    /// Sample of the newest plan, taken or not.
    last_planned: Option<u64>,
    /// Where and when the robot last moved by [`STALL_DISTANCE_M`].
    moved: Option<(u64, [f64; 2])>,
    /// Stall replans since the robot last made way (at most [`MAX_CLEARANCE_STEPS`]): each
    /// widens the clearance.
    clearance_steps: u32,
    /// Where the last stall replan was; the robot [`CLEARANCE_RESET_M`] from it has made
    /// way and the clearance is the configured one again.
    stalled_at: [f64; 2],
    /// The route the robot last stalled on, until it is [`CLEARANCE_RESET_M`] (or half the
    /// way, if that is less) nearer the goal than where it stalled last: a periodic replan
    /// does not go back to that way round the obstacles ([`Planner::switch`]). (Going
    /// round the other way may lead it away from the goal first, where the way it stalled
    /// on is the shorter again.)
    stalled_on: Option<Route>,
    /// The goal changed since the last step: the next one plans anew.
    retargeted: bool,
}

impl Planner {
    pub fn new(scenario: &Validated) -> Planner {
        let m = &scenario.mpc;
        let most = scenario.obstacles.len() + protocol::MAX_TRACKS;
        Planner {
            graph: TangentGraph::with_capacity(most),
            obstacles: scenario.known_obstacles().cloned().collect(),
            standing: Vec::with_capacity(protocol::MAX_TRACKS),
            discs: Vec::with_capacity(most),
            goal: scenario.robot.goal.position,
            goal_tolerance_m: scenario.robot.goal_tolerance_m,
            bounds: [
                [m.position_min[0], m.position_max[0]],
                [m.position_min[1], m.position_max[1]],
            ],
            growth: ObstacleGrowth::of(scenario),
            clearance_m: scenario.planner.clearance_m,
            period_s: scenario.planner.period_s,
            stray_m: scenario.planner.stray_m,
            switch_margin: scenario.planner.switch_margin,
            ts_s: scenario.timing.ts_s,
            route: Route::default(),
            candidate: Route::default(),
            last_planned: None,
            moved: None,
            clearance_steps: 0,
            stalled_at: [0.0; 2],
            stalled_on: None,
            retargeted: false,
        }
    }

    /// Plans to `goal` from the next step on (a goal set while the run drives): a new
    /// route, as at the start, and no memory of the stalls on the way to the old goal.
    pub fn retarget(&mut self, goal: [f64; 2]) {
        self.goal = goal;
        self.retargeted = true;
        self.stalled_on = None;
        self.clearance_steps = 0;
    }

    /// Takes the lidar's newest tracks: those that stand still
    /// ([`protocol::Track::stands_still`]) are obstacles at rest to the routes planned
    /// from now on.
    pub fn take_tracks(&mut self, tracks: &protocol::Tracks) {
        self.standing.clear();
        (self.standing).extend(
            tracks
                .tracks()
                .iter()
                .filter(|t| t.stands_still())
                .map(|t| protocol::Obstacle::fixed(t.center[0], t.center[1], t.radius_m)),
        );
    }

    /// The room added to `planner.clearance_m` after the stalls so far, m: a step of
    /// `max(planner.clearance_m, STALL_CLEARANCE_STEP_M)` per stall replan.
    pub fn extra_clearance_m(&self) -> f64 {
        f64::from(self.clearance_steps) * self.clearance_m.max(STALL_CLEARANCE_STEP_M)
    }

    /// The route for sample `sample` from its estimate: the newest one, planned again
    /// first if this is the first sample, `planner.period_s` has passed (the new route
    /// taken as [`Planner::switch`] decides), the robot has stalled or strayed from it.
    /// The header is left for the caller.
    pub fn step(&mut self, sample: u64, estimate: &Estimate) -> Route {
        let position = [estimate.state[0], estimate.state[1]];
        if let Some(reason) = self.replan_reason(sample, position) {
            if reason == ReplanReason::Stall {
                // Stalls in one place after the first are the robot stuck on the first's
                // way, not on the routes replanned since.
                if self.clearance_steps == 0 || self.stalled_on.is_none() {
                    self.stalled_on = Some(self.route);
                }
                self.clearance_steps = (self.clearance_steps + 1).min(MAX_CLEARANCE_STEPS);
                self.stalled_at = position;
            } else {
                if distance(position, self.stalled_at) > CLEARANCE_RESET_M {
                    self.clearance_steps = 0;
                }
                // (Half the way to the goal for a stall within 2 m of it.)
                let stalled_m = distance(self.stalled_at, self.goal);
                let nearer_m = stalled_m - distance(position, self.goal);
                if nearer_m > CLEARANCE_RESET_M.min(stalled_m / 2.0) {
                    self.stalled_on = None;
                }
            }
            let growth = self.growth.total_m(estimate.position_sigma());
            self.plan(sample, position, growth, reason);
            if let Some(switch) = self.switch(reason, position, growth) {
                let plans = self.route.plans + 1;
                self.route = self.candidate;
                self.route.plans = plans;
                self.route.switch = switch as u32;
            }
        }
        self.route.sample = sample;
        self.route
    }

    /// Why the route just planned (`candidate`) replaces the current one (`None`: the
    /// current one is kept). A replan on a stall or a stray, and one that finds no route
    /// or has none to compare with, always replaces it. A periodic replan replaces it if
    /// it is blocked now, or by a route that goes round the obstacles the same way and is
    /// [`SWITCH_GAIN_M`] shorter than what is left of it, or by one that goes another way
    /// and is `planner.switch_margin` of that shorter (and never less than
    /// [`SWITCH_GAIN_M`]): two ways of about the same length are not swapped replan after
    /// replan, near the goal either. Until the robot has come nearer the goal than where it
    /// last stalled, a periodic replan never goes another way that is the way it stalled on
    /// (a gap its grown discs close is shorter than the way round, and would be taken again
    /// and again). (The way it stalled on is compared from where the robot is now: from far
    /// off it, which way that is may be told wrongly; a stall replan is taken whatever.)
    fn switch(
        &mut self,
        reason: ReplanReason,
        position: [f64; 2],
        growth_m: f64,
    ) -> Option<RouteSwitch> {
        let comparable =
            reason == ReplanReason::Period && self.route.is_ok() && self.candidate.is_ok();
        if !comparable {
            return Some(RouteSwitch::Replanned);
        }
        if self.blocked(position, growth_m) {
            return Some(RouteSwitch::Blocked);
        }
        // What is left of the current route as it would be planned now: a route planned
        // under more uncertainty (the start's) is not compared by its wider detours.
        let left_m = taut_remaining_length(&self.route, position, &self.discs);
        let new_m = self.candidate.length_m;
        let obstacles = || self.obstacles.iter().chain(&self.standing);
        if same_way(&self.route, &self.candidate, position, obstacles()) {
            (new_m < left_m - SWITCH_GAIN_M).then_some(RouteSwitch::SameWay)
        } else if (self.stalled_on.as_ref())
            .is_some_and(|stalled| same_way(stalled, &self.candidate, position, obstacles()))
        {
            None
        } else {
            let gain_m = SWITCH_GAIN_M.max(left_m * self.switch_margin);
            (new_m < left_m - gain_m).then_some(RouteSwitch::Shorter)
        }
    }

    /// Whether the rest of the route from the robot's closest point enters an obstacle
    /// grown by `growth_m` (the clearance aside).
    fn blocked(&mut self, position: [f64; 2], growth_m: f64) -> bool {
        self.grow_discs(position, growth_m);
        let points = self.route.points();
        let (segment, _, _) = closest_on_polyline(points, position);
        points[segment..].windows(2).any(|w| {
            self.discs
                .iter()
                .any(|d| protocol::segment_distance(w[0], w[1], d.center) < d.radius - 1e-9)
        })
    }

    /// Why the route must be planned again at `sample`, if it must.
    fn replan_reason(&mut self, sample: u64, position: [f64; 2]) -> Option<ReplanReason> {
        if self.route.plans == 0 || std::mem::take(&mut self.retargeted) {
            self.moved = Some((sample, position));
            return Some(ReplanReason::Start);
        }
        let since_s = |then: u64| sample.saturating_sub(then) as f64 * self.ts_s;
        let stalled = match self.moved {
            Some((_, at)) if distance(at, position) >= STALL_DISTANCE_M => {
                self.moved = Some((sample, position));
                false
            }
            Some((then, _)) => {
                since_s(then) >= STALL_WINDOW_S
                    && distance(position, self.goal) > self.goal_tolerance_m
            }
            None => false,
        };
        if stalled {
            self.moved = Some((sample, position));
            Some(ReplanReason::Stall)
        } else if self.route.is_ok() && distance_to_route(&self.route, position) > self.stray_m {
            Some(ReplanReason::Stray)
        } else if self.period_s > 0.0
            && self
                .last_planned
                .is_some_and(|then| since_s(then) >= self.period_s)
        {
            Some(ReplanReason::Period)
        } else {
            None
        }
    }

    /// Plans `candidate` from `position` around the obstacles grown by `growth_m` and the
    /// clearance widened after stalls, or by the plain clearance, or by none, the first
    /// that leaves a route.
    fn plan(&mut self, sample: u64, position: [f64; 2], growth_m: f64, reason: ReplanReason) {
        // A robot outside the position box (it fled a moving obstacle across the box's
        // edge by a few millimetres) plans from the nearest point inside it.
        let position = [0, 1].map(|a| position[a].clamp(self.bounds[a][0], self.bounds[a][1]));
        self.last_planned = Some(sample);
        let mut found = false;
        let widened = self.clearance_m + self.extra_clearance_m();
        let mut tried = f64::NAN;
        for clearance in [widened, self.clearance_m, 0.0] {
            if clearance == tried {
                continue;
            }
            tried = clearance;
            self.grow_discs(position, growth_m + clearance);
            let (graph, route) = (&mut self.graph, &mut self.candidate);
            if let Ok(legs) = graph.shortest_path(position, self.goal, &self.discs, self.bounds) {
                write_waypoints(position, legs, route);
                found = true;
                break;
            }
        }
        let route = &mut self.candidate;
        if found {
            route.status = RouteStatus::Ok as u32;
            route.length_m = polyline_length(route.points());
        } else {
            route.status = RouteStatus::NoRoute as u32;
            route.count = 0;
            route.length_m = 0.0;
        }
        route.planned_sample = sample;
        route.reason = reason as u32;
    }

    /// Notes how long the step of `sample` took, ns, as its caller timed it (the task, on
    /// its context's clock): the route's `plan_ns` if that step planned the route.
    pub fn took(&mut self, sample: u64, step_ns: u64) -> &Route {
        if self.route.planned_sample == sample && self.route.plans > 0 {
            self.route.plan_ns = step_ns;
        }
        &self.route
    }

    /// The obstacles grown by `growth_m`, each shrunk where it would hold the robot or
    /// the goal (a robot pinned at an obstacle's edge plans from where it is).
    fn grow_discs(&mut self, position: [f64; 2], growth_m: f64) {
        self.discs.clear();
        for o in self.obstacles.iter().chain(&self.standing) {
            let Disc { center, radius, .. } = Disc::around(o, growth_m);
            let radius = radius
                .min(distance(center, position) - FREE_END_M)
                .min(distance(center, self.goal) - FREE_END_M);
            if radius > 0.0 {
                self.discs.push(Disc::still(center, radius));
            }
        }
    }
}

/// Writes the route through `legs` from `start` into `route`: the start, each straight
/// leg's end, and each arc as the corners of a polygon circumscribed about it (every
/// segment tangent to the circle), with arc steps widened until it fits.
fn write_waypoints(start: [f64; 2], legs: &[Leg], route: &mut Route) {
    let mut step = ARC_STEP_RAD;
    loop {
        let needed = 1 + legs
            .iter()
            .map(|leg| match leg {
                Leg::Straight { .. } => 1,
                Leg::Arc { sweep, .. } => arc_pieces(*sweep, step) + 1,
            })
            .sum::<usize>();
        if needed <= ROUTE_CAPACITY || step >= std::f64::consts::PI {
            break;
        }
        step *= 2.0;
    }
    let mut count = 0;
    let mut push = |p: [f64; 2]| {
        if count < ROUTE_CAPACITY {
            route.waypoints[count] = p;
            count += 1;
        }
    };
    push(start);
    for leg in legs {
        match *leg {
            Leg::Straight { to } => push(to),
            Leg::Arc {
                disc,
                from_angle,
                sweep,
                to,
            } => {
                let pieces = arc_pieces(sweep, step);
                let turn = sweep / pieces as f64;
                let corner = disc.radius / (0.5 * turn).cos();
                for j in 0..pieces {
                    let a = from_angle + (j as f64 + 0.5) * turn;
                    push([
                        disc.center[0] + corner * a.cos(),
                        disc.center[1] + corner * a.sin(),
                    ]);
                }
                push(to);
            }
        }
    }
    // The goal is the last waypoint even if the polygon had to be cut short.
    if let Some(Leg::Straight { to } | Leg::Arc { to, .. }) = legs.last() {
        route.waypoints[count - 1] = *to;
    }
    route.count = count as u32;
}

/// Straight pieces of an arc turning by `sweep` with turns of at most `step`.
fn arc_pieces(sweep: f64, step: f64) -> usize {
    ((sweep.abs() / step).ceil() as usize).max(1)
}

/// The length of what is left of `route` from `position` pulled taut against `discs`, m:
/// to the route's closest point, then each leg straight to the farthest waypoint it
/// reaches without entering a disc. A route planned round obstacles grown more than
/// `discs` (under the larger uncertainty of the start) cuts its corners; one planned
/// round `discs` keeps its length.
pub fn taut_remaining_length(route: &Route, position: [f64; 2], discs: &[Disc]) -> f64 {
    let points = route.points();
    if points.len() < 2 {
        return f64::INFINITY;
    }
    let clear = |a: [f64; 2], b: [f64; 2]| {
        discs
            .iter()
            .all(|d| protocol::segment_distance(a, b, d.center) >= d.radius - 1e-9)
    };
    let (segment, at, off) = closest_on_polyline(points, position);
    let (mut from, mut next, mut length_m) = (at, segment + 1, off);
    while next < points.len() {
        let reach = (next + 1..points.len())
            .rev()
            .find(|&j| clear(from, points[j]))
            .unwrap_or(next);
        length_m += distance(from, points[reach]);
        (from, next) = (points[reach], reach + 1);
    }
    length_m
}

/// Whether `new`, planned from `position`, goes round every obstacle the same way as what
/// is left of `old` from there: the loop out along `new` to the goal and back along `old`
/// winds round no obstacle's centre. (Both keep out of every obstacle, so the loop
/// passes no centre.)
pub fn same_way<'a>(
    old: &Route,
    new: &Route,
    position: [f64; 2],
    obstacles: impl IntoIterator<Item = &'a protocol::Obstacle>,
) -> bool {
    let old_points = old.points();
    if old_points.len() < 2 {
        return false;
    }
    let (segment, at, _) = closest_on_polyline(old_points, position);
    // Walked without a buffer: the planner allocates nothing per sample.
    let ring = || {
        std::iter::once(position)
            .chain(new.points().iter().copied())
            .chain(old_points[segment + 1..].iter().rev().copied())
            .chain(std::iter::once(at))
    };
    (obstacles.into_iter()).all(|o| winding_number(ring(), o.center_at(0.0)) == 0)
}

/// How many times the closed polygon through `ring` winds round `p` (counterclockwise
/// positive): the signed crossings of the ray from `p` towards +x.
fn winding_number(ring: impl Iterator<Item = [f64; 2]> + Clone, p: [f64; 2]) -> i32 {
    let next = ring.clone().cycle().skip(1);
    ring.zip(next)
        .map(|(a, b)| {
            let side = (b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1]);
            if a[1] <= p[1] && b[1] > p[1] && side > 0.0 {
                1
            } else if a[1] > p[1] && b[1] <= p[1] && side < 0.0 {
                -1
            } else {
                0
            }
        })
        .sum()
}

/// Distance from `position` to the route's polyline, m (infinite without one).
pub fn distance_to_route(route: &Route, position: [f64; 2]) -> f64 {
    let points = route.points();
    if points.len() < 2 {
        return f64::INFINITY;
    }
    closest_on_polyline(points, position).2
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, Obstacle, PlannerKind, Scenario, Tracks};

    fn scenario(obstacles: Vec<Obstacle>) -> Validated {
        let mut s = Scenario::default();
        s.planner.kind = PlannerKind::Route;
        s.obstacles = obstacles;
        s.validated("test").unwrap()
    }

    fn estimate_at(x: f64, y: f64) -> Estimate {
        Estimate {
            header: Header::default(),
            state: [x, y, 0.0, 0.0],
            ..Estimate::default()
        }
    }

    #[test]
    fn every_segment_of_the_route_keeps_the_clearance_from_every_grown_obstacle() {
        let obstacles = vec![
            Obstacle::fixed(3.0, 3.5, 1.5),
            Obstacle::fixed(5.0, 1.0, 0.8),
        ];
        let s = scenario(obstacles.clone());
        let mut planner = Planner::new(&s);
        let route = planner.step(0, &estimate_at(7.0, 7.0));
        assert!(route.is_ok());
        let points = route.points();
        assert_eq!(points[0], [7.0, 7.0]);
        assert_eq!(*points.last().unwrap(), s.robot.goal.position);
        // Grown by kappa sigma (sigma from a zero covariance: 0) and the clearance.
        for w in points.windows(2) {
            for o in &obstacles {
                let d = protocol::segment_distance(w[0], w[1], [o.x, o.y]);
                assert!(
                    d >= o.radius + s.planner.clearance_m - 1e-9,
                    "{w:?} {o:?}: {d}"
                );
            }
        }
        assert!((route.length_m - polyline_length(points)).abs() < 1e-12);
        assert!(route.length_m > 7.0 * 2f64.sqrt());
    }

    #[test]
    fn the_planner_replans_on_a_stall_a_stray_and_the_period_and_not_otherwise() {
        let s = scenario(vec![Obstacle::fixed(3.0, 3.5, 1.5)]);
        let mut planner = Planner::new(&s);
        let first = planner.step(0, &estimate_at(7.0, 7.0));
        assert_eq!(first.reason, ReplanReason::Start as u32);
        assert_eq!(first.plans, 1);
        // Moving along the route: no plan before the period (1 s = 20 samples).
        let along = first.points()[1];
        let mut last = first;
        for k in 1..20 {
            let f = k as f64 / 40.0;
            let p = [7.0 + f * (along[0] - 7.0), 7.0 + f * (along[1] - 7.0)];
            last = planner.step(k, &estimate_at(p[0], p[1]));
            assert_eq!(last.plans, 1, "sample {k}");
        }
        // The period's plan, from a point of the route: no shorter, so the route stays.
        let periodic = planner.step(20, &estimate_at(last.points()[0][0], last.points()[0][1]));
        assert_eq!((periodic.plans, periodic.planned_sample), (1, 0));
        // Far off the route.
        let strayed = planner.step(21, &estimate_at(8.0, -2.0));
        assert_eq!(strayed.reason, ReplanReason::Stray as u32);
        assert_eq!(strayed.plans, 2);
        // Standing still for a second.
        let mut stalled = strayed;
        for k in 22..=42 {
            stalled = planner.step(k, &estimate_at(8.0, -2.0));
        }
        assert_eq!(stalled.reason, ReplanReason::Stall as u32);
        assert_eq!(stalled.plans, 3);
    }

    #[test]
    fn a_steps_time_is_the_plan_time_of_the_route_it_planned_and_of_no_other() {
        let s = scenario(vec![Obstacle::fixed(3.0, 3.5, 1.5)]);
        let mut planner = Planner::new(&s);
        planner.step(0, &estimate_at(7.0, 7.0));
        assert_eq!(planner.took(0, 1234).plan_ns, 1234);
        // The next sample keeps the route: its step's time is not the route's.
        planner.step(1, &estimate_at(7.0, 7.0));
        assert_eq!(planner.took(1, 99).plan_ns, 1234);
    }

    #[test]
    fn a_track_that_stands_still_is_routed_round_and_a_moving_one_or_a_phantom_is_not() {
        // The paper's world seen through a lidar, nothing in the map: the straight way.
        let mut s = scenario(vec![]).into_inner();
        s.lidar = Some(protocol::LidarConfig::default());
        let s = s.validated("test").unwrap();
        let crosses_the_box = |route: &Route| {
            route.points().windows(2).any(|w| {
                let ([ax, ay], [bx, by]) = (w[0], w[1]);
                let (dx, dy) = (bx - ax, by - ay);
                let t = (((3.5 - ax) * dx + (3.5 - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                distance([ax + t * dx, ay + t * dy], [3.5, 3.5]) < 0.5
            })
        };
        let track = |velocity: [f64; 2], obstacle: u32| protocol::Track {
            obstacle,
            radius_m: 0.5,
            center: [3.5, 3.5],
            velocity,
            covariance: [1e-4, 0.0, 1e-4, 1e-4, 0.0, 1e-4],
            ..protocol::Track::default()
        };
        let route_with = |tracks: &[protocol::Track]| {
            let mut planner = Planner::new(&s);
            let mut message = Tracks::default();
            message.tracks[..tracks.len()].copy_from_slice(tracks);
            message.count = tracks.len() as u32;
            planner.take_tracks(&message);
            planner.step(0, &estimate_at(7.0, 7.0))
        };
        assert!(crosses_the_box(&route_with(&[])));
        assert!(!crosses_the_box(&route_with(&[track([0.0; 2], 0)])));
        assert!(crosses_the_box(&route_with(&[track([0.5, 0.0], 0)])));
        let phantom = track([0.0; 2], protocol::FIRST_PHANTOM);
        assert!(crosses_the_box(&route_with(&[phantom])));
    }

    /// One obstacle on the line from the start (6, 0) to the goal; strays allowed.
    fn one_obstacle_ahead() -> Validated {
        let mut s = Scenario::default();
        s.planner.kind = PlannerKind::Route;
        s.planner.stray_m = 100.0;
        s.robot.start = [6.0, 0.0, 0.0];
        s.obstacles = vec![Obstacle::fixed(3.0, 0.0, 1.0)];
        s.validated("test").unwrap()
    }

    #[test]
    fn a_periodic_plan_is_taken_when_it_is_clearly_shorter_than_the_rest_of_the_route() {
        // One obstacle on the line from the start to the goal; the robot drifts to the
        // other side of it (strays allowed) until going round that side is shorter.
        let s = one_obstacle_ahead();
        let mut planner = Planner::new(&s);
        let first = planner.step(0, &estimate_at(6.0, 0.0));
        let side = first.points()[1][1].signum();
        let mut route = first;
        // At the period (1 s = 20 samples), 1 m to the other side.
        for k in 1..=20 {
            route = planner.step(k, &estimate_at(6.0, -side * 0.05 * k as f64));
        }
        assert_eq!(route.reason, ReplanReason::Period as u32);
        assert_eq!(route.plans, 2);
        assert_eq!(route.switch, RouteSwitch::Shorter as u32);
        assert_eq!(route.points()[1][1].signum(), -side, "round the other side");
    }

    #[test]
    fn a_periodic_plan_round_the_other_way_is_not_taken_unless_shorter_by_the_margin() {
        // As above, but the robot drifts only 0.4 m to the other side: going round that
        // side is then shorter by more than SWITCH_GAIN_M, less than 10 %.
        let s = one_obstacle_ahead();
        let mut planner = Planner::new(&s);
        let first = planner.step(0, &estimate_at(6.0, 0.0));
        let side = first.points()[1][1].signum();
        let mut route = first;
        for k in 1..=20 {
            route = planner.step(k, &estimate_at(6.0, -side * 0.02 * k as f64));
        }
        let at = [6.0, -side * 0.4];
        let left_m = taut_remaining_length(&route, at, &planner.discs);
        let other = planner.candidate;
        assert_eq!(
            other.points()[1][1].signum(),
            -side,
            "planned round the other side"
        );
        assert!(
            other.length_m < left_m - SWITCH_GAIN_M
                && other.length_m >= left_m * (1.0 - s.planner.switch_margin),
            "{} m against {left_m} m left",
            other.length_m
        );
        assert_eq!((route.plans, route.points()[1][1].signum()), (1, side));
        // With no margin, the shorter way is taken.
        let mut s = s.into_inner();
        s.planner.switch_margin = 0.0;
        let s = s.validated("test").unwrap();
        let mut planner = Planner::new(&s);
        let mut route = planner.step(0, &estimate_at(6.0, 0.0));
        for k in 1..=20 {
            route = planner.step(k, &estimate_at(6.0, -side * 0.02 * k as f64));
        }
        assert_eq!(
            (route.plans, route.switch),
            (2, RouteSwitch::Shorter as u32)
        );
    }

    #[test]
    fn a_periodic_plan_does_not_return_to_a_stalled_way_until_nearer_the_goal() {
        // A gap of 0.6 m between the obstacle and the top of the position box: the way over
        // it is the shorter, but the robot stalls in it.
        let mut s = one_obstacle_ahead().into_inner();
        s.mpc.position_max = [10.0, 1.6];
        let s = s.validated("test").unwrap();
        let mut planner = Planner::new(&s);
        // Over the obstacle: every waypoint within 1 m of its centre line above it.
        let over = |route: &Route| {
            let beside = route.points().iter().filter(|p| (p[0] - 3.0).abs() <= 1.0);
            beside.fold(f64::INFINITY, |y, p| y.min(p[1])) > 0.0
        };
        let first = planner.step(0, &estimate_at(6.0, 0.3));
        assert!(over(&first));
        // Standing in the gap until a stall replan, with its widened clearance, goes under.
        let mut sample = 0;
        let mut route = first;
        while over(&route) {
            sample += 1;
            route = planner.step(sample, &estimate_at(4.2, 1.3));
            assert!(sample < 100, "never went under");
        }
        assert_eq!(route.reason, ReplanReason::Stall as u32);
        // Backing away from the gap, farther from the goal, then the period's plan: over is
        // shorter by the margin (the clearance is the configured one again), and not taken.
        let backed = [5.5, 1.0];
        let period = (s.planner.period_s / s.timing.ts_s).round() as u64;
        for _ in 0..period {
            sample += 1;
            route = planner.step(sample, &estimate_at(backed[0], backed[1]));
        }
        let periodic = (planner.candidate.planned_sample, planner.candidate.reason);
        assert_eq!(periodic, (sample, ReplanReason::Period as u32));
        let left_m = taut_remaining_length(&route, backed, &planner.discs);
        let candidate = planner.candidate;
        assert!(over(&candidate), "planned over");
        assert!(
            candidate.length_m < left_m - SWITCH_GAIN_M.max(left_m * s.planner.switch_margin),
            "{} m against {left_m} m left",
            candidate.length_m
        );
        assert!(!over(&route), "went back to the way it stalled on");
        // Over the obstacle, 1 m nearer the goal than where it stalled: the period's plan
        // goes over again.
        for _ in 0..period {
            sample += 1;
            route = planner.step(sample, &estimate_at(2.9, 1.5));
        }
        assert_eq!(planner.candidate.planned_sample, sample);
        assert!(over(&route), "{:?}", route.points());
    }

    /// A route from `points`.
    fn route_through(points: &[[f64; 2]]) -> Route {
        Route::through(points).unwrap()
    }

    #[test]
    fn what_is_left_of_a_route_is_measured_pulled_taut_round_the_obstacles_as_grown_now() {
        // Over a disc at the origin, planned round it grown to 1.25 m.
        let route = route_through(&[[-3.0, 0.0], [-1.0, 1.3], [1.0, 1.3], [3.0, 0.0]]);
        let along = 2.0 * 2.0_f64.hypot(1.3) + 2.0;
        let taut =
            |radius| taut_remaining_length(&route, [-3.0, 0.0], &[Disc::still([0.0; 2], radius)]);
        assert!((taut(1.25) - along).abs() < 1e-12, "no corner to cut");
        // Grown to 0.9 m now: straight from the start to the third waypoint (0.93 m from
        // the centre), then on.
        let cut = 4.0_f64.hypot(1.3) + 2.0_f64.hypot(1.3);
        assert!((taut(0.9) - cut).abs() < 1e-12, "{} m", taut(0.9));
        // From off the route: the way to it first.
        let off = taut_remaining_length(&route, [-3.0, -0.5], &[Disc::still([0.0; 2], 1.25)]);
        assert!((off - along - 0.5).abs() < 1e-12);
    }

    #[test]
    fn routes_go_the_same_way_when_they_pass_every_obstacle_on_the_same_side() {
        let obstacles = [
            Obstacle::fixed(3.0, 0.0, 1.0),
            Obstacle::fixed(8.0, 0.0, 1.0),
        ];
        // From (10, 0) to (0, 0): above both, below both, above one and below the other.
        let above = route_through(&[[10.0, 0.0], [8.0, 1.5], [3.0, 1.5], [0.0, 0.0]]);
        let above_too = route_through(&[[10.0, 0.0], [8.0, 2.0], [5.0, 2.5], [0.0, 0.0]]);
        let below = route_through(&[[10.0, 0.0], [8.0, -1.5], [3.0, -1.5], [0.0, 0.0]]);
        let mixed = route_through(&[[10.0, 0.0], [8.0, 1.5], [3.0, -1.5], [0.0, 0.0]]);
        let at = [10.0, 0.0];
        assert!(same_way(&above, &above_too, at, &obstacles));
        assert!(!same_way(&above, &below, at, &obstacles));
        assert!(!same_way(&above, &mixed, at, &obstacles));
        // Partway along, past the first obstacle: only the rest of the old route counts.
        let past = [5.5, 1.5];
        let from_past = route_through(&[past, [3.0, 1.6], [0.0, 0.0]]);
        assert!(same_way(&above, &from_past, past, &obstacles));
        let under = route_through(&[past, [3.0, -1.5], [0.0, 0.0]]);
        assert!(!same_way(&above, &under, past, &obstacles));
    }

    #[test]
    fn each_stall_replans_with_more_room_until_the_robot_makes_way() {
        let obstacle = Obstacle::fixed(3.0, 3.5, 1.5);
        let s = scenario(vec![obstacle.clone()]);
        let mut planner = Planner::new(&s);
        // The smallest distance of a route from the obstacle's centre.
        let room = |route: &Route| {
            route
                .points()
                .windows(2)
                .map(|w| protocol::segment_distance(w[0], w[1], [obstacle.x, obstacle.y]))
                .fold(f64::INFINITY, f64::min)
        };
        let first = planner.step(0, &estimate_at(7.0, 7.0));
        let mut rooms = vec![room(&first)];
        // Standing still: a stall replan every second (20 samples), each with 0.2 m more
        // (the configured clearance is 0.2), up to three.
        let mut sample = 0;
        for _ in 0..4 {
            let mut route = first;
            for _ in 0..21 {
                sample += 1;
                route = planner.step(sample, &estimate_at(7.0, 7.0));
            }
            assert_eq!(route.reason, ReplanReason::Stall as u32);
            rooms.push(room(&route));
        }
        let clearance = s.planner.clearance_m;
        for (k, r) in rooms.iter().enumerate() {
            let steps = k.min(MAX_CLEARANCE_STEPS as usize) as f64;
            let wanted = obstacle.radius + clearance + steps * STALL_CLEARANCE_STEP_M;
            assert!(*r >= wanted - 1e-9, "stall {k}: {r} < {wanted}");
        }
        assert!(rooms[3] > rooms[0] + 0.5, "{rooms:?}");
        // Far from where it stalled the clearance is the configured one again.
        planner.step(sample + 1, &estimate_at(8.5, 7.0));
        assert_eq!(planner.extra_clearance_m(), 0.0);
    }

    #[test]
    fn a_robot_inside_the_clearance_plans_from_where_it_is() {
        let s = scenario(vec![Obstacle::fixed(3.0, 3.5, 1.5)]);
        let mut planner = Planner::new(&s);
        // 5 cm off the obstacle's edge, within the 0.2 m clearance.
        let route = planner.step(0, &estimate_at(3.0 + 1.55, 3.5));
        assert!(route.is_ok());
        assert_eq!(route.points()[0], [4.55, 3.5]);
    }

    #[test]
    fn a_goal_walled_in_is_no_route() {
        let ring = (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 8.0;
                Obstacle::fixed(1.5 * a.cos(), 1.5 * a.sin(), 0.7)
            })
            .collect();
        let s = scenario(ring);
        let route = Planner::new(&s).step(0, &estimate_at(7.0, 7.0));
        assert_eq!(route.status(), Some(RouteStatus::NoRoute));
        assert_eq!(route.count, 0);
    }

    #[test]
    fn a_robot_just_outside_the_position_box_plans_from_the_nearest_point_inside() {
        let s = scenario(vec![Obstacle::fixed(3.0, 3.5, 1.5)]);
        let route = Planner::new(&s).step(0, &estimate_at(-10.005, 7.0));
        assert_eq!(route.status(), Some(RouteStatus::Ok));
        assert_eq!(route.points()[0], [-10.0, 7.0]);
        assert_eq!(route.points().last(), Some(&[0.0, 0.0]));
    }

    #[test]
    fn a_route_with_many_arcs_fits_the_message_and_ends_at_the_goal() {
        let legs: Vec<Leg> = (0..30)
            .map(|k| Leg::Arc {
                disc: Disc::still([k as f64, 0.0], 0.4),
                from_angle: 0.0,
                sweep: 3.0,
                to: [k as f64 + 0.5, 0.0],
            })
            .collect();
        let mut route = Route::default();
        write_waypoints([-1.0, 0.0], &legs, &mut route);
        assert!(route.count as usize <= ROUTE_CAPACITY);
        assert_eq!(route.points().last(), Some(&[29.5, 0.0]));
    }
}
