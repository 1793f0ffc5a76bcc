//! `scmpc bench` measures what it reports: every number present and plausible.

mod common;

use common::{run_into_tempdir, stderr};

#[test]
fn scmpc_bench_reports_the_pipeline_against_a_raw_iceoryx2_ping_pong() {
    let _machine = common::machine_alone();
    let (dir, out) = run_into_tempdir(&["bench", "--realtime-s", "2"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("raw iceoryx2 hop") && table.contains("lockstep"),
        "{table}"
    );
    let text = std::fs::read_to_string(dir.path().join("bench.json")).unwrap();
    let bench: serde_json::Value = serde_json::from_str(&text).unwrap();
    let number = |path: &[&str]| {
        path.iter()
            .fold(&bench, |v, k| &v[*k])
            .as_f64()
            .unwrap_or_else(|| panic!("{path:?} missing in {text}"))
    };
    let raw = number(&["raw_iceoryx2_one_way_us", "p50"]);
    let hop = number(&["pipeline_hop_us", "p50"]);
    assert!(raw > 0.0 && hop > 0.0);
    assert!((number(&["hop_ratio_p50"]) - hop / raw).abs() < 1e-9);
    assert!(number(&["raw_iceoryx2_one_way_us", "p99"]) >= raw);
    assert!(number(&["sensor_to_actuator_us", "p50"]) > 0.0);
    assert!(number(&["solve_us", "p50"]) > 0.0);
    for role in ["plant", "estimator", "mpc", "dfl", "orchestrator"] {
        let kib = number(&["peak_rss_kib", role]);
        assert!(kib > 1000.0, "{role}: {kib} KiB");
    }
    // The paper's 30 simulated seconds in lockstep take less than 30 s.
    assert_eq!(number(&["lockstep_simulated_s"]), 30.0);
    assert!(number(&["lockstep_speedup"]) > 1.0);
    assert!((number(&["lockstep_wall_s"]) * number(&["lockstep_speedup"]) - 30.0).abs() < 1e-6);
}
