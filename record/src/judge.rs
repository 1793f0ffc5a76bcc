//! The judge: decides how a run ends from what was recorded (the true pose tick by tick,
//! and the routes): collision, stall, goal, no route, and at the end reached or timed out.

use protocol::actuator::BaseModel;
use protocol::{Actuation, CommandMode, GroundTruth, Obstacle, ObstacleGrowth, Route, Scenario};
use serde::Serialize;
use std::collections::VecDeque;

/// How a run ended.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Within the goal tolerance from `time_to_goal_s` to the end of the run.
    Reached,
    /// The robot entered an obstacle (true radius, grown by the robot's radius) while it
    /// moved (a moving obstacle that runs into a robot at rest is counted apart:
    /// [`Judge::contacts_at_rest`]).
    Collided,
    /// Moved less than [`STALL_DISTANCE_M`] over [`STALL_WINDOW_S`] away from the goal,
    /// waiting for nothing that moves for that long ([`WAITING_WITHIN_M`]).
    Stalled,
    /// The run's duration elapsed outside the goal tolerance.
    Timeout,
    /// Stopped by the user (Ctrl-C).
    Interrupted,
    /// A process died and could not be replaced (a dead plant, or restarts exhausted).
    Aborted,
    /// The planner found no route from the robot to the goal around the grown obstacles.
    NoRoute,
}

impl Outcome {
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Reached => "reached",
            Outcome::Collided => "collided",
            Outcome::Stalled => "stalled",
            Outcome::Timeout => "timeout",
            Outcome::Interrupted => "interrupted",
            Outcome::Aborted => "aborted",
            Outcome::NoRoute => "no_route",
        }
    }
}

/// Why a robot that stalled or timed out did not arrive, decided from what the run
/// recorded ([`Judge::reason`]; the first that applies, in this order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StallReason {
    /// No plan of the run was solved: no controller started the robot.
    InfeasibleFromStart,
    /// It ended within [`NEAR_GOAL_M`] of the goal, outside its tolerance: it went to and
    /// fro, or crept, about the goal (not a run that timed out coming nearer by more than
    /// [`APPROACHING_NEAR_GOAL_M`] over the last stall window).
    OscillatingNearGoal,
    /// It ended at an obstacle (clearance within [`PINNED_CLEARANCE_M`] beyond the
    /// MPC's margins) that lies towards the goal: the CBF holds it where the straight way
    /// is blocked (a local minimum; a route planner goes round).
    PinnedAtObstacle,
    /// It timed out still getting nearer the goal (by more than [`STALL_DISTANCE_M`]
    /// over the last stall window, or [`APPROACHING_NEAR_GOAL_M`] within [`NEAR_GOAL_M`]
    /// of it): the run was too short for it.
    StillApproaching,
    /// A route was being followed and the robot made no progress along it.
    NoProgressOnRoute,
    /// None of the above: it stopped away from the goal and from every obstacle.
    NoProgress,
}

impl StallReason {
    pub fn as_str(self) -> &'static str {
        match self {
            StallReason::InfeasibleFromStart => "infeasible_from_start",
            StallReason::OscillatingNearGoal => "oscillating_near_goal",
            StallReason::PinnedAtObstacle => "pinned_at_obstacle",
            StallReason::StillApproaching => "still_approaching",
            StallReason::NoProgressOnRoute => "no_progress_on_route",
            StallReason::NoProgress => "no_progress",
        }
    }

    /// Every reason, in [`Judge::reason`]'s order.
    pub const ALL: [StallReason; 6] = [
        StallReason::InfeasibleFromStart,
        StallReason::OscillatingNearGoal,
        StallReason::PinnedAtObstacle,
        StallReason::StillApproaching,
        StallReason::NoProgressOnRoute,
        StallReason::NoProgress,
    ];
}

/// A robot that ends this near the goal (outside its tolerance) is
/// [`StallReason::OscillatingNearGoal`], m.
pub const NEAR_GOAL_M: f64 = 0.5;
/// A robot whose edge ends within this of an obstacle grown by the MPC's margins is at
/// it ([`StallReason::PinnedAtObstacle`]), m.
pub const PINNED_CLEARANCE_M: f64 = 0.15;

/// Length of the stall window, s.
pub const STALL_WINDOW_S: f64 = 3.0;
/// A robot that moved less than this over the stall window has stalled, m.
pub const STALL_DISTANCE_M: f64 = 0.005;
/// A robot that timed out within [`NEAR_GOAL_M`] of its goal, but came nearer by more than
/// this over the last stall window, was not going to and fro about the goal but still
/// approaching it ([`StallReason::StillApproaching`], unless pinned at an obstacle), m (a
/// lidar run on 2026-12-01 timed out 0.27 m from its goal at 0.27 m/s, after a detour
/// round a box it had seen late).
pub const APPROACHING_NEAR_GOAL_M: f64 = 0.1;

/// A robot standing still with a moving obstacle this near (edge to surface) waits for
/// it to pass and has not stalled, m: a person crossing or coming at it takes a few
/// seconds to go by. In a fleet another robot that moves counts as one ([`Judge::peers`]).
/// Once nothing moves that near, the robot stalls only after standing still for another
/// [`STALL_WINDOW_S`]: it gets that long to go on.
pub const WAITING_WITHIN_M: f64 = 3.0;

pub use protocol::REST_SPEED_M_S;

/// A robot farther than this from the straight start-goal line has left it, m.
pub const DEVIATION_M: f64 = 0.05;

/// A robot this near its goal has arrived at its final approach ([`Arrival`]), m.
pub const ARRIVING_WITHIN_M: f64 = 0.2;
/// A robot that stays this near its goal to the end of the run has come to rest there
/// ([`Arrival`]; the goal tolerance if that is smaller), m.
pub const AT_REST_WITHIN_M: f64 = 0.05;

/// How the robot ended its run at the goal (issue 48; docs/reach.md): from the first time
/// it came within [`ARRIVING_WITHIN_M`] of the goal, how far it went from it again, and
/// when its final stay within [`AT_REST_WITHIN_M`] (or the goal tolerance, if smaller)
/// began. A robot that settles goes no farther than it was and comes to rest soon; one
/// that wanders near its goal goes out again and takes long.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Arrival {
    /// The rest radius: [`AT_REST_WITHIN_M`], or the goal tolerance if smaller, m.
    pub rest_within_m: f64,
    /// First time within [`ARRIVING_WITHIN_M`], s.
    pub arriving_s: Option<f64>,
    /// Largest distance to the goal from then on, m.
    pub farthest_after_m: f64,
    /// Start of the current stay within the rest radius, s.
    pub resting_since_s: Option<f64>,
}

impl Arrival {
    /// Before the run, for a goal tolerance of `goal_tolerance_m`.
    pub fn new(goal_tolerance_m: f64) -> Arrival {
        Arrival {
            rest_within_m: AT_REST_WITHIN_M.min(goal_tolerance_m),
            ..Arrival::default()
        }
    }

    /// The robot `distance_m` from its goal at `t_s`.
    pub fn observe(&mut self, t_s: f64, distance_m: f64) {
        if self.arriving_s.is_none() && distance_m <= ARRIVING_WITHIN_M {
            self.arriving_s = Some(t_s);
        }
        if self.arriving_s.is_some() {
            self.farthest_after_m = self.farthest_after_m.max(distance_m);
        }
        if distance_m <= self.rest_within_m {
            self.resting_since_s.get_or_insert(t_s);
        } else {
            self.resting_since_s = None;
        }
    }

    /// From the first time within [`ARRIVING_WITHIN_M`] to the start of the stay within
    /// the rest radius that lasts to the end of the run, s (`None`: it never arrived, or
    /// ended outside the radius).
    pub fn time_to_rest_s(&self) -> Option<f64> {
        Some(self.resting_since_s? - self.arriving_s?)
    }
}

/// Watches the recorded run tick by tick.
pub struct Judge {
    obstacles: Vec<Obstacle>,
    /// The robot's radius, m: clearances are from its edge.
    footprint: ObstacleGrowth,
    start: [f64; 2],
    goal: [f64; 2],
    goal_tolerance_m: f64,
    /// `(t, x, y)` over the last stall window.
    window: VecDeque<(f64, f64, f64)>,
    pub min_clearance_m: f64,
    /// Least clearance to an obstacle that moves at some time, m (infinite without one).
    pub min_moving_clearance_m: f64,
    /// Least clearance to an obstacle that never moves, m (infinite without one): no
    /// person walking into a robot at rest lowers it.
    pub min_static_clearance_m: f64,
    /// Contacts the robot made while it moved (the run ends at the first: `collided`).
    pub contacts_moving: u64,
    /// Contacts a moving obstacle made with the robot at rest (the run goes on).
    pub contacts_at_rest: u64,
    /// The contact at the newest tick, if any: whether it is one at rest.
    contact: Option<bool>,
    /// The robot's commanded forward speed at the newest tick, m/s ([`Judge::tick`]).
    commanded_speed_m_s: f64,
    /// A base with a lag or a command delay (`plant.actuator_lag_s`,
    /// `plant.command_delay_s`) goes on moving after its commanded speed is zero: its
    /// speeds, as the simulated plant has them, from the commands it was sent.
    base: Option<(BaseModel, protocol::PlantConfig)>,
    /// Whether that base moves at the newest tick (faster than [`REST_SPEED_M_S`]).
    base_moving: bool,
    /// The DFL holds the robot at its goal at the newest tick, at rest (not turning to the
    /// goal heading; [`Judge::tick`]).
    holding: bool,
    /// The run ends `reached` once the DFL holds the robot within the goal tolerance
    /// (`robot.final_approach = "settle"` without `robot.hold_at_goal`).
    ends_at_hold: bool,
    /// Start of the current stay within the goal tolerance.
    pub inside_goal_since_s: Option<f64>,
    /// The final approach.
    pub arrival: Arrival,
    pub last_distance_to_goal_m: f64,
    /// How far the newest true heading is from the goal's, rad (`None`: no goal heading).
    pub last_heading_error_rad: Option<f64>,
    goal_yaw_rad: Option<f64>,
    goal_yaw_tolerance_rad: f64,
    /// First time the robot was more than [`DEVIATION_M`] off the straight start-goal
    /// line, s: how early the constraint makes it swerve (the paper's Fig. 4 (a)-(c)).
    pub deviation_time_s: Option<f64>,
    /// How far out a robot held at an obstacle stops, at most, m: the MPC's margins (the
    /// safety margin, the disturbance's, `kappa` output-noise deviations, an upper
    /// bound on `kappa sigma`) and [`PINNED_CLEARANCE_M`].
    pinned_within_m: f64,
    /// The last true position, and its time, s.
    last_position: [f64; 2],
    last_time_s: f64,
    /// In a fleet, the other robots that moved in the newest tracks, as discs where they
    /// were then ([`Judge::peers`]).
    moving_peers: Vec<Obstacle>,
    /// The last time the robot stood still waiting for something moving near it
    /// ([`WAITING_WITHIN_M`]), s.
    waited_at_s: Option<f64>,
}

impl Judge {
    pub fn new(scenario: &Scenario) -> Judge {
        Judge {
            obstacles: scenario.obstacles.clone(),
            footprint: ObstacleGrowth::footprint(scenario),
            start: [scenario.robot.start[0], scenario.robot.start[1]],
            goal: scenario.robot.goal.position,
            goal_tolerance_m: scenario.robot.goal_tolerance_m,
            window: VecDeque::new(),
            min_clearance_m: f64::INFINITY,
            min_moving_clearance_m: f64::INFINITY,
            min_static_clearance_m: f64::INFINITY,
            contacts_moving: 0,
            contacts_at_rest: 0,
            contact: None,
            commanded_speed_m_s: 0.0,
            base: BaseModel::of(scenario.simulated_actuator(), scenario)
                .map(|base| (base, scenario.plant.clone())),
            base_moving: false,
            holding: false,
            ends_at_hold: scenario.robot.final_approach == protocol::FinalApproach::Settle
                && !scenario.robot.hold_at_goal,
            inside_goal_since_s: None,
            arrival: Arrival::new(scenario.robot.goal_tolerance_m),
            last_distance_to_goal_m: f64::INFINITY,
            last_heading_error_rad: None,
            goal_yaw_rad: scenario.robot.goal.yaw_rad,
            goal_yaw_tolerance_rad: scenario.robot.goal_yaw_tolerance_rad,
            deviation_time_s: None,
            pinned_within_m: pinned_within_m(scenario),
            last_position: [scenario.robot.start[0], scenario.robot.start[1]],
            last_time_s: 0.0,
            moving_peers: Vec::new(),
            waited_at_s: None,
        }
    }

    /// The tracker's newest `tracks`: in a fleet, which other robots move (faster than
    /// [`protocol::ROBOT_STILL_SPEED_M_S`]). A robot standing still near one waits for it,
    /// as for a person passing, and has not stalled: robots meeting in a fleet hold each
    /// other up for a while, and the robot held up goes on once the others have passed. A
    /// robot whose neighbours all stand still too has stalled (a knot no rule broke).
    pub fn peers(&mut self, tracks: &protocol::Tracks) {
        let moves = |t: &&protocol::Track| {
            t.is_peer() && t.velocity[0].hypot(t.velocity[1]) > protocol::ROBOT_STILL_SPEED_M_S
        };
        self.moving_peers.clear();
        self.moving_peers.extend(
            (tracks.tracks().iter().filter(moves))
                .map(|t| Obstacle::fixed(t.center[0], t.center[1], t.radius_m)),
        );
    }

    /// Why a run that ended `outcome` did not arrive (`None` unless it stalled or timed
    /// out), from what it recorded: `solved_plans` of the MPC, whether it `followed_route`s,
    /// and the judge's own watch of the true position.
    pub fn reason(
        &self,
        outcome: Outcome,
        solved_plans: u64,
        followed_route: bool,
    ) -> Option<StallReason> {
        if !matches!(outcome, Outcome::Stalled | Outcome::Timeout) {
            return None;
        }
        let [x, y] = self.last_position;
        let towards_goal = [self.goal[0] - x, self.goal[1] - y];
        let pinned = self.obstacles.iter().any(|o| {
            let c = o.center_at(self.last_time_s);
            let towards_obstacle = [c[0] - x, c[1] - y];
            clearance_m(
                std::slice::from_ref(o),
                &self.footprint,
                self.last_time_s,
                [x, y],
            ) <= self.pinned_within_m
                && towards_obstacle[0] * towards_goal[0] + towards_obstacle[1] * towards_goal[1]
                    > 0.0
        });
        let nearer_by_m = self.window.front().map_or(0.0, |&(_, wx, wy)| {
            let then = (self.goal[0] - wx).hypot(self.goal[1] - wy);
            then - self.last_distance_to_goal_m
        });
        let near = self.last_distance_to_goal_m <= NEAR_GOAL_M;
        let nearer_enough_m = match near {
            true => APPROACHING_NEAR_GOAL_M,
            false => STALL_DISTANCE_M,
        };
        let approaching = outcome == Outcome::Timeout && nearer_by_m > nearer_enough_m;
        Some(if solved_plans == 0 {
            StallReason::InfeasibleFromStart
        } else if near && !approaching {
            StallReason::OscillatingNearGoal
        } else if pinned {
            StallReason::PinnedAtObstacle
        } else if approaching {
            StallReason::StillApproaching
        } else if followed_route {
            StallReason::NoProgressOnRoute
        } else {
            StallReason::NoProgress
        })
    }

    /// Distance from `(x, y)` to the straight line through the start and the goal, m.
    pub fn off_line(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (self.goal[0] - self.start[0], self.goal[1] - self.start[1]);
        let length = dx.hypot(dy);
        if length == 0.0 {
            return (x - self.start[0]).hypot(y - self.start[1]);
        }
        ((x - self.start[0]) * dy - (y - self.start[1]) * dx).abs() / length
    }

    /// Distance from the robot's edge at `(x, y)` to the nearest obstacle surface at
    /// time `t_s`, m.
    pub fn clearance(&self, t_s: f64, x: f64, y: f64) -> f64 {
        clearance_m(&self.obstacles, &self.footprint, t_s, [x, y])
    }

    /// A tick recorded: the truth at its start, and the DFL's command over it (its ζ, the
    /// forward speed, and whether it holds the robot at its goal). Returns an outcome that
    /// ends the run now (a collision, a stall, or the robot held within the goal
    /// tolerance).
    pub fn tick(&mut self, truth: &GroundTruth, act: &Actuation) -> Option<Outcome> {
        self.commanded_speed_m_s = act.zeta;
        self.base_moving = self.base.as_mut().is_some_and(|(base, wheels)| {
            let moving = base.speeds()[0].abs() >= REST_SPEED_M_S;
            base.advance(wheels.realized_inputs([act.u1, act.u2]), |_, _| {});
            moving
        });
        // Held, and done turning to the goal heading.
        self.holding = act.mode() == Some(CommandMode::Hold) && act.u2 == 0.0;
        self.observe_pose(truth)
    }

    /// A route recorded: a planner that found none ends the run.
    pub fn route(&mut self, route: &Route) -> Option<Outcome> {
        (!route.is_ok()).then_some(Outcome::NoRoute)
    }

    /// The outcome of a run that reached its last tick: the truth after that tick (when
    /// there is one) is judged too.
    pub fn end_of_run(&mut self, truth: Option<&GroundTruth>) -> Outcome {
        truth
            .and_then(|truth| self.observe_pose(truth))
            .unwrap_or_else(|| self.final_outcome())
    }

    /// Observes the true pose; returns an outcome that ends the run now ([`Judge::observe`]).
    fn observe_pose(&mut self, truth: &GroundTruth) -> Option<Outcome> {
        self.last_heading_error_rad = self
            .goal_yaw_rad
            .map(|yaw| protocol::wrap_angle(truth.pose[2] - yaw).abs());
        self.observe(truth.header.time_s, truth.pose[0], truth.pose[1])
    }

    /// The run goes to `goal` from now on: its arrival, its stay within the tolerance and
    /// its stall window start again, from where the robot is.
    pub fn retarget(&mut self, goal: protocol::Goal) {
        self.goal = goal.position;
        self.goal_yaw_rad = goal.yaw_rad;
        self.inside_goal_since_s = None;
        self.arrival = Arrival::new(self.goal_tolerance_m);
        self.window.clear();
        self.start = self.last_position;
    }

    /// Observes the true position at time `t_s`; returns an outcome that ends the run now
    /// (a collision, a stall, or the robot held at its goal, within the goal tolerance
    /// and, with a goal heading, the yaw tolerance).
    pub fn observe(&mut self, t_s: f64, x: f64, y: f64) -> Option<Outcome> {
        let (mut moving_clearance, mut static_clearance) = (f64::INFINITY, f64::INFINITY);
        for o in &self.obstacles {
            let c = clearance_m(std::slice::from_ref(o), &self.footprint, t_s, [x, y]);
            let least = if o.moves() {
                &mut moving_clearance
            } else {
                &mut static_clearance
            };
            *least = least.min(c);
        }
        self.min_moving_clearance_m = self.min_moving_clearance_m.min(moving_clearance);
        self.min_static_clearance_m = self.min_static_clearance_m.min(static_clearance);
        let clearance = moving_clearance.min(static_clearance);
        self.min_clearance_m = self.min_clearance_m.min(clearance);
        self.last_time_s = t_s;
        if self.deviation_time_s.is_none() && self.off_line(x, y) > DEVIATION_M {
            self.deviation_time_s = Some(t_s);
        }
        let distance = (x - self.goal[0]).hypot(y - self.goal[1]);
        self.last_distance_to_goal_m = distance;
        self.last_position = [x, y];
        if distance <= self.goal_tolerance_m {
            self.inside_goal_since_s.get_or_insert(t_s);
        } else {
            self.inside_goal_since_s = None;
        }
        self.arrival.observe(t_s, distance);
        let at_rest = self.commanded_speed_m_s.abs() < REST_SPEED_M_S && !self.base_moving;
        // A contact is judged when it starts, and stays what it was until it ends (the
        // obstacle may stop in the robot, the robot may drive out of its way). It starts
        // at rest only against an obstacle moving then: a robot at rest cannot enter one
        // at rest.
        let contact = (clearance < 0.0).then(|| {
            self.contact
                .unwrap_or_else(|| at_rest && self.contact_with_moving(t_s, x, y))
        });
        let entered = contact.is_some() && self.contact.is_none();
        self.contact = contact;
        match contact {
            Some(false) => {
                self.contacts_moving += 1;
                return Some(Outcome::Collided);
            }
            Some(true) => self.contacts_at_rest += u64::from(entered),
            None => {}
        }
        self.window.push_back((t_s, x, y));
        // Keep the newest sample at least a window old at the front (the tick need not
        // divide the window).
        while self
            .window
            .get(1)
            .is_some_and(|&(t1, _, _)| t_s - t1 >= STALL_WINDOW_S - 1e-9)
        {
            self.window.pop_front();
        }
        let full = self
            .window
            .front()
            .is_some_and(|&(t0, _, _)| t_s - t0 >= STALL_WINDOW_S - 1e-9);
        let still = self
            .window
            .iter()
            .all(|&(_, wx, wy)| (wx - x).hypot(wy - y) < STALL_DISTANCE_M);
        let facing = self
            .last_heading_error_rad
            .is_none_or(|e| e <= self.goal_yaw_tolerance_rad);
        if self.ends_at_hold && self.holding && facing && distance <= self.goal_tolerance_m {
            return Some(Outcome::Reached);
        }
        let away = still && distance > self.goal_tolerance_m;
        if away && self.waits_for_moving(t_s, x, y) {
            self.waited_at_s = Some(t_s);
        }
        let waited_lately = (self.waited_at_s).is_some_and(|at| t_s - at < STALL_WINDOW_S - 1e-9);
        (full && away && !waited_lately).then_some(Outcome::Stalled)
    }

    /// Whether an obstacle moving at `t_s`, or another robot that moved in the newest
    /// tracks, is within [`WAITING_WITHIN_M`] of the robot at `(x, y)`.
    fn waits_for_moving(&self, t_s: f64, x: f64, y: f64) -> bool {
        let moving = (self.obstacles.iter()).filter(|o| o.velocity_at(t_s) != [0.0; 2]);
        moving.chain(&self.moving_peers).any(|o| {
            clearance_m(std::slice::from_ref(o), &self.footprint, t_s, [x, y]) <= WAITING_WITHIN_M
        })
    }

    /// Whether every obstacle the robot at `(x, y)` touches at `t_s` is moving then.
    fn contact_with_moving(&self, t_s: f64, x: f64, y: f64) -> bool {
        self.obstacles
            .iter()
            .filter(|o| clearance_m(std::slice::from_ref(o), &self.footprint, t_s, [x, y]) < 0.0)
            .all(|o| o.velocity_at(t_s) != [0.0; 2])
    }

    /// The outcome of a run that went its full length.
    fn final_outcome(&self) -> Outcome {
        if self.inside_goal_since_s.is_some() {
            Outcome::Reached
        } else {
            Outcome::Timeout
        }
    }
}

/// How far from an obstacle's surface (beyond the robot's radius) a robot the CBF holds
/// there may stop, m ([`Judge::reason`]).
fn pinned_within_m(scenario: &Scenario) -> f64 {
    let growth = ObstacleGrowth::of(scenario);
    let noise = scenario
        .plant
        .noise_variance
        .per_axis()
        .into_iter()
        .take(2)
        .fold(0.0, f64::max);
    let margins = growth.fixed_m - scenario.robot.radius_m;
    margins + growth.uncertainty_m(noise.max(0.0).sqrt()) + PINNED_CLEARANCE_M
}

/// Distance from the edge of a robot with `footprint` at `p` (its centre, for the paper's
/// point robot) to the nearest obstacle surface at time `t_s` (where the obstacles truly
/// are then), m.
pub fn clearance_m(
    obstacles: &[Obstacle],
    footprint: &ObstacleGrowth,
    t_s: f64,
    p: [f64; 2],
) -> f64 {
    obstacles
        .iter()
        .map(|o| protocol::distance(p, o.center_at(t_s)) - o.radius - footprint.fixed_m)
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A command at forward speed `zeta`, m/s.
    fn moving(zeta: f64) -> Actuation {
        Actuation {
            zeta,
            ..Actuation::default()
        }
    }

    /// The truth at `t_s`, at `x` on the x axis.
    fn at(t_s: f64, x: f64) -> GroundTruth {
        GroundTruth {
            pose: [x, 0.0, 0.0],
            header: protocol::Header {
                time_s: t_s,
                ..protocol::Header::default()
            },
            ..GroundTruth::default()
        }
    }

    #[test]
    fn a_robot_held_within_the_goal_tolerance_ends_the_run_reached_unless_it_holds_on() {
        let held = Actuation {
            mode: CommandMode::Hold as u32,
            ..Actuation::default()
        };
        let mut m = Judge::new(&Scenario::default());
        assert_eq!(m.tick(&at(1.0, 0.05), &moving(0.01)), None, "not held yet");
        assert_eq!(
            m.tick(&at(1.1, 0.15), &held),
            None,
            "held outside the tolerance"
        );
        assert_eq!(m.tick(&at(1.2, 0.05), &held), Some(Outcome::Reached));
        let mut s = Scenario::default();
        s.robot.hold_at_goal = true;
        let mut m = Judge::new(&s);
        assert_eq!(
            m.tick(&at(1.2, 0.05), &held),
            None,
            "holds on to duration_s"
        );
        s.robot.final_approach = protocol::FinalApproach::Paper;
        s.robot.hold_at_goal = false;
        let mut m = Judge::new(&s);
        assert_eq!(m.tick(&at(1.2, 0.05), &held), None, "the paper's arrival");
    }

    #[test]
    fn with_a_goal_heading_the_run_ends_once_the_held_robot_has_turned_to_it() {
        let mut s = Scenario::default();
        s.robot.goal.yaw_rad = Some(1.0);
        let mut m = Judge::new(&s);
        let facing = |t_s: f64, theta: f64| GroundTruth {
            pose: [0.0, 0.0, theta],
            ..at(t_s, 0.0)
        };
        let (held, turning) = (
            Actuation {
                mode: CommandMode::Hold as u32,
                ..Actuation::default()
            },
            Actuation {
                mode: CommandMode::Hold as u32,
                u2: 0.1,
                ..Actuation::default()
            },
        );
        assert_eq!(m.tick(&facing(1.0, 0.0), &held), None, "1 rad off");
        assert_eq!(m.last_heading_error_rad, Some(1.0));
        assert_eq!(m.tick(&facing(1.1, 0.95), &turning), None, "still turning");
        assert_eq!(m.tick(&facing(1.2, 0.95), &held), Some(Outcome::Reached));
    }

    #[test]
    fn the_arrival_is_the_first_time_within_0_2_m_then_the_farthest_and_the_final_rest() {
        let mut a = Arrival::new(0.1);
        assert_eq!(a.rest_within_m, AT_REST_WITHIN_M);
        // In from 1 m, within 0.2 m at t = 3, out to 0.3 m, within 0.05 m at t = 6 for
        // a moment, out to 0.08 m, and within 0.05 m from t = 8 to the end.
        let path = [
            (0.0, 1.0),
            (3.0, 0.2),
            (4.0, 0.3),
            (5.0, 0.1),
            (6.0, 0.04),
            (7.0, 0.08),
            (8.0, 0.05),
            (9.0, 0.01),
        ];
        for (t, d) in path {
            a.observe(t, d);
        }
        assert_eq!(a.arriving_s, Some(3.0));
        assert_eq!(a.farthest_after_m, 0.3);
        assert_eq!(a.time_to_rest_s(), Some(5.0));
        // Ending outside the rest radius: never at rest.
        a.observe(10.0, 0.06);
        assert_eq!(a.time_to_rest_s(), None);
        // Never within 0.2 m: nothing to say.
        let mut far = Arrival::new(0.02);
        far.observe(0.0, 0.21);
        assert_eq!((far.arriving_s, far.time_to_rest_s()), (None, None));
        // A goal tolerance under 0.05 m is the rest radius.
        far.observe(1.0, 0.03);
        assert_eq!((far.arriving_s, far.time_to_rest_s()), (Some(1.0), None));
        far.observe(2.0, 0.02);
        assert_eq!(far.time_to_rest_s(), Some(1.0));
    }

    #[test]
    fn a_robot_standing_still_away_from_the_goal_stalls_after_the_window() {
        let mut m = Judge::new(&Scenario::default());
        let mut ended = None;
        for i in 0..1000 {
            let t = i as f64 * 0.005;
            if let Some(o) = m.observe(t, 7.0, 7.0) {
                ended = Some((o, t));
                break;
            }
        }
        let (outcome, t) = ended.unwrap();
        assert_eq!(outcome, Outcome::Stalled);
        assert!((t - STALL_WINDOW_S).abs() < 0.01, "stalled at {t}");
    }

    #[test]
    fn a_robot_waiting_for_a_person_to_pass_stalls_only_a_window_after_the_person_is_gone() {
        // The person (0.3 m) walks past the robot standing at (7, 7) at 1 m/s along y = 5,
        // from x = 5: within 3 m of the robot's edge until x = 7 + 2.62 m, at 4.62 s.
        let s = Scenario {
            obstacles: vec![Obstacle {
                velocity: [1.0, 0.0],
                ..Obstacle::fixed(5.0, 5.0, 0.3)
            }],
            ..Scenario::default()
        };
        let mut m = Judge::new(&s);
        let ended = (0..4000)
            .map(|i| i as f64 * 0.005)
            .find_map(|t| m.observe(t, 7.0, 7.0).map(|o| (o, t)));
        let (outcome, t) = ended.expect("never stalled");
        assert_eq!(outcome, Outcome::Stalled);
        // Still for 3 s at 3 s, but waiting for the person until 4.62 s, then free to go
        // for a window.
        let gone_s = 4.62;
        assert!(
            (gone_s + STALL_WINDOW_S - 0.01..gone_s + STALL_WINDOW_S + 0.01).contains(&t),
            "stalled at {t}"
        );
    }

    #[test]
    fn a_robot_of_a_fleet_waiting_for_another_that_moves_stalls_only_a_window_after_it_stands() {
        // Another robot (0.3 m) drives past 1 m away at 0.5 m/s for 5 s, then stops there.
        let mut m = Judge::new(&Scenario::default());
        let track = |x: f64, speed: f64| {
            let mut tracks = protocol::Tracks::default();
            tracks.tracks[0] = protocol::Track {
                obstacle: protocol::FIRST_PEER + 1,
                radius_m: 0.3,
                center: [x, 8.0],
                velocity: [speed, 0.0],
                ..protocol::Track::default()
            };
            tracks.count = 1;
            tracks
        };
        let ended = (0..4000).map(|i| i as f64 * 0.005).find_map(|t| {
            let (x, speed) = if t < 5.0 {
                (5.0 + 0.5 * t, 0.5)
            } else {
                (7.5, 0.0)
            };
            m.peers(&track(x, speed));
            m.observe(t, 7.0, 7.0).map(|o| (o, t))
        });
        let (outcome, t) = ended.expect("never stalled");
        assert_eq!(outcome, Outcome::Stalled);
        // Still for 3 s at 3 s, but waiting for the other robot until it stood at 5 s, then
        // free to go for a window.
        let stood_s = 5.0;
        assert!(
            (stood_s + STALL_WINDOW_S - 0.01..stood_s + STALL_WINDOW_S + 0.01).contains(&t),
            "stalled at {t}"
        );
    }

    #[test]
    fn a_robot_standing_still_stalls_whatever_the_tick() {
        // 2 s is no whole number of these ticks.
        for tick_s in [0.0059318, 0.0033, 0.01] {
            let mut m = Judge::new(&Scenario::default());
            let ended = (0..2000)
                .map(|i| i as f64 * tick_s)
                .find_map(|t| m.observe(t, 7.0, 7.0).map(|o| (o, t)));
            let (outcome, t) = ended.expect("never stalled");
            assert_eq!(outcome, Outcome::Stalled);
            assert!(
                (STALL_WINDOW_S..STALL_WINDOW_S + tick_s + 1e-9).contains(&t),
                "tick {tick_s}: stalled at {t}"
            );
        }
    }

    #[test]
    fn a_robot_that_moved_a_centimetre_within_the_window_has_not_stalled() {
        let mut m = Judge::new(&Scenario::default());
        for i in 0..1000 {
            let t = i as f64 * 0.0059318;
            // 1.5 cm over each 2 s.
            assert_eq!(m.observe(t, 7.0 + 0.0075 * t, 7.0), None, "at {t}");
        }
    }

    #[test]
    fn entering_an_obstacle_is_a_collision_and_the_goal_needs_a_stay() {
        let mut m = Judge::new(&Scenario::default());
        assert_eq!(m.observe(0.0, 3.0, 2.1), Some(Outcome::Collided));
        let mut m = Judge::new(&Scenario::default());
        m.observe(0.0, 0.05, 0.0);
        m.observe(0.1, 0.5, 0.0);
        m.observe(0.2, 0.05, 0.0);
        assert_eq!(m.inside_goal_since_s, Some(0.2));
        assert_eq!(m.final_outcome(), Outcome::Reached);
    }

    #[test]
    fn a_moving_obstacle_is_judged_where_it_is_and_a_contact_at_rest_is_counted_apart() {
        // A person of radius 0.3 m walking along y = 5 at 1 m/s from x = -3, and a box at
        // rest 2 m from the robot's edge.
        let mut s = Scenario::default();
        s.obstacles.push(Obstacle::fixed(0.0, 7.5, 0.5));
        s.obstacles.push(Obstacle {
            velocity: [1.0, 0.0],
            ..Obstacle::fixed(-3.0, 5.0, 0.3)
        });
        // A robot standing at (0, 5) from t = 2 s to 4 s (not long enough to stall):
        // touched from t = 2.7 s to 3.3 s, one contact at rest, and the run goes on.
        let truth = |t: f64, x: f64| GroundTruth {
            pose: [x, 5.0, 0.0],
            header: protocol::Header {
                time_s: t,
                ..protocol::Header::default()
            },
            ..GroundTruth::default()
        };
        let mut m = Judge::new(&s);
        for k in 20..=40 {
            let t = k as f64 * 0.1;
            assert_eq!(m.tick(&truth(t, 0.0), &moving(0.0)), None, "t = {t}");
        }
        assert_eq!((m.contacts_at_rest, m.contacts_moving), (1, 0));
        assert!(m.min_moving_clearance_m < -0.2 && m.min_clearance_m < -0.2);
        // The box at rest was never touched: its clearance is the box's alone.
        let mut only_the_box = Scenario::default();
        only_the_box.obstacles.push(s.obstacles[0].clone());
        let mut b = Judge::new(&only_the_box);
        assert_eq!(b.observe(2.0, 0.0, 5.0), None);
        assert!(b.min_clearance_m > 1.5);
        assert_eq!(m.min_static_clearance_m, b.min_clearance_m);
        // A robot driving into the same person: a collision.
        let mut m = Judge::new(&s);
        assert_eq!(m.tick(&truth(2.8, 0.1), &moving(-0.5)), None);
        assert_eq!(
            m.tick(&truth(2.9, 0.05), &moving(-0.5)),
            Some(Outcome::Collided)
        );
        assert_eq!((m.contacts_at_rest, m.contacts_moving), (0, 1));
        // A robot at rest that drives out of the person's way while in contact: still the
        // contact at rest it was.
        let mut m = Judge::new(&s);
        assert_eq!(m.tick(&truth(2.9, 0.0), &moving(0.0)), None);
        assert_eq!(m.tick(&truth(3.0, 0.05), &moving(0.3)), None);
        assert_eq!((m.contacts_at_rest, m.contacts_moving), (1, 0));
        // Standing where the person was at t = 0 touches nothing at t = 3 s.
        let mut m = Judge::new(&s);
        assert_eq!(m.observe(3.0, -3.0, 5.0), None);
        assert!(m.min_clearance_m > 2.0);
    }

    /// A judge that watched a robot stand at `at` for the stall window.
    fn stood_at(scenario: &Scenario, at: [f64; 2]) -> (Judge, Outcome) {
        let mut m = Judge::new(scenario);
        let outcome = (0..1000)
            .find_map(|i| m.observe(i as f64 * 0.01, at[0], at[1]))
            .expect("stalls");
        (m, outcome)
    }

    #[test]
    fn a_stall_has_the_reason_the_record_shows() {
        let paper = Scenario::default();
        // Nothing solved: infeasible from the start, wherever it stands.
        let (m, outcome) = stood_at(&paper, [7.0, 7.0]);
        assert_eq!(outcome, Outcome::Stalled);
        assert_eq!(
            m.reason(outcome, 0, false),
            Some(StallReason::InfeasibleFromStart)
        );
        // Solved plans, standing 5 cm from the obstacle (centre (3, 3.5), radius 1.5) on
        // its far side from the goal: pinned; on its near side: not.
        let behind = [3.0 + 1.55 * 0.6, 3.5 + 1.55 * 0.8];
        let (m, outcome) = stood_at(&paper, behind);
        assert_eq!(
            m.reason(outcome, 10, false),
            Some(StallReason::PinnedAtObstacle)
        );
        let before = [3.0 - 1.55 * 0.6, 3.5 - 1.55 * 0.8];
        let (m, outcome) = stood_at(&paper, before);
        assert_eq!(m.reason(outcome, 10, false), Some(StallReason::NoProgress));
        assert_eq!(
            m.reason(outcome, 10, true),
            Some(StallReason::NoProgressOnRoute)
        );
        // 0.35 m off it: pinned only where output noise grows the MPC's discs (kappa
        // deviations of the noise, 0.3 m at a variance of 0.01).
        let farther = [3.0 + 1.85 * 0.6, 3.5 + 1.85 * 0.8];
        let (m, outcome) = stood_at(&paper, farther);
        assert_eq!(m.reason(outcome, 10, false), Some(StallReason::NoProgress));
        let noisy = paper
            .with_overrides(&["plant.noise_variance=0.01".into()])
            .unwrap();
        let (m, outcome) = stood_at(&noisy, farther);
        assert_eq!(
            m.reason(outcome, 10, false),
            Some(StallReason::PinnedAtObstacle)
        );
        // Near the goal.
        let (m, outcome) = stood_at(&paper, [0.3, 0.0]);
        assert_eq!(
            m.reason(outcome, 10, false),
            Some(StallReason::OscillatingNearGoal)
        );
        // A robot that arrived has no reason.
        assert_eq!(m.reason(Outcome::Reached, 10, false), None);
    }

    #[test]
    fn a_timeout_while_still_getting_nearer_is_still_approaching() {
        let mut m = Judge::new(&Scenario::default());
        for i in 0..500 {
            let t = i as f64 * 0.01;
            assert_eq!(m.observe(t, -8.0 + 0.1 * t, -8.0), None);
        }
        assert_eq!(m.final_outcome(), Outcome::Timeout);
        assert_eq!(
            m.reason(Outcome::Timeout, 10, false),
            Some(StallReason::StillApproaching)
        );
    }

    #[test]
    fn a_timeout_near_the_goal_is_still_approaching_only_if_it_came_much_nearer() {
        let goal = Scenario::default().robot.goal.position;
        let run = |speed_m_s: f64| {
            let mut m = Judge::new(&Scenario::default());
            // Along x towards the goal, ending 0.3 m short of it at 5 s.
            for i in 0..=500 {
                let t = i as f64 * 0.01;
                let x = goal[0] - 0.3 - speed_m_s * (5.0 - t);
                assert_eq!(m.observe(t, x, goal[1]), None);
            }
            m.reason(Outcome::Timeout, 10, false)
        };
        assert_eq!(run(0.27), Some(StallReason::StillApproaching));
        assert_eq!(run(0.01), Some(StallReason::OscillatingNearGoal));
    }
}
