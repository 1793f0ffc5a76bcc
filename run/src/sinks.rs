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

/// What a run records beyond its files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Recording {
    /// `run.mcap` (`--no-mcap` leaves it out).
    pub mcap: bool,
    /// The status line, when stdout is a terminal: `scmpc run`'s, not a study's (a sweep
    /// runs many at once).
    pub status_line: bool,
}

impl Recording {
    /// The files, with `run.mcap` if `mcap`, and no status line (studies and benches).
    pub fn files(mcap: bool) -> Recording {
        Recording {
            mcap,
            status_line: false,
        }
    }
}

/// The recorder of a run of `scenario` into `out`.
pub fn recorder(
    scenario: &protocol::Scenario,
    out: &Path,
    recording: Recording,
) -> anyhow::Result<Recorder> {
    let run = RunStart {
        dir: out,
        scenario,
        mcap: recording.mcap,
        status_line: recording.status_line,
    };
    Recorder::create(&run, &SINKS)
        .with_context(|| format!("creating the record in {}", out.display()))
}
