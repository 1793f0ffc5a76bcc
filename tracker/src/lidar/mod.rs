//! Perception from a lidar's scans (docs/running.md, "A lidar"): every scan's points put
//! into the world with the robot's pose at the scan's time, the points on the obstacles the
//! pipeline knows taken out, the rest grouped, each group a disc, the discs assigned to
//! tracks (gated, globally), tracks born once confirmed, predicted while unseen and dropped
//! once lost. Math only, in buffers sized once: a scan allocates nothing.

mod assignment;
mod geometry;
mod phantoms;

use crate::AxisFilter;
use assignment::Assignment;
pub use geometry::{Circle, behind_the_face, enclosing_circle};
use phantoms::{Phantom, PhantomModel};
use protocol::{MAX_BEAMS, MAX_TRACKS, Scan, Tracks, Validated};

/// The most groups a scan is split into; beyond them the farthest are left out.
pub const MAX_GROUPS: usize = 64;

/// How far beyond a known obstacle's edge a point is still taken as that obstacle's, m,
/// at range 0; it grows by [`KNOWN_MARGIN_PER_M`] per metre of range (the estimate's
/// heading error moves far points more).
const KNOWN_MARGIN_M: f64 = 0.1;
const KNOWN_MARGIN_PER_M: f64 = 0.02;

/// How far beyond a known obstacle's edge a return at range `range_m` is still that
/// obstacle's, m.
fn known_margin_m(range_m: f64) -> f64 {
    KNOWN_MARGIN_M + KNOWN_MARGIN_PER_M * range_m
}

/// `1 / sin(10 deg)`: two neighbouring points belong to one group while their gap is at
/// most this many times the arc between their beams (the adaptive breakpoint detector:
/// a surface seen at 10 deg from its beams or steeper stays one group), plus
/// `perception.cluster_gap_m`.
const BREAK_FACTOR: f64 = 5.76;

/// The least standard deviation of a fitted centre, m: the centre of a group's circle
/// moves as the robot sees another side of its obstacle.
const CENTRE_STD_M: f64 = 0.05;

/// How much larger than the smallest circle of a group seen from one side its obstacle's
/// circle may be found ([`behind_the_face`]): arcs of 84 degrees or more (`2 asin(1 /
/// 1.5)`) give back their own circle.
const ARC_RADIUS_FACTOR: f64 = 1.5;

/// A point of the scan in the world.
#[derive(Debug, Clone, Copy)]
struct Point {
    xy: [f64; 2],
    range_m: f64,
    beam: usize,
}

/// A group of neighbouring points and its disc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Group {
    pub disc: Circle,
    pub points: usize,
}

/// A track of a group seen over scans.
#[derive(Debug, Clone, Copy)]
struct LidarTrack {
    id: u32,
    axes: [AxisFilter; 2],
    radius_m: f64,
    /// Bit `i`: seen `i` scans ago (of the last [`CONFIRM_WINDOW`]).
    seen: u32,
    confirmed: bool,
    last_seen_s: f64,
}

/// The perception of a run's tracker with a lidar (module docs).
pub struct Perception {
    /// The known obstacles' discs (the map).
    known: Vec<Circle>,
    /// The other robots of a fleet at the newest scan's time, where they say they are
    /// ([`Perception::take`]): their returns are theirs, not an obstacle's.
    peers: Vec<Circle>,
    /// The tracks' slots left for the other robots of a fleet ([`Perception::tracks`]).
    peer_slots: usize,
    min_radius_m: f64,
    confirm: u32,
    lost_s: f64,
    gate: f64,
    cluster_gap_m: f64,
    accel_max: f64,
    /// Variance of a fitted centre, m^2.
    centre_variance: f64,
    points: Vec<Point>,
    scratch: Vec<[f64; 2]>,
    groups: Vec<Group>,
    tracks: Vec<LidarTrack>,
    /// The group each track was paired with in this scan.
    paired: Vec<Option<usize>>,
    group_taken: Vec<bool>,
    assignment: Assignment,
    next_id: u32,
    time_s: Option<f64>,
    /// The lidar in the world at the newest scan.
    origin: [f64; 2],
    /// What a phantom is, when phantoms are assumed.
    phantom: Option<PhantomModel>,
    /// The phantoms of the newest scan.
    phantoms: Vec<Phantom>,
    /// The inner tick, s: the unit of a scan's age ([`Scan::age_ticks`]).
    inner_tick_s: f64,
    /// When the newest scan was taken, s.
    scan_taken_s: f64,
    /// How far a group's disc may reach out in front of its nearest return, m: the lidar's
    /// noise (`lidar.noise_std`; [`behind_the_face`]).
    face_tolerance_m: f64,
}

impl Perception {
    pub fn new(scenario: &Validated) -> Perception {
        let p = &scenario.perception;
        Perception {
            known: (scenario.known_obstacles())
                .map(|o| ([o.x, o.y], o.radius))
                .collect(),
            peers: Vec::with_capacity(scenario.robot_count()),
            peer_slots: scenario.robot_count() - 1,
            min_radius_m: p.min_radius,
            confirm: p.confirm,
            lost_s: p.lost_s,
            gate: p.gate,
            cluster_gap_m: p.cluster_gap_m,
            accel_max: p.accel_max,
            centre_variance: p.noise_std.max(CENTRE_STD_M).powi(2),
            points: Vec::with_capacity(MAX_BEAMS),
            scratch: Vec::with_capacity(MAX_BEAMS),
            groups: Vec::with_capacity(MAX_BEAMS),
            tracks: Vec::with_capacity(MAX_TRACKS),
            paired: Vec::with_capacity(MAX_TRACKS),
            group_taken: Vec::with_capacity(MAX_BEAMS),
            assignment: Assignment::with_capacity(MAX_TRACKS, MAX_GROUPS),
            next_id: 0,
            time_s: None,
            origin: [0.0; 2],
            phantom: scenario.phantoms().then(|| PhantomModel {
                radius_m: p.phantom_radius,
                speed_m_s: p.phantom_speed,
                velocity_sigma: p.phantom_speed / scenario.mpc.uncertainty_sigmas,
            }),
            phantoms: Vec::with_capacity(MAX_BEAMS),
            inner_tick_s: scenario.timing.dt_s(),
            scan_taken_s: 0.0,
            face_tolerance_m: scenario.lidar.as_ref().map_or(0.01, |l| l.noise_std),
        }
    }

    /// Takes in `scan`, taken with the robot at `pose` (`[x, y, theta]`, the estimate at
    /// the scan's time). A scan that arrived before its perception tick (a robot's:
    /// [`Scan::age_ticks`]) measures the obstacles where they were when it was taken: the
    /// tracks are updated then and predicted on to the tick.
    ///
    /// `peers` are the other robots of a fleet where they are when the scan was taken
    /// (their footprints where their estimates put them, grown by their uncertainty;
    /// `Peers::footprints`): their returns are left out as those on a known obstacle
    /// are, since their plans track them (docs/fleet.md, "A lidar in a fleet").
    pub fn take(&mut self, scan: &Scan, pose: [f64; 3], peers: &[Circle]) {
        let time_s = scan.header.time_s;
        let taken_s = time_s - f64::from(scan.age_ticks) * self.inner_tick_s;
        self.peers.clear();
        self.peers.extend_from_slice(peers);
        self.predict_to(taken_s);
        self.points_of(scan, pose);
        self.group(scan.angle_increment_rad.abs(), full_circle(scan));
        self.associate();
        self.update(taken_s);
        self.predict_to(time_s);
        self.scan_taken_s = taken_s;
    }

    /// The groups of the newest scan.
    pub fn groups(&self) -> &[Group] {
        &self.groups
    }

    /// The confirmed tracks, then the phantoms of the newest scan, into `tracks` (the
    /// phantoms have their places kept: the tracks take what they leave), leaving a slot
    /// for each other robot of a fleet.
    pub fn tracks(&self, tracks: &mut Tracks) {
        let slots = MAX_TRACKS - self.peer_slots;
        let confirmed = (self.tracks.iter().filter(|t| t.confirmed))
            .map(|t| crate::track(t.id, t.radius_m, &t.axes))
            .take(slots.saturating_sub(self.phantoms.len()));
        let mut count = 0;
        for (slot, track) in
            (tracks.tracks[..slots].iter_mut()).zip(confirmed.chain(self.phantom_tracks()))
        {
            *slot = track;
            count += 1;
        }
        tracks.count = count as u32;
    }

    /// Predicts every track to `time_s` (also without a scan: none came, or it was
    /// dropped).
    pub fn predict_to(&mut self, time_s: f64) {
        let dt = self.time_s.map_or(0.0, |last| time_s - last);
        if dt > 0.0 {
            for axis in self.tracks.iter_mut().flat_map(|t| &mut t.axes) {
                axis.predict(dt, self.accel_max);
            }
        }
        // Never back: a scan taken before the tracks' time is taken in as of then.
        self.time_s = Some(self.time_s.map_or(time_s, |last| last.max(time_s)));
    }

    /// The scan's returns in the world, but those on a known obstacle.
    fn points_of(&mut self, scan: &Scan, pose: [f64; 3]) {
        let [x, y, heading] = protocol::mounted(pose, scan.offset);
        let origin = [x, y];
        self.origin = origin;
        self.shadow_edges(scan, origin, heading);
        self.points.clear();
        for (beam, &range) in scan.ranges().iter().enumerate() {
            let range_m = f64::from(range);
            if !range_m.is_finite() || range_m < scan.range_min_m || range_m > scan.range_max_m {
                continue;
            }
            let angle = heading + scan.angle_rad(beam);
            let xy = [
                origin[0] + range_m * angle.cos(),
                origin[1] + range_m * angle.sin(),
            ];
            if self.known_at(xy, range_m).is_none() {
                self.points.push(Point { xy, range_m, beam });
            }
        }
    }

    /// The known obstacle, or the other robot, a return at `xy`, seen at range `range_m`,
    /// is taken as (within [`known_margin_m`] of its edge), if any.
    fn known_at(&self, xy: [f64; 2], range_m: f64) -> Option<Circle> {
        let margin = known_margin_m(range_m);
        (self.known.iter().chain(&self.peers).copied())
            .find(|(centre, radius)| geometry::distance(*centre, xy) <= radius + margin)
    }

    /// Whether neighbouring points `a` and `b` (`b` after `a`) are of one group.
    fn joined(&self, a: &Point, b: &Point, beams: usize, step_rad: f64) -> bool {
        let apart = (b.beam + beams - a.beam) % beams;
        let range = a.range_m.min(b.range_m);
        apart <= 2
            && geometry::distance(a.xy, b.xy)
                <= self.cluster_gap_m + BREAK_FACTOR * range * step_rad * apart as f64
    }

    /// Splits the points into groups and fits each a disc; with a scan all around, a
    /// group may span the seam between the last beam and the first.
    fn group(&mut self, step_rad: f64, beams_around: Option<usize>) {
        self.groups.clear();
        let n = self.points.len();
        if n == 0 {
            return;
        }
        let beams = beams_around.unwrap_or(usize::MAX / 2);
        // Start after a break, so no group is cut at the seam.
        let start = match beams_around {
            Some(_) => (0..n)
                .find(|&i| {
                    let (a, b) = (&self.points[(i + n - 1) % n], &self.points[i]);
                    !self.joined(a, b, beams, step_rad)
                })
                .unwrap_or(0),
            None => 0,
        };
        let mut first_k = 0;
        for k in 1..=n {
            let (previous, i) = ((start + k - 1) % n, (start + k) % n);
            if k == n || !self.joined(&self.points[previous], &self.points[i], beams, step_rad) {
                self.close_group((start + first_k) % n, k - first_k, step_rad);
                first_k = k;
            }
        }
        if self.groups.len() > MAX_GROUPS {
            // The nearest to the lidar are kept.
            let origin = self.origin;
            let range = |g: &Group| geometry::distance(g.disc.0, origin) - g.disc.1;
            (self.groups).sort_unstable_by(|a, b| range(a).total_cmp(&range(b)));
            self.groups.truncate(MAX_GROUPS);
        }
    }

    /// The group of `len` points from `first` (cyclically): its disc (the smallest circle
    /// of its points, or behind it the circle of the arc they make: [`behind_the_face`]),
    /// grown by the beam spacing at its range and to `perception.min_radius` away from the
    /// lidar.
    fn close_group(&mut self, first: usize, len: usize, step_rad: f64) {
        let n = self.points.len();
        self.scratch.clear();
        let mut nearest = f64::INFINITY;
        for k in 0..len {
            let p = self.points[(first + k) % n];
            self.scratch.push(p.xy);
            nearest = nearest.min(p.range_m);
        }
        shuffle(&mut self.scratch);
        let enclosing = enclosing_circle(&self.scratch);
        let circle = behind_the_face(
            &self.scratch,
            enclosing,
            self.origin,
            ARC_RADIUS_FACTOR * enclosing.1,
            self.face_tolerance_m,
        );
        let (mut centre, radius) = (circle.0, circle.1 + nearest * step_rad);
        if radius < self.min_radius_m {
            // Seen from one side: the disc keeps its near edge and reaches back.
            let away = [centre[0] - self.origin[0], centre[1] - self.origin[1]];
            let length = away[0].hypot(away[1]).max(1e-9);
            let push = self.min_radius_m - radius;
            centre = [
                centre[0] + push * away[0] / length,
                centre[1] + push * away[1] / length,
            ];
        }
        let disc = (centre, radius.max(self.min_radius_m));
        self.groups.push(Group { disc, points: len });
    }
}

/// Puts `points` in an order that looks random and is the same for the same points
/// (Fisher-Yates driven by a fixed xorshift): [`enclosing_circle`] runs in expected linear
/// time on points in random order, in quadratic time or worse on an arc in scan order.
fn shuffle(points: &mut [[f64; 2]]) {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    for i in (1..points.len()).rev() {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        points.swap(i, (state % (i as u64 + 1)) as usize);
    }
}

/// The number of beams of a scan that covers the whole circle, else `None`.
fn full_circle(scan: &Scan) -> Option<usize> {
    let beams = scan.beams as usize;
    let around = scan.angle_increment_rad.abs() * beams as f64;
    (beams > 0 && around >= std::f64::consts::TAU - 1e-6).then_some(beams)
}

mod tracks;

#[cfg(test)]
mod tests;
