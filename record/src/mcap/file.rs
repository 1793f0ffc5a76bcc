//! `run.mcap` on disk: the [`Channels`] the encoder writes to a file.

use super::Channels;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// An open `run.mcap`.
pub struct McapFile {
    writer: mcap::Writer<BufWriter<File>>,
    channels: BTreeMap<String, u16>,
    sequence: u32,
}

/// An error of the MCAP writer, as an I/O error (the recorder's).
pub(super) fn io(e: mcap::McapError) -> std::io::Error {
    std::io::Error::other(format!("run.mcap: {e}"))
}

/// A new MCAP file at `path`, written as every `run.mcap` is.
pub(super) fn create(path: &Path) -> std::io::Result<mcap::Writer<BufWriter<File>>> {
    let file = BufWriter::new(File::create(path)?);
    // Chunks are kept in memory until whole (no seeking back to patch a chunk's
    // length), so a chunk on disk is a whole record: a run killed mid-chunk leaves a
    // file whose records read in order up to the last flush.
    mcap::WriteOptions::new()
        .disable_seeking(true)
        .profile("")
        .library(concat!("scmpc ", env!("CARGO_PKG_VERSION")))
        .create(file)
        .map_err(io)
}

impl McapFile {
    pub fn create(path: &Path) -> std::io::Result<McapFile> {
        let writer = create(path)?;
        Ok(McapFile {
            writer,
            channels: BTreeMap::new(),
            sequence: 0,
        })
    }
}

impl Channels for McapFile {
    fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &[u8],
    ) -> std::io::Result<()> {
        let schema_id = (self.writer)
            .add_schema(schema_name, "jsonschema", schema)
            .map_err(io)?;
        let channel = (self.writer)
            .add_channel(schema_id, topic, "json", &BTreeMap::new())
            .map_err(io)?;
        self.channels.insert(topic.to_string(), channel);
        Ok(())
    }

    fn message(&mut self, topic: &str, time_ns: u64, json: &[u8]) -> std::io::Result<()> {
        let channel_id = *(self.channels.get(topic)).ok_or_else(|| {
            std::io::Error::other(format!(
                "run.mcap: a message on {topic}, which has no channel"
            ))
        })?;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer
            .write_to_known_channel(&header, json)
            .map_err(io)
    }

    /// Closes the chunk being written and hands it to the file system: a reader that scans
    /// records in order reads everything up to here, whatever happens to the run after.
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer.flush().map_err(io)
    }

    fn finish(mut self) -> std::io::Result<()> {
        self.writer.finish().map(|_| ()).map_err(io)
    }
}
