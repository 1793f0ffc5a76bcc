//! Consumers refuse samples they should not trust, count them, and carry on.

mod common;

use common::{run, spawn_run, summary, unique_prefix, wait_for};
use protocol::ipc::{ACTUATION, MEASUREMENT, create_node, open_topic};
use protocol::{Actuation, Header, Measurement, Message};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Publishes `message` with `epoch` on the run `prefix`'s topic `name` every millisecond
/// until `done`; returns how many were sent.
fn intrude<T: Message>(
    prefix: &str,
    name: &'static str,
    epoch: u32,
    message: T,
    done: &AtomicBool,
) -> u64 {
    let node = create_node(prefix, "intruder", false).unwrap();
    let mut topic = None;
    wait_for(Duration::from_secs(5), || {
        topic = open_topic::<T>(&node, name).ok();
        topic.is_some() || done.load(Ordering::Relaxed)
    });
    let Some(topic) = topic else { return 0 };
    let sender = topic.sender(epoch).unwrap();
    let mut sent = 0;
    while !done.load(Ordering::Relaxed) {
        if sender.send(message).is_ok() {
            sent += 1;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    sent
}

#[test]
fn a_foreign_actuation_under_a_wrong_epoch_has_no_effect_and_is_counted() {
    let _machine = common::machine_shared();
    let prefix = unique_prefix("epoch");
    let (reference, dir) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    run(&[
        "run",
        "--in-process",
        "--set",
        "duration_s=10",
        "--out",
        reference.path().to_str().unwrap(),
    ]);
    let done = AtomicBool::new(false);
    let rogue = Actuation {
        u1: 2.0,
        u2: 3.0,
        header: Header {
            tick: 1_000_000,
            ..Header::default()
        },
        ..Actuation::default()
    };
    let sent = std::thread::scope(|scope| {
        let intruder = scope.spawn(|| intrude(&prefix, ACTUATION, 7, rogue, &done));
        // Lockstep runs fast: slow the estimator a little so the intruder gets a word in.
        run(&[
            "run",
            "--set",
            "duration_s=10",
            "--set",
            "fault.estimator_delay_ms=0.2",
            "--prefix",
            &prefix,
            "--out",
            dir.path().to_str().unwrap(),
        ]);
        done.store(true, Ordering::Relaxed);
        intruder.join().unwrap()
    });
    assert!(sent > 0, "the intruder never published");
    let read =
        |d: &tempfile::TempDir| std::fs::read_to_string(d.path().join("trajectory.csv")).unwrap();
    assert!(
        read(&dir) == read(&reference),
        "the foreign actuation changed the trajectory"
    );
    let rejected = summary(dir.path())["rejected_samples"]["wrong_epoch"]
        .as_u64()
        .unwrap_or(0);
    assert!(
        rejected > 0,
        "no wrong-epoch rejection counted ({sent} sent)"
    );
    // The intruder outlived the run's own clean-up: remove what the run left.
    protocol::ipc::remove_run_resources(&prefix).unwrap();
    assert!(common::leftovers(&prefix).is_empty());
}

#[test]
fn a_sample_with_a_nan_is_rejected_and_counted_and_the_loop_continues() {
    let _machine = common::machine_alone();
    let prefix = unique_prefix("nan");
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(
        dir.path(),
        &[
            "--mode",
            "realtime",
            "--set",
            "duration_s=3",
            "--prefix",
            &prefix,
        ],
    );
    let done = AtomicBool::new(false);
    let poisoned = Measurement {
        y: [f64::NAN, 1.0, 0.0],
        ..Measurement::default()
    };
    let sent = std::thread::scope(|scope| {
        let intruder = scope.spawn(|| intrude(&prefix, MEASUREMENT, 0, poisoned, &done));
        child.wait().unwrap();
        done.store(true, Ordering::Relaxed);
        intruder.join().unwrap()
    });
    assert!(sent > 0, "the intruder never published");
    let s = summary(dir.path());
    assert!(
        s["rejected_samples"]["non_finite"].as_u64().unwrap_or(0) > 0,
        "{}",
        s["rejected_samples"]
    );
    assert_eq!(s["ticks"], 600, "the loop did not carry on");
    assert_ne!(s["outcome"], "aborted");
    assert_eq!(s["deadline_misses"], 0);
    protocol::ipc::remove_run_resources(&prefix).unwrap();
    assert!(common::leftovers(&prefix).is_empty());
}

#[test]
fn one_forged_measurement_a_million_ticks_ahead_is_refused_and_the_paper_run_goes_on() {
    let _machine = common::machine_alone();
    let prefix = unique_prefix("ahead");
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(dir.path(), &["--mode", "realtime", "--prefix", &prefix]);
    // A real measurement of the running run, copied: its run id and epoch are right.
    let node = create_node(&prefix, "forger", false).unwrap();
    let mut tap = None;
    assert!(wait_for(Duration::from_secs(5), || {
        tap = open_topic::<Measurement>(&node, MEASUREMENT)
            .ok()
            .and_then(|t| t.receiver().ok());
        tap.is_some()
    }));
    let tap = tap.unwrap();
    let mut real = None;
    assert!(
        wait_for(Duration::from_secs(10), || {
            while let Ok(Some((m, _))) = tap.receive() {
                real = Some(m);
            }
            real.is_some_and(|m| m.header.tick >= 400)
        }),
        "no measurement of t >= 2 s heard"
    );
    let mut forged = real.unwrap();
    forged.header.tick += 1_000_000;
    forged.header.time_s = forged.header.tick as f64 * 0.005; // consistent with its tick
    let forger = open_topic::<Measurement>(&node, MEASUREMENT)
        .unwrap()
        .sender(forged.header.epoch)
        .unwrap();
    forger.send(forged).unwrap();
    // Every subscriber of the topic gets it: the tap as well.
    assert!(
        wait_for(Duration::from_secs(5), || {
            let mut heard = false;
            while let Ok(Some((m, _))) = tap.receive() {
                heard |= m.header.tick == forged.header.tick;
            }
            heard
        }),
        "the forged sample was never delivered"
    );
    let status = child.wait().unwrap();
    drop((forger, tap, node));
    assert!(status.success(), "the run did not reach the goal");

    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached");
    assert_eq!(s["record_gaps"], 0);
    assert_eq!(s["restarts"], 0);
    assert_eq!(
        s["rejected_samples"],
        serde_json::json!({ "tick_ahead": 2 })
    );
    // Refused once by each consumer of the topic: the estimator and the recorder.
    let refusals: Vec<_> = common::events(dir.path())
        .into_iter()
        .filter(|e| e["event"] == "rejected")
        .map(|e| {
            (
                e["consumer"].clone(),
                e["reason"].clone(),
                e["count"].clone(),
            )
        })
        .collect();
    assert_eq!(refusals.len(), 2, "{refusals:?}");
    for (consumer, reason, count) in refusals {
        assert!(consumer == "estimator" || consumer == "orchestrator");
        assert_eq!(
            (reason.as_str(), count.as_u64()),
            (Some("tick_ahead"), Some(1))
        );
    }
}
