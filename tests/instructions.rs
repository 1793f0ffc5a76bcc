//! Regressions caught by instruction counts, not time: each hot path's instructions per
//! call, counted by `valgrind --tool=callgrind` on a fixed workload, held to its baseline in
//! `benches/instructions.toml`. More than 10 % above the baseline fails and says by how
//! much; more than 10 % below fails too, asking for the baseline to be updated in the same
//! commit as the change that made it faster (`SCMPC_UPDATE_INSTRUCTIONS=1 cargo test
//! --release --test suite instructions::` rewrites the file from this machine's counts).
//!
//! Instruction counts of a deterministic run repeat exactly from run to run; time on a
//! shared two-core machine varies by tens of percent. Every workload runs in process but
//! the lockstep orchestrator's. Of its loop, only the recording of each tick is counted
//! (`Intake::record`: the judge, the tables, the sinks): its waits, its polls for input,
//! its commands and checks run as often as its processes' timing makes them, and varied
//! by up to a third in CI, where its processes shared the CPUs with another workload under
//! callgrind. Counts are of the release build: a debug build is refused. Without valgrind
//! the test fails: it never skips (`.ci/run` installs valgrind where it is missing).

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The largest change from a baseline that passes, as a fraction of it.
const TOLERANCE: f64 = 0.10;

/// A hot path: the function counted, in which run, divided by what.
struct HotPath {
    /// Its key in the baselines file.
    key: &'static str,
    /// The function (callgrind's demangled name), counted with what it calls.
    function: &'static str,
    /// Divided by what it did.
    per: Per,
}

#[derive(Clone, Copy)]
enum Per {
    /// The calls of a function called once for each step that gave an output (the
    /// executor steps a task until it has nothing to do, so a task's own calls are more).
    CallOf(&'static str),
    /// The run's ticks (`summary.json`).
    Tick,
}

const MPC_STEP: &str = "<mpc::task::MpcTask as protocol::task::Task>::step";
const DFL_STEP: &str = "<dfl::task::DflTask as protocol::task::Task>::step";
const TRACKER_STEP: &str = "<tracker::task::TrackerTask as protocol::task::Task>::step";
/// Once per plan.
const PLANS: Per = Per::CallOf("mpc::Mpc::step_on_route");

/// A fixed workload (`scmpc` arguments) and the hot paths counted in it.
fn workloads() -> Vec<(&'static str, Vec<&'static str>, Vec<HotPath>)> {
    let path = |key, function, per| HotPath { key, function, per };
    let field = |n: &'static str, key| {
        (
            key,
            vec![
                "run",
                "field",
                "--in-process",
                "--set",
                n,
                "--set",
                "duration_s=3",
            ],
            vec![path(key, MPC_STEP, PLANS)],
        )
    };
    // The tracker's step in `world`, per tracks published (`published` is called once for
    // each: with the truth, or with a lidar).
    let tracker = |world, duration, key, published| {
        (
            world,
            vec!["run", world, "--in-process", "--set", duration],
            vec![path(key, TRACKER_STEP, Per::CallOf(published))],
        )
    };
    // The longest first (measure runs them two at a time).
    vec![
        field("mpc.horizon=30", "mpc_step_field_n30_3s"),
        field("mpc.horizon=16", "mpc_step_field_n16_3s"),
        field("mpc.horizon=8", "mpc_step_field_n8_3s"),
        (
            "paper",
            vec!["run", "--in-process", "--set", "duration_s=10"],
            vec![
                path("mpc_step_paper_10s", MPC_STEP, PLANS),
                path("dfl_step_paper_10s", DFL_STEP, Per::Tick),
            ],
        ),
        tracker(
            "crossing",
            "duration_s=10",
            "tracker_step_crossing_10s",
            "tracker::Tracker::tracks",
        ),
        tracker(
            "occluded",
            "duration_s=4",
            "perception_step_occluded_4s",
            "tracker::lidar::Perception::tracks",
        ),
        (
            "lockstep",
            vec!["run", "--mode", "lockstep", "--set", "duration_s=5"],
            vec![path(
                "orchestrator_record_tick_paper_5s",
                "run::multiproc::intake::Intake::record",
                Per::CallOf("run::multiproc::intake::Intake::record"),
            )],
        ),
    ]
}

/// What callgrind counted of each function: instructions with what it calls (inclusive),
/// and its calls.
#[derive(Debug, Default, Clone, Copy)]
struct Counted {
    inclusive: u64,
    calls: u64,
}

/// Reads a callgrind output file written with `--compress-strings=no --compress-pos=no`:
/// a function's `fn=` block holds its own costs (`position Ir` lines) and, after each
/// `calls=N ...` line, the inclusive cost of the call on the next line.
fn read_callgrind(text: &str) -> BTreeMap<String, Counted> {
    let mut counted: BTreeMap<String, Counted> = BTreeMap::new();
    let (mut function, mut callee) = (String::new(), String::new());
    let mut call_cost_next = false;
    // `position Ir`: the one event is the second number (a line of a position alone
    // would have cost nothing).
    let last_number = |line: &str| {
        line.split_whitespace()
            .nth(1)
            .and_then(|n| n.parse::<u64>().ok())
    };
    for line in text.lines() {
        if let Some(name) = line.strip_prefix("fn=") {
            function = name.to_owned();
        } else if let Some(name) = line.strip_prefix("cfn=") {
            callee = name.to_owned();
        } else if let Some(call) = line.strip_prefix("calls=") {
            let n = call.split_whitespace().next().and_then(|n| n.parse().ok());
            counted.entry(callee.clone()).or_default().calls += n.unwrap_or(0);
            call_cost_next = true;
        } else if line.starts_with(|c: char| c.is_ascii_digit() || c == '+' || c == '-') {
            // A cost line: own, or the inclusive cost of the call just named.
            if let Some(ir) = last_number(line) {
                counted.entry(function.clone()).or_default().inclusive += ir;
            }
            call_cost_next = false;
        } else if call_cost_next {
            panic!("callgrind output: a call without its cost: {line}");
        }
    }
    counted
}

/// Runs `scmpc ARGS` under callgrind into `dir`; returns what it counted and the run's
/// `summary.json`.
fn count(dir: &Path, name: &str, args: &[&str]) -> (BTreeMap<String, Counted>, serde_json::Value) {
    let out_file = dir.join(format!("{name}.callgrind"));
    let run_dir = dir.join(name);
    let output = std::process::Command::new("valgrind")
        .args([
            "--tool=callgrind",
            "--compress-strings=no",
            "--compress-pos=no",
        ])
        .arg(format!("--callgrind-out-file={}", out_file.display()))
        .arg(env!("CARGO_BIN_EXE_scmpc"))
        .args(args)
        .args(["-q", "--no-mcap", "--out"])
        .arg(&run_dir)
        .output();
    let output = match output {
        Ok(output) => output,
        Err(e) => panic!(
            "valgrind cannot be started ({e}): the instruction counts need it (Debian: \
             apt-get install valgrind; .ci/run installs it where it is missing)"
        ),
    };
    let text = std::fs::read_to_string(&out_file).unwrap_or_else(|e| {
        panic!(
            "{name}: no callgrind output ({e}): {}",
            common::stderr(&output)
        )
    });
    (read_callgrind(&text), common::summary(&run_dir))
}

/// Each hot path's instructions per call (or tick), by its key.
fn measure() -> BTreeMap<String, u64> {
    let dir = tempfile::tempdir().unwrap();
    let workloads = workloads();
    // Two runs at a time, the longest first: callgrind runs a program on one CPU.
    let next = std::sync::atomic::AtomicUsize::new(0);
    let counted = std::sync::Mutex::new(BTreeMap::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                while let Some((name, args, _)) =
                    workloads.get(next.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
                {
                    let c = count(dir.path(), name, args);
                    counted.lock().unwrap().insert(*name, c);
                }
            });
        }
    });
    let counted = counted.into_inner().unwrap();
    let mut per_call = BTreeMap::new();
    for (name, _, paths) in &workloads {
        let (functions, summary) = &counted[name];
        for path in paths {
            let Some(c) = functions.get(path.function) else {
                panic!("{name}: callgrind counted no `{}`", path.function)
            };
            let per = match path.per {
                Per::CallOf(once) => functions.get(once).map_or(0, |c| c.calls),
                Per::Tick => summary["ticks"].as_u64().expect("ticks"),
            };
            assert!(per > 0, "{}: `{}` never ran", path.key, path.function);
            per_call.insert(path.key.to_owned(), c.inclusive / per);
        }
    }
    per_call
}

fn baselines_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/instructions.toml")
}

/// The commit the counts are taken at (`+` when the working tree differs from it).
fn taken_at() -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
            .unwrap_or_default()
    };
    let commit = git(&["rev-parse", "--short=7", "HEAD"]);
    let dirty = !git(&["status", "--porcelain", "--untracked-files=no"]).is_empty();
    format!("{commit}{}", if dirty { "+" } else { "" })
}

fn write_baselines(counts: &BTreeMap<String, u64>) {
    let mut text = format!(
        "# Instructions per call (per tick for the orchestrator) of each hot path, counted by\n\
         # `valgrind --tool=callgrind` on the workloads of tests/instructions.rs, which fails\n\
         # when a count moves more than 10 % from its baseline here. Rewritten by\n\
         # `SCMPC_UPDATE_INSTRUCTIONS=1 cargo test --release --test suite instructions::`.\n\
         # `taken_at`: the commit (`+`: with the change it is committed with).\n\
         taken_at = \"{}\"\ndate = \"{}\"\n\n[instructions]\n",
        taken_at(),
        today()
    );
    for (key, n) in counts {
        text.push_str(&format!("{key} = {n}\n"));
    }
    std::fs::write(baselines_file(), text).expect("writing the baselines");
}

/// Today's date (UTC), `YYYY-MM-DD`.
fn today() -> String {
    let out = std::process::Command::new("date")
        .args(["-u", "+%Y-%m-%d"])
        .output()
        .expect("date");
    String::from_utf8_lossy(&out.stdout).trim().to_owned()
}

fn read_baselines() -> BTreeMap<String, u64> {
    let text = std::fs::read_to_string(baselines_file()).expect("benches/instructions.toml");
    let table: toml::Table = text.parse().expect("benches/instructions.toml is not TOML");
    table["instructions"]
        .as_table()
        .expect("[instructions]")
        .iter()
        .map(|(k, v)| (k.clone(), v.as_integer().expect("a count") as u64))
        .collect()
}

/// Each count's change from its baseline that is more than [`TOLERANCE`]; and keys in one
/// but not the other.
fn judge(baselines: &BTreeMap<String, u64>, counts: &BTreeMap<String, u64>) -> Vec<String> {
    let mut wrong = Vec::new();
    for (key, &n) in counts {
        let Some(&base) = baselines.get(key) else {
            wrong.push(format!("{key}: {n} has no baseline"));
            continue;
        };
        let change = n as f64 / base as f64 - 1.0;
        if n as f64 > base as f64 * (1.0 + TOLERANCE) {
            wrong.push(format!(
                "{key}: {n} instructions, {:.1} % above its baseline {base}",
                100.0 * change
            ));
        } else if (n as f64) < base as f64 * (1.0 - TOLERANCE) {
            wrong.push(format!(
                "{key}: {n} instructions, {:.1} % below its baseline {base}: update the \
                 baseline in the commit that made it faster",
                -100.0 * change
            ));
        }
    }
    for key in baselines.keys().filter(|k| !counts.contains_key(*k)) {
        wrong.push(format!("{key}: a baseline no workload counts"));
    }
    wrong
}

#[test]
fn each_hot_paths_instructions_stay_within_ten_percent_of_its_baseline() {
    let _machine = common::machine_shared();
    if cfg!(debug_assertions) {
        panic!("the baselines count the release build: run `cargo test --release`");
    }
    let counts = measure();
    for (key, n) in &counts {
        eprintln!("{key}: {n} instructions");
    }
    if std::env::var_os("SCMPC_UPDATE_INSTRUCTIONS").is_some() {
        write_baselines(&counts);
        eprintln!("baselines written to {}", baselines_file().display());
        return;
    }
    let wrong = judge(&read_baselines(), &counts);
    assert!(
        wrong.is_empty(),
        "instruction counts off their baselines (benches/instructions.toml, taken at {}):\n{}",
        read_baselines_taken_at(),
        wrong.join("\n")
    );
}

fn read_baselines_taken_at() -> String {
    let text = std::fs::read_to_string(baselines_file()).unwrap_or_default();
    let table: toml::Table = text.parse().unwrap_or_default();
    table
        .get("taken_at")
        .and_then(|v| v.as_str())
        .unwrap_or("?")
        .to_owned()
}

#[test]
fn a_count_more_than_ten_percent_off_its_baseline_fails_saying_by_how_much() {
    let baselines = BTreeMap::from([("a".to_owned(), 1000), ("b".to_owned(), 1000)]);
    let within = BTreeMap::from([("a".to_owned(), 1100), ("b".to_owned(), 900)]);
    assert!(judge(&baselines, &within).is_empty());
    let off = BTreeMap::from([("a".to_owned(), 1150), ("b".to_owned(), 850)]);
    let wrong = judge(&baselines, &off);
    assert!(wrong[0].contains("15.0 % above"), "{wrong:?}");
    assert!(wrong[1].contains("15.0 % below") && wrong[1].contains("update"));
}

#[test]
fn callgrinds_output_is_read_as_inclusive_counts_and_calls() {
    // An inlined file between cost lines, and a function in two blocks.
    let text = "events: Ir\nfn=outer\n0 10\ncfn=inner\ncalls=3 0\n0 300\nfi=x.rs\n12 5\n\
                fe=y.rs\nfn=inner\n0 300\nfn=outer\n0 1\n";
    let counted = read_callgrind(text);
    assert_eq!(counted["outer"].inclusive, 316);
    assert_eq!(counted["inner"].calls, 3);
    assert_eq!(counted["inner"].inclusive, 300);
}
