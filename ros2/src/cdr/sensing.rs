//! What a base's lidar says: `sensor_msgs/msg/LaserScan` (its ranges and intensities as
//! sequences of `float32`), and where the lidar sits on the base,
//! `tf2_msgs/msg/TFMessage` on `tf_static` (`geometry_msgs/msg/TransformStamped`s).

use super::{CdrError, Header, Message, Reader, Writer};

/// `sensor_msgs/msg/LaserScan`: beam `i` looks `angle_min + i angle_increment` (rad) from
/// the x axis of `header.frame_id`; ranges in m, REP 117 (`+inf` nothing in range, `-inf`
/// too near, NaN no return; drivers also give values outside `[range_min, range_max]`,
/// which are to be discarded).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    /// Between two beams, s.
    pub time_increment: f32,
    /// Between two scans, s.
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

/// `geometry_msgs/msg/TransformStamped`: where `child_frame_id` is in `header.frame_id`,
/// a translation (m) and a rotation quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

/// A sequence's count, refused when its elements (each at least `min_bytes`) could not
/// fit in what is left of the payload.
fn count(r: &mut Reader, min_bytes: usize) -> Result<usize, CdrError> {
    let count = r.u32()? as usize;
    if count > r.remaining() / min_bytes {
        return Err(CdrError::Truncated(r.remaining()));
    }
    Ok(count)
}

fn write_f32s(w: &mut Writer, values: &[f32]) {
    w.u32(values.len() as u32);
    values.iter().for_each(|&v| w.f32(v));
}

fn read_f32s(r: &mut Reader) -> Result<Vec<f32>, CdrError> {
    let n = count(r, 4)?;
    (0..n).map(|_| r.f32()).collect()
}

impl Message for LaserScan {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        let scalars = [
            self.angle_min,
            self.angle_max,
            self.angle_increment,
            self.time_increment,
            self.scan_time,
            self.range_min,
            self.range_max,
        ];
        scalars.iter().for_each(|&v| w.f32(v));
        write_f32s(w, &self.ranges);
        write_f32s(w, &self.intensities);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(LaserScan {
            header: Header::read(r)?,
            angle_min: r.f32()?,
            angle_max: r.f32()?,
            angle_increment: r.f32()?,
            time_increment: r.f32()?,
            scan_time: r.f32()?,
            range_min: r.f32()?,
            range_max: r.f32()?,
            ranges: read_f32s(r)?,
            intensities: read_f32s(r)?,
        })
    }
}

impl Message for TransformStamped {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        w.string(&self.child_frame_id);
        w.f64s(&self.translation);
        w.f64s(&self.rotation);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(TransformStamped {
            header: Header::read(r)?,
            child_frame_id: r.string()?,
            translation: r.f64s()?,
            rotation: r.f64s()?,
        })
    }
}

impl Message for TfMessage {
    fn write(&self, w: &mut Writer) {
        w.u32(self.transforms.len() as u32);
        self.transforms.iter().for_each(|t| t.write(w));
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        // A transform takes at least 72 bytes: two empty strings and seven doubles.
        let n = count(r, 72)?;
        let transforms = (0..n)
            .map(|_| TransformStamped::read(r))
            .collect::<Result<_, _>>()?;
        Ok(TfMessage { transforms })
    }
}
