//! Sinks: what a run's record is made of. A [`Sink`] is opened when the run starts, is
//! handed every sample the run records and every event, in the order they happen, and is
//! closed with the run's summary. Both executors feed every sink through one path, the
//! [`Recorder`](crate::Recorder); which sinks a run has is a list of [`OpenSink`]s
//! (`run::sinks::Recording::sinks`), so a new one (a live view) is one more entry there.
//!
//! The run directory's own files ([`RunDirectory`]: `INCOMPLETE`, `scenario.toml`,
//! `summary.json`) and `events.jsonl` ([`EventsFile`]) are sinks here; the CSV files are
//! [`crate::csv::CsvFiles`], `run.mcap` is [`crate::Encoded::open_mcap`].

use crate::lines::Lines;
use crate::{EventLine, Summary};
use protocol::{
    Actuation, DeadlineVerdict, Estimate, GroundTruth, Measurement, Plan, Route, Scenario, Tracks,
};
use std::path::Path;

/// What every sink is opened with.
pub struct RunStart<'a> {
    /// The run directory (it exists).
    pub dir: &'a Path,
    pub scenario: &'a Scenario,
    /// Where a sink that takes goals from outside (a live view's client) hands them to the
    /// run, checked ([`Scenario::live_goal`]); the executor sets them
    /// ([`crate::Recorder::requested_goal`]).
    pub goals: crate::goals::GoalInbox,
}

/// A sink's opener: `None` when the sink has nothing to record in this run.
pub type OpenSink = fn(&RunStart) -> std::io::Result<Option<Box<dyn Sink>>>;

/// One inner tick as it is recorded.
#[derive(Debug, Clone, Copy)]
pub struct TickSample<'a> {
    /// The truth at `t_j`.
    pub truth: &'a GroundTruth,
    /// The plant's measurement of the tick, when the executor has it as a message (a
    /// multi-process run).
    pub measurement: Option<&'a Measurement>,
    /// The estimate the DFL used (NaN when the estimator was silent).
    pub estimate: &'a Estimate,
    /// The command over `[t_j, t_j+1)`.
    pub actuation: &'a Actuation,
    /// The robot's clearance from the nearest obstacle at `t_j`, m (from its edge).
    pub clearance_m: f64,
}

/// A sample the run records, as its topic's message.
#[derive(Debug, Clone, Copy)]
pub enum Sample<'a> {
    Tick(TickSample<'a>),
    /// A plan as it is published.
    Plan(&'a Plan),
    /// The DFL's verdict on a sample, once (a replay is not handed on).
    Verdict(&'a DeadlineVerdict),
    /// A route newly planned, or none found (a route republished unchanged is not handed
    /// on).
    Route(&'a Route),
    Tracks(&'a Tracks),
    /// A message of a topic the record has no place of its own for, whose type names
    /// what it is recorded with ([`protocol::Message::RECORDED`]): a role added as
    /// docs/design.md says is recorded with no edit here.
    Data(&'a protocol::Data),
}

/// A part of the record (module docs).
pub trait Sink {
    /// A sample recorded.
    fn sample(&mut self, sample: &Sample<'_>) -> std::io::Result<()>;

    /// An event: its line, and the line as the JSON object written to `events.jsonl`.
    fn event(&mut self, _line: &EventLine, _json: &serde_json::Value) -> std::io::Result<()> {
        Ok(())
    }

    /// The run ended with `summary`; `whole`: every sink closed before this one did so
    /// without an error. Sinks are closed in the reverse order of their opening, so the
    /// run directory's, opened first, closes last.
    fn end(self: Box<Self>, _summary: &Summary, _whole: bool) -> std::io::Result<()> {
        Ok(())
    }
}

/// The file of a run directory whose run has not written `summary.json`: it is going on,
/// or it died (its orchestrator's pid, in the file, is gone). Removed with the summary.
pub const INCOMPLETE: &str = "INCOMPLETE";

/// The run directory's own files: [`INCOMPLETE`] and `scenario.toml` when the run starts,
/// `summary.json` (and `INCOMPLETE` removed) when it ends.
pub struct RunDirectory {
    dir: std::path::PathBuf,
}

impl RunDirectory {
    pub fn open(run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
        std::fs::write(
            run.dir.join(INCOMPLETE),
            format!(
                "This run has not written summary.json: it is going on, or its orchestrator \
                 (pid {}) died.\nIts records hold what happened up to {} ms before that, in \
                 whole lines; run.mcap is read by a reader that scans records in order.\n",
                std::process::id(),
                crate::FLUSH_PERIOD.as_millis()
            ),
        )?;
        std::fs::write(run.dir.join("scenario.toml"), run.scenario.to_toml())?;
        Ok(Some(Box::new(RunDirectory {
            dir: run.dir.to_path_buf(),
        })))
    }
}

impl Sink for RunDirectory {
    fn sample(&mut self, _sample: &Sample<'_>) -> std::io::Result<()> {
        Ok(())
    }

    /// A record that is not whole keeps [`INCOMPLETE`] and gets no summary.
    fn end(self: Box<Self>, summary: &Summary, whole: bool) -> std::io::Result<()> {
        if !whole {
            return Ok(());
        }
        let json = serde_json::to_string_pretty(summary).map_err(std::io::Error::other)?;
        std::fs::write(self.dir.join("summary.json"), json + "\n")?;
        std::fs::remove_file(self.dir.join(INCOMPLETE))
    }
}

/// `events.jsonl`: a line per event ([`EventLine`]), on disk at once (events are rare),
/// so a live run can be followed in the file.
pub struct EventsFile(Lines);

impl EventsFile {
    pub fn open(run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
        Ok(Some(Box::new(EventsFile(Lines::create(
            &run.dir.join("events.jsonl"),
        )?))))
    }
}

impl Sink for EventsFile {
    fn sample(&mut self, _sample: &Sample<'_>) -> std::io::Result<()> {
        Ok(())
    }

    fn event(&mut self, _line: &EventLine, json: &serde_json::Value) -> std::io::Result<()> {
        writeln!(self.0, "{json}")?;
        self.0.flush()
    }
}
