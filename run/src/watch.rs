//! Watching runs from outside, as `ros2 topic` and `dora list` do (docs/running.md,
//! "Watching a run"): the runs going on on this machine ([`running`], `scmpc ps`), the
//! data topics of one with their rates ([`topic_rates`], `scmpc topics`), and one topic's
//! samples as JSON lines ([`echo`], `scmpc echo`).
//!
//! A watcher only subscribes: it opens the run's services without creating any
//! ([`runtime::ipc::wire::watch`]), takes one subscriber slot of a topic, and its
//! subscriber's queue overflows (its oldest samples dropped) rather than holding up a
//! publisher. Samples are read as bytes and decoded by the layouts `scmpc schema` prints,
//! so a watcher sees what a process of another language would.

use crate::multiproc::RunInfo;
use anyhow::bail;
use runtime::ipc::{self, wire::WireTap};
use runtime::layout::TypeLayout;
use serde_json::{Map, Value, json};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// A run going on on this machine.
#[derive(Debug, Clone)]
pub struct Running {
    pub pid: u32,
    pub dir: PathBuf,
    /// `lockstep` or `realtime` (from its `run.json`; empty for a host's agent's share).
    pub mode: String,
    /// Its scenario's name (from the run directory's `scenario.toml`).
    pub scenario: String,
}

/// The runs going on on this machine, oldest prefix first.
pub fn running() -> Vec<Running> {
    (ipc::running_runs().into_iter())
        .map(|run| {
            let info = RunInfo::read(&run.dir).ok();
            let scenario = std::fs::read_to_string(run.dir.join("scenario.toml"))
                .ok()
                .and_then(|text| text.parse::<toml::Table>().ok())
                .and_then(|t| t.get("name").and_then(|n| n.as_str()).map(String::from))
                .unwrap_or_default();
            Running {
                pid: run.pid,
                mode: info.map_or_else(String::new, |i| i.mode),
                dir: run.dir,
                scenario,
            }
        })
        .collect()
}

/// The run recorded into `dir`, if it is going on: its `run.json`.
fn running_in(dir: &Path) -> anyhow::Result<RunInfo> {
    let info = RunInfo::read(dir)?;
    if dir.join("summary.json").exists() || !ipc::process_alive(info.orchestrator_pid) {
        bail!("{}: the run has ended", dir.display());
    }
    Ok(info)
}

/// A node of the run in `dir` for a watcher called `what`.
fn watcher_node(
    info: &RunInfo,
    what: &str,
) -> anyhow::Result<iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>> {
    let name = format!("{what}-{}", std::process::id());
    Ok(ipc::create_node(&info.iceoryx2_prefix, &name, false)?)
}

/// One data topic of a running run, as `scmpc topics` lists it.
#[derive(Debug, Clone)]
pub struct TopicRate {
    pub topic: &'static str,
    /// Its iceoryx2 type name.
    pub message: &'static str,
    /// The role that publishes it.
    pub producer: String,
    /// Samples per second over the time watched (0: none came).
    pub rate_hz: f64,
}

/// The data topics the run in `dir` has, each with the rate its samples came at over
/// `over` (wall time).
pub fn topic_rates(
    dir: &Path,
    over: Duration,
    stop: &AtomicBool,
) -> anyhow::Result<Vec<TopicRate>> {
    let info = running_in(dir)?;
    let node = watcher_node(&info, "topics")?;
    let taps: Vec<(&protocol::graph::Topic, Box<dyn WireTap>)> = (protocol::graph::TOPICS.iter())
        .filter_map(|t| {
            Some((
                t,
                ipc::wire::watch(&node, protocol::FIRST_ROBOT, t.name).ok()?,
            ))
        })
        .collect();
    let mut counts = vec![0u64; taps.len()];
    let started = Instant::now();
    while started.elapsed() < over
        && !stop.load(Ordering::Relaxed)
        && ipc::is_registered(&info.iceoryx2_prefix)
    {
        for ((_, tap), count) in taps.iter().zip(&mut counts) {
            tap.take(&mut |_, _| *count += 1)?;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let seconds = started.elapsed().as_secs_f64();
    Ok((taps.iter().zip(counts))
        .map(|((topic, _), count)| TopicRate {
            topic: topic.name,
            message: topic.message,
            producer: protocol::graph::producer_of(topic.name)
                .map_or_else(|| "-".into(), |r| r.as_str().to_string()),
            rate_hz: count as f64 / seconds,
        })
        .collect())
}

/// Prints the samples of `topic` of the run in `dir` to `out` as JSON lines, each with
/// the topic's name, until `count` samples (if given), the run's end or `stop`. Returns
/// how many were printed.
pub fn echo(
    dir: &Path,
    topic: &str,
    count: Option<u64>,
    stop: &AtomicBool,
    out: &mut dyn std::io::Write,
) -> anyhow::Result<u64> {
    let Some(declared) = protocol::graph::TOPICS.iter().find(|t| t.name == topic) else {
        let names: Vec<&str> = protocol::graph::TOPICS.iter().map(|t| t.name).collect();
        bail!("no data topic `{topic}` (there are: {})", names.join(", "));
    };
    let info = running_in(dir)?;
    let node = watcher_node(&info, "echo")?;
    let tap = ipc::wire::watch(&node, protocol::FIRST_ROBOT, topic)
        .map_err(|e| anyhow::anyhow!("this run has no topic `{topic}` ({e})"))?;
    let types = runtime::layout::types();
    let waitset = ipc::waitset(false)?;
    let _guard = ipc::attach(&waitset, tap.listener())?;
    let mut printed = 0;
    while !stop.load(Ordering::Relaxed) && count.is_none_or(|n| printed < n) {
        let mut failed = None;
        tap.take(&mut |bytes, _| {
            if failed.is_some() || count.is_some_and(|n| printed >= n) {
                return;
            }
            let mut line = (decode(&types, declared.message, bytes))
                .unwrap_or_else(|| json!({ "undecoded_bytes": bytes.len() }));
            if let Value::Object(fields) = &mut line {
                fields.insert("topic".into(), json!(topic));
            }
            match writeln!(out, "{line}").and_then(|()| out.flush()) {
                Ok(()) => printed += 1,
                Err(e) => failed = Some(e),
            }
        })?;
        if let Some(e) = failed {
            // A reader that went away (`| head`) ends the echo; nothing else is wrong.
            return match e.kind() {
                std::io::ErrorKind::BrokenPipe => Ok(printed),
                _ => Err(e.into()),
            };
        }
        tap.clear_wakeups();
        // The run unregisters as it ends, and waits for its watchers to leave.
        if !ipc::is_registered(&info.iceoryx2_prefix) || !ipc::process_alive(info.orchestrator_pid)
        {
            break;
        }
        ipc::wait(&waitset, Duration::from_millis(100))?;
    }
    Ok(printed)
}

/// A sample's bytes as JSON, field by field as the layout of `type_name` in `types`
/// describes it (`scmpc schema`): numbers as numbers (a `u128` as a decimal string, a NaN
/// as `null`), nested types as objects, arrays as arrays, and a `[u8; N]` as the text it
/// holds. `None` when the type is unknown or the bytes are too short.
pub fn decode(types: &[TypeLayout], type_name: &str, bytes: &[u8]) -> Option<Value> {
    let layout = types.iter().find(|t| t.type_name == type_name)?;
    let bytes = bytes.get(..layout.size)?;
    let mut fields = Map::new();
    for field in &layout.fields {
        let at = bytes.get(field.offset..field.offset + field.size)?;
        fields.insert(field.name.to_string(), value_of(types, &field.ty, at)?);
    }
    Some(Value::Object(fields))
}

/// The value of type `ty` (a layout's spelling: `f64`, `[f64; 3]`, `scmpc::Header`) in
/// `bytes`, which are exactly its size.
fn value_of(types: &[TypeLayout], ty: &str, bytes: &[u8]) -> Option<Value> {
    if let Some(inner) = ty.strip_prefix('[').and_then(|t| t.strip_suffix(']')) {
        let (element, n) = inner.rsplit_once("; ")?;
        let n: usize = n.parse().ok()?;
        if element == "u8" {
            let text = bytes.split(|b| *b == 0).next().unwrap_or(&[]);
            return Some(json!(String::from_utf8_lossy(text)));
        }
        let size = bytes.len().checked_div(n)?;
        return (bytes.chunks_exact(size))
            .map(|chunk| value_of(types, element, chunk))
            .collect::<Option<Vec<Value>>>()
            .map(Value::Array);
    }
    Some(match ty {
        "f64" => json!(f64::from_ne_bytes(bytes.try_into().ok()?)),
        "f32" => json!(f32::from_ne_bytes(bytes.try_into().ok()?)),
        "u64" => json!(u64::from_ne_bytes(bytes.try_into().ok()?)),
        "u32" => json!(u32::from_ne_bytes(bytes.try_into().ok()?)),
        "u128" => json!(u128::from_ne_bytes(bytes.try_into().ok()?).to_string()),
        nested => decode(types, nested, bytes)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, Measurement};

    #[test]
    fn a_sample_decodes_by_its_layout_into_the_fields_it_holds() {
        let measurement = Measurement {
            header: Header {
                tick: 42,
                time_s: 2.1,
                ..Header::default()
            },
            y: [1.0, -2.5, f64::NAN],
            odometry: [0.5, 0.0],
        };
        // SAFETY: a `#[repr(C)]` value of integers and floats, read as its bytes.
        let bytes = unsafe {
            std::slice::from_raw_parts(
                &measurement as *const Measurement as *const u8,
                size_of::<Measurement>(),
            )
        };
        let types = runtime::layout::types();
        let json = decode(&types, "scmpc::Measurement", bytes).unwrap();
        assert_eq!(json["header"]["tick"], 42);
        assert_eq!(json["header"]["time_s"], 2.1);
        assert_eq!(json["y"], json!([1.0, -2.5, null]));
        assert!(decode(&types, "scmpc::Measurement", &bytes[..10]).is_none());
        assert!(decode(&types, "scmpc::Nothing", bytes).is_none());
    }
}
