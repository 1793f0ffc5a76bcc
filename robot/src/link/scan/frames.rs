//! Where the lidar sits on the base, from `tf_static`'s transforms: the chain from the
//! scan's frame up to the base's, flattened to the plane (`[x_m, y_m, yaw_rad]`; a lidar
//! mounted level, as a 2D scan assumes).

use ros2::cdr::TransformStamped;
use std::collections::BTreeMap;

/// Longest chain of frames followed (a loop in the transforms ends there).
const MAX_CHAIN: usize = 16;

/// A frame's mount on its parent, in the plane.
#[derive(Debug, Clone, PartialEq)]
pub struct Mount {
    pub parent: String,
    /// The child frame's origin and heading in the parent's, `[x_m, y_m, yaw_rad]`.
    pub pose: [f64; 3],
}

impl Mount {
    pub fn of(transform: &TransformStamped) -> Mount {
        let [x, y, _] = transform.translation;
        Mount {
            parent: transform.header.frame_id.clone(),
            pose: [x, y, crate::link::yaw(transform.rotation)],
        }
    }
}

/// The pose of `frame` in `base`, following each frame's mount on its parent; `None`
/// when the chain does not reach `base`.
pub fn mount_of(mounts: &BTreeMap<String, Mount>, frame: &str, base: &str) -> Option<[f64; 3]> {
    let mut pose = [0.0; 3];
    let mut at = frame;
    for _ in 0..MAX_CHAIN {
        if at == base {
            return Some(pose);
        }
        let mount = mounts.get(at)?;
        pose = protocol::mounted(mount.pose, pose);
        at = &mount.parent;
    }
    None
}
