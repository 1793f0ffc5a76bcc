//! The shortest path around discs: Dijkstra on the tangent visibility graph.
//!
//! Among disjoint or overlapping discs in the plane, a shortest path from `s` to `g` that
//! stays outside every open disc is made of straight segments tangent to the discs it
//! touches and arcs of their circles between the tangent points. The graph therefore
//! holds, as nodes, `s`, `g` and the tangent points of every line from `s` or `g` to a
//! circle and of every line tangent to two circles (the two outer and, for disjoint discs,
//! the two inner tangents); as edges, each such segment that enters no disc and leaves
//! no box side, and on each circle the arc between two angularly adjacent tangent points
//! that no other disc and no box side cuts. The search is exact for circles: it finds the
//! shortest path if one exists, and reports none only when `s` and `g` are not connected
//! in the free space (a route that leaves the box is no route).
//!
//! Cost for `n` discs: `O(n^2)` tangents, each checked against every disc (`O(n^3)`
//! segment tests: 17,000 for 20 discs), then Dijkstra on `O(n^2)` nodes. Every buffer is
//! reserved for `n` discs up front ([`TangentGraph::with_capacity`]), so a search does not
//! allocate.

use protocol::{Disc, distance};
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::TAU;

/// The axis-aligned box every route stays in: `[min, max]` per axis, m.
pub type Bounds = [[f64; 2]; 2];

/// How far inside a disc a tangent may dip by rounding and still count as outside, m.
const TOUCH_TOLERANCE_M: f64 = 1e-9;

/// No path joins the start and the goal outside the discs and inside the box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("no route: the start and the goal are not connected around the obstacles")]
pub struct NoRoute;

/// A node: `s`, `g`, or a tangent point on a circle at `angle` (rad).
#[derive(Debug, Clone, Copy)]
struct Node {
    point: [f64; 2],
    /// The disc the point lies on (`None`: the start or the goal).
    disc: Option<u32>,
    angle: f64,
}

/// An undirected edge: a tangent segment, or an arc between two nodes of one circle.
#[derive(Debug, Clone, Copy)]
struct Edge {
    a: u32,
    b: u32,
    length: f64,
}

/// A queue entry of Dijkstra's search, ordered by distance (smallest first).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Queued(f64, u32);

impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Queued {
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

/// One piece of a shortest path: a straight segment to `to`, or an arc of a circle to it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Leg {
    Straight {
        to: [f64; 2],
    },
    /// Along the circle of `disc` from the previous point, turning by `sweep` rad
    /// (positive: counter-clockwise), to `to`.
    Arc {
        disc: Disc,
        from_angle: f64,
        sweep: f64,
        to: [f64; 2],
    },
}

/// The graph's buffers, reused by every search.
#[derive(Debug, Default)]
pub struct TangentGraph {
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    /// Node indices of each circle, sorted by angle (scratch).
    on_circle: Vec<u32>,
    /// Angular intervals `(centre, half width)` of a circle cut by other discs or the box.
    blocked: Vec<(f64, f64)>,
    /// Adjacency in compressed rows: `first[v]..first[v + 1]` index `adjacent`.
    first: Vec<u32>,
    adjacent: Vec<(u32, f64)>,
    distance: Vec<f64>,
    previous: Vec<u32>,
    queue: BinaryHeap<Queued>,
    legs: Vec<Leg>,
}

impl TangentGraph {
    /// Buffers for searches among up to `discs` discs (larger searches still work; they
    /// allocate).
    pub fn with_capacity(discs: usize) -> TangentGraph {
        let nodes = 2 + 4 * discs + 8 * discs * discs.saturating_sub(1) / 2;
        let edges = 1 + 4 * discs + 4 * discs * discs.saturating_sub(1) / 2 + nodes;
        TangentGraph {
            nodes: Vec::with_capacity(nodes),
            edges: Vec::with_capacity(edges),
            on_circle: Vec::with_capacity(nodes),
            blocked: Vec::with_capacity(discs + 4),
            first: Vec::with_capacity(nodes + 1),
            adjacent: Vec::with_capacity(2 * edges),
            distance: Vec::with_capacity(nodes),
            previous: Vec::with_capacity(nodes),
            queue: BinaryHeap::with_capacity(2 * edges + nodes),
            legs: Vec::with_capacity(nodes),
        }
    }

    /// The shortest path from `start` to `goal` outside every disc and inside `bounds`,
    /// as legs from `start` (the last ends at `goal`). The start and the goal must lie
    /// outside every disc and inside the box (the caller shrinks discs that hold them).
    pub fn shortest_path(
        &mut self,
        start: [f64; 2],
        goal: [f64; 2],
        discs: &[Disc],
        bounds: Bounds,
    ) -> Result<&[Leg], NoRoute> {
        self.build(start, goal, discs, bounds);
        self.search()?;
        self.trace(discs);
        Ok(&self.legs)
    }

    fn build(&mut self, start: [f64; 2], goal: [f64; 2], discs: &[Disc], bounds: Bounds) {
        self.nodes.clear();
        self.edges.clear();
        for point in [start, goal] {
            self.nodes.push(Node {
                point,
                disc: None,
                angle: 0.0,
            });
        }
        self.segment(start, None, goal, None, discs, bounds);
        for (i, disc) in discs.iter().enumerate() {
            for (end, node) in [(start, 0), (goal, 1)] {
                for touch in point_tangents(end, disc) {
                    self.tangent_to_node(node, (touch, i), discs, bounds);
                }
            }
        }
        for i in 0..discs.len() {
            for j in i + 1..discs.len() {
                for (p, q) in circle_tangents(&discs[i], &discs[j]) {
                    self.segment(p, Some(i), q, Some(j), discs, bounds);
                }
            }
        }
        for i in 0..discs.len() {
            self.arcs(i, discs, bounds);
        }
    }

    /// Adds the segment from node `node` to the tangent point `touch` on disc `i`, if free.
    fn tangent_to_node(
        &mut self,
        node: u32,
        (touch, i): ([f64; 2], usize),
        discs: &[Disc],
        bounds: Bounds,
    ) {
        let from = self.nodes[node as usize].point;
        if !segment_is_free(from, touch, discs, bounds) {
            return;
        }
        let b = self.push_node(touch, Some(i), discs);
        self.edges.push(Edge {
            a: node,
            b,
            length: distance(from, touch),
        });
    }

    /// Adds the segment `p` (on disc `i`, or a free end) to `q` (on disc `j`), if free.
    fn segment(
        &mut self,
        p: [f64; 2],
        i: Option<usize>,
        q: [f64; 2],
        j: Option<usize>,
        discs: &[Disc],
        bounds: Bounds,
    ) {
        if !segment_is_free(p, q, discs, bounds) {
            return;
        }
        let a = match i {
            Some(i) => self.push_node(p, Some(i), discs),
            None => 0,
        };
        let b = match j {
            Some(j) => self.push_node(q, Some(j), discs),
            None => 1,
        };
        self.edges.push(Edge {
            a,
            b,
            length: distance(p, q),
        });
    }

    fn push_node(&mut self, point: [f64; 2], disc: Option<usize>, discs: &[Disc]) -> u32 {
        let angle = disc.map_or(0.0, |i| {
            let c = discs[i].center;
            (point[1] - c[1]).atan2(point[0] - c[0]).rem_euclid(TAU)
        });
        self.nodes.push(Node {
            point,
            disc: disc.map(|i| i as u32),
            angle,
        });
        (self.nodes.len() - 1) as u32
    }

    /// The arcs of disc `i`'s circle between angularly adjacent tangent points.
    fn arcs(&mut self, i: usize, discs: &[Disc], bounds: Bounds) {
        self.on_circle.clear();
        self.on_circle.extend(
            (0..self.nodes.len() as u32).filter(|&v| self.nodes[v as usize].disc == Some(i as u32)),
        );
        if self.on_circle.len() < 2 {
            return;
        }
        let nodes = &self.nodes;
        self.on_circle
            .sort_unstable_by(|&a, &b| nodes[a as usize].angle.total_cmp(&nodes[b as usize].angle));
        let disc = discs[i];
        if !blocked_arcs(i, discs, bounds, &mut self.blocked) {
            return; // the whole circle lies in another disc or out of the box
        }
        let count = self.on_circle.len();
        for k in 0..count {
            let (a, b) = (self.on_circle[k], self.on_circle[(k + 1) % count]);
            let from = self.nodes[a as usize].angle;
            let sweep = (self.nodes[b as usize].angle - from).rem_euclid(TAU);
            let free = self
                .blocked
                .iter()
                .all(|&(centre, half)| !arc_meets(from, sweep, centre, half));
            if free {
                self.edges.push(Edge {
                    a,
                    b,
                    length: disc.radius * sweep,
                });
            }
        }
    }

    /// Dijkstra from node 0 to node 1 over the edges.
    fn search(&mut self) -> Result<(), NoRoute> {
        let n = self.nodes.len();
        self.first.clear();
        self.first.resize(n + 1, 0);
        for e in &self.edges {
            self.first[e.a as usize + 1] += 1;
            self.first[e.b as usize + 1] += 1;
        }
        for v in 0..n {
            self.first[v + 1] += self.first[v];
        }
        self.adjacent.clear();
        self.adjacent.resize(self.first[n] as usize, (0, 0.0));
        // `previous` counts the entries written per node while the rows are filled.
        self.previous.clear();
        self.previous.resize(n, 0);
        for e in &self.edges {
            for (from, to) in [(e.a, e.b), (e.b, e.a)] {
                let at = self.first[from as usize] + self.previous[from as usize];
                self.adjacent[at as usize] = (to, e.length);
                self.previous[from as usize] += 1;
            }
        }
        self.distance.clear();
        self.distance.resize(n, f64::INFINITY);
        self.previous.fill(u32::MAX);
        self.queue.clear();
        self.distance[0] = 0.0;
        self.queue.push(Queued(0.0, 0));
        while let Some(Queued(d, v)) = self.queue.pop() {
            if v == 1 {
                return Ok(());
            }
            if d > self.distance[v as usize] {
                continue;
            }
            let row = self.first[v as usize] as usize..self.first[v as usize + 1] as usize;
            for &(w, length) in &self.adjacent[row] {
                let through = d + length;
                if through < self.distance[w as usize] {
                    self.distance[w as usize] = through;
                    self.previous[w as usize] = v;
                    self.queue.push(Queued(through, w));
                }
            }
        }
        Err(NoRoute)
    }

    /// The legs of the path found, from the start.
    fn trace(&mut self, discs: &[Disc]) {
        self.legs.clear();
        let mut v = 1u32;
        while v != 0 {
            let u = self.previous[v as usize];
            let (from, to) = (self.nodes[u as usize], self.nodes[v as usize]);
            let along_circle = from.disc.is_some() && from.disc == to.disc;
            self.legs.push(match (along_circle, from.disc) {
                (true, Some(i)) => {
                    let disc = discs[i as usize];
                    // The arc edge joins angularly adjacent nodes counter-clockwise from
                    // the lower index of the pair; its length says which way it runs.
                    let ccw = (to.angle - from.angle).rem_euclid(TAU);
                    let arc_length = self.distance[v as usize] - self.distance[u as usize];
                    let sweep = if (disc.radius * ccw - arc_length).abs()
                        <= (disc.radius * (TAU - ccw) - arc_length).abs()
                    {
                        ccw
                    } else {
                        ccw - TAU
                    };
                    Leg::Arc {
                        disc,
                        from_angle: from.angle,
                        sweep,
                        to: to.point,
                    }
                }
                _ => Leg::Straight { to: to.point },
            });
            v = u;
        }
        self.legs.reverse();
    }
}

/// Whether the segment `p q` stays outside every disc (touching allowed) and in the box.
fn segment_is_free(p: [f64; 2], q: [f64; 2], discs: &[Disc], bounds: Bounds) -> bool {
    let inside = |x: [f64; 2]| {
        (0..2).all(|axis| {
            x[axis] >= bounds[axis][0] - TOUCH_TOLERANCE_M
                && x[axis] <= bounds[axis][1] + TOUCH_TOLERANCE_M
        })
    };
    inside(p)
        && inside(q)
        && discs
            .iter()
            .all(|d| protocol::segment_distance(p, q, d.center) >= d.radius - TOUCH_TOLERANCE_M)
}

/// The two points where lines from `point` touch the circle of `disc` (none from inside).
fn point_tangents(point: [f64; 2], disc: &Disc) -> impl Iterator<Item = [f64; 2]> {
    let (dx, dy) = (point[0] - disc.center[0], point[1] - disc.center[1]);
    let d = dx.hypot(dy);
    let touches = (d > disc.radius && disc.radius > 0.0).then(|| {
        let base = dy.atan2(dx);
        let half = (disc.radius / d).acos();
        [base + half, base - half].map(|a| {
            [
                disc.center[0] + disc.radius * a.cos(),
                disc.center[1] + disc.radius * a.sin(),
            ]
        })
    });
    touches.into_iter().flatten()
}

/// The end points `(on a, on b)` of the lines tangent to both circles: the two outer
/// tangents, and the two inner ones when the discs are apart. None when one disc holds
/// the other.
fn circle_tangents(a: &Disc, b: &Disc) -> impl Iterator<Item = ([f64; 2], [f64; 2])> {
    let (dx, dy) = (b.center[0] - a.center[0], b.center[1] - a.center[1]);
    let d = dx.hypot(dy);
    let (vx, vy) = (dx / d, dy / d);
    // For a signed radius `rb` (negative: inner), the unit normal `n` of the tangent line
    // satisfies `n . v = (ra - rb) / d`; the touch points are `ca + ra n`, `cb + rb n`.
    [b.radius, -b.radius]
        .into_iter()
        .filter(move |_| d > 0.0)
        .flat_map(move |rb| {
            let c = (a.radius - rb) / d;
            let h = (1.0 - c * c).max(0.0).sqrt();
            let sides = if c.abs() <= 1.0 { 2 } else { 0 };
            [1.0, -1.0].into_iter().take(sides).map(move |k: f64| {
                let n = [vx * c - k * h * vy, vy * c + k * h * vx];
                (
                    [a.center[0] + a.radius * n[0], a.center[1] + a.radius * n[1]],
                    [b.center[0] + rb * n[0], b.center[1] + rb * n[1]],
                )
            })
        })
}

/// Writes into `blocked` the angular intervals `(centre, half width)` of disc `i`'s circle
/// that lie inside another disc or outside the box; false when the whole circle does.
fn blocked_arcs(i: usize, discs: &[Disc], bounds: Bounds, blocked: &mut Vec<(f64, f64)>) -> bool {
    blocked.clear();
    let Disc { center, radius, .. } = discs[i];
    for (k, other) in discs.iter().enumerate() {
        if k == i {
            continue;
        }
        let (dx, dy) = (other.center[0] - center[0], other.center[1] - center[1]);
        let d = dx.hypot(dy);
        if d >= radius + other.radius || d + other.radius <= radius {
            continue; // apart, or the other inside this one: the circle is not cut
        }
        if d + radius <= other.radius {
            return false;
        }
        let cos = (d * d + radius * radius - other.radius * other.radius) / (2.0 * d * radius);
        blocked.push((dy.atan2(dx), cos.clamp(-1.0, 1.0).acos()));
    }
    // Each box side: the part of the circle beyond it, `u` being the room to the side
    // in radii (centred on the side's outward direction).
    use std::f64::consts::{FRAC_PI_2, PI};
    for (direction, room) in [
        (0.0, bounds[0][1] - center[0]),
        (PI, center[0] - bounds[0][0]),
        (FRAC_PI_2, bounds[1][1] - center[1]),
        (-FRAC_PI_2, center[1] - bounds[1][0]),
    ] {
        let u = room / radius;
        if u <= -1.0 {
            return false;
        }
        if u < 1.0 {
            blocked.push((direction, u.acos()));
        }
    }
    true
}

/// Whether the arc from `from` turning counter-clockwise by `sweep` meets the interval
/// `centre +- half` (angles in rad).
fn arc_meets(from: f64, sweep: f64, centre: f64, half: f64) -> bool {
    if half >= std::f64::consts::PI {
        return true;
    }
    let start = (centre - half - from).rem_euclid(TAU);
    start < sweep || start + 2.0 * half > TAU
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOX: Bounds = [[-10.0, 10.0], [-10.0, 10.0]];

    fn length(start: [f64; 2], legs: &[Leg]) -> f64 {
        let mut at = start;
        let mut total = 0.0;
        for leg in legs {
            match *leg {
                Leg::Straight { to } => {
                    total += distance(at, to);
                    at = to;
                }
                Leg::Arc {
                    disc, sweep, to, ..
                } => {
                    total += disc.radius * sweep.abs();
                    at = to;
                }
            }
        }
        total
    }

    #[test]
    fn with_nothing_in_the_way_the_route_is_the_straight_line() {
        let mut g = TangentGraph::with_capacity(1);
        let far = [Disc::still([0.0, 5.0], 1.0)];
        let legs = g.shortest_path([-3.0, 0.0], [3.0, 0.0], &far, BOX).unwrap();
        assert_eq!(legs, &[Leg::Straight { to: [3.0, 0.0] }]);
    }

    #[test]
    fn around_one_disc_the_route_is_tangent_arc_tangent_of_the_exact_length() {
        let mut g = TangentGraph::with_capacity(1);
        let disc = Disc::still([0.0, 0.0], 1.0);
        let (s, goal) = ([-3.0, 0.0], [3.0, 0.0]);
        let legs = g.shortest_path(s, goal, &[disc], BOX).unwrap().to_vec();
        // Two tangents of sqrt(9 - 1) and the arc between their touch points, 2 (pi/2 -
        // acos(1/3)) rad.
        let expected =
            2.0 * 8f64.sqrt() + 2.0 * (std::f64::consts::FRAC_PI_2 - (1.0f64 / 3.0).acos());
        assert!((length(s, &legs) - expected).abs() < 1e-9, "{legs:?}");
        assert_eq!(legs.len(), 3);
        assert!(matches!(legs[1], Leg::Arc { .. }));
    }

    #[test]
    fn overlapping_discs_are_gone_around_as_one() {
        let mut g = TangentGraph::with_capacity(2);
        let discs = [Disc::still([0.0, -0.8], 1.0), Disc::still([0.0, 0.8], 1.0)];
        let (s, goal) = ([-3.0, 0.0], [3.0, 0.0]);
        let legs = g.shortest_path(s, goal, &discs, BOX).unwrap().to_vec();
        let mut at = s;
        for leg in &legs {
            let to = match *leg {
                Leg::Straight { to } | Leg::Arc { to, .. } => to,
            };
            if let Leg::Straight { to } = *leg {
                for d in &discs {
                    assert!(protocol::segment_distance(at, to, d.center) >= d.radius - 1e-9);
                }
            }
            at = to;
        }
        // Longer than around one disc alone.
        assert!(length(s, &legs) > 2.0 * 8f64.sqrt());
    }

    #[test]
    fn a_goal_walled_in_has_no_route() {
        let mut g = TangentGraph::with_capacity(8);
        // A ring of eight overlapping discs around the goal.
        let ring: Vec<Disc> = (0..8)
            .map(|k| {
                let a = k as f64 * TAU / 8.0;
                Disc::still([2.0 * a.cos(), 2.0 * a.sin()], 1.0)
            })
            .collect();
        assert_eq!(
            g.shortest_path([6.0, 0.0], [0.0, 0.0], &ring, BOX).err(),
            Some(NoRoute)
        );
    }

    #[test]
    fn a_gap_closed_by_the_box_side_is_no_way_through() {
        let mut g = TangentGraph::with_capacity(1);
        // A disc touching the top and bottom of a narrow box blocks it; with a taller box
        // the route goes around.
        let disc = [Disc::still([0.0, 0.0], 1.5)];
        let narrow = [[-10.0, 10.0], [-1.0, 1.0]];
        assert!(
            g.shortest_path([-5.0, 0.0], [5.0, 0.0], &disc, narrow)
                .is_err()
        );
        assert!(g.shortest_path([-5.0, 0.0], [5.0, 0.0], &disc, BOX).is_ok());
    }

    #[test]
    fn the_arc_test_finds_the_intervals_it_crosses() {
        assert!(arc_meets(0.0, 1.0, 0.5, 0.1));
        assert!(!arc_meets(0.0, 1.0, 2.0, 0.5));
        // An interval that wraps through zero.
        assert!(arc_meets(6.0, 0.5, 0.1, 0.05));
        assert!(arc_meets(1.0, 0.5, 0.0, 1.2));
    }
}
