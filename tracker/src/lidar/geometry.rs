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
    fn one_point_is_a_circle_of_radius_zero_and_points_on_a_line_are_held() {
        assert_eq!(enclosing_circle(&[[1.0, 2.0]]), ([1.0, 2.0], 0.0));
        let line: Vec<[f64; 2]> = (0..10).map(|i| [f64::from(i), 0.0]).collect();
        let (centre, radius) = enclosing_circle(&line);
        assert!(distance(centre, [4.5, 0.0]) < 1e-9 && (radius - 4.5).abs() < 1e-9);
    }
}
