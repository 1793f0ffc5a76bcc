//! The sinks of a run, both executors alike: the one place a new sink (a live view) is
//! registered ([`record::sink`]).

use anyhow::Context;
use record::csv::CsvFiles;
use record::sink::{EventsFile, RunDirectory};
use record::{Encoded, OpenSink, Recorder};
use std::path::Path;

/// The sinks every run has, in the order they open (and the reverse of the order they
/// close): the run directory's own files first, so that `summary.json` is written last.
const FILES: [OpenSink; 3] = [RunDirectory::open, EventsFile::open, CsvFiles::open];

/// What a run records beyond its files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Recording {
    /// `run.mcap` (`--no-mcap` leaves it out).
    pub mcap: bool,
    /// The status line (on a terminal) or progress lines (elsewhere): `scmpc run`'s
    /// without `-q`, not a study's (a sweep runs many at once).
    pub status_line: bool,
    /// The live view, when the scenario has `[live]` (`scmpc run`'s, not a study's).
    pub live: bool,
}

impl Recording {
    /// The files, with `run.mcap` if `mcap`, and no status line (studies and benches).
    pub fn files(mcap: bool) -> Recording {
        Recording {
            mcap,
            status_line: false,
            live: false,
        }
    }

    /// The sinks of a run that records this, in the order they open.
    pub fn sinks(self) -> Vec<OpenSink> {
        let mut sinks = FILES.to_vec();
        if self.mcap {
            sinks.push(Encoded::open_mcap);
        }
        if self.status_line {
            sinks.push(crate::status_line::StatusLine::open);
        }
        if self.live {
            sinks.push(live::open);
        }
        sinks
    }
}

/// The recorder of a run of `scenario` into `out`.
pub fn recorder(
    scenario: &protocol::Scenario,
    out: &Path,
    recording: Recording,
) -> anyhow::Result<Recorder> {
    Recorder::create(out, scenario, &recording.sinks())
        .with_context(|| format!("creating the record in {}", out.display()))
}

/// A fleet's live view, when `recording` has one and the fleet's scenario `[live]`
/// ([`live::FleetView`]): served from now on, each robot's record joining it
/// ([`member_recorder`]).
pub fn fleet_view(
    fleet: &protocol::Scenario,
    recording: Recording,
) -> anyhow::Result<Option<live::FleetView>> {
    if !recording.live {
        return Ok(None);
    }
    live::FleetView::serve(fleet).context("opening the fleet's live view")
}

/// The recorder of robot `id` of a fleet, whose scenario is `member`, into `dir`: the
/// sinks of `recording` but its status line and live view (the fleet has one of each),
/// and its part of the fleet's live `view`.
pub fn member_recorder(
    member: &protocol::Scenario,
    id: usize,
    dir: &Path,
    recording: Recording,
    view: Option<&live::FleetView>,
) -> anyhow::Result<Recorder> {
    let recording = Recording {
        status_line: false,
        live: false,
        ..recording
    };
    let recorder = recorder(member, dir, recording)?;
    let Some(view) = view else {
        return Ok(recorder);
    };
    let sink =
        (view.sink(id, member, recorder.goal_inbox())).context("joining the fleet's live view")?;
    Ok(recorder.with_sink(sink))
}

/// A fleet's `run.mcap` from its robots' ([`record::mcap::merge_fleet`]); a merge that
/// fails is a warning, and the robots keep their own files.
pub fn merge_fleet_mcap(out: &Path, robots: usize) {
    if let Err(e) = record::mcap::merge_fleet(out, robots) {
        tracing::warn!(
            "merging the robots' run.mcap in {}: {e}; each robot's is in robot<id>/",
            out.display()
        );
    }
}
