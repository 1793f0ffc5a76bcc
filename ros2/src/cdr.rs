//! The CDR (XCDR1, little-endian) of the messages a differential-drive base speaks, as
//! rmw_zenoh writes them (`rmw_zenoh_cpp/src/detail/cdr.cpp`, Fast-CDR's `DDS_CDR`): a
//! 4-byte encapsulation header `00 01 00 00`, then the fields in order, each primitive
//! aligned to its size counted from the byte after the header; a string is its length
//! with the NUL (`uint32`), its bytes and the NUL; a sequence its count (`uint32`) and
//! its elements; a fixed array its elements alone; a nested message inline. No padding
//! follows the last field.

/// The encapsulation header of little-endian plain CDR.
pub const ENCAPSULATION_LE: [u8; 4] = [0, 1, 0, 0];

/// Why bytes are not the message they were read as.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    #[error("the payload ends at byte {0}, inside a field")]
    Truncated(usize),
    #[error("encapsulation {0:02x?} is not little-endian plain CDR (00 01)")]
    Encapsulation([u8; 2]),
    #[error("the string at byte {0} is not NUL-terminated UTF-8")]
    String(usize),
    #[error("{0} is not read by this crate")]
    Unsupported(&'static str),
}

/// Writes a message's fields after the encapsulation header.
#[derive(Debug, Clone)]
pub struct Writer {
    bytes: Vec<u8>,
}

impl Default for Writer {
    fn default() -> Self {
        Writer {
            bytes: ENCAPSULATION_LE.to_vec(),
        }
    }
}

impl Writer {
    fn align(&mut self, size: usize) {
        while !(self.bytes.len() - ENCAPSULATION_LE.len()).is_multiple_of(size) {
            self.bytes.push(0);
        }
    }

    pub fn i32(&mut self, value: i32) {
        self.align(4);
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    pub fn u32(&mut self, value: u32) {
        self.align(4);
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    pub fn f64(&mut self, value: f64) {
        self.align(8);
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    pub fn f64s(&mut self, values: &[f64]) {
        values.iter().for_each(|&v| self.f64(v));
    }

    pub fn f32(&mut self, value: f32) {
        self.align(4);
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    pub fn bool(&mut self, value: bool) {
        self.bytes.push(u8::from(value));
    }

    pub fn string(&mut self, value: &str) {
        self.u32(value.len() as u32 + 1);
        self.bytes.extend_from_slice(value.as_bytes());
        self.bytes.push(0);
    }

    /// The payload: header and fields.
    pub fn into_bytes(self) -> Vec<u8> {
        self.bytes
    }
}

/// Reads a message's fields after the encapsulation header.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// A reader of `payload`, if its header is little-endian plain CDR.
    pub fn new(payload: &'a [u8]) -> Result<Reader<'a>, CdrError> {
        match payload {
            [0, 1, _, _, ..] => Ok(Reader {
                bytes: payload,
                at: ENCAPSULATION_LE.len(),
            }),
            [a, b, ..] => Err(CdrError::Encapsulation([*a, *b])),
            _ => Err(CdrError::Truncated(payload.len())),
        }
    }

    fn take<const N: usize>(&mut self) -> Result<[u8; N], CdrError> {
        while !(self.at - ENCAPSULATION_LE.len()).is_multiple_of(N) {
            self.at += 1;
        }
        let bytes = self
            .bytes
            .get(self.at..self.at + N)
            .ok_or(CdrError::Truncated(self.bytes.len()))?;
        self.at += N;
        let mut array = [0; N];
        array.copy_from_slice(bytes);
        Ok(array)
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.at)
    }

    pub fn i32(&mut self) -> Result<i32, CdrError> {
        self.take().map(i32::from_le_bytes)
    }

    pub fn u32(&mut self) -> Result<u32, CdrError> {
        self.take().map(u32::from_le_bytes)
    }

    pub fn f64(&mut self) -> Result<f64, CdrError> {
        self.take().map(f64::from_le_bytes)
    }

    pub fn f32(&mut self) -> Result<f32, CdrError> {
        self.take().map(f32::from_le_bytes)
    }

    pub fn bool(&mut self) -> Result<bool, CdrError> {
        self.take::<1>().map(|[b]| b != 0)
    }

    pub fn f64s<const N: usize>(&mut self) -> Result<[f64; N], CdrError> {
        let mut values = [0.0; N];
        for v in &mut values {
            *v = self.f64()?;
        }
        Ok(values)
    }

    pub fn string(&mut self) -> Result<String, CdrError> {
        let len = self.u32()? as usize;
        let start = self.at;
        let bytes =
            (self.bytes.get(start..start + len)).ok_or(CdrError::Truncated(self.bytes.len()))?;
        self.at += len;
        match bytes.split_last() {
            Some((0, text)) => {
                String::from_utf8(text.to_vec()).map_err(|_| CdrError::String(start))
            }
            _ => Err(CdrError::String(start)),
        }
    }
}

/// A message with its CDR.
pub trait Message: Sized {
    fn write(&self, w: &mut Writer);
    fn read(r: &mut Reader) -> Result<Self, CdrError>;

    /// The payload of the message: header and fields.
    fn to_cdr(&self) -> Vec<u8> {
        let mut w = Writer::default();
        self.write(&mut w);
        w.into_bytes()
    }

    fn from_cdr(payload: &[u8]) -> Result<Self, CdrError> {
        Self::read(&mut Reader::new(payload)?)
    }
}

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/msg/Twist`: m/s and rad/s.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Twist {
    pub linear: [f64; 3],
    pub angular: [f64; 3],
}

/// `geometry_msgs/msg/TwistStamped`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}

/// `geometry_msgs/msg/Pose`: a position (m) and an orientation quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pose {
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `nav_msgs/msg/Odometry`: the pose in `header.frame_id`, the twist in `child_frame_id`,
/// each with its row-major 6×6 covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: Pose,
    pub pose_covariance: [f64; 36],
    pub twist: Twist,
    pub twist_covariance: [f64; 36],
}

/// `nav_msgs/msg/Path`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Path {
    pub header: Header,
    pub poses: Vec<PoseStamped>,
}

impl Message for Time {
    fn write(&self, w: &mut Writer) {
        w.i32(self.sec);
        w.u32(self.nanosec);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(Time {
            sec: r.i32()?,
            nanosec: r.u32()?,
        })
    }
}

impl Message for Header {
    fn write(&self, w: &mut Writer) {
        self.stamp.write(w);
        w.string(&self.frame_id);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(Header {
            stamp: Time::read(r)?,
            frame_id: r.string()?,
        })
    }
}

impl Message for Twist {
    fn write(&self, w: &mut Writer) {
        w.f64s(&self.linear);
        w.f64s(&self.angular);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(Twist {
            linear: r.f64s()?,
            angular: r.f64s()?,
        })
    }
}

impl Message for TwistStamped {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        self.twist.write(w);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(TwistStamped {
            header: Header::read(r)?,
            twist: Twist::read(r)?,
        })
    }
}

impl Message for Pose {
    fn write(&self, w: &mut Writer) {
        w.f64s(&self.position);
        w.f64s(&self.orientation);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(Pose {
            position: r.f64s()?,
            orientation: r.f64s()?,
        })
    }
}

impl Message for PoseStamped {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        self.pose.write(w);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(PoseStamped {
            header: Header::read(r)?,
            pose: Pose::read(r)?,
        })
    }
}

impl Message for Odometry {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        w.string(&self.child_frame_id);
        self.pose.write(w);
        w.f64s(&self.pose_covariance);
        self.twist.write(w);
        w.f64s(&self.twist_covariance);
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        Ok(Odometry {
            header: Header::read(r)?,
            child_frame_id: r.string()?,
            pose: Pose::read(r)?,
            pose_covariance: r.f64s()?,
            twist: Twist::read(r)?,
            twist_covariance: r.f64s()?,
        })
    }
}

impl Message for Path {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        w.u32(self.poses.len() as u32);
        self.poses.iter().for_each(|p| p.write(w));
    }
    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        let header = Header::read(r)?;
        let count = r.u32()? as usize;
        // Every pose takes at least 64 bytes: a count beyond the payload is a lie.
        if count > r.bytes.len() / 64 {
            return Err(CdrError::Truncated(r.bytes.len()));
        }
        let poses = (0..count)
            .map(|_| PoseStamped::read(r))
            .collect::<Result<_, _>>()?;
        Ok(Path { header, poses })
    }
}

mod markers;
pub use markers::{Marker, MarkerArray};
mod sensing;
pub use sensing::{LaserScan, TfMessage, TransformStamped};

#[cfg(test)]
mod tests;
