//! Phantoms (docs/safety.md, "What the lidar cannot see"): at every shadow edge of a scan,
//! where the range jumps from near to far by more than a phantom's width, an obstacle of
//! `perception.phantom_radius` is assumed in the shadow, as near the edge as it can be
//! unseen (touching the edge's beam from the shadow's side, level with the nearer return,
//! or, behind an obstacle of the map, as near as it can be without standing in it),
//! and it may come out at up to `perception.phantom_speed` in any direction. It goes out as a track whose
//! centre is certain and whose velocity is zero with a standard deviation of
//! `phantom_speed / kappa`, so every consumer grows its predicted disc by `phantom_speed t`
//! (and the acceleration bound), the rule it already applies to every track.

use super::Perception;
use protocol::{FIRST_PHANTOM, Scan, Track};

/// The most phantoms a scan gives: the nearest to the lidar.
pub const MAX_PHANTOMS: usize = 8;

/// What a phantom is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PhantomModel {
    pub radius_m: f64,
    /// `perception.phantom_speed`, m/s.
    pub speed_m_s: f64,
    /// `phantom_speed / kappa`, m/s: its velocity's standard deviation.
    pub velocity_sigma: f64,
}

/// A phantom of a scan: its centre, m, and the range of the edge it hides behind, m.
pub(super) type Phantom = ([f64; 2], f64);

/// A shadow edge of a scan: where the nearer beam's return is, the nearer beam's direction
/// away from the lidar (a unit vector), the two beams' ranges, m, and the arc left unseen
/// between them at the nearer range, m.
struct ShadowEdge {
    at: [f64; 2],
    along: [f64; 2],
    near_m: f64,
    far_m: f64,
    gap_m: f64,
}

impl Perception {
    /// The phantoms of `scan`, taken from the lidar at `origin` heading `heading` (rad);
    /// every return counts, those of known obstacles too (a person hides behind a wall of
    /// the map as well as behind a box).
    pub(super) fn shadow_edges(&mut self, scan: &Scan, origin: [f64; 2], heading: f64) {
        self.phantoms.clear();
        let Some(model) = self.phantom else {
            return;
        };
        let ranges = scan.ranges();
        // A dropout says nothing: the beams beside it are compared across it.
        let range = |r: f32| match r {
            r if r.is_nan() => None,
            f32::INFINITY => Some(scan.range_max_m),
            f32::NEG_INFINITY => Some(scan.range_min_m),
            r => Some(f64::from(r).clamp(scan.range_min_m, scan.range_max_m)),
        };
        let around = super::full_circle(scan).is_some();
        let mut previous = match around {
            true => (ranges.iter().enumerate().rev()).find_map(|(i, r)| Some((i, range(*r)?))),
            false => None,
        };
        let jump = 2.0 * model.radius_m;
        for (i, r) in ranges.iter().enumerate() {
            let Some(r) = range(*r) else { continue };
            if let Some((j, q)) = previous {
                // The nearer of the two beams is the edge of what hides the shadow; the
                // farther one looks past it (`+1`: at the next beam's angle).
                let edge = match r - q {
                    d if d > jump => Some((j, q, 1.0)),
                    d if d < -jump => Some((i, r, -1.0)),
                    _ => None,
                };
                if let Some((beam, near, past)) = edge {
                    let apart = (i + ranges.len() - j) % ranges.len();
                    let angle = heading + scan.angle_rad(beam);
                    let (sin, cos) = angle.sin_cos();
                    // Away from the side the farther beam saw clear.
                    let into_shadow = -past * scan.angle_increment_rad.signum();
                    let aside = into_shadow * model.radius_m;
                    let centre = [
                        origin[0] + near * cos - aside * sin,
                        origin[1] + near * sin + aside * cos,
                    ];
                    let edge = ShadowEdge {
                        at: [origin[0] + near * cos, origin[1] + near * sin],
                        along: [cos, sin],
                        near_m: near,
                        far_m: r.max(q),
                        gap_m: near * scan.angle_increment_rad.abs() * apart as f64,
                    };
                    let centre = self.out_of_known(centre, &edge, model.radius_m);
                    self.phantoms.push((centre, near));
                }
            }
            previous = Some((i, r));
        }
        if self.phantoms.len() > MAX_PHANTOMS {
            (self.phantoms).sort_unstable_by(|a, b| a.1.total_cmp(&b.1));
            self.phantoms.truncate(MAX_PHANTOMS);
        }
    }

    /// A phantom at `centre` beside `edge`, moved along the edge's beam out of the known
    /// obstacle the edge is on, if it is on one: nobody hides inside a pillar of the map,
    /// only behind it. The phantom is kept clear of the obstacle's edge less the margin
    /// within which a return is taken as the obstacle's (what stands that near it is not
    /// seen apart; it also holds the estimate's error of the lidar's pose) and less the gap
    /// the two beams leave unseen between them; it goes no farther than the farther beam
    /// saw. This assumes that what hides is no smaller than a phantom: a smaller thing
    /// could stand nearer the silhouette (docs/safety.md, "What the lidar cannot see").
    fn out_of_known(&self, centre: [f64; 2], edge: &ShadowEdge, radius_m: f64) -> [f64; 2] {
        let Some((k, r)) = self.known_at(edge.at, edge.near_m) else {
            return centre;
        };
        // The farther root `s` of `|centre + s along - k| = keep`.
        let margin = super::known_margin_m(edge.near_m);
        let keep = (r + radius_m - margin - edge.gap_m).max(0.0);
        let w = [centre[0] - k[0], centre[1] - k[1]];
        let b = w[0] * edge.along[0] + w[1] * edge.along[1];
        let c = w[0] * w[0] + w[1] * w[1] - keep * keep;
        if c >= 0.0 {
            return centre;
        }
        let s = (-b + (b * b - c).sqrt()).min(edge.far_m - edge.near_m);
        [centre[0] + s * edge.along[0], centre[1] + s * edge.along[1]]
    }

    /// The phantoms of the newest scan as tracks, numbered from [`FIRST_PHANTOM`], each
    /// grown by how far it may have come out since the scan was taken (a robot's scan
    /// arrives after it is taken; a tick without a new scan keeps the last one's).
    pub(super) fn phantom_tracks(&self) -> impl Iterator<Item = Track> + '_ {
        // There are phantoms only with a model.
        let model = self.phantom.unwrap_or(PhantomModel {
            radius_m: 0.0,
            speed_m_s: 0.0,
            velocity_sigma: 0.0,
        });
        let variance = model.velocity_sigma * model.velocity_sigma;
        let age_s = self
            .time_s
            .map_or(0.0, |now| (now - self.scan_taken_s).max(0.0));
        let radius_m = model.radius_m + model.speed_m_s * age_s;
        (self.phantoms.iter().enumerate()).map(move |(k, (centre, _))| Track {
            obstacle: FIRST_PHANTOM + k as u32,
            reserved: 0,
            radius_m,
            center: *centre,
            velocity: [0.0; 2],
            covariance: [0.0, 0.0, variance, 0.0, 0.0, variance],
        })
    }
}
