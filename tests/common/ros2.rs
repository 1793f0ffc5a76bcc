//! The simulated ROS 2 robot of the tests (tests/python/ros2_base.py: `eclipse-zenoh` and
//! `rosbags`, pinned in the tests' venv): its router and its base as Python processes,
//! and `scmpc` driving it.

use super::python::{python, repo};
use super::stalls::{TooBusy, Unjudged, record_excuse};
use super::{Alone, events, run, spawn_run, wait_for};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::Duration;

/// The paper's start, where the base starts (the run takes it from the first odometry).
pub const PAPER_START: [&str; 3] = ["7", "7", "-2.356194490192345"];

/// `ros2.odom_timeout_s`'s default, s.
pub const ODOM_TIMEOUT_S: f64 = 0.2;
/// `ros2.scan_timeout_s`'s default, s.
pub const SCAN_TIMEOUT_S: f64 = 0.5;
/// The inner tick of the paper, s.
pub const TICK_S: f64 = 0.005;

/// For a drive on the base whose claim is not its timing: if the run into `out_dir`
/// aborted because one of the base's inputs (its odometry, its scans) went silent (the
/// plant's `input_lost`), was the machine stalled meanwhile? The robot's watchdog brakes
/// at the input's timeout and gives up at twice it (or once the braked robot is at rest,
/// which a silent odometry cannot say), so the silence is the two timeouts before the
/// loss, give or take a tick of the check and one of the input's way to the plant. If a
/// `SCHED_FIFO` watcher woke late on a CPU the run was on within it (a stall of the
/// machine; steal time alone, which an idle VM gains every second or two, does not
/// count), the drive is to run again (`Err`, for [`super::until_judged`], recorded as too
/// busy to judge); otherwise the test fails, naming the event. The runtime's own loss of
/// an input silent for 5 s names the odometry too, and is judged the same way. (A fresh
/// clone's CI at 7be13d1, in a busy hour, saw the TLS test's plant exit 1 in the run that
/// must pass; it passed 3 of 3 by hand after.)
pub fn base_inputs_kept(machine: &Alone, out_dir: &Path) -> Result<(), TooBusy> {
    let run_events = events(out_dir);
    let lost = run_events
        .iter()
        .find(|e| e["event"] == "input_lost" && e["role"] == "plant");
    let Some(lost) = lost else {
        return Ok(());
    };
    let input = lost["input"].as_str().unwrap_or_default().to_lowercase();
    let timeout_s = if input.contains("scan") {
        SCAN_TIMEOUT_S
    } else {
        ODOM_TIMEOUT_S
    };
    let lost_s = lost["t"].as_f64().expect("input_lost has its time");
    let tick0_ns = super::stalls::tick0_ns(&run_events);
    let at_ns = |s: f64| tick0_ns.saturating_add_signed((s * 1e9) as i64);
    let (from_ns, to_ns) = (
        at_ns(lost_s - 2.0 * timeout_s - 2.0 * TICK_S),
        at_ns(lost_s + TICK_S),
    );
    let stalled = (machine.stalls.seen().on_the_runs_cpus().iter())
        .any(|s| s.late_wakeup && s.from < to_ns && from_ns < s.to);
    assert!(
        stalled,
        "the base's input went silent with no stall of the machine on the run's CPUs \
         (tick 0 at {tick0_ns} ns, the silence {from_ns}..{to_ns} ns): {lost}"
    );
    let busy = TooBusy(format!(
        "the base's input went silent in a stall of the machine, and the run aborted: {lost}"
    ));
    record_excuse(&Err(Unjudged::TooBusy(busy.clone())), machine.attempt);
    Err(busy)
}

/// A Python process of tests/python/ros2_base.py, its stdout line by line.
pub struct Python {
    child: Child,
    lines: Receiver<String>,
}

impl Python {
    pub fn start(args: &[&str]) -> Python {
        let mut child = Command::new(python())
            .arg(repo().join("tests/python/ros2_base.py"))
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("cannot start tests/python/ros2_base.py");
        let lines = super::lines_of(child.stdout.take().expect("stdout piped"));
        let python = Python { child, lines };
        let ready = python.lines.recv_timeout(Duration::from_secs(60));
        assert!(
            ready.as_deref().is_ok_and(|l| l.ends_with("ready")),
            "{args:?} never said it was ready: {ready:?}"
        );
        python
    }

    pub fn signal(&self, signal: i32) {
        // SAFETY: a signal to a process this test started and has not reaped.
        unsafe { libc::kill(self.child.id() as i32, signal) };
    }

    /// SIGTERM, then its exit (30 s at most).
    pub fn stop(&mut self) {
        self.signal(libc::SIGTERM);
        let exited = wait_for(Duration::from_secs(30), || {
            self.child.try_wait().ok().flatten().is_some()
        });
        assert!(exited, "the Python process did not exit on SIGTERM");
    }
}

impl Drop for Python {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A robot: its Zenoh router on a free loopback port and the simulated base on it.
pub struct Robot {
    pub base: Python,
    router: Python,
    pub endpoint: String,
    log: PathBuf,
    /// Zenoh's shared-memory files in /dev/shm before the robot started.
    shm_before: Vec<PathBuf>,
}

/// Zenoh's shared-memory files in /dev/shm (the Python package makes them unless told
/// not to).
pub fn zenoh_shm_files() -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir("/dev/shm") else {
        return Vec::new();
    };
    entries
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "zenoh"))
        .collect()
}

/// A free port on loopback.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("no free port")
        .port()
}

impl Robot {
    pub fn start(dir: &Path, base_args: &[&str]) -> Robot {
        Robot::start_with(dir, base_args, None)
    }

    /// A robot whose router also listens on TLS with mutual authentication by the CA of
    /// `tls` (`[ca, cert, key]`); the pipeline is to take [`Robot::endpoint`], now that one.
    pub fn start_with(dir: &Path, base_args: &[&str], tls: Option<&[String; 3]>) -> Robot {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let shm_before = zenoh_shm_files();
        let tls_endpoint = format!("tls/127.0.0.1:{}", free_port());
        let mut router_args = vec!["--router", &endpoint];
        if let Some(files) = tls {
            router_args.extend([tls_endpoint.as_str(), "--tls"]);
            router_args.extend(files.iter().map(String::as_str));
        }
        let router = Python::start(&router_args);
        let log = dir.join("base.json");
        let base = Python::start(
            &[
                &["--connect", &endpoint, "--log", log.to_str().unwrap()][..],
                &["--start"],
                &PAPER_START,
                base_args,
            ]
            .concat(),
        );
        Robot {
            base,
            router,
            endpoint: if tls.is_some() {
                tls_endpoint
            } else {
                endpoint
            },
            log,
            shm_before,
        }
    }

    /// Stops the base and the router, which leave no shared-memory file; the base's log.
    pub fn finish(mut self) -> Value {
        self.base.stop();
        self.router.stop();
        let left: Vec<PathBuf> = (zenoh_shm_files().into_iter())
            .filter(|f| !self.shm_before.contains(f))
            .collect();
        assert!(left.is_empty(), "the robot left {left:?}");
        let text = std::fs::read_to_string(&self.log).expect("the base wrote no log");
        serde_json::from_str(&text).expect("the base's log is not JSON")
    }
}

/// `scmpc run` on the robot whose router is at `endpoint` (real time, no MCAP), with more
/// `args`, into `out_dir`.
pub fn run_on(endpoint: &str, args: &[&str], out_dir: &Path) -> std::process::Output {
    let drive = drive_args(endpoint);
    let out = ["--out", out_dir.to_str().unwrap()];
    let drive: Vec<&str> = drive.iter().map(String::as_str).collect();
    run(&[&["run"][..], &drive, args, &out].concat())
}

/// [`run_on`] in the background, on iceoryx2 prefix `prefix`.
pub fn spawn_on(endpoint: &str, prefix: &str, out_dir: &Path) -> Child {
    let args = [drive_args(endpoint), vec!["--prefix".into(), prefix.into()]].concat();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    spawn_run(out_dir, &args)
}

/// The arguments of `scmpc run` that drive the robot whose router is at `endpoint`.
pub fn drive_args(endpoint: &str) -> Vec<String> {
    [
        "--mode",
        "realtime",
        "--no-mcap",
        "--set",
        "plant.kind=ros2",
        "--set",
    ]
    .map(String::from)
    .into_iter()
    .chain([format!("ros2.endpoint={endpoint}")])
    .collect()
}
