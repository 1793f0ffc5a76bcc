//! Tracks of the groups (docs/running.md, "A lidar"): each scan's discs paired with the
//! tracks predicted to its time, by the Mahalanobis distance of their centres within
//! `perception.gate`, in one global assignment.

use super::{LidarTrack, Perception};
use crate::AxisFilter;
use protocol::{CONFIRM_WINDOW, MAX_TRACKS};

/// How much of a track's radius is the newest disc's when that one is smaller: a radius
/// shrinks slowly (the disc of a group seen from one side is smaller than its obstacle).
const RADIUS_SHRINK: f64 = 0.2;

impl Perception {
    /// Pairs the groups of the scan with the tracks.
    pub(super) fn associate(&mut self) {
        self.paired.clear();
        self.paired.resize(self.tracks.len(), None);
        self.group_taken.clear();
        self.group_taken.resize(self.groups.len(), false);
        let (tracks, groups) = (&self.tracks, &self.groups);
        let (variance, gate) = (self.centre_variance, self.gate);
        let cost = |t: usize, g: usize| {
            let track = &tracks[t];
            let centre = groups[g].disc.0;
            let distance_sq: f64 = (0..2)
                .map(|axis| {
                    let filter = &track.axes[axis];
                    let innovation = centre[axis] - filter.state[0];
                    innovation * innovation / (filter.covariance[0] + variance)
                })
                .sum();
            (distance_sq <= gate * gate).then_some(distance_sq)
        };
        let (paired, taken) = (&mut self.paired, &mut self.group_taken);
        self.assignment
            .solve(tracks.len(), groups.len(), cost, |t, g| {
                paired[t] = Some(g);
                taken[g] = true;
            });
    }

    /// Updates the paired tracks, starts a track of every group left, and drops the
    /// tracks lost.
    pub(super) fn update(&mut self, time_s: f64) {
        let window = (1u32 << CONFIRM_WINDOW) - 1;
        for (track, paired) in self.tracks.iter_mut().zip(&self.paired) {
            track.seen = (track.seen << 1) & window;
            let Some(g) = *paired else { continue };
            let (centre, radius) = self.groups[g].disc;
            for (filter, z) in track.axes.iter_mut().zip(centre) {
                filter.update(z, self.centre_variance);
            }
            track.radius_m = radius.max(track.radius_m + RADIUS_SHRINK * (radius - track.radius_m));
            track.seen |= 1;
            track.last_seen_s = time_s;
            track.confirmed |= track.seen.count_ones() >= self.confirm;
        }
        // A confirmed track is kept, predicted, until it is lost; one not confirmed only
        // while it was seen within the window.
        let lost_s = self.lost_s;
        (self.tracks).retain(|t| time_s - t.last_seen_s <= lost_s && (t.confirmed || t.seen != 0));
        for (group, taken) in self.groups.iter().zip(&self.group_taken) {
            if *taken || self.tracks.len() >= MAX_TRACKS {
                continue;
            }
            let (centre, radius) = group.disc;
            self.tracks.push(LidarTrack {
                id: self.next_id,
                axes: centre.map(|z| AxisFilter::start(z, self.centre_variance)),
                radius_m: radius,
                seen: 1,
                confirmed: self.confirm <= 1,
                last_seen_s: time_s,
            });
            self.next_id = self.next_id.wrapping_add(1);
        }
    }
}
