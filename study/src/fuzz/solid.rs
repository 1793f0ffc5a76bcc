//! Obstacles at rest are solid to the people of the fuzz ([`super`]'s module docs). A
//! person drawn walking through a pillar or a box would come out of it beside the robot
//! (of the worlds of seed 1 with contacts at rest on 2026-11-30, 14 of 19 had one, and 28
//! of 29 lidar worlds, where no shadow has its edge there and no phantom stands), and no
//! person walks through one. So a person who walks at a constant velocity stops short of
//! the first obstacle at rest in their way, braking at [`STEP_IN_ACCEL`] (the tracker's
//! bound) to stand [`STAND_OFF_M`] back along their way from where they would touch it;
//! one who cannot, or whose path (stepping into the way) would take them through one, is
//! left out of the world.

use super::{STEP_IN_ACCEL, walking};
use protocol::{Obstacle, Scenario, distance};

/// The people of `s` kept out of its obstacles at rest ([`kept_out`]), in their order.
pub(super) fn keep_people_out(s: &mut Scenario) {
    let at_rest: Vec<Obstacle> = s.obstacles.iter().filter(|o| !o.moves()).cloned().collect();
    let duration_s = s.duration_s;
    s.obstacles = std::mem::take(&mut s.obstacles)
        .into_iter()
        .filter_map(|o| match o.moves() {
            true => kept_out(o, &at_rest, duration_s),
            false => Some(o),
        })
        .collect();
}

/// How far short of where they would touch an obstacle at rest a person stops, along
/// their way, m.
pub const STAND_OFF_M: f64 = 0.05;

/// How often [`walks_through`] checks where a person on a path is, s: a person at
/// 1.5 m/s moves 7.5 cm in it, less than a person's radius.
const WALK_CHECK_S: f64 = 0.05;

/// `person` in a world where `at_rest` are solid, over `duration_s` (module docs): as
/// drawn if they touch none; walking at their velocity until they brake to stand short of
/// the first they would touch; `None` if they cannot stop short of it or touch it at
/// the start, or walk a path through one.
pub(super) fn kept_out(
    person: Obstacle,
    at_rest: &[Obstacle],
    duration_s: f64,
) -> Option<Obstacle> {
    if !person.path.is_empty() {
        return (!walks_through(&person, at_rest, duration_s)).then_some(person);
    }
    let Some(touch_s) = first_touch_s(&person, at_rest) else {
        return Some(person);
    };
    if touch_s > duration_s {
        return Some(person);
    }
    let [vx, vy] = person.velocity;
    let speed = vx.hypot(vy);
    let stand_m = speed * touch_s - STAND_OFF_M;
    let brake_m = speed * speed / (2.0 * STEP_IN_ACCEL);
    if stand_m < brake_m {
        return None;
    }
    let brakes_at_s = (stand_m - brake_m) / speed;
    let brake_s = speed / STEP_IN_ACCEL;
    let along = |t: f64| {
        let into = (t - brakes_at_s).clamp(0.0, brake_s);
        speed * t.min(brakes_at_s) + speed * into - 0.5 * STEP_IN_ACCEL * into * into
    };
    let point = |t: f64| {
        let d = along(t) / speed;
        [t, person.x + vx * d, person.y + vy * d]
    };
    let steps = (brake_s / 0.1).ceil() as usize;
    // Every 0.1 s to the first such time at rest (`protocol::PATH_CORNER_S`), from a
    // first point at least 0.1 s before they brake: one who brakes at once (sooner than
    // 0.1 s into the run) was walking before it, and a first point before the run has
    // no corner, so their first change of velocity is spread over 0.1 s like the others.
    let braking = (0..=steps).map(|k| point(brakes_at_s + k as f64 * 0.1));
    let first_s = (brakes_at_s - 0.1).min(0.0);
    let path = std::iter::once(point(first_s)).chain(braking).collect();
    Some(walking(person.radius, path))
}

/// When `person`, walking at their velocity, first touches one of `at_rest`, s: `Some(0)`
/// if they touch one at the start, `None` if never.
fn first_touch_s(person: &Obstacle, at_rest: &[Obstacle]) -> Option<f64> {
    first_touch(
        [person.x, person.y],
        person.velocity,
        person.radius,
        at_rest,
    )
}

/// How far a person of `radius` (m) at `from` can walk along the unit vector `direction`
/// before they stand [`STAND_OFF_M`] short of one of `at_rest`, m (0 if they touch one
/// already; infinite if none is in their way).
pub(super) fn room_m(
    from: [f64; 2],
    direction: [f64; 2],
    radius: f64,
    at_rest: &[Obstacle],
) -> f64 {
    first_touch(from, direction, radius, at_rest)
        .map_or(f64::INFINITY, |m| (m - STAND_OFF_M).max(0.0))
}

/// The first `t` at which a disc of `radius` from `from` moving at `velocity` touches one
/// of `at_rest` (`Some(0)` if it does at the start; `None` if never).
fn first_touch(
    from: [f64; 2],
    velocity: [f64; 2],
    radius: f64,
    at_rest: &[Obstacle],
) -> Option<f64> {
    let [vx, vy] = velocity;
    let a = vx * vx + vy * vy;
    at_rest
        .iter()
        .filter_map(|o| {
            // |d + v t| = R: a t^2 + b t + c = 0.
            let reach = o.radius + radius;
            let d = [from[0] - o.x, from[1] - o.y];
            let (b, c) = (
                2.0 * (d[0] * vx + d[1] * vy),
                d[0] * d[0] + d[1] * d[1] - reach * reach,
            );
            if c <= 0.0 {
                return Some(0.0);
            }
            let discriminant = b * b - 4.0 * a * c;
            (a > 0.0 && discriminant >= 0.0 && b < 0.0)
                .then(|| (-b - discriminant.sqrt()) / (2.0 * a))
        })
        .min_by(f64::total_cmp)
}

/// Whether `person` touches one of `at_rest` within `duration_s`, checked every
/// [`WALK_CHECK_S`].
fn walks_through(person: &Obstacle, at_rest: &[Obstacle], duration_s: f64) -> bool {
    let samples = (duration_s / WALK_CHECK_S).ceil() as usize;
    (0..=samples).any(|k| {
        let p = person.center_at(k as f64 * WALK_CHECK_S);
        at_rest
            .iter()
            .any(|o| distance(p, [o.x, o.y]) < o.radius + person.radius)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A person of radius 0.3 m walking along y = `y` at 1 m/s from x = 0.
    fn walker(y: f64) -> Obstacle {
        Obstacle {
            velocity: [1.0, 0.0],
            ..Obstacle::fixed(0.0, y, 0.3)
        }
    }

    #[test]
    fn a_person_stops_short_of_a_pillar_in_their_way_within_the_trackers_acceleration_bound() {
        let pillar = [Obstacle::fixed(5.0, 0.0, 1.0)];
        // Along y = 1.4 they pass 10 cm clear, and are kept as drawn.
        assert_eq!(kept_out(walker(1.4), &pillar, 40.0), Some(walker(1.4)));
        // Along y = 1.25 they would touch it at about 3.9 s: they stand short of it.
        let stopped = kept_out(walker(1.25), &pillar, 40.0).expect("room to stop");
        let end = stopped.path[stopped.path.len() - 1][0];
        let touch_x = 5.0 - (1.3f64.powi(2) - 1.25f64.powi(2)).sqrt();
        let [x, y] = stopped.center_at(end + 1.0);
        assert!(
            (x - (touch_x - STAND_OFF_M)).abs() < 1e-9 && y == 1.25,
            "{x}"
        );
        let gap = |t: f64| distance(stopped.center_at(t), [5.0, 0.0]) - 1.3;
        assert!((0..=400).all(|k| gap(f64::from(k) * 0.1) > 0.0));
        // At their speed until they brake, then slowing within the bound.
        assert_eq!(stopped.center_at(1.0), [1.0, 1.25]);
        assert_slows_within_the_bound(&stopped, [1.0, 0.0]);
        // Not there before the run ends: as drawn.
        assert_eq!(kept_out(walker(1.25), &pillar, 3.0), Some(walker(1.25)));
        // Too close to stop, or touching from the start: left out.
        let near = Obstacle {
            x: 4.0,
            ..walker(1.25)
        };
        assert_eq!(kept_out(near, &pillar, 40.0), None);
        assert_eq!(
            kept_out(walker(0.0), &[Obstacle::fixed(0.2, 0.0, 0.3)], 40.0),
            None
        );
    }

    /// `person`'s velocity, checked every 10 ms from the start of the run until after
    /// their path ends: `start` at first (or within half a corner's change of it, if they
    /// brake sooner than 0.05 s into the run), then never changing faster than
    /// [`STEP_IN_ACCEL`], and at rest at the end.
    fn assert_slows_within_the_bound(person: &Obstacle, start: [f64; 2]) {
        let end = person.path[person.path.len() - 1][0];
        let v = |k: u32| person.velocity_at(f64::from(k) * 0.01);
        let steps = (end / 0.01).ceil() as u32 + 10;
        assert!(
            distance(v(0), start) <= STEP_IN_ACCEL * 0.05 + 1e-9,
            "{:?}",
            v(0)
        );
        for k in 0..steps {
            let dv = distance(v(k + 1), v(k));
            assert!(dv <= STEP_IN_ACCEL * 0.01 + 1e-9, "{dv} m/s at {k}0 ms");
        }
        assert_eq!(v(steps), [0.0, 0.0]);
    }

    #[test]
    fn a_person_who_must_brake_at_once_still_slows_within_the_bound() {
        // Walking at 1 m/s, they need 1 m to stop and have 1.001 m or 1.01 m (they would
        // touch the pillar at 1.051 s or 1.06 s): they brake 1 ms or 10 ms into the run.
        for (pillar_x, brakes_at_s) in [(2.351, 0.001), (2.36, 0.01)] {
            let pillar = [Obstacle::fixed(pillar_x, 0.0, 1.0)];
            let stopped = kept_out(walker(0.0), &pillar, 40.0).expect("room to stop");
            assert!(stopped.path[0][0] < 0.0, "{:?}", stopped.path[0]);
            assert!((stopped.path[1][0] - brakes_at_s).abs() < 1e-9);
            assert!(distance(stopped.center_at(0.0), [0.0, 0.0]) < 1e-3);
            assert_slows_within_the_bound(&stopped, [1.0, 0.0]);
            let gap = |k: u32| distance(stopped.center_at(f64::from(k) * 0.01), [pillar_x, 0.0]);
            assert!((0..=400).all(|k| gap(k) > 1.3), "{pillar_x}");
        }
    }

    #[test]
    fn a_person_whose_path_goes_through_an_obstacle_at_rest_is_left_out() {
        let path = vec![[0.0, 0.0, 1.25], [10.0, 10.0, 1.25]];
        let person = walking(0.3, path);
        let pillar = [Obstacle::fixed(5.0, 0.0, 1.0)];
        assert_eq!(kept_out(person.clone(), &pillar, 40.0), None);
        assert!(kept_out(person, &[Obstacle::fixed(5.0, -1.0, 1.0)], 40.0).is_some());
    }
}
