//! The final approach (`robot.final_approach = "settle"`, docs/reach.md): within
//! [`APPROACH_RADIUS_M`] of the goal the linear scheme hands over to a second linear MPC,
//! the same program with the approach weights (`mpc.approach_q_diag`, `approach_r_diag`):
//! its own LQR, terminal weight (DARE) and terminal set, so the terminal ingredients match
//! the cost they close. The paper's weights (`R = 100 Q`) let a robot that comes in fast
//! pass its goal and wander about it for tens of seconds; the approach weights bring it to
//! rest there. Every safety row is the same in both. Where the approach's program fails
//! (its terminal set about the goal out of reach: a person drives the robot off it), the
//! sample is solved with the paper's weights ([`crate::Mpc::step_on_route`]).

use crate::{LinearMpc, MpcError};
use protocol::{
    APPROACH_LEFT_BEYOND_M, APPROACH_RADIUS_M, FinalApproach, MpcConfig, Route, Scenario, distance,
};

/// The MPC of the final approach, and whether the robot is on it.
pub struct Approach {
    pub mpc: LinearMpc,
    goal: [f64; 2],
    /// Whether the last step was on the final approach.
    pub on: bool,
}

impl Approach {
    /// The final approach of `scenario`, if it has one (`robot.final_approach`).
    pub fn new(scenario: &Scenario) -> Result<Option<Approach>, MpcError> {
        if scenario.robot.final_approach != FinalApproach::Settle {
            return Ok(None);
        }
        let weighted = Scenario {
            mpc: MpcConfig {
                q_diag: scenario.mpc.approach_q_diag,
                r_diag: scenario.mpc.approach_r_diag,
                ..scenario.mpc.clone()
            },
            ..scenario.clone()
        };
        Ok(Some(Approach {
            mpc: LinearMpc::new(&weighted)?,
            goal: scenario.robot.goal.position,
            on: false,
        }))
    }

    /// Whether a robot at `position` following `route` (if any) is on its final approach:
    /// it begins within [`APPROACH_RADIUS_M`] of the goal (along the route, or straight
    /// without one) and ends beyond [`APPROACH_LEFT_BEYOND_M`]. Returns true when that
    /// changed.
    pub fn update(&mut self, position: [f64; 2], route: Option<&Route>) -> bool {
        let left_m = match route.filter(|r| r.is_ok()) {
            Some(route) => length_left(route.points(), position),
            None => distance(position, self.goal),
        };
        let on = if self.on {
            left_m <= APPROACH_LEFT_BEYOND_M
        } else {
            left_m <= APPROACH_RADIUS_M
        };
        std::mem::replace(&mut self.on, on) != on
    }
}

/// The length of `points` from the point closest to `position` to the end, m.
fn length_left(points: &[[f64; 2]], position: [f64; 2]) -> f64 {
    let (segment, at, _) = protocol::closest_on_polyline(points, position);
    distance(at, points[segment + 1]) + protocol::polyline_length(&points[segment + 1..])
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::RouteStatus;

    #[test]
    fn the_approach_begins_within_a_metre_of_the_goal_along_the_route_and_ends_beyond_1_5_m() {
        let scenario = Scenario {
            obstacles: Vec::new(),
            ..Scenario::default()
        };
        let mut a = Approach::new(&scenario).unwrap().unwrap();
        // Straight to the goal (the origin) without a route.
        assert!(!a.update([0.8, 0.8], None) && !a.on, "1.13 m out");
        assert!(a.update([0.7, 0.7], None) && a.on, "0.99 m out");
        assert!(!a.update([1.0, 1.0], None) && a.on, "1.41 m out: still on");
        assert!(a.update([1.1, 1.1], None) && !a.on, "1.56 m out");
        // Along a route round a corner: 0.5 m from the goal, 2 m of route left.
        let mut route = Route {
            status: RouteStatus::Ok as u32,
            count: 3,
            ..Route::default()
        };
        route.waypoints[..3].copy_from_slice(&[[0.5, 2.0], [0.5, 0.0], [0.0, 0.0]]);
        assert!(!a.update([0.5, 1.5], Some(&route)) && !a.on);
        assert!(
            a.update([0.5, 0.4], Some(&route)) && a.on,
            "0.9 m of route left"
        );
        // The paper's arrival has none.
        let paper = Scenario {
            robot: protocol::Robot {
                final_approach: FinalApproach::Paper,
                ..scenario.robot.clone()
            },
            ..scenario
        };
        assert!(Approach::new(&paper).unwrap().is_none());
    }
}
