//! The sinks of every run, both executors alike: the one list a new sink (a live view) is
//! registered in ([`record::sink`]).

use anyhow::Context;
use record::csv::CsvFiles;
use record::sink::{EventsFile, RunDirectory};
use record::{McapLog, OpenSink, Recorder, RunStart};
use std::path::Path;

/// Every sink a run has, in the order they open (and the reverse of the order they close):
/// the run directory's own files first, so that `summary.json` is written last.
pub const SINKS: [OpenSink; 5] = [
    RunDirectory::open,
    EventsFile::open,
    CsvFiles::open,
    McapLog::open,
    crate::status_line::StatusLine::open,
];

/// The recorder of a run of `scenario` into `out` (with `run.mcap` if `mcap`).
pub fn recorder(scenario: &protocol::Scenario, out: &Path, mcap: bool) -> anyhow::Result<Recorder> {
    let run = RunStart {
        dir: out,
        scenario,
        mcap,
    };
    Recorder::create(&run, &SINKS)
        .with_context(|| format!("creating the record in {}", out.display()))
}
