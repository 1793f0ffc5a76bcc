//! How well a simulated run saw through its lidar, judged against the truth
//! (`summary.json`'s `perception`): the tracks born and lost, the false ones, and the
//! obstacles not in the map that came near in plain sight and were never tracked.

use protocol::{Obstacle, Scenario, Tracks};
use serde::Serialize;
use std::collections::BTreeMap;

/// A track is on an obstacle when its centre is within the obstacle's true radius and
/// this of the obstacle's true centre, m.
pub const ON_OBSTACLE_M: f64 = 0.3;
/// An obstacle not in the map is near when its edge is within this of the robot's centre,
/// m.
pub const NEAR_M: f64 = 3.0;

/// `summary.json`'s `perception` (runs of the simulated plant that see with a lidar).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct PerceptionReport {
    /// Tracks confirmed during the run (phantoms not counted).
    pub tracks_born: u64,
    /// Tracks dropped before the run's end (unseen for `perception.lost_s`: hidden, out
    /// of range, or false).
    pub tracks_lost: u64,
    /// Tracks never on an obstacle not in the map ([`ON_OBSTACLE_M`]).
    pub false_tracks: u64,
    /// Obstacles not in the map that came within [`NEAR_M`] of the robot in its lidar's
    /// plain sight (no other obstacle across the line between their centres, within the
    /// field of view) and that no track was ever on.
    pub missed_obstacles: u64,
}

/// What the judge has seen of the tracks so far.
#[derive(Debug, Clone)]
pub struct PerceptionJudge {
    /// Every obstacle, and whether each is one the lidar is to find (not in the map).
    obstacles: Vec<(Obstacle, bool)>,
    /// Half the lidar's field of view, rad, and its heading on the robot.
    half_fov_rad: f64,
    lidar_yaw_rad: f64,
    /// Each track by number: whether it was ever on an obstacle, and whether it is in
    /// the newest tracks.
    tracks: BTreeMap<u32, (bool, bool)>,
    /// Each obstacle to find: whether it came near in plain sight, and whether a track was
    /// ever on it.
    found: Vec<(bool, bool)>,
}

impl PerceptionJudge {
    /// The judge of `scenario`'s run, if it sees with a simulated lidar.
    pub fn of(scenario: &Scenario) -> Option<PerceptionJudge> {
        let simulated = scenario.plant.kind == protocol::PlantKind::Sim;
        if !(simulated && scenario.sees_with_lidar()) {
            return None;
        }
        let lidar = scenario.lidar.clone().unwrap_or_default();
        let obstacles: Vec<(Obstacle, bool)> = (scenario.obstacles.iter())
            .map(|o| (o.clone(), !o.is_known()))
            .collect();
        Some(PerceptionJudge {
            found: vec![(false, false); obstacles.len()],
            obstacles,
            half_fov_rad: lidar.fov_deg.to_radians() / 2.0,
            lidar_yaw_rad: lidar.offset[2],
            tracks: BTreeMap::new(),
        })
    }

    /// The robot at `pose` at `t_s`: which obstacles to find are near and in plain sight.
    pub fn robot_at(&mut self, t_s: f64, pose: [f64; 3]) {
        let [x, y, yaw] = pose;
        for (i, (obstacle, to_find)) in self.obstacles.iter().enumerate() {
            let [ox, oy] = obstacle.center_at(t_s);
            let near = (ox - x).hypot(oy - y) - obstacle.radius <= NEAR_M;
            if !*to_find || !near || self.found[i].0 {
                continue;
            }
            let bearing = (oy - y).atan2(ox - x) - yaw - self.lidar_yaw_rad;
            let in_view = bearing.sin().atan2(bearing.cos()).abs() <= self.half_fov_rad;
            let hidden = (self.obstacles.iter().enumerate())
                .filter(|(j, _)| *j != i)
                .any(|(_, (other, _))| {
                    let c = other.center_at(t_s);
                    protocol::geometry::segment_distance([x, y], [ox, oy], c) < other.radius
                });
            self.found[i].0 = in_view && !hidden;
        }
    }

    /// The tracker's tracks at their time.
    pub fn tracks(&mut self, tracks: &Tracks) {
        let t_s = tracks.header.time_s;
        self.tracks.values_mut().for_each(|(_, now)| *now = false);
        for track in tracks.tracks().iter().filter(|t| !t.is_phantom()) {
            let on = (self.obstacles.iter().enumerate())
                .filter(|(_, (_, to_find))| *to_find)
                .find(|(_, (o, _))| {
                    let [ox, oy] = o.center_at(t_s);
                    let [x, y] = track.center;
                    (x - ox).hypot(y - oy) <= o.radius + ON_OBSTACLE_M
                })
                .map(|(i, _)| i);
            if let Some(i) = on {
                self.found[i].1 = true;
            }
            let entry = self.tracks.entry(track.obstacle).or_default();
            *entry = (entry.0 || on.is_some(), true);
        }
    }

    /// The report at the run's end.
    pub fn report(&self) -> PerceptionReport {
        let count = |keep: &dyn Fn(&(bool, bool)) -> bool| {
            self.tracks.values().filter(|t| keep(t)).count() as u64
        };
        PerceptionReport {
            tracks_born: self.tracks.len() as u64,
            tracks_lost: count(&|(_, now)| !now),
            false_tracks: count(&|(on, _)| !on),
            missed_obstacles: (self.found.iter())
                .filter(|(near, tracked)| *near && !tracked)
                .count() as u64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, Track};

    fn scenario() -> Scenario {
        let at = |x: f64, y: f64, known: bool| Obstacle {
            known: Some(known),
            ..Obstacle::fixed(x, y, 0.3)
        };
        // A box nobody mapped, a pillar in the map, and a box behind the pillar.
        Scenario {
            lidar: Some(Default::default()),
            obstacles: vec![at(2.0, 0.0, false), at(0.0, 2.0, true), at(0.0, 3.0, false)],
            ..Scenario::default()
        }
    }

    fn tracks(t_s: f64, centres: &[(u32, [f64; 2])]) -> Tracks {
        let mut tracks = Tracks {
            header: Header {
                time_s: t_s,
                ..Header::default()
            },
            count: centres.len() as u32,
            ..Tracks::default()
        };
        for (slot, (number, center)) in tracks.tracks.iter_mut().zip(centres) {
            *slot = Track {
                obstacle: *number,
                center: *center,
                ..Track::default()
            };
        }
        tracks
    }

    #[test]
    fn tracks_on_obstacles_are_found_others_false_and_a_hidden_obstacle_is_not_missed() {
        let mut judge = PerceptionJudge::of(&scenario()).unwrap();
        judge.robot_at(0.0, [0.0, 0.0, 0.0]);
        judge.tracks(&tracks(0.0, &[(1, [2.1, 0.0]), (2, [-2.0, -2.0])]));
        judge.tracks(&tracks(0.1, &[(1, [2.1, 0.0])]));
        let report = judge.report();
        assert_eq!(
            report,
            PerceptionReport {
                tracks_born: 2,
                tracks_lost: 1,
                false_tracks: 1,
                missed_obstacles: 0,
            }
        );
        // From beside the pillar the box behind it is in plain sight, and never tracked.
        judge.robot_at(0.2, [1.0, 2.5, 0.0]);
        assert_eq!(judge.report().missed_obstacles, 1);
    }

    #[test]
    fn a_run_without_a_lidar_has_no_perception_report() {
        assert!(PerceptionJudge::of(&Scenario::default()).is_none());
    }
}
