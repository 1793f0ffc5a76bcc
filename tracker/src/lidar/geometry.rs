//! The disc of a group of points: the smallest circle enclosing them (Welzl's incremental
//! algorithm, which allocates nothing, and runs in expected linear time on points in random
//! order: the caller shuffles points that come in scan order).

/// A centre, m, and a radius, m.
pub type Circle = ([f64; 2], f64);

/// The smallest circle holding every point of `points` (none: a zero circle at the origin).
pub fn enclosing_circle(points: &[[f64; 2]]) -> Circle {
    let n = points.len();
    let at = |k: usize| points[k];
    if n == 0 {
        return ([0.0; 2], 0.0);
    }
    let mut circle = (at(0), 0.0);
    for i in 1..n {
        let p = at(i);
        if holds(&circle, p) {
            continue;
        }
        circle = (p, 0.0);
        for j in 0..i {
            let q = at(j);
            if holds(&circle, q) {
                continue;
            }
            circle = diametral(p, q);
            for k in 0..j {
                let r = at(k);
                if !holds(&circle, r) {
                    circle = circumscribed(p, q, r);
                }
            }
        }
    }
    circle
}

/// `circle`, which holds `points` (the returns of one group, seen from `viewer`), moved
/// straight away from the viewer and grown to hold them still, until its near side is no
/// more than `tolerance_m` nearer the viewer than the nearest point, or its radius is
/// `most_radius_m`. For an arc of a circle that is the arc's own circle, where the smallest
/// circle of the arc sits on its chord and reaches out in front of the face seen; a flat
/// face, or an arc too short to tell its circle, moves until the radius is at the cap. The
/// circle moves continuously with the points, so a track fed with it does not jump as
/// less or more of its obstacle is seen.
///
/// Closed form, one pass per bound: with the centre at `c + s u` (`u` away from the
/// viewer, `q = p - c` for each point `p`), the near side `|c - viewer| + s - |q - s u|`
/// clears `nearest - tolerance_m` for point `p` (`|q - s u| <= s + k`, with `k = |c -
/// viewer| - nearest + tolerance_m` and `s + k >= 0`) once `s >= (|q|^2 - k^2) / (2 (k +
/// q.u))`, never if `k + q.u <= 0`; and `|q - s u| <= most_radius_m` while `s <= q.u
/// + sqrt(most_radius_m^2 - |q|^2 + (q.u)^2)`.
pub fn behind_the_face(
    points: &[[f64; 2]],
    circle: Circle,
    viewer: [f64; 2],
    most_radius_m: f64,
    tolerance_m: f64,
) -> Circle {
    let (centre, radius) = circle;
    let range = distance(centre, viewer);
    let Some(nearest) = points.iter().map(|&p| distance(p, viewer)).reduce(f64::min) else {
        return circle;
    };
    let k = range - (nearest - tolerance_m);
    if range < 1e-9 || most_radius_m <= radius {
        return circle;
    }
    let u = [
        (centre[0] - viewer[0]) / range,
        (centre[1] - viewer[1]) / range,
    ];
    // The bound below squares `|q - s u| <= s + k`, which needs `s + k >= 0`.
    let (mut face, mut cap) = ((-k).max(0.0), f64::INFINITY);
    for p in points {
        let q = [p[0] - centre[0], p[1] - centre[1]];
        let (along, q2) = (q[0] * u[0] + q[1] * u[1], q[0] * q[0] + q[1] * q[1]);
        // No point is farther than `radius < most_radius_m` at `s = 0`: a positive root.
        cap = cap.min(along + (most_radius_m * most_radius_m - q2 + along * along).sqrt());
        face = match k + along {
            // Never clear of this point: only the cap stops the circle.
            gain if gain <= 0.0 => f64::INFINITY,
            gain => face.max((q2 - k * k) / (2.0 * gain)),
        };
    }
    let s = face.min(cap);
    if !(s.is_finite() && s > 0.0) {
        return circle;
    }
    let moved = [centre[0] + s * u[0], centre[1] + s * u[1]];
    let reach = points
        .iter()
        .fold(0.0, |r: f64, &p| r.max(distance(moved, p)));
    (moved, reach)
}

/// Whether `circle` holds `p` (to a nanometre).
fn holds(circle: &Circle, p: [f64; 2]) -> bool {
    distance(circle.0, p) <= circle.1 + 1e-9
}

/// The distance between two points, m.
pub fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The circle on the segment `a b` as its diameter.
fn diametral(a: [f64; 2], b: [f64; 2]) -> Circle {
    (
        [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0],
        distance(a, b) / 2.0,
    )
}

/// The circle through `a`, `b` and `c`; for points (nearly) on a line, the circle on the
/// two farthest apart.
fn circumscribed(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> Circle {
    let (bx, by) = (b[0] - a[0], b[1] - a[1]);
    let (cx, cy) = (c[0] - a[0], c[1] - a[1]);
    let d = 2.0 * (bx * cy - by * cx);
    let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
    if d.abs() < 1e-12 * (b2 + c2).max(1e-12) {
        return [diametral(a, b), diametral(a, c), diametral(b, c)]
            .into_iter()
            .fold(
                ([0.0; 2], -1.0),
                |best, c| if c.1 > best.1 { c } else { best },
            );
    }
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    ([a[0] + ux, a[1] + uy], ux.hypot(uy))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_enclosing_circle_of_an_arc_is_on_its_chord_and_of_a_full_ring_is_the_ring() {
        // A half circle of radius 1 about (2, 0): its chord is a diameter.
        let arc: Vec<[f64; 2]> = (0..=90)
            .map(|i| {
                let a = std::f64::consts::PI * f64::from(i) / 90.0;
                [2.0 + a.cos(), a.sin()]
            })
            .collect();
        let (centre, radius) = enclosing_circle(&arc);
        assert!(distance(centre, [2.0, 0.0]) < 1e-9, "{centre:?}");
        assert!((radius - 1.0).abs() < 1e-9, "{radius}");
        // A third of it: the circle on its chord, smaller than the ring.
        let (centre, radius) = enclosing_circle(&arc[..31]);
        let chord = distance(arc[0], arc[30]);
        assert!((radius - chord / 2.0).abs() < 1e-9, "{radius} vs {chord}");
        assert!(
            arc[..31]
                .iter()
                .all(|p| distance(centre, *p) <= radius + 1e-9)
        );
    }

    #[test]
    fn an_arc_seen_from_one_side_gets_its_own_circle_back_and_a_flat_face_one_at_the_cap_behind_it()
    {
        // A box of radius 0.5 at (3, 0) seen from the origin over 120 degrees of its face.
        let arc: Vec<[f64; 2]> = (0..=40)
            .map(|i| {
                let a = std::f64::consts::PI * (1.0 + (f64::from(i) - 20.0) / 60.0);
                [3.0 + 0.5 * a.cos(), 0.5 * a.sin()]
            })
            .collect();
        let enclosing = enclosing_circle(&arc);
        // On the chord, reaching 0.18 m out in front of the face (the face is at 2.5 m).
        assert!(enclosing.0[0] - enclosing.1 < 2.35, "{enclosing:?}");
        // Its own circle, to within the tolerance allowed in front of the face (1 mm)
        // either way.
        let tolerance = 1e-3;
        let (centre, radius) =
            behind_the_face(&arc, enclosing, [0.0; 2], 1.5 * enclosing.1, tolerance);
        assert!(distance(centre, [3.0, 0.0]) < 3.0 * tolerance, "{centre:?}");
        assert!((radius - 0.5).abs() < 3.0 * tolerance, "{radius}");
        assert!(arc.iter().all(|p| distance(centre, *p) <= radius + 1e-9));
        // A flat face 1 m wide, across the view: the circle goes back until its radius is
        // at the cap, and still holds the face.
        let face: Vec<[f64; 2]> = (0..=20).map(|i| [3.0, f64::from(i) / 20.0 - 0.5]).collect();
        let enclosing = enclosing_circle(&face);
        let (centre, radius) = behind_the_face(&face, enclosing, [0.0; 2], 0.75, 0.0);
        assert!((radius - 0.75).abs() < 1e-6, "{radius}");
        // Its ends are at the cap: the centre is sqrt(0.75^2 - 0.5^2) behind the face.
        let behind = (0.75f64 * 0.75 - 0.5 * 0.5).sqrt();
        assert!((centre[0] - 3.0 - behind).abs() < 1e-6, "{centre:?}");
        assert!(face.iter().all(|p| distance(centre, *p) <= radius + 1e-9));
    }

    #[test]
    fn one_point_is_a_circle_of_radius_zero_and_points_on_a_line_are_held() {
        assert_eq!(enclosing_circle(&[[1.0, 2.0]]), ([1.0, 2.0], 0.0));
        let line: Vec<[f64; 2]> = (0..10).map(|i| [f64::from(i), 0.0]).collect();
        let (centre, radius) = enclosing_circle(&line);
        assert!(distance(centre, [4.5, 0.0]) < 1e-9 && (radius - 4.5).abs() < 1e-9);
    }
}
