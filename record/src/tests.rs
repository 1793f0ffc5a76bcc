use super::*;
use protocol::{Actuation, Estimate};
use std::cell::RefCell;
use std::path::Path;
use std::rc::Rc;

/// What a sink of the test saw.
#[derive(Default)]
struct Seen {
    ticks: u64,
    verdicts: Vec<u64>,
    events: Vec<String>,
    ended_with: Option<u64>,
}

/// A sink that notes what reaches it.
struct Noting(Rc<RefCell<Seen>>);

impl Sink for Noting {
    fn sample(&mut self, sample: &Sample<'_>) -> std::io::Result<()> {
        let mut seen = self.0.borrow_mut();
        match sample {
            Sample::Tick(_) => seen.ticks += 1,
            Sample::Verdict(v) => seen.verdicts.push(v.sample),
            _ => {}
        }
        Ok(())
    }

    fn event(&mut self, line: &EventLine, json: &serde_json::Value) -> std::io::Result<()> {
        assert_eq!(json["event"], line.event.kind());
        self.0.borrow_mut().events.push(line.event.kind().into());
        Ok(())
    }

    fn end(self: Box<Self>, summary: &Summary, _whole: bool) -> std::io::Result<()> {
        self.0.borrow_mut().ended_with = Some(summary.ticks);
        Ok(())
    }
}

thread_local! {
    static SEEN: Rc<RefCell<Seen>> = Rc::default();
}

fn open_noting(_run: &RunStart) -> std::io::Result<Option<Box<dyn Sink>>> {
    Ok(Some(Box::new(Noting(SEEN.with(Rc::clone)))))
}

fn recorder(dir: &Path, scenario: &Scenario) -> Recorder {
    let sinks: [OpenSink; 4] = [
        sink::RunDirectory::open,
        sink::EventsFile::open,
        csv::CsvFiles::open,
        open_noting,
    ];
    Recorder::create(dir, scenario, &sinks).unwrap()
}

#[test]
fn a_registered_sink_gets_every_tick_each_verdict_once_every_event_and_the_summary() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::default();
    let mut recorder = recorder(dir.path(), &scenario);
    let (truth, estimate) = (GroundTruth::default(), Estimate::default());
    for _ in 0..3 {
        recorder
            .tick(&truth, None, &estimate, &Actuation::default())
            .unwrap();
    }
    let missed = DeadlineVerdict {
        sample: 1,
        ..DeadlineVerdict::default()
    };
    // The verdict, then its replay.
    recorder.verdict(&missed).unwrap();
    recorder.verdict(&missed).unwrap();
    recorder
        .finish(&scenario, "test", Outcome::Timeout, 0.0, None, None)
        .unwrap();
    SEEN.with(|seen| {
        let seen = seen.borrow();
        assert_eq!(seen.ticks, 3);
        assert_eq!(seen.verdicts, [1]);
        assert_eq!(seen.events, ["deadline_miss", "end"]);
        assert_eq!(seen.ended_with, Some(3));
    });
    // The run directory's sink closed last: the summary is written, INCOMPLETE gone.
    assert!(dir.path().join("summary.json").exists());
    assert!(!dir.path().join(INCOMPLETE).exists());
    let events = std::fs::read_to_string(dir.path().join("events.jsonl")).unwrap();
    assert_eq!(events.lines().count(), 2);
}

#[test]
fn the_summary_counts_each_dfls_interventions_once_however_they_arrive() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::default();
    let mut recorder = recorder(dir.path(), &scenario);
    let truth = GroundTruth {
        pose: [7.0, 7.0, 0.0],
        ..GroundTruth::default()
    };
    let estimate = Estimate::default();
    // The first DFL: a tick with two interventions (a plan refused and the committed
    // trajectory given up), then a replay of that tick; a restarted DFL (epoch 1)
    // counts from zero again.
    for (epoch, count, intervention) in [
        (0, 0, Intervention::None),
        (0, 2, Intervention::CommittedUnsafe),
        (0, 2, Intervention::CommittedUnsafe),
        (1, 1, Intervention::PlanRefused),
    ] {
        let mut act = Actuation {
            safety_interventions: count,
            intervention: intervention as u32,
            ..Actuation::default()
        };
        act.header.epoch = epoch;
        recorder.tick(&truth, None, &estimate, &act).unwrap();
    }
    let summary = recorder
        .finish(&scenario, "test", Outcome::Timeout, 0.0, None, None)
        .unwrap();
    assert_eq!(summary.safety_interventions, 3);
}

#[test]
fn percentiles_use_nearest_rank() {
    let v: Vec<f64> = (1..=100).map(f64::from).collect();
    assert_eq!(
        Percentiles::of(&v),
        Percentiles {
            p50: 50.0,
            p99: 99.0,
            max: 100.0
        }
    );
    assert_eq!(Percentiles::of(&[]), Percentiles::default());
}

/// A sink that cannot close.
struct Failing;

impl Sink for Failing {
    fn sample(&mut self, _sample: &Sample<'_>) -> std::io::Result<()> {
        Ok(())
    }

    fn end(self: Box<Self>, _summary: &Summary, _whole: bool) -> std::io::Result<()> {
        Err(std::io::Error::other("the disk is full"))
    }
}

#[test]
fn a_sink_that_cannot_close_leaves_the_run_incomplete_and_the_others_closed() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::default();
    let failing: OpenSink = |_| Ok(Some(Box::new(Failing)));
    let sinks = [sink::RunDirectory::open, csv::CsvFiles::open, failing];
    let mut recorder = Recorder::create(dir.path(), &scenario, &sinks).unwrap();
    // A plan the run ends before the DFL judges: its row is written as the CSV closes.
    recorder.plan(&Plan::default()).unwrap();
    let closed = recorder.finish(&scenario, "test", Outcome::Timeout, 0.0, None, None);
    assert_eq!(closed.unwrap_err().to_string(), "the disk is full");
    let plans = std::fs::read_to_string(dir.path().join("plans.csv")).unwrap();
    assert_eq!(plans.lines().count(), 2, "the header and the unjudged plan");
    assert!(dir.path().join(INCOMPLETE).exists());
    assert!(!dir.path().join("summary.json").exists());
}
