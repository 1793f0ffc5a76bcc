//! Consumers refuse samples they should not trust, count them, and carry on.

use crate::common;

use common::{run, spawn_run, summary, unique_prefix, wait_for};
use protocol::{Actuation, Control, ControlCommand, Header, Measurement};
use runtime::ipc::CONTROL;
use runtime::ipc::{ACTUATION, MEASUREMENT, create_node, open_topic};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Publishes `message` with `epoch` on the run `prefix`'s topic `name` every millisecond
/// until `done`; returns how many were sent.
fn intrude<T: runtime::ipc::Wire>(
    prefix: &str,
    name: &'static str,
    epoch: u32,
    message: T,
    done: &AtomicBool,
) -> u64 {
    let node = create_node(prefix, "intruder", false).unwrap();
    let mut topic = None;
    wait_for(Duration::from_secs(5), || {
        topic = open_topic::<T>(&node, protocol::FIRST_ROBOT, name).ok();
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
        // Lockstep runs fast: slow the estimator (2,000 ticks of at least 1 ms) so the
        // intruder, which joins when the run has made its topic, has a second or more to
        // be heard in (with 0.2 ms it was not, in 1 of 7 runs).
        run(&[
            "run",
            "--set",
            "duration_s=10",
            "--set",
            "fault.estimator_delay_ms=1",
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
    runtime::ipc::remove_run_resources(&prefix).unwrap();
    assert!(common::leftovers(&prefix).is_empty());
}

#[test]
fn an_estimator_whose_estimates_are_refused_for_half_a_second_is_restarted_and_the_goal_reached() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    // The first estimator publishes a NaN in every estimate from t = 5 s on.
    let out = run(&[
        "run",
        "--set",
        "fault.estimator_nan_from_s=5",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", common::stderr(&out));
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached");
    assert_eq!(s["restarts"], 1);
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
    let refused = s["rejected_samples"]["non_finite"].as_u64().unwrap_or(0);
    assert!(refused > 0, "{}", s["rejected_samples"]);
    let ev = common::events(dir.path());
    let find = |event: &str| {
        ev.iter()
            .position(|e| e["event"] == event && e["role"] == "estimator")
            .unwrap_or_else(|| panic!("no `{event}` of the estimator in {ev:#?}"))
    };
    let (failed, crashed, restarted) =
        (find("refused_too_long"), find("crashed"), find("restarted"));
    assert!(failed < crashed && crashed < restarted);
    assert_eq!(ev[failed]["epoch"], 0);
    assert!(ev[crashed]["status"].as_str().unwrap().contains("SIGKILL"));
    // Consumers refused the broken estimates, never a stranger's.
    for e in ev.iter().filter(|e| e["event"] == "rejected") {
        assert_eq!(e["reason"], "non_finite", "{e}");
    }
}

#[test]
fn a_forged_measurement_and_a_forged_stop_from_another_publisher_are_refused_and_the_run_goes_on() {
    // Alone, so that the run is not slowed; the claim is the refusals, not its timing.
    let _machine = common::machine_alone();
    let prefix = unique_prefix("ahead");
    let dir = tempfile::tempdir().unwrap();
    // Ended once the robot is held at its goal (`settle`), the input weighed less: about 9 s
    // instead of 30. The claim is the forgeries refused, not the paper's final approach.
    let args = [
        "--mode",
        "realtime",
        "--prefix",
        &prefix,
        "--set",
        "robot.final_approach=settle",
        "--set",
        "mpc.r_diag=[3,3]",
    ];
    let mut child = spawn_run(dir.path(), &args);
    // A real measurement and control message of the running run, copied: their run id,
    // epoch and times are right; only their publisher is not the one announced.
    let node = create_node(&prefix, "forger", false).unwrap();
    let mut taps = None;
    assert!(wait_for(Duration::from_secs(5), || {
        let measurement = open_topic::<Measurement>(&node, protocol::FIRST_ROBOT, MEASUREMENT)
            .and_then(|t| t.receiver());
        let control =
            open_topic::<Control>(&node, protocol::FIRST_ROBOT, CONTROL).and_then(|t| t.receiver());
        taps = measurement.ok().zip(control.ok());
        taps.is_some()
    }));
    let (tap, control_tap) = taps.unwrap();
    let (mut real, mut real_control) = (None, None);
    assert!(
        wait_for(Duration::from_secs(10), || {
            while let Ok(Some((m, _))) = tap.receive() {
                real = Some(m);
            }
            while let Ok(Some((c, _))) = control_tap.receive() {
                real_control = Some(c);
            }
            real.is_some_and(|m| m.header.tick >= 400) && real_control.is_some()
        }),
        "no measurement of t >= 2 s or no control message heard"
    );
    let mut forged = real.unwrap();
    forged.header.tick += 1_000_000;
    forged.header.time_s = forged.header.tick as f64 * 0.005; // consistent with its tick
    let forger = open_topic::<Measurement>(&node, protocol::FIRST_ROBOT, MEASUREMENT)
        .unwrap()
        .sender(forged.header.epoch)
        .unwrap();
    forger.send(forged).unwrap();
    let stop = Control {
        command: ControlCommand::Stop as u32,
        ..real_control.unwrap()
    };
    let control_forger = open_topic::<Control>(&node, protocol::FIRST_ROBOT, CONTROL)
        .unwrap()
        .sender(0)
        .unwrap();
    control_forger.send(stop).unwrap();
    // Every subscriber of the topics gets them: the taps as well.
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
    // Gone before the run ends, so that the run leaves nothing of its prefix behind; but
    // only once the six refusals are recorded (a publisher's samples not yet taken go with
    // it).
    let refusals_recorded = || {
        let text = std::fs::read_to_string(dir.path().join("events.jsonl")).unwrap_or_default();
        (text
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()))
        .filter(|e| e["event"] == "rejected")
        .count()
    };
    assert!(
        wait_for(Duration::from_secs(10), || refusals_recorded() >= 6),
        "{} refusals recorded",
        refusals_recorded()
    );
    drop((forger, control_forger, tap, control_tap, node));
    let status = child.wait().unwrap();
    assert!(status.success(), "the run did not reach the goal");

    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached");
    assert!(s["leftover_files"].as_array().unwrap().is_empty(), "{s}");
    assert!(
        common::leftovers(&prefix).is_empty(),
        "{:?}",
        common::leftovers(&prefix)
    );
    assert_eq!(s["restarts"], 0);
    // The measurement refused by its two consumers (the estimator and the recorder), the
    // stop by the four role processes.
    assert_eq!(
        s["rejected_samples"],
        serde_json::json!({ "unknown_publisher": 6 })
    );
    let mut refusals: Vec<String> = common::events(dir.path())
        .into_iter()
        .filter(|e| e["event"] == "rejected")
        .map(|e| {
            assert_eq!(
                (&e["reason"], &e["count"]),
                (&"unknown_publisher".into(), &1.into())
            );
            e["consumer"].as_str().unwrap().to_string()
        })
        .collect();
    refusals.sort();
    assert_eq!(
        refusals,
        [
            "dfl",
            "estimator",
            "estimator",
            "mpc",
            "orchestrator",
            "plant"
        ]
    );
}
