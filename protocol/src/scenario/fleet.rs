//! A fleet (`[[robots]]`, docs/fleet.md): several robots in one world, each driven by a
//! pipeline of its own. Every robot is the scenario's `robot` with its own start, goal
//! and radius ([`Scenario::member`]); the other robots are moving discs to it, predicted
//! from the plans they publish ([`crate::PeerPrediction`]).

use super::validate::Validator;
use super::{Goal, Scenario};
use serde::{Deserialize, Serialize};

/// One robot of a fleet; what it does not set is the scenario's `robot`'s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FleetRobot {
    /// Initial pose `[x_m, y_m, theta_rad]`.
    pub start: [f64; 3],
    /// The goal, `[x_m, y_m]` or `[x_m, y_m, theta_rad]`.
    #[schemars(with = "Vec<f64>")]
    pub goal: Goal,
    /// Radius of its footprint, m; default `robot.radius_m`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_m: Option<f64>,
    /// Its input box, m/s^2 (what `mpc.v_max` is to a robot alone: the bound on its flat
    /// outputs' acceleration); default `mpc.v_max`. The others take every robot to
    /// accelerate up to the fleet's largest ([`Scenario::peer_accel_max`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub v_max: Option<f64>,
    /// Faults injected into its pipeline alone (`[robots.fault]`, the keys of `[fault]`);
    /// default: the scenario's `[fault]`, as every robot's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fault: Option<super::FaultConfig>,
    /// The host its roles of [`FleetRobot::host_roles`] run on (docs/fleet.md, "Across
    /// hosts"; empty: the orchestrator's). Its plant, the simulated robot, runs where
    /// the world is simulated.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub host: String,
    /// Which of its roles run on its `host`.
    #[serde(default, skip_serializing_if = "HostRoles::is_default")]
    pub host_roles: HostRoles,
}

/// Which of a fleet robot's roles its host runs ([`FleetRobot::host_roles`]).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum HostRoles {
    /// Its tracker, MPC and route planner: its estimator and DFL stay beside the plant,
    /// as a robot's inner loop runs on the robot, and a lost host leaves it its DFL,
    /// which brakes it to rest.
    #[default]
    Planning,
    /// Every role but the plant, its estimator and DFL too: every inner tick's
    /// measurement and command cross the link, and a lost host leaves the plant to its
    /// command watchdog (`plant.command_timeout_s`).
    Pipeline,
}

impl HostRoles {
    fn is_default(&self) -> bool {
        *self == HostRoles::default()
    }

    /// The roles placed on the robot's host.
    pub fn roles(self) -> &'static [crate::Role] {
        use crate::Role::*;
        match self {
            HostRoles::Planning => &[Tracker, Mpc, Planner],
            HostRoles::Pipeline => &[Estimator, Tracker, Mpc, Dfl, Planner],
        }
    }
}

impl FleetRobot {
    /// A robot from `start` (`[x_m, y_m, theta_rad]`) to `goal`, with the scenario's
    /// radius and faults.
    pub fn between(start: [f64; 3], goal: Goal) -> FleetRobot {
        FleetRobot {
            start,
            goal,
            radius_m: None,
            v_max: None,
            fault: None,
            host: String::new(),
            host_roles: HostRoles::default(),
        }
    }
}

/// The most robots of a fleet: each robot's MPC keeps one disc per other robot, and its
/// tracks message holds [`crate::MAX_TRACKS`].
pub const MAX_ROBOTS: usize = 16;

/// The [`crate::Track::obstacle`] of robot `robot`'s disc in another robot's tracks: far
/// from the scenario's obstacle indices and below the phantoms'
/// ([`crate::FIRST_PHANTOM`]).
pub const FIRST_PEER: u32 = 1 << 30;

impl Scenario {
    /// The robots of the run: one without `[[robots]]`, else one per entry.
    pub fn robot_count(&self) -> usize {
        self.robots.len().max(1)
    }

    /// Whether the run is a fleet's (`[[robots]]`): its robots keep clear of each other.
    pub fn is_fleet(&self) -> bool {
        !self.robots.is_empty()
    }

    /// The scenario of robot `id` of a fleet: the scenario's `robot` with that robot's
    /// start, goal and radius, and its own seed (`seed + id`), so that no two robots share
    /// their noise. The fleet stays in it: its MPC and DFL keep clear of the others.
    /// Without `[[robots]]`, robot 0 is the scenario itself.
    pub fn member(&self, id: usize) -> Scenario {
        let mut member = self.clone();
        if let Some(robot) = self.robots.get(id) {
            member.robot.start = robot.start;
            member.robot.goal = robot.goal;
            member.robot.radius_m = self.radius_of(id);
            member.mpc.v_max = robot.v_max.unwrap_or(self.mpc.v_max);
            member.seed = self.seed.wrapping_add(id as u64);
            member.fleet_id = Some(id);
            if let Some(fault) = &robot.fault {
                member.fault = fault.clone();
            }
            if robot.host.is_empty() {
                // No link of its own to act on.
                member.fault = member.fault.without_link_faults();
            } else {
                member.place_on(&robot.host, robot.host_roles);
            }
        }
        member
    }

    /// The `roles` of a robot's host that run in it placed on `host`
    /// ([`FleetRobot::host`]).
    fn place_on(&mut self, host: &str, roles: HostRoles) {
        for &role in roles.roles() {
            if let (None, Some(placed)) = (self.absent(role), self.hosts.role_mut(role)) {
                *placed = host.to_string();
            }
        }
    }

    /// Every host a role runs on: those of `[hosts]` and the robots' own.
    pub fn host_names(&self) -> Vec<String> {
        let mut names = self.hosts.names();
        names.extend(
            (self.robots.iter()).filter_map(|r| Some(r.host.clone()).filter(|h| !h.is_empty())),
        );
        names.sort();
        names.dedup();
        names
    }

    /// The other robots of this member's fleet ([`Scenario::member`]): each one's id, its
    /// start pose `[x m, y m, theta rad]` and its footprint's radius, m; none for a robot
    /// alone (or the fleet's own scenario, which is no robot's).
    pub fn other_robots(&self) -> impl Iterator<Item = (usize, [f64; 3], f64)> + '_ {
        let own = self.fleet_id;
        (0..self.robots.len())
            .filter(move |&id| own.is_some_and(|own| own != id))
            .map(|id| (id, self.robots[id].start, self.radius_of(id)))
    }

    /// The radius of robot `id`'s footprint, m.
    pub fn radius_of(&self, id: usize) -> f64 {
        (self.robots.get(id))
            .and_then(|r| r.radius_m)
            .unwrap_or(self.robot.radius_m)
    }

    /// The bound on another robot's acceleration, m/s^2: its input box along both axes
    /// (its flat outputs' acceleration, which the DFL realizes), `sqrt(2) v_max`, with the
    /// largest `v_max` of the fleet's robots (`robots.<i>.v_max`, else `mpc.v_max`), so
    /// that one bound holds for every robot a track may be.
    pub fn peer_accel_max(&self) -> f64 {
        let v_max = (self.robots.iter())
            .map(|r| r.v_max.unwrap_or(self.mpc.v_max))
            .fold(self.mpc.v_max, f64::max);
        std::f64::consts::SQRT_2 * v_max
    }

    /// `[[robots]]`: each robot's values, the room between them, each robot in the world
    /// as the scenario's `robot` is checked, and what a fleet does not run with yet.
    pub(super) fn check_fleet(&self, v: &mut Validator) {
        if self.robots.is_empty() {
            return;
        }
        if self.robots.len() > MAX_ROBOTS {
            v.fail(
                "robots",
                format!(
                    "{} robots; a fleet has at most {MAX_ROBOTS}",
                    self.robots.len()
                ),
            );
        }
        for (i, robot) in self.robots.iter().enumerate() {
            self.check_robot(v, i, robot);
        }
        self.check_room_between_robots(v);
        if self.mpc.uncertainty_sigmas <= 0.0 {
            v.fail(
                "mpc.uncertainty_sigmas",
                "a fleet's robots carry how far another may be off its plan as standard \
                 deviations: it needs mpc.uncertainty_sigmas > 0"
                    .into(),
            );
        }
        let unsupported = [
            ("plant.kind", self.plant.kind != crate::PlantKind::Sim),
            ("swap", !self.swap.is_empty()),
            // A robot's roles go to its host by `robots.<i>.host` (its member's placement).
            (
                "hosts",
                self.fleet_id.is_none()
                    && crate::Role::ALL.iter().any(|r| self.hosts.of(*r).is_some()),
            ),
            // A disturbance pushes a robot beyond its input box, which bounds how far the
            // others take it to leave its plan.
            ("plant.disturbance_std", self.plant.disturbance_std > 0.0),
            // So do saturated wheels: with one wheel at its limit, the forward speed changes
            // as fast as the turn rate does (`PlantConfig::realized_inputs`), which the
            // input box does not bound.
            (
                "plant.max_wheel_speed_rad_s",
                self.plant.max_wheel_speed_rad_s > 0.0,
            ),
            // The others' tracks are where a robot is on the clock; a delay's plans run
            // behind it.
            ("robot.command_delay_s", self.command_lead_s() > 0.0),
        ];
        for (key, used) in unsupported {
            if used {
                v.fail(
                    key,
                    "a fleet (`[[robots]]`) runs simulated robots without a disturbance, \
                     wheel limits or a command delay, swaps or roles placed by [hosts] (a \
                     robot's own `host` places its pipeline; docs/fleet.md, \"Left out\")"
                        .into(),
                );
            }
        }
    }

    /// Robot `i`'s own values, and the robot in the world as the scenario's `robot` is
    /// checked.
    fn check_robot(&self, v: &mut Validator, i: usize, robot: &FleetRobot) {
        v.finite_all(&format!("robots.{i}.start"), &robot.start);
        v.finite_all(&format!("robots.{i}.goal"), &robot.goal.position);
        if let Some(radius) = robot.radius_m {
            v.non_negative(&format!("robots.{i}.radius_m"), radius);
        }
        if let Some(v_max) = robot.v_max {
            self.check_own_v_max(v, i, v_max);
        }
        if !robot.host.is_empty() {
            self.check_own_host(v, i, &robot.host);
        } else if !robot.host_roles.is_default() {
            v.fail(
                &format!("robots.{i}.host_roles"),
                format!("places roles on robot {i}'s host, and it has none (robots.{i}.host)"),
            );
        } else if robot
            .fault
            .as_ref()
            .is_some_and(super::FaultConfig::acts_on_links)
        {
            v.fail(
                &format!("robots.{i}.fault"),
                format!(
                    "fault.link_* acts on the links of a robot on another host, and robot {i} \
                     has none (robots.{i}.host)"
                ),
            );
        }
        let mut member = Validator {
            origin: v.origin,
            errors: Vec::new(),
        };
        let scenario = self.member(i);
        scenario.check_geometry(&mut member);
        if robot.fault.is_some() {
            scenario.check_faults(&mut member);
        }
        // What is the robot's own, under its entry (the rest, the world's, the
        // scenario's own check reports once).
        for mut error in member.errors {
            let own = (error.key.strip_prefix("robot."))
                .map(String::from)
                .or_else(|| error.key.starts_with("fault.").then(|| error.key.clone()));
            if let Some(key) = own {
                error.key = format!("robots.{i}.{key}");
                v.errors.push(error);
            }
        }
    }

    /// Robot `i`'s own input box: positive, and delivering the brake's deceleration when
    /// `dfl.brake_decel` is set (as `mpc.v_max` must).
    fn check_own_v_max(&self, v: &mut Validator, i: usize, v_max: f64) {
        let key = format!("robots.{i}.v_max");
        v.positive(&key, v_max);
        if let super::AutoOr::Value(decel) = self.dfl.brake_decel
            && decel > v_max
        {
            v.fail(
                &key,
                format!(
                    "{v_max} m/s^2 delivers less than the brake's dfl.brake_decel = {decel} \
                     m/s^2; give at least that, or set dfl.brake_decel = \"auto\""
                ),
            );
        }
    }

    /// Robot `i`'s host: a host name. (Two robots may share one: its agent joins the run
    /// once for each.)
    fn check_own_host(&self, v: &mut Validator, i: usize, host: &str) {
        super::check_host_name(v, &format!("robots.{i}.host"), host);
    }

    /// No two robots start, or end, within their two radii of each other.
    fn check_room_between_robots(&self, v: &mut Validator) {
        for i in 0..self.robots.len() {
            for j in 0..i {
                let room = self.radius_of(i) + self.radius_of(j);
                let (a, b) = (&self.robots[i], &self.robots[j]);
                let starts = crate::distance([a.start[0], a.start[1]], [b.start[0], b.start[1]]);
                if starts <= room {
                    v.fail(
                        &format!("robots.{i}.start"),
                        format!(
                            "{starts:.3} m from robot {j}'s start; two robots need {room:.3} m"
                        ),
                    );
                }
                let goals = crate::distance(a.goal.position, b.goal.position);
                if goals <= room + self.robot.goal_tolerance_m {
                    v.fail(
                        &format!("robots.{i}.goal"),
                        format!(
                            "{goals:.3} m from robot {j}'s goal; two robots resting there need \
                             their radii and robot.goal_tolerance_m, {:.3} m",
                            room + self.robot.goal_tolerance_m
                        ),
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Obstacle;
    use crate::scenario::{AutoOr, SampleSet};

    fn swap4() -> Scenario {
        Scenario::from_toml(include_str!("../../../scenarios/swap4.toml"), "swap4").unwrap()
    }

    #[test]
    fn a_robots_own_faults_start_from_the_scenarios_in_whichever_order_they_are_set() {
        let own = "robots.1.fault.mpc_fail_samples=\"60..=2000\"".to_string();
        let every = "fault.estimator_delay_ms=2".to_string();
        for overrides in [[&own, &every], [&every, &own]] {
            let overrides: Vec<String> = overrides.map(String::clone).into();
            let fleet = swap4().with_overrides(&overrides).unwrap();
            let robot1 = fleet.member(1).fault;
            assert_eq!(robot1.estimator_delay_ms, 2.0, "{overrides:?}");
            assert_eq!(
                robot1.mpc_fail_samples,
                SampleSet::Range("60..=2000".into()),
                "{overrides:?}"
            );
            let robot0 = fleet.member(0).fault;
            assert_eq!(robot0.estimator_delay_ms, 2.0, "{overrides:?}");
            assert_ne!(robot0.mpc_fail_samples, robot1.mpc_fail_samples);
        }
    }

    #[test]
    fn a_local_robots_own_faults_start_from_the_scenarios_without_its_link_faults() {
        let overrides = [
            "robots.0.host=b",
            "robots.1.fault.mpc_delay_ms=5",
            "fault.link_loss=0.1",
        ]
        .map(String::from);
        let fleet = swap4().with_overrides(&overrides).unwrap();
        let fleet = fleet.validated("test").unwrap();
        assert_eq!(fleet.member(0).fault.link_loss, 0.1, "robot 0's link");
        let robot1 = fleet.member(1).fault;
        assert_eq!((robot1.mpc_delay_ms, robot1.link_loss), (5.0, 0.0));
    }

    #[test]
    fn a_robots_own_input_box_is_its_members_and_the_others_take_the_fleets_largest() {
        let mut fleet = swap4();
        fleet.robots[1].v_max = Some(2.0);
        assert_eq!(fleet.member(1).mpc.v_max, 2.0);
        assert_eq!(fleet.member(0).mpc.v_max, fleet.mpc.v_max);
        for id in 0..4 {
            assert_eq!(
                fleet.member(id).peer_accel_max(),
                std::f64::consts::SQRT_2 * 2.0
            );
        }
        assert!(fleet.clone().validated("test").is_ok());

        fleet.robots[1].v_max = Some(0.5);
        fleet.dfl.brake_decel = AutoOr::Value(0.8);
        let refused = fleet.clone().validated("test").unwrap_err().to_string();
        assert!(refused.contains("robots.1.v_max"), "{refused}");
        fleet.robots[1].v_max = Some(-1.0);
        fleet.dfl.brake_decel = AutoOr::Auto(crate::scenario::Auto::Auto);
        let refused = fleet.clone().validated("test").unwrap_err().to_string();
        assert!(refused.contains("robots.1.v_max"), "{refused}");
    }

    #[test]
    fn a_fleet_tracks_people_from_the_truth_while_its_tracks_have_room_beside_the_robots() {
        // swap4's four robots: three others in each robot's tracks, beside the people.
        let person = |i: usize| Obstacle {
            velocity: [1.0, 0.0],
            ..Obstacle::fixed(-9.0, -9.0 + 0.5 * i as f64, 0.1)
        };
        let mut fleet = swap4();
        fleet.obstacles = (0..crate::MAX_TRACKS - 3).map(person).collect();
        let valid = fleet.clone().validated("test").unwrap();
        assert_eq!(valid.member(0).tracked().count(), crate::MAX_TRACKS - 3);
        fleet.obstacles.push(person(crate::MAX_TRACKS));
        let refused = fleet.validated("test").unwrap_err().to_string();
        let room = format!("hold {} beside the 3 other robots", crate::MAX_TRACKS - 3);
        assert!(refused.contains(&room), "{refused}");
    }
}
