//! The occluders of the lidar fuzz (`--perception lidar`, [`super`]'s module docs): a
//! pillar in the map beside the way with a person standing behind it, in its shadow from
//! where the robot comes, who steps out across the way about when the robot comes by.
//! The case phantoms are for (docs/safety.md, "What the lidar cannot see").

use super::{STEP_IN_ACCEL, Way, step_in, walking};
use protocol::{Obstacle, distance};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// The share of the lidar worlds with an occluder and its person.
pub const OCCLUDED: f64 = 0.5;

/// Radii of the pillar and of the person, m.
pub const PILLAR_RADIUS_M: std::ops::Range<f64> = 0.5..1.0;
pub const PERSON_RADIUS_M: std::ops::Range<f64> = 0.2..0.35;

/// Between the pillar and the person stepping out past it, m.
pub const BEHIND_M: f64 = 0.1;

/// With probability [`OCCLUDED`]: a pillar at 30–70 % of the way, its edge 0.3–1 m (and
/// the robot's radius `footprint_m`) to either side of it, and a person behind it, on the
/// line through its centre from where a robot at 0.4–1.2 m/s on the way would be when
/// they leave, so hidden then, and far enough along the way to step out past the pillar
/// with [`BEHIND_M`] to spare (a person does not walk through a pillar: [`super::solid`]).
/// They leave so as to reach the way about when that robot reaches the pillar (their
/// place and their leaving found together, in two rounds), step out across the way to
/// 1 m past it, speeding up and
/// slowing down at [`STEP_IN_ACCEL`] (the tracker's bound, whether they are seen or not)
/// to at most 0.8–1.5 m/s, and stand there. None when the pillar would be within 0.3 m of
/// the start or the goal, or the person beyond the goal.
pub(super) fn pillar_and_person(
    rng: &mut ChaCha8Rng,
    way: &Way,
    footprint_m: f64,
) -> Option<[Obstacle; 2]> {
    if !rng.random_bool(OCCLUDED) {
        return None;
    }
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let along = way.span * rng.random_range(0.3..0.7);
    let pillar_radius = rng.random_range(PILLAR_RADIUS_M);
    let aside = footprint_m + rng.random_range(0.3..1.0) + pillar_radius;
    let [x, y] = way.at(along, side * aside);
    let radius = rng.random_range(PERSON_RADIUS_M);
    let speed = rng.random_range(0.8..1.5);
    let robot_speed = rng.random_range(0.4..1.2);
    let clear = |p: [f64; 2]| distance(p, [x, y]) > pillar_radius + footprint_m + 0.3;
    if !(clear(way.start) && clear(way.at(way.span, 0.0))) {
        return None;
    }
    let to_the_way_s = |aside: f64| aside / speed + speed / (2.0 * STEP_IN_ACCEL);
    let (mut leaves_s, mut behind, mut person_aside) = (0.0, along, aside);
    for _ in 0..2 {
        leaves_s = (along / robot_speed - to_the_way_s(person_aside)).max(0.5);
        // Behind the pillar on the line from where the robot is then (short of the
        // pillar), past it along the way by the two radii and `BEHIND_M`.
        let seen_from = (robot_speed * leaves_s)
            .min(along - pillar_radius - 0.5)
            .max(0.0);
        let (run, rise) = (along - seen_from, aside);
        let past = (pillar_radius + BEHIND_M + radius) / run;
        (behind, person_aside) = (along + run * past, aside + rise * past);
    }
    if behind > way.span - 0.5 {
        return None;
    }
    let path = step_in(person_aside + 1.0, speed, leaves_s)
        .map(|(t, walked)| {
            let [px, py] = way.at(behind, side * (person_aside - walked));
            [t, px, py]
        })
        .collect();
    Some([Obstacle::fixed(x, y, pillar_radius), walking(radius, path)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_person_stands_in_the_pillars_shadow_then_crosses_the_way_within_the_trackers_acceleration_bound()
     {
        let way = Way {
            start: [0.0, 0.0],
            along: [1.0, 0.0],
            normal: [0.0, 1.0],
            span: 10.0,
        };
        let mut drawn = 0;
        for seed in 0..200 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let Some([pillar, person]) = pillar_and_person(&mut rng, &way, 0.2) else {
                continue;
            };
            drawn += 1;
            assert!(PILLAR_RADIUS_M.contains(&pillar.radius));
            assert!(PERSON_RADIUS_M.contains(&person.radius));
            let (first, last) = (person.path[0], person.path[person.path.len() - 1]);
            // Behind the pillar as seen from a point of the way short of it, on the line
            // through its centre: in its shadow from there (the person is the smaller);
            // past it along the way, so that the walk keeps `BEHIND_M` from it.
            let past = first[1] - pillar.x - pillar.radius - person.radius;
            assert!((past - BEHIND_M).abs() < 1e-9, "{past}");
            for p in &person.path {
                let gap =
                    distance([p[1], p[2]], [pillar.x, pillar.y]) - pillar.radius - person.radius;
                assert!(gap >= BEHIND_M - 1e-9, "{gap}");
            }
            let slope = (first[1] - pillar.x) / (first[2] - pillar.y);
            let seen_from = pillar.x - slope * pillar.y;
            assert!((0.0..=pillar.x - pillar.radius - 0.5 + 1e-9).contains(&seen_from));
            assert_eq!([first[1], first[2]], [person.path[1][1], person.path[1][2]]);
            // Across the way to 1 m past it, within the tracker's acceleration bound.
            assert!(first[2] * pillar.y > 0.0 && (last[2] + pillar.y.signum()).abs() < 1e-9);
            for w in person.path.windows(3).skip(1) {
                let v = |a: &[f64; 3], b: &[f64; 3]| (b[2] - a[2]) / (b[0] - a[0]);
                let dv = (v(&w[1], &w[2]) - v(&w[0], &w[1])).abs();
                assert!(dv <= STEP_IN_ACCEL * 0.1 + 1e-9, "{dv}");
            }
            assert!((3.0..=7.0).contains(&pillar.x));
        }
        assert!((60..140).contains(&drawn), "{drawn} of 200 drawn");
    }
}
