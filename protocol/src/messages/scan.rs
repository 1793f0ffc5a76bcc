//! The lidar's scan (docs/running.md, "A lidar"): what `sensor_msgs/msg/LaserScan` carries
//! of one sweep, in a fixed-size sample.

#[cfg(feature = "iceoryx2")]
use iceoryx2::prelude::ZeroCopySend;

use super::Header;
use crate::MAX_BEAMS;

/// One scan: beam `i` looks `angle_min_rad + i angle_increment_rad` from the lidar's
/// heading, the lidar sits at `offset` on the robot, and its ranges are REP 117's.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Scan"))]
pub struct Scan {
    /// The tick of the truth the scan was taken at (its time).
    pub header: Header,
    /// Beams in the scan: `ranges_m[..beams]`. 0: no new scan at this perception tick (a
    /// robot's lidar slower than `lidar.rate_hz`, or late): the tracker predicts its
    /// tracks, the DFL keeps the points it has.
    pub beams: u32,
    /// Inner ticks from the scan's taking to `header.tick` (a robot's scan arrives between
    /// two perception ticks): its points are placed with the estimate of then. 0 for the
    /// simulated lidar.
    pub age_ticks: u32,
    /// Angle of beam 0 from the lidar's heading, rad.
    pub angle_min_rad: f64,
    /// Angle between two beams, counter-clockwise, rad.
    pub angle_increment_rad: f64,
    pub range_min_m: f64,
    pub range_max_m: f64,
    /// The lidar's pose on the robot, `[x_m, y_m, yaw_rad]`.
    pub offset: [f64; 3],
    /// One range per beam, m: `+inf` nothing within `range_max_m`, `-inf` something
    /// nearer than `range_min_m`, NaN no return (REP 117).
    pub ranges_m: [f32; MAX_BEAMS],
}

impl Default for Scan {
    fn default() -> Self {
        Scan {
            header: Header::default(),
            beams: 0,
            age_ticks: 0,
            angle_min_rad: 0.0,
            angle_increment_rad: 0.0,
            range_min_m: 0.0,
            range_max_m: 0.0,
            offset: [0.0; 3],
            ranges_m: [f32::NAN; MAX_BEAMS],
        }
    }
}

impl Scan {
    /// The ranges of the scan's beams, m.
    pub fn ranges(&self) -> &[f32] {
        &self.ranges_m[..(self.beams as usize).min(MAX_BEAMS)]
    }

    /// The tick the scan was taken at: [`Scan::age_ticks`] before its header's.
    pub fn taken_tick(&self) -> u64 {
        self.header.tick.saturating_sub(self.age_ticks.into())
    }

    /// Beams that hit something in range (a finite range).
    pub fn returns(&self) -> usize {
        self.ranges().iter().filter(|r| r.is_finite()).count()
    }

    /// The least range that hit something, m; `range_max_m` when nothing is in range.
    pub fn nearest_m(&self) -> f64 {
        (self.ranges().iter())
            .filter(|r| r.is_finite())
            .fold(self.range_max_m, |least, &r| least.min(f64::from(r)))
    }

    /// The angle of beam `i` from the lidar's heading, rad.
    pub fn angle_rad(&self, i: usize) -> f64 {
        self.angle_min_rad + self.angle_increment_rad * i as f64
    }
}

crate::layouts! {
    Scan {
        header: Header,
        beams: u32,
        age_ticks: u32,
        angle_min_rad: f64,
        angle_increment_rad: f64,
        range_min_m: f64,
        range_max_m: f64,
        offset: [f64; 3],
        ranges_m: [f32; MAX_BEAMS],
    }
}
