//! One `run.mcap` for a fleet (docs/fleet.md): the files its robots' recorders wrote,
//! `robot<id>/run.mcap`, merged into the run directory's, every channel under its robot's
//! id ([`fleet_topic`]) and every message in log-time order, as a viewer plays them.

use super::file::{create, io};
use std::collections::HashMap;
use std::iter::Peekable;
use std::path::Path;

/// The topic of robot `robot`'s channel `topic` in a fleet's `run.mcap`:
/// `/robot1/mpc/plan`.
pub fn fleet_topic(robot: usize, topic: &str) -> String {
    format!("/robot{robot}{topic}")
}

/// Merges `robot<id>/run.mcap` of robots `0..robots` in run directory `dir` into
/// `dir/run.mcap` and removes them. Nothing when the robots have none (a run without
/// `run.mcap`). A file that does not read, or a merge that fails, leaves every robot's
/// file where it is and no `dir/run.mcap`. Every robot's file is in log-time order (its
/// recorder writes each tick's messages after the last's); a channel without a message
/// has none to carry over and is left out.
pub fn merge_fleet(dir: &Path, robots: usize) -> std::io::Result<()> {
    let paths: Vec<_> = (0..robots)
        .map(|id| dir.join(format!("robot{id}")).join("run.mcap"))
        .collect();
    if !paths.iter().all(|p| p.exists()) {
        return Ok(());
    }
    // Every file in memory at once: a message can only be taken in log-time order
    // across them all.
    let files = (paths.iter().map(std::fs::read)).collect::<std::io::Result<Vec<_>>>()?;
    let mut streams = (files.iter())
        .map(|f| mcap::MessageStream::new(f).map(Iterator::peekable))
        .collect::<Result<Vec<_>, _>>()
        .map_err(io)?;
    let (merging, merged) = (dir.join("run.mcap.part"), dir.join("run.mcap"));
    let written = write_merged(&merging, &mut streams);
    if written.is_err() {
        let _ = std::fs::remove_file(&merging);
    }
    written?;
    std::fs::rename(&merging, &merged)?;
    for path in &paths {
        std::fs::remove_file(path)?;
    }
    Ok(())
}

/// Writes every message of `streams` (robot `i`'s at `i`) to a new file at `path`, the
/// earliest first (of equal times, the lowest robot's).
fn write_merged(path: &Path, streams: &mut [Peekable<mcap::MessageStream>]) -> std::io::Result<()> {
    let mut writer = create(path)?;
    let mut channels: HashMap<(usize, u16), u16> = HashMap::new();
    let mut sequence = 0_u32;
    loop {
        let earliest = (streams.iter_mut().enumerate())
            .filter_map(|(i, s)| Some((s.peek()?.as_ref().map_or(0, |m| m.log_time), i)))
            .min();
        let Some((_, i)) = earliest else {
            break;
        };
        let Some(message) = streams[i].next().transpose().map_err(io)? else {
            break;
        };
        let channel = &message.channel;
        let channel_id = match channels.get(&(i, channel.id)) {
            Some(id) => *id,
            None => {
                let schema_id = match &channel.schema {
                    Some(s) => writer
                        .add_schema(&s.name, &s.encoding, &s.data)
                        .map_err(io)?,
                    None => 0,
                };
                let id = (writer)
                    .add_channel(
                        schema_id,
                        &fleet_topic(i, &channel.topic),
                        &channel.message_encoding,
                        &channel.metadata,
                    )
                    .map_err(io)?;
                channels.insert((i, channel.id), id);
                id
            }
        };
        sequence = sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence,
            log_time: message.log_time,
            publish_time: message.publish_time,
        };
        (writer)
            .write_to_known_channel(&header, &message.data)
            .map_err(io)?;
    }
    writer.finish().map(|_| ()).map_err(io)
}
