//! A simulated 2D lidar: every beam ray-cast exactly against the true discs of the world
//! at the scan's time, so nearer discs hide farther ones, with range noise and dropouts
//! drawn from the caller's generator. Ranges follow ROS's REP 117, as `sensor_msgs/msg/LaserScan` carries them:
//! `+inf` when nothing is within `range_max_m`, `-inf` when something is nearer than
//! `range_min_m`, NaN for a beam that returned nothing (a dropout).

use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal};

/// The sensor: its beams, its field of view and its range, and where it sits on the
/// robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Lidar {
    pub beams: usize,
    /// The field of view, rad, centred on the lidar's heading (2 pi: all around).
    pub fov_rad: f64,
    pub range_min_m: f64,
    pub range_max_m: f64,
    /// Standard deviation of the range noise, m.
    pub noise_std_m: f64,
    /// The probability that a beam returns nothing.
    pub dropout: f64,
    /// The lidar's pose on the robot, `[x_m, y_m, yaw_rad]` (x forward).
    pub offset: [f64; 3],
}

/// A disc of the world at the scan's time: its centre, m, and its radius, m.
pub type Disc = ([f64; 2], f64);

impl Lidar {
    /// The sensor `[lidar]` describes.
    pub fn of(config: &protocol::LidarConfig) -> Lidar {
        Lidar {
            beams: config.beams as usize,
            fov_rad: config.fov_rad(),
            range_min_m: config.range_min_m,
            range_max_m: config.range_max_m,
            noise_std_m: config.noise_std,
            dropout: config.dropout,
            offset: config.offset,
        }
    }

    /// The angle of beam 0 from the lidar's heading, rad, and the angle between beams:
    /// all around, the beams split the circle evenly; else the first and the last lie on
    /// the edges of the field of view. One beam looks along the heading.
    pub fn angles(&self) -> (f64, f64) {
        if self.beams < 2 {
            return (0.0, 0.0);
        }
        let full = self.fov_rad >= std::f64::consts::TAU - 1e-9;
        let gaps = if full { self.beams } else { self.beams - 1 };
        (-self.fov_rad / 2.0, self.fov_rad / gaps as f64)
    }

    /// The lidar's pose in the world when the robot is at `pose` (`[x, y, theta]`).
    pub fn pose_on(&self, pose: [f64; 3]) -> [f64; 3] {
        protocol::mounted(pose, self.offset)
    }

    /// The scan message of the robot at `pose` among `discs`, with `header` ([`Lidar::scan`]
    /// into its ranges; its angles, range and offset the sensor's).
    pub fn scan_message(
        &self,
        header: protocol::Header,
        pose: [f64; 3],
        discs: &[Disc],
        rng: &mut impl Rng,
    ) -> protocol::Scan {
        let (angle_min_rad, angle_increment_rad) = self.angles();
        let mut scan = protocol::Scan {
            header,
            beams: self.beams as u32,
            angle_min_rad,
            angle_increment_rad,
            range_min_m: self.range_min_m,
            range_max_m: self.range_max_m,
            offset: self.offset,
            ..protocol::Scan::default()
        };
        self.scan(pose, discs, rng, &mut scan.ranges_m[..self.beams]);
        scan
    }

    /// The scan of the robot at `pose` among `discs`, one range per beam into `ranges`
    /// (its length is the number of beams written).
    pub fn scan(&self, pose: [f64; 3], discs: &[Disc], rng: &mut impl Rng, ranges: &mut [f32]) {
        let [x, y, heading] = self.pose_on(pose);
        let (first, step) = self.angles();
        let noise = Normal::new(0.0, self.noise_std_m.max(0.0)).ok();
        for (i, range) in ranges.iter_mut().enumerate().take(self.beams) {
            let angle = heading + first + step * i as f64;
            let direction = [angle.cos(), angle.sin()];
            let hit = discs
                .iter()
                .filter_map(|disc| ray_to_disc([x, y], direction, disc))
                .fold(f64::INFINITY, f64::min);
            // Every beam draws the same numbers whatever it hits, so one obstacle more
            // changes no other beam's noise.
            let dropped = rng.random::<f64>() < self.dropout;
            let error = noise.map_or(0.0, |n| n.sample(rng));
            *range = if dropped {
                f32::NAN
            } else if hit > self.range_max_m {
                f32::INFINITY
            } else if hit < self.range_min_m {
                f32::NEG_INFINITY
            } else {
                (hit + error).clamp(self.range_min_m, self.range_max_m) as f32
            };
        }
    }
}

/// The distance along the ray from `origin` in unit `direction` to the edge of `disc`, m
/// (0 from inside it); `None` when the ray misses it.
pub fn ray_to_disc(origin: [f64; 2], direction: [f64; 2], disc: &Disc) -> Option<f64> {
    let ([cx, cy], radius) = *disc;
    let (ox, oy) = (cx - origin[0], cy - origin[1]);
    let along = ox * direction[0] + oy * direction[1];
    let across_sq = (ox * ox + oy * oy) - along * along;
    let half_chord_sq = radius * radius - across_sq;
    if half_chord_sq < 0.0 {
        return None;
    }
    let half_chord = half_chord_sq.sqrt();
    let (near, far) = (along - half_chord, along + half_chord);
    if far < 0.0 { None } else { Some(near.max(0.0)) }
}

#[cfg(test)]
mod tests;
