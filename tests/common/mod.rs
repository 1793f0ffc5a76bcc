//! Helpers shared by the cross-process tests: run the real `scmpc` executable.

#![allow(dead_code)]

pub mod agent;
pub mod python;
pub mod ros2;
pub mod stalls;

use std::path::Path;
use std::process::{Command, Output};

pub fn scmpc() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scmpc"))
}

/// Runs `scmpc` with `args`, failing the test if it cannot be started.
pub fn run(args: &[&str]) -> Output {
    scmpc().args(args).output().expect("cannot start scmpc")
}

/// Runs `scmpc ARGS --out DIR` with `DIR` a fresh temporary directory, returned with
/// the output (the directory lives as long as the returned handle).
pub fn run_into_tempdir(args: &[&str]) -> (tempfile::TempDir, Output) {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().to_str().unwrap().to_owned();
    let out = run(&[args, &["--out", &out_dir]].concat());
    (dir, out)
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Runs scenario `file` in real time into `dir/run`; returns that directory, its summary
/// and its events.
pub fn run_realtime(
    dir: &Path,
    file: &str,
) -> (
    std::path::PathBuf,
    serde_json::Value,
    Vec<serde_json::Value>,
) {
    let out_dir = dir.join("run");
    let out = run(&[
        "run",
        file,
        "--mode",
        "realtime",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    (out_dir.clone(), summary(&out_dir), events(&out_dir))
}

/// The run directory's `summary.json`.
pub fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json missing");
    serde_json::from_str(&text).expect("summary.json is not JSON")
}

/// Files of the iceoryx2 run `prefix` still in `/dev/shm` or iceoryx2's directory.
pub fn leftovers(prefix: &str) -> Vec<std::path::PathBuf> {
    runtime::ipc::leftover_files(prefix)
}

/// A prefix no other test uses.
pub fn unique_prefix(tag: &str) -> String {
    use std::sync::atomic::{AtomicU32, Ordering};
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    format!(
        "scmpct{}{tag}{}_",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// Polls `condition` every 10 ms until it holds or `timeout` passes; returns whether it held.
pub fn wait_for(timeout: std::time::Duration, mut condition: impl FnMut() -> bool) -> bool {
    let deadline = std::time::Instant::now() + timeout;
    while std::time::Instant::now() < deadline {
        if condition() {
            return true;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    condition()
}

/// Whether `events` hold an `event` of `role`.
pub fn has_event(events: &[serde_json::Value], event: &str, role: &str) -> bool {
    events
        .iter()
        .any(|e| e["event"] == event && e["role"] == role)
}

/// The run's `events.jsonl` as far as it has been written.
pub fn events(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("events.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// The pid of `role` from the run's `spawned` events, once the run is ready.
pub fn wait_for_pid(dir: &Path, role: &str) -> u32 {
    let mut pid = None;
    let ready = wait_for(std::time::Duration::from_secs(10), || {
        let ev = events(dir);
        pid = ev
            .iter()
            .find(|e| e["event"] == "spawned" && e["role"] == role)
            .and_then(|e| e["pid"].as_u64());
        pid.is_some() && ev.iter().any(|e| e["event"] == "ready")
    });
    assert!(ready, "the run never became ready");
    pid.unwrap() as u32
}

/// The processes whose parent is `pid` now.
pub fn children_of(pid: u32) -> Vec<u32> {
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    entries
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|child| {
            let stat = std::fs::read_to_string(format!("/proc/{child}/stat")).unwrap_or_default();
            // `pid (comm) state ppid ...`: the fields after the last `)`.
            let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
            after.split_whitespace().nth(1) == Some(pid.to_string().as_str())
        })
        .collect()
}

pub fn sigkill(pid: u32) {
    // SAFETY: sending a signal to a process this test started.
    unsafe { libc::kill(pid as i32, libc::SIGKILL) };
}

/// Starts `scmpc run ARGS --out DIR` in the background, its stdout discarded.
pub fn spawn_run(dir: &Path, args: &[&str]) -> std::process::Child {
    scmpc()
        .arg("run")
        .args(args)
        .args(["--out", dir.to_str().expect("non-UTF-8 temp dir")])
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("cannot start scmpc")
}

/// The simulated time of a run as its plant publishes it: a subscriber on the `truth`
/// service of the run with iceoryx2 prefix `prefix`.
pub struct SimulatedClock {
    truth: runtime::ipc::Receiver<protocol::GroundTruth>,
    _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
    now_s: f64,
}

impl SimulatedClock {
    pub fn of(prefix: &str) -> SimulatedClock {
        use runtime::ipc::{TRUTH, create_node, open_topic};
        let node = create_node(prefix, "test-clock", false).expect("a node of the run");
        let truth = open_topic::<protocol::GroundTruth>(&node, protocol::FIRST_ROBOT, TRUTH)
            .and_then(|t| t.receiver())
            .expect("the run's truth");
        SimulatedClock {
            truth,
            _node: node,
            now_s: 0.0,
        }
    }

    /// Waits until the run has simulated `t_s` (at most 30 s of wall time).
    pub fn wait_until(&mut self, t_s: f64) {
        let reached = wait_for(std::time::Duration::from_secs(30), || {
            while let Ok(Some((truth, _))) = self.truth.receive() {
                self.now_s = truth.header.time_s;
            }
            self.now_s >= t_s
        });
        assert!(
            reached,
            "the run never reached t = {t_s} s (at {} s)",
            self.now_s
        );
    }
}

/// Whether `pid` is the process of `role` in the run with iceoryx2 prefix `prefix` (and
/// not a pid the system has given to another process since).
pub fn is_role_process(pid: u32, role: &str, prefix: &str) -> bool {
    let environ = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
    let has = |var: String| environ.split(|b| *b == 0).any(|v| v == var.as_bytes());
    has(format!("SCMPC_ROLE={role}")) && has(format!("SCMPC_PREFIX={prefix}"))
}

/// Runs `scmpc run ARGS` into `dir`, SIGKILLs the `role` process once the run has
/// simulated `at_s`, and waits for the run to end.
pub fn kill_role_during_run(dir: &Path, args: &[&str], role: &str, at_s: f64) {
    let prefix = unique_prefix("kill");
    let mut child = spawn_run(dir, &[args, &["--prefix", &prefix]].concat());
    let pid = wait_for_pid(dir, role);
    SimulatedClock::of(&prefix).wait_until(at_s);
    assert!(
        is_role_process(pid, role, &prefix),
        "pid {pid} is no longer the {role}"
    );
    sigkill(pid);
    child.wait().expect("the run did not end");
}

/// A CSV file as rows of `column -> value`.
pub fn csv(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(String::from))
                .collect()
        })
        .collect()
}

/// A number of a [`csv`] row.
pub fn num(row: &std::collections::HashMap<String, String>, column: &str) -> f64 {
    row[column]
        .parse()
        .unwrap_or_else(|_| panic!("{column} = {:?}", row[column]))
}

/// The machine as the tests share it: the harness runs them on parallel threads, in one
/// binary (tests/suite.rs). Every test that starts a process or keeps a core busy holds it,
/// alone ([`machine_alone`]) or shared ([`machine_shared`]).
static MACHINE: std::sync::RwLock<()> = std::sync::RwLock::new(());

/// For a real-time test: holds the machine alone for as long as the value lives. Its
/// timing claims (no deadline miss, no record gap, every tick) cannot hold with another
/// run on the same two cores (README, "On a new machine"), nor in a stall of the machine
/// itself, which it watches for meanwhile ([`Alone::judge`]). A test whose name claims
/// timing runs under [`until_judged`]; one that holds the machine alone only so that its
/// run is not slowed takes it here.
pub fn machine_alone() -> Alone {
    let guard = MACHINE
        .write()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    Alone {
        stalls: stalls::Stalls::watch(),
        attempt: 1,
        _guard: guard,
    }
}

/// How many times [`until_judged`] runs a test while the machine is too busy to judge it.
pub const ATTEMPTS: u32 = 3;

/// For a test of a real-time claim: runs `attempt` (one real-time run, the checks of its
/// behaviour, and its judgement by [`Alone::judge`], whose `?` ends the attempt when the
/// machine was too busy to judge the run) with the machine alone. While the machine was
/// too busy, the attempt runs again once the machine is calm (at most 3 minutes of
/// waiting: [`stalls::Stalls::wait_for_calm`]), up to [`ATTEMPTS`] in all; then the test
/// fails. A fault outside every stall fails it at once. (The CI run at the end of a
/// session on 2026-12-01 failed five real-time tests in one busy spell of the VM: one run
/// saw 826 stalls in 8 s.)
pub fn until_judged<T>(attempt: impl FnMut(&Alone) -> Result<T, stalls::TooBusy>) -> T {
    until_judged_waiting(|machine| machine.stalls.wait_for_calm(), attempt)
}

/// [`until_judged`], with `wait` before each attempt after the first (how long it waited).
pub fn until_judged_waiting<T>(
    mut wait: impl FnMut(&Alone) -> std::time::Duration,
    mut attempt: impl FnMut(&Alone) -> Result<T, stalls::TooBusy>,
) -> T {
    let mut too_busy = Vec::new();
    for n in 1..=ATTEMPTS {
        let mut machine = machine_alone();
        machine.attempt = n;
        if n > 1 {
            let waited = wait(&machine);
            eprintln!("attempt {n} of {ATTEMPTS}, after {waited:.1?} waiting for calm");
        }
        match attempt(&machine) {
            Ok(value) => return value,
            Err(stalls::TooBusy(why)) => too_busy.push(why),
        }
    }
    panic!("{ATTEMPTS} attempts, each too busy to judge: {too_busy:#?}")
}

/// The machine held alone ([`machine_alone`]), its stalls watched.
pub struct Alone {
    pub stalls: stalls::Stalls,
    /// Which of [`until_judged`]'s attempts this is (1 outside it).
    pub attempt: u32,
    _guard: std::sync::RwLockWriteGuard<'static, ()>,
}

impl Alone {
    /// Judges the real-time run of `events`: it lost no tick and missed no deadline
    /// ([`stalls::faults`]) but in a stall of the machine seen so far on a CPU the run was
    /// on, and those excused are at most 1 % of its ticks ([`stalls::Seen::judge`]). A
    /// fault outside every stall fails the test; `Err` says the machine was too busy to
    /// judge. The verdict goes to the file `.ci/run` summarizes. (Before a count of record
    /// gaps was allowed, which a CI run at ca71f2d exceeded; then any fault in any stall
    /// was, with no bound.)
    pub fn judge(&self, events: &[serde_json::Value]) -> Result<stalls::Excused, stalls::TooBusy> {
        self.judge_faults(events, &stalls::faults(events))
    }

    /// [`Alone::judge`] of `faults` of the run of `events`, which the test found.
    pub fn judge_faults(
        &self,
        events: &[serde_json::Value],
        faults: &[stalls::Fault],
    ) -> Result<stalls::Excused, stalls::TooBusy> {
        let verdict = self.stalls.seen().judge(events, faults);
        stalls::record_excuse(&verdict, self.attempt);
        match verdict {
            Ok(excused) => Ok(excused),
            Err(stalls::Unjudged::TooBusy(busy)) => Err(busy),
            Err(stalls::Unjudged::Faults(why)) => panic!("{why}"),
        }
    }
}

/// For any other test that starts a process or keeps a core busy: shares the machine with
/// tests like it, never with a real-time one.
pub fn machine_shared() -> std::sync::RwLockReadGuard<'static, ()> {
    MACHINE
        .read()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `plans.csv` without the columns the machine's speed decides (solve time, arrival in
/// real time).
pub fn plans_made(dir: &Path) -> Vec<String> {
    let table = record::schema::Table::read(&dir.join("plans.csv")).unwrap();
    // The solve time and the real-time arrival depend on the machine.
    let keep = record::schema::PLANS_COLUMNS
        .iter()
        .filter(|c| !["solve_us", "arrival_ms"].contains(c));
    let columns: Vec<Vec<&str>> = keep.map(|c| table.column(c).unwrap()).collect();
    (0..table.len())
        .map(|r| columns.iter().map(|c| c[r]).collect::<Vec<_>>().join(","))
        .collect()
}

/// A CA and one certificate it signs for 127.0.0.1, as PEM files in `dir`.
pub fn tls_files(dir: &Path) -> [String; 3] {
    use rcgen::{BasicConstraints, CertificateParams, IsCa, Issuer, KeyPair};
    let ca_key = KeyPair::generate().unwrap();
    let mut ca_params = CertificateParams::new(Vec::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = ca_params.self_signed(&ca_key).unwrap();
    let issuer = Issuer::new(ca_params, ca_key);
    let key = KeyPair::generate().unwrap();
    let cert = CertificateParams::new(vec!["127.0.0.1".into(), "localhost".into()])
        .unwrap()
        .signed_by(&key, &issuer)
        .unwrap();
    let write = |name: &str, pem: String| {
        let path = dir.join(name);
        std::fs::write(&path, pem).unwrap();
        path.to_str().unwrap().to_string()
    };
    [
        write("ca.pem", ca.pem()),
        write("cert.pem", cert.pem()),
        write("key.pem", key.serialize_pem()),
    ]
}

/// The lines of `stream` (a child's piped stdout or stderr) as they come, read on a thread
/// of their own.
pub fn lines_of(stream: impl std::io::Read + Send + 'static) -> std::sync::mpsc::Receiver<String> {
    use std::io::BufRead;
    let (send, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stream)
            .lines()
            .map_while(Result::ok)
        {
            if send.send(line).is_err() {
                break;
            }
        }
    });
    lines
}

/// `(name, policy, priority)` of each thread of process `pid` named one of `names`, from
/// `/proc`.
fn threads_of(pid: u32, names: &[&str]) -> Vec<(String, i32, u32)> {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).expect("the process's threads");
    let mut threads = Vec::new();
    for task in tasks.flatten() {
        let (Ok(name), Ok(stat)) = (
            std::fs::read_to_string(task.path().join("comm")),
            std::fs::read_to_string(task.path().join("stat")),
        ) else {
            continue;
        };
        let name = name.trim().to_string();
        if !names.contains(&name.as_str()) {
            continue;
        }
        let (policy, priority) = runtime::realtime::scheduling_in_stat(&stat).expect("a stat line");
        threads.push((name, policy, priority));
    }
    threads.sort();
    threads
}

/// Zenoh's worker threads that read and write its links (the default `rx` pool of two, the
/// `tx` pool of one; helper threads it starts later are named on from these).
pub const ZENOH_WORKERS: [&str; 3] = ["rx-0", "rx-1", "tx-0"];

/// Process `pid` has a thread named each of `names` (carriers of the control loop's
/// samples: a bridge's, Zenoh's workers; a name as `/proc` gives it, cut to 15 bytes),
/// and each runs at the control loop's real-time priority where the machine grants one,
/// at the normal policy where it does not (then this checks only that they exist).
pub fn assert_threads_at_the_control_tier(pid: u32, names: &[&str]) {
    let (policy, _) = runtime::realtime::Policy::for_this_process(
        &protocol::RealtimeConfig::default(),
        runtime::realtime::Tier::Control,
    );
    let expected = policy
        .fifo_priority
        .map_or((libc::SCHED_OTHER, 0), |p| (libc::SCHED_FIFO, u32::from(p)));
    let threads = threads_of(pid, names);
    for wanted in names {
        assert!(
            threads.iter().any(|(name, ..)| name == wanted),
            "no thread {wanted} in process {pid}: {threads:?}"
        );
    }
    for (name, policy, priority) in &threads {
        assert_eq!(
            (*policy, *priority),
            expected,
            "thread {name} of {pid}: {threads:?}"
        );
    }
}

/// The arrival of a robot along `path` (`(t_s, distance to the goal, m)` in time order):
/// the first time within 0.2 m of its goal, the largest distance after that, and the time
/// from then to the stay within `rest_m` that lasts to the end (`None` if it never came
/// within 0.2 m).
pub fn arrival_of(path: &[(f64, f64)], rest_m: f64) -> Option<(f64, f64, Option<f64>)> {
    let first = path.iter().position(|&(_, d)| d <= 0.2)?;
    let farthest = path[first..].iter().map(|&(_, d)| d).fold(0.0, f64::max);
    // The final stay within the rest radius: after the last point outside it.
    let resting_from = match path.iter().rposition(|&(_, d)| d > rest_m) {
        None => Some(0),
        Some(last) if last + 1 < path.len() => Some(last + 1),
        Some(_) => None,
    };
    let to_rest = resting_from.map(|i| path[i].0 - path[first].0);
    Some((path[first].0, farthest, to_rest))
}
