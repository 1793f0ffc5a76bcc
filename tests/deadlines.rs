//! Timing violations on purpose: every miss is flagged and the robot is never without a
//! safe command (docs/design.md, "Deadlines and fallback"). Real processes, lockstep clock.

use crate::common;

use common::{run, stderr, summary};
use record::schema::Table;
use std::path::Path;

/// Trajectory rows as `(t, zeta, u2, mode)`.
fn commands(dir: &Path) -> Vec<(f64, f64, f64, String)> {
    let table = Table::read(&dir.join("trajectory.csv")).unwrap();
    let (t, zeta, u2) = (
        table.numbers("t").unwrap(),
        table.numbers("zeta").unwrap(),
        table.numbers("u2").unwrap(),
    );
    let mode = table.column("mode").unwrap();
    (0..table.len())
        .map(|i| (t[i], zeta[i], u2[i], mode[i].to_string()))
        .collect()
}

fn miss_events(dir: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("events.jsonl")).unwrap();
    text.lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|e| e["event"] == "deadline_miss")
        .collect()
}

fn run_with(sets: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["run", "--out", dir.path().to_str().unwrap()];
    for s in sets {
        args.extend(["--set", s]);
    }
    let out = run(&args);
    assert!(dir.path().join("summary.json").exists(), "{}", stderr(&out));
    dir
}

#[test]
fn a_late_plan_at_samples_100_to_104_is_flagged_five_times_and_the_shifted_plan_drives() {
    let _machine = common::machine_shared();
    // 2.5 Ts: each of plans 100..=104 reaches the DFL 3 samples late.
    let dir = run_with(&[
        "fault.mpc_delay_ms=125",
        "fault.mpc_delay_samples=\"100..=104\"",
    ]);
    let s = summary(dir.path());
    assert_eq!(s["deadline_misses"], 5);
    assert_eq!(s["longest_miss_streak"], 5);
    assert_eq!(
        s["faults"].as_array().unwrap().len(),
        1,
        "the fault is not listed: {s}"
    );
    let samples: Vec<u64> = miss_events(dir.path())
        .iter()
        .map(|e| e["sample"].as_u64().unwrap())
        .collect();
    assert_eq!(samples, vec![100, 101, 102, 103, 104]);
    assert!(
        miss_events(dir.path())
            .iter()
            .all(|e| e["fallback"] == "shifted")
    );
    let in_window: Vec<_> = commands(dir.path())
        .into_iter()
        .filter(|c| (5.0..5.25 - 1e-9).contains(&c.0))
        .collect();
    assert_eq!(in_window.len(), 50);
    assert!(
        in_window.iter().all(|c| c.3 == "shifted"),
        "not all from the shifted plan"
    );
    assert_eq!(s["outcome"], "reached");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
}

#[test]
fn more_than_n_misses_exhaust_the_plan_and_the_dfl_brakes_until_plans_return() {
    let _machine = common::machine_shared();
    // Plans 100..=115 arrive 21 samples late: plan 99 covers samples up to 106 (N = 8),
    // then nothing does until plan 116 comes on time.
    let dir = run_with(&[
        "fault.mpc_delay_ms=1000",
        "fault.mpc_delay_samples=\"100..=115\"",
    ]);
    let s = summary(dir.path());
    assert_eq!(s["deadline_misses"], 16);
    assert_eq!(s["longest_miss_streak"], 16);
    let rows = commands(dir.path());
    let braking: Vec<_> = rows.iter().filter(|c| c.3 == "brake").collect();
    assert!(!braking.is_empty(), "the DFL never braked");
    let first = braking.first().unwrap().0;
    let last = braking.last().unwrap().0;
    assert!(
        (first - 5.35).abs() < 1e-6 && (last - 5.795).abs() < 1e-6,
        "braked from {first} to {last}"
    );
    assert!(braking.iter().all(|c| c.2 == 0.0), "steering while braking");
    for pair in rows
        .windows(2)
        .filter(|w| w[0].3 == "brake" && w[1].3 == "brake")
    {
        assert!(
            pair[1].1.abs() <= pair[0].1.abs(),
            "zeta grew while braking at t = {}",
            pair[1].0
        );
    }
    let after: Vec<_> = rows.iter().filter(|c| (5.8..5.85).contains(&c.0)).collect();
    // Back on the current plan (from rest, zeta starts below the guard's threshold).
    assert!(
        after
            .iter()
            .all(|c| c.3 == "nominal" || c.3 == "zeta_guard"),
        "plans came back but the DFL did not use them"
    );
}

#[test]
fn a_forced_solver_failure_is_flagged_with_its_status_and_handled_like_a_miss() {
    let _machine = common::machine_shared();
    let dir = run_with(&["fault.mpc_fail_samples=[50]"]);
    let s = summary(dir.path());
    assert_eq!(
        (s["deadline_misses"].as_u64(), s["solver_failures"].as_u64()),
        (Some(1), Some(1))
    );
    let misses = miss_events(dir.path());
    assert_eq!(misses.len(), 1);
    assert_eq!(
        (misses[0]["sample"].as_u64(), misses[0]["status"].as_str()),
        (Some(50), Some("numerical_error"))
    );
    let at_50: Vec<_> = commands(dir.path())
        .into_iter()
        .filter(|c| (2.5..2.55 - 1e-9).contains(&c.0))
        .collect();
    assert!(
        at_50.iter().all(|c| c.3 == "shifted"),
        "sample 50 did not use the shifted plan"
    );
    assert_eq!(s["outcome"], "reached");
}
