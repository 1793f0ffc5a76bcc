//! Following the planner's route (docs/planner.md): the MPC's reference is a point
//! moving along the route at `planner.speed_m_s` from the robot's closest point on it,
//! stage by stage (position and velocity, `z_i = [x, xdot, y, ydot]`), coming to rest at
//! the route's end, the goal; once every stage's reference is the goal at rest, the MPC
//! solves the paper's problem itself (terminal analysis and all). The reference enters
//! the cost only; no constraint changes.

use protocol::{Route, distance};

/// The reference slows to rest at the goal at this deceleration, m/s^2: gently enough for
/// the paper's cost (`R = 100 Q`) to follow it without overshooting the goal.
pub const ARRIVAL_DECEL_M_S2: f64 = 0.1;

/// Writes into `reference[i]` (`i = 1..reference.len()`) the reference state of stage `i`
/// on `route` for a robot at `position`: from the robot's closest point on the route, each
/// stage `Ts` further at `speed_m_s`, or slower near the end so as to come to rest there at
/// [`ARRIVAL_DECEL_M_S2`], with that velocity along the route. Returns false when the reference is the goal at rest instead (no
/// route to follow, or every stage's point at the route's end).
pub fn reference(
    route: &Route,
    position: [f64; 2],
    speed_m_s: f64,
    ts_s: f64,
    reference: &mut [[f64; 4]],
) -> bool {
    if !route.is_ok() {
        return false;
    }
    let points = route.points();
    let (segment, at, _) = protocol::closest_on_polyline(points, position);
    let along_m = distance(points[segment], at);
    let length = protocol::polyline_length(&points[segment..]);
    let speed_at =
        |s: f64| speed_m_s.min((2.0 * ARRIVAL_DECEL_M_S2 * (length - s).max(0.0)).sqrt());
    let mut s = along_m;
    for z in reference.iter_mut().skip(1) {
        s = (s + ts_s * speed_at(s)).min(length);
        *z = state_at(points, segment, s, speed_at(s));
    }
    let goal = points[points.len() - 1];
    reference[1..]
        .iter()
        .any(|z| *z != [goal[0], 0.0, goal[1], 0.0])
}

/// The state `distance_m` along `points` from the start of segment `segment`, moving at
/// `speed_m_s` along it; at rest at the end.
fn state_at(points: &[[f64; 2]], segment: usize, distance_m: f64, speed_m_s: f64) -> [f64; 4] {
    let mut left = distance_m;
    for w in points[segment..].windows(2) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::RouteStatus;

    fn route(points: &[[f64; 2]]) -> Route {
        let mut r = Route {
            status: RouteStatus::Ok as u32,
            count: points.len() as u32,
            ..Route::default()
        };
        r.waypoints[..points.len()].copy_from_slice(points);
        r
    }

    #[test]
    fn the_reference_moves_along_the_route_at_the_speed_and_comes_to_rest_at_the_goal() {
        let r = route(&[[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]]);
        let mut z = [[f64::NAN; 4]; 4];
        // From (1, -0.5): closest point (1, 0); 1 m/s, 1 s a stage, far from the end.
        assert!(reference(&r, [1.0, -0.5], 1.0, 1.0, &mut z));
        assert!(z[0][0].is_nan(), "stage 0 is the robot's own");
        assert_eq!(z[1], [2.0, 1.0, 0.0, 0.0]);
        assert_eq!(z[3], [4.0, 1.0, 0.0, 0.0]);
        // Round the corner: 3.5 m on from (37, 0) is (40, 0.5), going up.
        assert!(reference(&r, [37.0, 0.0], 3.5, 1.0, &mut z));
        assert_eq!(z[1], [40.0, 0.0, 0.5, 3.5]);
        // Near the end the reference slows to rest at the goal.
        let mut z = [[f64::NAN; 4]; 40];
        assert!(reference(&r, [2.0, 40.1], 1.0, 1.0, &mut z));
        let speeds: Vec<f64> = z[1..].iter().map(|z| z[1].hypot(z[3])).collect();
        assert!(speeds.windows(2).all(|w| w[1] <= w[0]), "{speeds:?}");
        assert_eq!(z[39], [0.0, 0.0, 40.0, 0.0]);
        for (z, speed) in z[1..].iter().zip(&speeds) {
            let left = z[0];
            assert!(speed * speed <= 2.0 * ARRIVAL_DECEL_M_S2 * left + 1e-9);
        }
        // Every stage at the goal, or no route: the goal itself.
        let mut z = [[f64::NAN; 4]; 4];
        assert!(!reference(&r, [0.0, 40.1], 1.0, 1.0, &mut z));
        assert!(!reference(&Route::default(), [1.0, 0.0], 1.0, 1.0, &mut z));
    }
}
