//! A real-time run of the whole paper scenario (30 s of wall time).

mod common;

use common::{run, run_into_tempdir, stderr, summary};

#[test]
fn realtime_paper_run_reaches_the_goal_without_collision_or_deadline_miss() {
    let _machine = common::machine_alone();
    let (dir, out) = run_into_tempdir(&["run", "--mode", "realtime"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let s = summary(dir.path());
    assert_eq!(s["mode"], "realtime");
    assert_eq!(s["outcome"], "reached");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
    assert_eq!(s["deadline_misses"], 0);
    assert_eq!(s["record_gaps"], 0);
    assert!(s["leftover_files"].as_array().unwrap().is_empty());
    for key in ["p50", "p99", "max"] {
        assert!(s["loop_latency_us"][key].as_f64().unwrap() > 0.0);
        assert!(s["hop_latency_us"][key].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn realtime_late_plans_are_all_flagged_and_on_time_plans_never() {
    let _machine = common::machine_alone();
    // 1.5 Ts on every 20th sample over 20 s: samples 0, 20, ..., 380.
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "run",
        "--mode",
        "realtime",
        "--set",
        "duration_s=20",
        "--set",
        "fault.mpc_delay_ms=75",
    ];
    let out = run(&[
        &args[..],
        &[
            "--set",
            "fault.mpc_delay_every=20",
            "--out",
            dir.path().to_str().unwrap(),
        ],
    ]
    .concat());
    assert!(dir.path().join("summary.json").exists(), "{}", stderr(&out));
    let events = std::fs::read_to_string(dir.path().join("events.jsonl")).unwrap();
    let flagged: Vec<u64> = events
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|e| e["event"] == "deadline_miss")
        .map(|e| e["sample"].as_u64().unwrap())
        .collect();
    let delayed: Vec<u64> = (0..400).filter(|k| k % 20 == 0).collect();
    assert_eq!(
        flagged, delayed,
        "flagged samples differ from the delayed ones"
    );
    assert_eq!(summary(dir.path())["deadline_misses"], 20);
}
