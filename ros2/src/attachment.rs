//! The attachment rmw_zenoh puts on every sample (`attachment_helpers.cpp`, Jazzy 0.2.4
//! on): the publisher's sequence number and the source timestamp, each an `int64`
//! little-endian, then the publisher's GID as zenoh-ext serializes a 16-byte array (its
//! length as a one-byte LEB128, `0x10`, then the bytes). A subscriber drops a sample
//! without one.

/// The length of the GID, bytes (`RMW_GID_STORAGE_SIZE`).
pub const GID_LEN: usize = 16;

/// The attachment's length, bytes.
pub const LEN: usize = 8 + 8 + 1 + GID_LEN;

/// What a publisher attaches to a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// Starts at 1 for each publisher and counts its samples.
    pub sequence_number: i64,
    /// When the sample was published, ns since the UNIX epoch.
    pub source_timestamp_ns: i64,
    pub gid: [u8; GID_LEN],
}

/// Why bytes are not an attachment.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AttachmentError {
    #[error("an attachment is {LEN} bytes, not {0}")]
    Length(usize),
    #[error("the GID's length is {0}, not {GID_LEN}")]
    GidLength(u8),
}

impl Attachment {
    pub fn to_bytes(&self) -> [u8; LEN] {
        let mut bytes = [0; LEN];
        bytes[..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        bytes[8..16].copy_from_slice(&self.source_timestamp_ns.to_le_bytes());
        bytes[16] = GID_LEN as u8;
        bytes[17..].copy_from_slice(&self.gid);
        bytes
    }

    pub fn from_bytes(bytes: &[u8]) -> Result<Attachment, AttachmentError> {
        let bytes: &[u8; LEN] = bytes
            .try_into()
            .map_err(|_| AttachmentError::Length(bytes.len()))?;
        if bytes[16] != GID_LEN as u8 {
            return Err(AttachmentError::GidLength(bytes[16]));
        }
        let int64 = |at: usize| {
            let mut le = [0; 8];
            le.copy_from_slice(&bytes[at..at + 8]);
            i64::from_le_bytes(le)
        };
        let mut gid = [0; GID_LEN];
        gid.copy_from_slice(&bytes[17..]);
        Ok(Attachment {
            sequence_number: int64(0),
            source_timestamp_ns: int64(8),
            gid,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_attachment_is_two_little_endian_int64_then_the_gid_with_its_length() {
        let a = Attachment {
            sequence_number: 1,
            source_timestamp_ns: 0x0102_0304_0506_0708,
            gid: core::array::from_fn(|i| 0xa0 + i as u8),
        };
        let bytes = a.to_bytes();
        assert_eq!(bytes.len(), 33);
        assert_eq!(bytes[..8], [1, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(bytes[8..16], [8, 7, 6, 5, 4, 3, 2, 1]);
        assert_eq!(bytes[16], 0x10);
        assert_eq!(bytes[17], 0xa0);
        assert_eq!(bytes[32], 0xaf);
        assert_eq!(Attachment::from_bytes(&bytes), Ok(a));
    }

    #[test]
    fn bytes_of_another_length_or_gid_length_are_refused() {
        let bytes = Attachment {
            sequence_number: 7,
            source_timestamp_ns: 9,
            gid: [3; GID_LEN],
        }
        .to_bytes();
        // The keyed format of Jazzy before 0.2.4 is 77 bytes.
        assert_eq!(
            Attachment::from_bytes(&[0; 77]),
            Err(AttachmentError::Length(77))
        );
        let mut wrong = bytes;
        wrong[16] = 8;
        assert_eq!(
            Attachment::from_bytes(&wrong),
            Err(AttachmentError::GidLength(8))
        );
    }
}
