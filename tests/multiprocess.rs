//! Runs over iceoryx2: four real processes, real shared memory.

use crate::common;

use common::{
    leftovers, run, run_into_tempdir, scmpc, spawn_run, stderr, summary, unique_prefix, wait_for,
};
use protocol::Measurement;
use runtime::ipc::{MEASUREMENT, create_node, open_topic};
use std::path::Path;
use std::time::Duration;

fn trajectory(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("trajectory.csv")).expect("trajectory.csv missing")
}

/// Runs `scenario` in process and over iceoryx2 in lockstep; returns both directories.
fn both_modes(scenario: &str, sets: &[&str]) -> (tempfile::TempDir, tempfile::TempDir) {
    let (reference, ipc) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    for (dir, extra) in [(&reference, Some("--in-process")), (&ipc, None)] {
        let mut args = vec!["run", scenario, "--out", dir.path().to_str().unwrap()];
        args.extend(extra);
        for s in sets {
            args.extend(["--set", s]);
        }
        let out = run(&args);
        assert!(
            dir.path().join("summary.json").exists(),
            "{args:?} failed: {}",
            stderr(&out)
        );
    }
    (reference, ipc)
}

#[test]
fn lockstep_over_iceoryx2_matches_in_process_number_for_number() {
    let _machine = common::machine_shared();
    for scenario in ["paper", "paper-noisy"] {
        let (reference, ipc) = both_modes(scenario, &[]);
        assert_eq!(summary(ipc.path())["mode"], "lockstep");
        assert!(
            trajectory(ipc.path()) == trajectory(reference.path()),
            "{scenario}: trajectories differ"
        );
        let prefix = summary(ipc.path())["iceoryx2_prefix"]
            .as_str()
            .unwrap()
            .to_string();
        assert!(
            leftovers(&prefix).is_empty(),
            "left behind: {:?}",
            leftovers(&prefix)
        );
    }
}

#[test]
fn every_fault_gives_the_same_run_in_process_and_in_lockstep() {
    let _machine = common::machine_shared();
    // Each fault key with a value that exercises it, over the part of the run it acts in
    // (the links' faults need a second host and real time: tests/hosts.rs).
    let cases: [(&str, &[&str]); 9] = [
        (
            "mpc_delay_ms",
            &[
                "fault.mpc_delay_ms=60",
                "fault.mpc_delay_samples=[20, 21, 22]",
            ],
        ),
        (
            "mpc_delay_samples",
            &[
                "fault.mpc_delay_ms=130",
                "fault.mpc_delay_samples=\"30..40\"",
            ],
        ),
        (
            "mpc_delay_every",
            &["fault.mpc_delay_ms=120", "fault.mpc_delay_every=7"],
        ),
        (
            "mpc_fail_samples",
            &["fault.mpc_fail_samples=[10, 11, 12, 50]"],
        ),
        ("estimator_delay_ms", &["fault.estimator_delay_ms=0.2"]),
        ("mpc_ignore_obstacles", &["fault.mpc_ignore_obstacles=true"]),
        ("estimator_nan_from_s", &["fault.estimator_nan_from_s=3"]),
        // The tracker's, with the paper's obstacle tracked (a tracker runs).
        (
            "tracker_delay_ms",
            &["perception.kind=track", "fault.tracker_delay_ms=0.2"],
        ),
        (
            "tracker_drop_samples",
            &[
                "perception.kind=track",
                "fault.tracker_drop_samples=[20, 21, 22]",
            ],
        ),
    ];
    let keys = serde_json::to_value(protocol::FaultConfig::default()).unwrap();
    let keys: Vec<&String> = keys
        .as_object()
        .unwrap()
        .keys()
        .filter(|k| !k.starts_with("link_"))
        .collect();
    assert_eq!(
        keys.len(),
        cases.len(),
        "a fault key without a case here: {keys:?}"
    );
    for (key, sets) in cases {
        assert!(keys.iter().any(|k| *k == key), "{key} is no fault key");
        let sets = [sets, &["duration_s=6"]].concat();
        let (reference, ipc) = both_modes("paper-noisy", &sets);
        assert!(
            trajectory(ipc.path()) == trajectory(reference.path()),
            "{key}: trajectories differ"
        );
        assert_eq!(
            common::plans_made(ipc.path()),
            common::plans_made(reference.path()),
            "{key}: plans differ"
        );
        if key == "estimator_nan_from_s" {
            for dir in [&reference, &ipc] {
                let restarted = common::events(dir.path())
                    .iter()
                    .any(|e| e["event"] == "restarted" && e["role"] == "estimator");
                assert!(restarted, "the refused estimator was not replaced");
            }
        }
        for field in ["outcome", "deadline_misses", "solver_failures", "ticks"] {
            assert_eq!(
                summary(ipc.path())[field],
                summary(reference.path())[field],
                "{key}: {field}"
            );
        }
    }
}

#[test]
fn the_four_roles_are_separate_processes() {
    let _machine = common::machine_shared();
    let (dir, _) = run_into_tempdir(&["run", "--set", "duration_s=1"]);
    let pids = &summary(dir.path())["pids"];
    let mut all: Vec<u64> = ["orchestrator", "plant", "estimator", "mpc", "dfl"]
        .iter()
        .map(|r| pids[r].as_u64().unwrap_or_else(|| panic!("no pid for {r}")))
        .collect();
    all.sort_unstable();
    all.dedup();
    assert_eq!(all.len(), 5, "pids not distinct: {pids}");
    // events.jsonl tells the same story: four spawns, four clean exits, one end.
    let events = std::fs::read_to_string(dir.path().join("events.jsonl")).unwrap();
    let events: Vec<serde_json::Value> = events
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let count = |kind: &str| events.iter().filter(|e| e["event"] == kind).count();
    assert_eq!((count("spawned"), count("exited"), count("end")), (4, 4, 1));
    assert!(
        events
            .iter()
            .filter(|e| e["event"] == "exited")
            .all(|e| e["killed"] == false)
    );
}

#[test]
fn a_foreign_process_receives_the_plants_measurements_over_iceoryx2() {
    let _machine = common::machine_shared();
    let prefix = unique_prefix("tap");
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(
        dir.path(),
        &[
            "--mode",
            "realtime",
            "--set",
            "duration_s=4",
            "--prefix",
            &prefix,
        ],
    );
    let node = create_node(&prefix, "test-tap", false).unwrap();
    let mut receiver = None;
    assert!(
        wait_for(Duration::from_secs(3), || {
            receiver = open_topic::<Measurement>(&node, protocol::FIRST_ROBOT, MEASUREMENT)
                .ok()
                .and_then(|t| t.receiver().ok());
            receiver.is_some()
        }),
        "the measurement service never appeared"
    );
    let receiver = receiver.unwrap();
    let mut ticks = Vec::new();
    wait_for(Duration::from_secs(3), || {
        while let Ok(Some((m, _))) = receiver.receive() {
            ticks.push(m.header.tick);
        }
        ticks.len() >= 20
    });
    drop(receiver);
    drop(node);
    assert!(
        ticks.len() >= 20,
        "received only {} measurements",
        ticks.len()
    );
    assert!(
        ticks.windows(2).all(|w| w[1] > w[0]),
        "ticks out of order: {ticks:?}"
    );
    child.wait().unwrap();
    // The tap takes nothing from the run: it ran its 4 s (the ticks without a command are
    // for the real-time tests to judge: a CI run at 6f7633e recorded 798).
    let s = summary(dir.path());
    let (ticks, gaps) = (
        s["ticks"].as_u64().unwrap(),
        s["record_gaps"].as_u64().unwrap(),
    );
    assert_eq!(ticks + gaps, 800, "the tapped run did not run its 4 s: {s}");
}

#[test]
fn two_runs_at_the_same_time_do_not_see_each_other() {
    let _machine = common::machine_shared();
    let dirs: Vec<tempfile::TempDir> = (0..2).map(|_| tempfile::tempdir().unwrap()).collect();
    let children: Vec<_> = dirs
        .iter()
        .zip(["seed=1", "seed=2"])
        .map(|(dir, seed)| {
            scmpc()
                .args([
                    "run",
                    "paper-noisy",
                    "--set",
                    seed,
                    "--set",
                    "duration_s=10",
                ])
                .args(["--out", dir.path().to_str().unwrap()])
                .stdout(std::process::Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    for mut c in children {
        c.wait().unwrap();
    }
    for (dir, seed) in dirs.iter().zip(["seed=1", "seed=2"]) {
        let reference = tempfile::tempdir().unwrap();
        run(&[
            "run",
            "paper-noisy",
            "--in-process",
            "--set",
            seed,
            "--set",
            "duration_s=10",
            "--out",
            reference.path().to_str().unwrap(),
        ]);
        assert!(
            trajectory(dir.path()) == trajectory(reference.path()),
            "{seed}: the concurrent run was disturbed"
        );
    }
}

#[test]
fn sigint_ends_every_process_within_two_seconds_and_leaves_no_shared_memory() {
    let _machine = common::machine_alone();
    let prefix = unique_prefix("int");
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn_run(dir.path(), &["--mode", "realtime", "--prefix", &prefix]);
    // Mid-run: the plant is publishing.
    let running = wait_for(Duration::from_secs(5), || {
        std::fs::metadata(dir.path().join("trajectory.csv")).is_ok_and(|m| m.len() > 10_000)
    });
    assert!(running, "the run never started recording");
    // SAFETY: sending a signal to our own child process.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let sent = std::time::Instant::now();
    let status = child.wait().unwrap();
    assert!(
        sent.elapsed() < Duration::from_secs(2),
        "took {:?} to stop",
        sent.elapsed()
    );
    assert_eq!(
        status.code(),
        Some(1),
        "an interrupted run did not reach the goal"
    );
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "interrupted");
    for role in ["plant", "estimator", "mpc", "dfl"] {
        let pid = s["pids"][role].as_u64().unwrap();
        assert!(
            !Path::new(&format!("/proc/{pid}")).exists(),
            "{role} (pid {pid}) still running"
        );
    }
    assert!(
        leftovers(&prefix).is_empty(),
        "left behind: {:?}",
        leftovers(&prefix)
    );
}

#[test]
fn a_scenario_error_is_refused_before_any_process_starts() {
    let _machine = common::machine_shared();
    let prefix = unique_prefix("bad");
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        "--set",
        "mpc.horizon=0",
        "--prefix",
        &prefix,
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("mpc.horizon"));
    assert!(!out_dir.exists());
    assert!(leftovers(&prefix).is_empty());
}

/// `scmpc ARGS` with its stdout on a pseudo-terminal; returns what the terminal got.
fn run_on_a_terminal(args: &[&str]) -> String {
    use std::io::Read;
    use std::os::fd::{FromRawFd, OwnedFd};
    let (mut master, mut slave) = (0, 0);
    // SAFETY: both pointers are to valid ints; name, termios and window size may be null.
    let opened = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(opened, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: openpty returned two open descriptors that nothing else owns.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let mut child = common::scmpc()
        .args(args)
        .stdout(std::process::Stdio::from(slave))
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Read as it comes (a full terminal buffer would block the run); the read fails once
    // the child, the last holder of the other end, is gone.
    let reader = std::thread::spawn(move || {
        let mut master = std::fs::File::from(master);
        let mut seen = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = master.read(&mut buf) {
            if n == 0 {
                break;
            }
            seen.extend_from_slice(&buf[..n]);
        }
        String::from_utf8_lossy(&seen).into_owned()
    });
    child.wait().unwrap();
    reader.join().unwrap()
}

#[test]
fn a_run_shows_a_live_status_line_on_a_terminal_and_nothing_extra_otherwise() {
    // Two multi-process runs: beside the real-time tests, not during them.
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let on_terminal = dir.path().join("terminal");
    let seen = run_on_a_terminal(&[
        "run",
        "--set",
        "duration_s=3",
        "--out",
        on_terminal.to_str().unwrap(),
    ]);
    let erase = "\r\x1b[2K";
    assert!(
        seen.contains(&format!("{erase}t ")) && seen.contains("/ 3.0 s | deadline misses 0"),
        "{seen:?}"
    );
    assert!(
        seen.contains("sensor→actuator") && seen.contains("clearance"),
        "{seen:?}"
    );
    // The line is wiped before what the run prints at its end.
    assert!(seen.starts_with("run directory: "), "{seen:?}");
    let end = seen.find("  scenario ").unwrap();
    assert!(seen[..end].ends_with(erase), "{seen:?}");
    let piped = common::run(&[
        "run",
        "--set",
        "duration_s=3",
        "--out",
        dir.path().join("piped").to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&piped.stdout);
    assert!(
        !stdout.contains('\r') && !stdout.contains('\x1b'),
        "{stdout:?}"
    );
}

/// Each role's stderr goes to `logs/<role>.log` of the run directory, a replacement's
/// after it; a scheduled swap whose command fails is in the end table and `summary.json`;
/// `-v` (or `RUST_LOG=info`) says which process started where its stderr goes, `-q`
/// silences that.
#[test]
fn role_logs_a_failed_swap_and_verbosity_are_where_a_user_looks() {
    let _machine = common::machine_shared();
    let (dir, out) = run_into_tempdir(&[
        "run",
        "-v",
        "--set",
        "duration_s=1",
        "--set",
        r#"swap=[{time_s=0.2, role="mpc", command=["sh", "-c", "echo the-replacement-speaks >&2; exit 3"]}]"#,
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.starts_with("run directory: "), "{stdout}");
    let row = (stdout.lines())
        .find(|l| l.trim_start().starts_with("failed swap"))
        .unwrap_or_else(|| panic!("no failed swap in the end table: {stdout}"));
    assert!(
        row.contains("mpc epoch 1") && row.contains("exit status: 3"),
        "{row}"
    );
    let failed = &summary(dir.path())["failed_swaps"];
    assert_eq!(failed.as_array().map(Vec::len), Some(1), "{failed}");
    let mpc_log = std::fs::read_to_string(dir.path().join("logs/mpc.log")).unwrap();
    assert!(
        mpc_log.contains("=== mpc epoch 0")
            && mpc_log.contains("=== mpc epoch 1: sh -c")
            && mpc_log.contains("the-replacement-speaks"),
        "{mpc_log}"
    );
    for role in ["plant", "estimator", "dfl"] {
        assert!(
            dir.path().join(format!("logs/{role}.log")).exists(),
            "{role}"
        );
    }
    assert!(
        !stderr(&out).contains("the-replacement-speaks"),
        "{}",
        stderr(&out)
    );
    assert!(
        stderr(&out).contains("started the mpc process"),
        "{}",
        stderr(&out)
    );
    let quiet = scmpc()
        .args(["run", "-q", "--set", "duration_s=0.2", "--out"])
        .arg(dir.path().join("quiet"))
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(
        !stderr(&quiet).contains("started the"),
        "{}",
        stderr(&quiet)
    );
    let told = scmpc()
        .args(["run", "--set", "duration_s=0.2", "--out"])
        .arg(dir.path().join("told"))
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(
        stderr(&told).contains("started the mpc process"),
        "{}",
        stderr(&told)
    );
}
