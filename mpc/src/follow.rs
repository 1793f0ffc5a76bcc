//! Following the planner's route (docs/planner.md): the MPC's reference is a point
//! moving along the route from the robot's closest point on it, stage by stage (position
//! and velocity, `z_i = [x, xdot, y, ydot]`), at a speed that fits the robot
//! ([`SpeedProfile`]): a cruising speed, slower on bends so that `zeta^2 kappa` stays within
//! the input box, and coming to rest at the route's end, the goal. Once every stage's
//! reference is the goal at rest, the MPC solves the paper's problem itself. The reference
//! enters the cost, and the terminal set is taken about its last stage (a sub-goal,
//! [`crate::terminal_set`]); no safety row changes.

use protocol::{Route, distance};

/// The reference slows at this deceleration, m/s^2, to rest at the goal and to a bend's
/// speed: gently enough for the paper's cost (`R = 100 Q`) to follow it without
/// overshooting.
pub const ARRIVAL_DECEL_M_S2: f64 = 0.1;

/// How fast the reference moves along a route.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedProfile {
    /// Cruising speed, m/s.
    pub cruise_m_s: f64,
    /// The largest `zeta^2 kappa` on a bend, m/s^2 (`mpc.v_max`: the input box bounds the
    /// flat outputs' acceleration, the centripetal one included).
    pub lateral_m_s2: f64,
}

impl SpeedProfile {
    /// The speed limit `at_m` along `points` (from its first point), m/s: the cruising
    /// speed, lowered so that the reference can slow at [`ARRIVAL_DECEL_M_S2`] to
    /// `sqrt(lateral / kappa)` at every corner ahead and to rest at the end. A corner turning
    /// by `theta` between pieces of lengths `a` and `b` has `kappa = theta / min(a, b)`:
    /// the planner writes an arc of radius `R` as the corners of a circumscribed polygon,
    /// pieces of about `R theta`.
    pub fn limit(&self, points: &[[f64; 2]], at_m: f64) -> f64 {
        let reach = |to_m: f64, speed: f64| {
            (speed * speed + 2.0 * ARRIVAL_DECEL_M_S2 * (to_m - at_m).max(0.0)).sqrt()
        };
        let mut limit = self.cruise_m_s;
        let mut corner_m = 0.0;
        for w in points.windows(3) {
            let (before, after) = (distance(w[0], w[1]), distance(w[1], w[2]));
            corner_m += before;
            if corner_m < at_m || before == 0.0 || after == 0.0 {
                continue;
            }
            let heading = |p: [f64; 2], q: [f64; 2]| (q[1] - p[1]).atan2(q[0] - p[0]);
            let turn = protocol::wrap_angle(heading(w[1], w[2]) - heading(w[0], w[1])).abs();
            if turn > 0.0 {
                let kappa = turn / before.min(after);
                limit = limit.min(reach(corner_m, (self.lateral_m_s2 / kappa).sqrt()));
            }
        }
        limit.min(reach(protocol::polyline_length(points), 0.0))
    }
}

/// Writes into `reference[i]` (`i = 1..reference.len()`) the reference state of stage `i`
/// on `route` for a robot at `position`: from the robot's closest point on the route, each
/// stage `Ts` further at the speed `profile` allows there, with that velocity along the
/// route. Returns false when the reference is the goal at rest instead (no route to
/// follow, or every stage's point at the route's end).
pub fn reference(
    route: &Route,
    position: [f64; 2],
    profile: &SpeedProfile,
    ts_s: f64,
    reference: &mut [[f64; 4]],
) -> bool {
    if !route.is_ok() {
        return false;
    }
    let points = route.points();
    let (segment, at, _) = protocol::closest_on_polyline(points, position);
    let ahead = &points[segment..];
    let length = protocol::polyline_length(ahead);
    let mut s = distance(points[segment], at);
    // The limit at each stage's point serves twice: its velocity, and the step to the next.
    let mut speed = profile.limit(ahead, s);
    for z in reference.iter_mut().skip(1) {
        s = (s + ts_s * speed).min(length);
        speed = profile.limit(ahead, s);
        *z = state_at(ahead, s, speed);
    }
    let goal = points[points.len() - 1];
    reference[1..]
        .iter()
        .any(|z| *z != [goal[0], 0.0, goal[1], 0.0])
}

/// The state `distance_m` along `points`, moving at `speed_m_s` along it; at rest at the
/// end.
fn state_at(points: &[[f64; 2]], distance_m: f64, speed_m_s: f64) -> [f64; 4] {
    let mut left = distance_m;
    for w in points.windows(2) {
        let length = distance(w[0], w[1]);
        if left <= length && length > 0.0 {
            let (dx, dy) = ((w[1][0] - w[0][0]) / length, (w[1][1] - w[0][1]) / length);
            return [
                w[0][0] + left * dx,
                speed_m_s * dx,
                w[0][1] + left * dy,
                speed_m_s * dy,
            ];
        }
        left -= length;
    }
    let end = points[points.len() - 1];
    [end[0], 0.0, end[1], 0.0]
}

/// The route's speed profile: cruising no faster than `planner.speed_m_s` (unless `auto`),
/// than the wheels turn (`plant.max_wheel_speed_rad_s` times the wheel radius, when
/// limited), and than a robot can follow a point `N` samples ahead of it and still come to
/// rest at that point within the input box under the LQR
/// ([`crate::terminal_set::tracking_speed`]: then the route's reference at stage `N` is
/// its own sub-goal); on bends, `zeta^2 kappa <= mpc.v_max`.
pub fn route_speed(
    scenario: &protocol::Scenario,
    terminal_set: &[crate::terminal_set::SetRow],
) -> SpeedProfile {
    let lead_s = scenario.mpc.horizon as f64 * scenario.timing.ts_s;
    let mut cruise_m_s = crate::terminal_set::tracking_speed(terminal_set, lead_s);
    if let protocol::AutoOr::Value(bound) = scenario.planner.speed_m_s {
        cruise_m_s = cruise_m_s.min(bound);
    }
    let p = &scenario.plant;
    if p.max_wheel_speed_rad_s > 0.0 {
        cruise_m_s = cruise_m_s.min(p.max_wheel_speed_rad_s * p.wheel_radius_m);
    }
    SpeedProfile {
        cruise_m_s,
        lateral_m_s2: scenario.mpc.v_max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn route(points: &[[f64; 2]]) -> Route {
        Route::through(points).unwrap()
    }

    const GENTLE: SpeedProfile = SpeedProfile {
        cruise_m_s: 1.0,
        lateral_m_s2: 1.0,
    };

    #[test]
    fn the_reference_moves_along_the_route_at_cruise_and_comes_to_rest_at_the_goal() {
        let r = route(&[[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]]);
        let mut z = [[f64::NAN; 4]; 4];
        // From (1, -0.5): closest point (1, 0); 1 m/s, 1 s a stage, far from the end and
        // from the corner (kappa = (pi / 2) / 40 m: 5 m/s there).
        assert!(reference(&r, [1.0, -0.5], &GENTLE, 1.0, &mut z));
        assert!(z[0][0].is_nan(), "stage 0 is the robot's own");
        assert_eq!(z[1], [2.0, 1.0, 0.0, 0.0]);
        assert_eq!(z[3], [4.0, 1.0, 0.0, 0.0]);
        // Near the end the reference slows to rest at the goal.
        let mut z = [[f64::NAN; 4]; 40];
        assert!(reference(&r, [2.0, 40.1], &GENTLE, 1.0, &mut z));
        let speeds: Vec<f64> = z[1..].iter().map(|z| z[1].hypot(z[3])).collect();
        assert!(speeds.windows(2).all(|w| w[1] <= w[0]), "{speeds:?}");
        assert_eq!(z[39], [0.0, 0.0, 40.0, 0.0]);
        for (z, speed) in z[1..].iter().zip(&speeds) {
            let left = z[0];
            assert!(speed * speed <= 2.0 * ARRIVAL_DECEL_M_S2 * left + 1e-9);
        }
        // Every stage at the goal, or no route: the goal itself.
        let mut z = [[f64::NAN; 4]; 4];
        assert!(!reference(&r, [0.0, 40.1], &GENTLE, 1.0, &mut z));
        assert!(!reference(
            &Route::default(),
            [1.0, 0.0],
            &GENTLE,
            1.0,
            &mut z
        ));
    }

    #[test]
    fn on_a_bend_the_reference_slows_so_that_its_centripetal_acceleration_fits_the_box() {
        // Half a circle of radius 1 m written as the planner writes arcs (corners of a
        // circumscribed polygon, 30 degrees a corner), between two 60 m straights.
        let step = std::f64::consts::PI / 6.0;
        let outer = 1.0 / (step / 2.0).cos();
        let mut points = vec![[-60.0, -1.0]];
        for i in 0..6 {
            let angle = -std::f64::consts::FRAC_PI_2 + (i as f64 + 0.5) * step;
            points.push([outer * angle.cos(), outer * angle.sin()]);
        }
        points.push([-60.0, 1.0]);
        let fast = SpeedProfile {
            cruise_m_s: 3.0,
            lateral_m_s2: 0.5,
        };
        // At every corner of the arc: zeta^2 / R within 0.5 m/s^2 (to the 2.3 % by which
        // the polygon's corners turn less sharply than the circle).
        let mut at_m = 0.0;
        for c in 1..points.len() - 1 {
            at_m += distance(points[c - 1], points[c]);
            if (2..=5).contains(&c) {
                let speed = fast.limit(&points, at_m);
                assert!(speed * speed <= 0.5 * 1.025, "{speed} m/s at corner {c}");
                assert!(speed > 0.6, "{speed} m/s at corner {c}");
            }
        }
        // Far before the bend: cruise; before it, slowing at the arrival deceleration.
        assert_eq!(fast.limit(&points, 0.0), 3.0);
        let before = fast.limit(&points, 55.0);
        assert!(before < 3.0 && before > 0.8, "{before}");
    }
}
