//! A real-time run of the whole paper scenario (30 s of wall time).

mod common;

use common::{run, stderr, summary};

#[test]
fn realtime_paper_run_reaches_the_goal_without_collision_or_deadline_miss() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--mode",
        "realtime",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
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
