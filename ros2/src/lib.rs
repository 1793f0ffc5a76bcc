//! A ROS 2 robot as the pipeline sees it (issue 46, docs/ros2.md): rmw_zenoh's wire
//! format, byte for byte, with no ROS installation. This crate holds the format alone and
//! no transport: the data keys and the liveliness tokens ([`keys`]), the attachment every
//! rmw_zenoh publisher sends with a sample ([`attachment`]), and the CDR of the messages a
//! differential-drive base speaks ([`cdr`]).
//!
//! The facts it follows are rmw_zenoh's (`ros2/rmw_zenoh`, `docs/design.md` and
//! `rmw_zenoh_cpp/src/detail/`: `liveliness_utils.cpp`, `attachment_helpers.cpp`,
//! `qos.cpp`) for Jazzy from 0.2.4 on, and the same for Kilted and Rolling.

pub mod attachment;
pub mod cdr;
pub mod keys;

pub use attachment::Attachment;
pub use keys::{Distro, EntityKind, MessageType, NameError, Node, Qos};
