//! `visualization_msgs/msg/MarkerArray` (Jazzy and Kilted) as the pipeline draws its
//! obstacles: shapes with a pose, a scale and a colour. The fields it does not use
//! (points, colours per point, textures, meshes) are written empty, and a marker that
//! carries them is not read.

use super::{CdrError, Header, Message, Pose, Reader, Time, Writer};

/// `visualization_msgs/msg/Marker`, the fields a shape needs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Marker {
    pub header: Header,
    pub ns: String,
    pub id: i32,
    /// [`Marker::CYLINDER`], ...
    pub kind: i32,
    /// [`Marker::ADD`] or [`Marker::DELETE_ALL`].
    pub action: i32,
    pub pose: Pose,
    /// m along x, y, z.
    pub scale: [f64; 3],
    /// `[r, g, b, a]`, 0 to 1.
    pub color: [f32; 4],
    /// How long the marker stays without a newer one (`builtin_interfaces/msg/Duration`,
    /// laid out as a time); zero: for ever.
    pub lifetime: Time,
    pub frame_locked: bool,
    pub text: String,
}

impl Marker {
    pub const CYLINDER: i32 = 3;
    pub const ADD: i32 = 0;
    pub const DELETE_ALL: i32 = 3;
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MarkerArray {
    pub markers: Vec<Marker>,
}

/// A sequence the crate writes empty: its count must be 0.
fn empty(r: &mut Reader, field: &'static str) -> Result<(), CdrError> {
    match r.u32()? {
        0 => Ok(()),
        _ => Err(CdrError::Unsupported(field)),
    }
}

impl Message for Marker {
    fn write(&self, w: &mut Writer) {
        self.header.write(w);
        w.string(&self.ns);
        w.i32(self.id);
        w.i32(self.kind);
        w.i32(self.action);
        self.pose.write(w);
        w.f64s(&self.scale);
        self.color.iter().for_each(|&c| w.f32(c));
        self.lifetime.write(w);
        w.bool(self.frame_locked);
        w.u32(0); // points
        w.u32(0); // colors
        w.string(""); // texture_resource
        Header::default().write(w); // texture: header, format, data
        w.string("");
        w.u32(0);
        w.u32(0); // uv_coordinates
        w.string(&self.text);
        w.string(""); // mesh_resource
        w.string(""); // mesh_file: filename, data
        w.u32(0);
        w.bool(false); // mesh_use_embedded_materials
    }

    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        let header = Header::read(r)?;
        let ns = r.string()?;
        let (id, kind, action) = (r.i32()?, r.i32()?, r.i32()?);
        let pose = Pose::read(r)?;
        let scale = r.f64s()?;
        let color = [r.f32()?, r.f32()?, r.f32()?, r.f32()?];
        let lifetime = Time::read(r)?;
        let frame_locked = r.bool()?;
        empty(r, "a marker's points")?;
        empty(r, "a marker's colors")?;
        r.string()?;
        Header::read(r)?;
        r.string()?;
        empty(r, "a marker's texture")?;
        empty(r, "a marker's uv_coordinates")?;
        let text = r.string()?;
        r.string()?;
        r.string()?;
        empty(r, "a marker's mesh_file")?;
        r.bool()?;
        Ok(Marker {
            header,
            ns,
            id,
            kind,
            action,
            pose,
            scale,
            color,
            lifetime,
            frame_locked,
            text,
        })
    }
}

impl Message for MarkerArray {
    fn write(&self, w: &mut Writer) {
        w.u32(self.markers.len() as u32);
        self.markers.iter().for_each(|m| m.write(w));
    }

    fn read(r: &mut Reader) -> Result<Self, CdrError> {
        let count = r.u32()? as usize;
        // Every marker takes well over 100 bytes: a count beyond the payload is a lie.
        if count > r.remaining() / 100 {
            return Err(CdrError::Truncated(r.remaining()));
        }
        let markers = (0..count)
            .map(|_| Marker::read(r))
            .collect::<Result<_, _>>()?;
        Ok(MarkerArray { markers })
    }
}
