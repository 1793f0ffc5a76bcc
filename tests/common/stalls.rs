//! Stalls of the machine itself during a real-time run, and the run's faults they excuse.
//!
//! A real-time test cannot promise what the host does not give: on a shared two-core
//! virtual machine the hypervisor now and then takes a CPU away for 4-60 ms (steal time),
//! and no priority in the guest beats that (docs/limitations.md). A real-time test watches
//! for such stalls while its run lasts ([`Stalls::watch`]) and excuses a fault of the run
//! (a tick without a command, a deadline miss) only inside one it saw on a CPU the run was
//! on or the two ticks after it, and only up to [`MAX_EXCUSED_SHARE`] of the run's ticks
//! ([`Seen::judge`]); above that the machine was too busy to judge the run, and the test
//! runs it again ([`crate::common::until_judged`]). What each test excused is appended to
//! [`excuses_file`], whose summary `.ci/run` prints.

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

const MS: u64 = 1_000_000;
/// The inner tick of every scenario the tests run in real time, ns.
const DT_NS: u64 = 5 * MS;
/// The inner ticks of a sample of every scenario the tests run in real time.
const TICKS_A_SAMPLE: u64 = 10;
/// How often the run's CPUs and the steal time are read, ns.
const POLL_NS: u64 = 20 * MS;
/// The largest share of a run's ticks a test may excuse: above it the machine was too
/// busy to judge the run ([`Unjudged::TooBusy`]).
pub const MAX_EXCUSED_SHARE: f64 = 0.01;
/// How long no stall must be seen for the machine to count as calm again, ns.
const CALM_NS: u64 = 2_000_000_000;
/// How long [`Stalls::wait_for_calm`] waits at most.
const CALM_WAIT: std::time::Duration = std::time::Duration::from_secs(180);

/// A stall of one CPU: it fell within `from..to` (monotonic ns).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stall {
    pub cpu: usize,
    pub from: u64,
    pub to: u64,
    /// Seen by a `SCHED_FIFO` 99 watcher that woke late (else by steal time, which an idle
    /// VM's CPUs gain a jiffy of about every 1-2 s: measured 2026-12-02).
    pub late_wakeup: bool,
}

/// What the watchers saw: the stalls, and the CPUs the run's threads were last on at each
/// poll (`(monotonic ns, bit mask of CPUs)`).
#[derive(Debug, Default, Clone)]
pub struct Seen {
    pub stalls: Vec<Stall>,
    pub run_cpus: Vec<(u64, u64)>,
}

/// Stalls of the machine itself, while it lives (a test holding the machine alone watches
/// them: [`crate::common::machine_alone`]): times when nothing of this system ran on
/// a CPU, which no priority of the pipeline can beat. Two watches, each per CPU:
/// - steal time (`/proc/stat`, in 10 ms jiffies), read every 20 ms at normal priority: the
///   hypervisor took the CPU. Beside two CPU-bound processes the host stalls a CPU of the
///   development machine for 4-16 ms a few times a minute, none when idle; each such stall
///   of a `SCHED_FIFO` 99 probe showed as steal within 50 ms of its end (docs/performance.md,
///   "Real time under load");
/// - where the machine grants it, a `SCHED_FIFO` 99 thread pinned to each CPU,
///   waking every 10 ms (the scheduler's own tick; a 1 ms watcher preempted the load so
///   often that it hid the load's effect): a wake-up more than 2 ms late is a stall of that
///   CPU, whatever took it. The stall ended then; it began at any time since the watcher's
///   last wake-up, which it slept through (a fresh-clone CI at 9edad08 had a tick without a
///   command 9.8 ms before both CPUs' watchers woke 3.8 ms late). At the normal policy such
///   a watcher would be late whenever the run itself held the CPU: there is none then.
///
/// Beside them, every 20 ms, the CPU each thread of the run's processes (every process
/// descended from the test's, but a `bench-burn` load) was last on: a stall counts only on
/// a CPU the run was on around it.
pub struct Stalls {
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<Seen>>,
    watchers: Vec<std::thread::JoinHandle<()>>,
}

impl Stalls {
    /// Watches until dropped.
    pub fn watch() -> Stalls {
        let stop = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Mutex::new(Seen::default()));
        let mut watchers = Vec::new();
        let (running, into) = (stop.clone(), seen.clone());
        watchers.push(std::thread::spawn(move || {
            watch_steal_and_run(&running, &into)
        }));
        for cpu in runtime::realtime::allowed_cpus().expect("the CPUs") {
            let (running, into) = (stop.clone(), seen.clone());
            watchers.push(std::thread::spawn(move || watch_cpu(cpu, &running, &into)));
        }
        Stalls {
            stop,
            seen,
            watchers,
        }
    }

    /// Everything seen so far.
    pub fn seen(&self) -> Seen {
        lock(&self.seen).clone()
    }

    /// Waits until no watcher has woken late for 2 s ([`CALM_NS`]; steal time, which an
    /// idle VM gains too, does not count), or [`CALM_WAIT`] has passed, and forgets what was
    /// seen meanwhile; returns how long it waited.
    pub fn wait_for_calm(&self) -> std::time::Duration {
        let started = std::time::Instant::now();
        let since = runtime::clock::monotonic_ns();
        while started.elapsed() < CALM_WAIT {
            std::thread::sleep(std::time::Duration::from_millis(100));
            let seen = lock(&self.seen);
            let late = seen.stalls.iter().filter(|s| s.late_wakeup);
            let last = late.map(|s| s.to).max().unwrap_or(since).max(since);
            if runtime::clock::monotonic_ns() >= last + CALM_NS {
                break;
            }
        }
        *lock(&self.seen) = Seen::default();
        started.elapsed()
    }
}

impl Drop for Stalls {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for watcher in self.watchers.drain(..) {
            let _ = watcher.join();
        }
    }
}

/// A fault of a real-time run: what it was, the ticks it may have arisen in (`ticks` from
/// `tick` on), and what the record says of it.
#[derive(Debug)]
pub struct Fault {
    pub what: &'static str,
    pub tick: u64,
    pub ticks: u64,
    pub detail: String,
}

impl Fault {
    /// A fault of one tick.
    pub fn at(what: &'static str, tick: u64, detail: String) -> Fault {
        Fault {
            what,
            tick,
            ticks: 1,
            detail,
        }
    }
}

/// Why a run's faults were not all excused ([`Seen::judge`]).
#[derive(Debug)]
pub enum Unjudged {
    /// Faults outside every stall of the machine: the run's own.
    Faults(String),
    /// The machine was too busy to judge the run.
    TooBusy(TooBusy),
}

impl std::fmt::Display for Unjudged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unjudged::Faults(why) | Unjudged::TooBusy(TooBusy(why)) => f.write_str(why),
        }
    }
}

/// The machine was too busy to judge a run: the faults in its stalls were more than
/// [`MAX_EXCUSED_SHARE`] of the run's ticks (the figures).
#[derive(Debug, Clone)]
pub struct TooBusy(pub String);

/// What a test excused of its run.
#[derive(Debug, PartialEq)]
pub struct Excused {
    /// The run's ticks.
    pub ticks: u64,
    /// Its faults, and the distinct ticks of those (all excused when judged).
    pub faults: usize,
    pub excused_ticks: usize,
    /// Stalls seen on a CPU the run was on, and elsewhere (not counted).
    pub stalls: usize,
    pub stalls_elsewhere: usize,
}

impl Excused {
    /// The share of the run's ticks excused.
    pub fn share(&self) -> f64 {
        self.excused_ticks as f64 / self.ticks.max(1) as f64
    }
}

impl Seen {
    /// The stalls on a CPU a thread of the run was on at a poll within one poll of it.
    pub fn on_the_runs_cpus(&self) -> Vec<Stall> {
        self.stalls
            .iter()
            .filter(|s| {
                self.run_cpus.iter().any(|&(at, cpus)| {
                    at + POLL_NS >= s.from && at <= s.to + POLL_NS && cpus & cpu_bit(s.cpu) != 0
                })
            })
            .copied()
            .collect()
    }

    /// Whether `fault` of a run whose tick 0 was at `tick0_ns` (monotonic) falls inside
    /// `stall` or the two ticks after it: its ticks overlap them.
    fn excuses(stall: &Stall, tick0_ns: u64, fault: &Fault) -> bool {
        let at = tick0_ns + fault.tick * DT_NS;
        stall.from < at + fault.ticks * DT_NS && at < stall.to + 2 * DT_NS
    }

    /// Judges the `faults` of the run of `events` (real time, from its `clock_started`
    /// event to its `end`): each must fall inside a stall seen on a CPU the run was on (or
    /// the two ticks after it), and their distinct ticks must be at most
    /// [`MAX_EXCUSED_SHARE`] of the run's. An error names every fault outside a stall (what,
    /// tick, record), or says the machine was too busy to judge, with the figures.
    pub fn judge(
        &self,
        events: &[serde_json::Value],
        faults: &[Fault],
    ) -> Result<Excused, Unjudged> {
        let (tick0_ns, ticks) = (tick0_ns(events), run_ticks(events));
        let stalls = self.on_the_runs_cpus();
        let outside: Vec<&Fault> = faults
            .iter()
            .filter(|f| !stalls.iter().any(|s| Self::excuses(s, tick0_ns, f)))
            .collect();
        let mut excused_ticks: Vec<u64> = faults.iter().map(|f| f.tick).collect();
        excused_ticks.sort_unstable();
        excused_ticks.dedup();
        let excused = Excused {
            ticks,
            faults: faults.len(),
            excused_ticks: excused_ticks.len(),
            stalls: stalls.len(),
            stalls_elsewhere: self.stalls.len() - stalls.len(),
        };
        if !outside.is_empty() && self.run_cpus.iter().all(|&(_, cpus)| cpus == 0) {
            return Err(Unjudged::Faults(format!(
                "{} faults, and the run was never seen on a CPU (no process descended from \
                 the test's, or no /proc/PID/task/TID/children): {outside:?}",
                faults.len()
            )));
        }
        if !outside.is_empty() {
            return Err(Unjudged::Faults(format!(
                "{} of {} faults not in a stall of the machine on the run's CPUs: {outside:?} \
                 (tick 0 at {tick0_ns} ns; stalls on the run's CPUs {stalls:?})",
                outside.len(),
                faults.len()
            )));
        }
        if excused.share() > MAX_EXCUSED_SHARE {
            return Err(Unjudged::TooBusy(TooBusy(format!(
                "the machine was too busy to judge the run: {} of its {} ticks ({:.2} %) had a \
                 fault in a stall, more than the {} % a test may excuse ({} stalls on the \
                 run's CPUs)",
                excused.excused_ticks,
                ticks,
                100.0 * excused.share(),
                100.0 * MAX_EXCUSED_SHARE,
                excused.stalls
            ))));
        }
        Ok(excused)
    }
}

/// The file every real-time test appends what it excused to, one JSON line per judged
/// run: `target/tmp/excused.jsonl`. `.ci/run` empties it first and prints its summary last.
pub fn excuses_file() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("excused.jsonl")
}

/// Appends the verdict of the calling test's `attempt` (1, 2, ...) to [`excuses_file`].
pub fn record_excuse(verdict: &Result<Excused, Unjudged>, attempt: u32) {
    use std::io::Write;
    let test = std::thread::current().name().unwrap_or("?").to_owned();
    let line = match verdict {
        Ok(e) => serde_json::json!({
            "test": test, "attempt": attempt, "ticks": e.ticks, "faults": e.faults,
            "excused_ticks": e.excused_ticks, "stalls": e.stalls,
            "stalls_elsewhere": e.stalls_elsewhere,
        }),
        Err(Unjudged::TooBusy(TooBusy(why))) => {
            serde_json::json!({ "test": test, "attempt": attempt, "too_busy": why })
        }
        Err(Unjudged::Faults(why)) => {
            serde_json::json!({ "test": test, "attempt": attempt, "failed": why })
        }
    };
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(excuses_file());
    // One write of the whole line: tests of one binary may append at once.
    if let Ok(mut file) = file {
        let _ = file.write_all(format!("{line}\n").as_bytes());
    }
}

/// The monotonic time of the run's tick 0 (its `clock_started` event), ns.
pub fn tick0_ns(events: &[serde_json::Value]) -> u64 {
    events
        .iter()
        .find(|e| e["event"] == "clock_started")
        .and_then(|e| e["tick0_monotonic_ns"].as_u64())
        .expect("no clock_started event")
}

/// The ticks the run of `events` lasted (its `end` event's time).
pub fn run_ticks(events: &[serde_json::Value]) -> u64 {
    let end_s = events
        .iter()
        .find(|e| e["event"] == "end")
        .and_then(|e| e["t"].as_f64())
        .expect("no end event");
    (end_s * 1e9 / DT_NS as f64).round() as u64
}

/// The record gaps (ticks without a command, with the topics whose sample never came) and
/// deadline misses (over their sample's 10 ticks: a stall anywhere in the sample makes its
/// plan late) of the run of `events`.
pub fn faults(events: &[serde_json::Value]) -> Vec<Fault> {
    let tick = |e: &serde_json::Value, key: &str| e[key].as_u64().expect("a tick");
    events
        .iter()
        .filter_map(|e| match e["event"].as_str() {
            Some("record_gap") => Some(Fault::at(
                "tick without a command",
                tick(e, "tick"),
                format!("missing {}", e["missing"]),
            )),
            Some("deadline_miss") => Some(Fault {
                what: "deadline miss",
                tick: TICKS_A_SAMPLE * tick(e, "sample"),
                ticks: TICKS_A_SAMPLE,
                detail: e.to_string(),
            }),
            _ => None,
        })
        .collect()
}

/// The deadline misses among the [`faults`] of the run of `events` whose sample is not in
/// `samples`: where a test provokes misses in `samples`, the others are faults to judge.
pub fn misses_outside(events: &[serde_json::Value], samples: impl Fn(u64) -> bool) -> Vec<Fault> {
    faults(events)
        .into_iter()
        .filter(|f| f.what == "deadline miss" && !samples(f.tick / TICKS_A_SAMPLE))
        .collect()
}

fn lock(seen: &Mutex<Seen>) -> std::sync::MutexGuard<'_, Seen> {
    seen.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Every 20 ms: each CPU whose steal time grew had a stall within the 50 ms before, and
/// the CPUs the run's threads were last on.
fn watch_steal_and_run(stop: &AtomicBool, seen: &Mutex<Seen>) {
    let mut before = steal_jiffies();
    let mut loads = HashSet::new();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(std::time::Duration::from_nanos(POLL_NS));
        let now = steal_jiffies();
        let at = runtime::clock::monotonic_ns();
        let cpus = run_cpus(&mut loads);
        let mut seen = lock(seen);
        for (&(cpu, was), &(_, is)) in before.iter().zip(&now) {
            if was != is {
                seen.stalls.push(Stall {
                    cpu,
                    from: at - 50 * MS,
                    to: at,
                    late_wakeup: false,
                });
            }
        }
        seen.run_cpus.push((at, cpus));
        before = now;
    }
}

/// Each CPU's steal time so far, jiffies (the 8th value of its `cpuN` line), by `N`.
fn steal_jiffies() -> Vec<(usize, u64)> {
    std::fs::read_to_string("/proc/stat")
        .expect("/proc/stat")
        .lines()
        .filter_map(|l| {
            let mut fields = l.split_whitespace();
            let cpu = fields.next()?.strip_prefix("cpu")?.parse().ok()?;
            Some((cpu, fields.nth(7).and_then(|v| v.parse().ok()).unwrap_or(0)))
        })
        .collect()
}

/// The bit of `cpu` in a mask of CPUs (none past 63).
fn cpu_bit(cpu: usize) -> u64 {
    1u64.checked_shl(cpu as u32).unwrap_or(0)
}

/// Whether a command line (`/proc/PID/cmdline`) is a `bench-burn` load's.
pub fn is_load(cmdline: &[u8]) -> bool {
    cmdline.split(|&b| b == 0).any(|arg| arg == b"bench-burn")
}

/// The CPUs (a bit mask) every thread of the run's processes was last on: the processes
/// descended from this one, but a `bench-burn` load (`loads` remembers the pids found to be
/// one; any other is asked again, since a child between fork and exec still shows its
/// parent's command line).
fn run_cpus(loads: &mut HashSet<u32>) -> u64 {
    let mut mask = 0;
    let mut parents = vec![std::process::id()];
    while let Some(parent) = parents.pop() {
        for child in children(parent) {
            parents.push(child);
            if loads.contains(&child) {
                continue;
            }
            let cmdline = std::fs::read(format!("/proc/{child}/cmdline")).unwrap_or_default();
            if is_load(&cmdline) {
                loads.insert(child);
            } else {
                mask |= threads_cpus(child);
            }
        }
    }
    mask
}

/// The children of process `pid` (of any of its threads).
fn children(pid: u32) -> Vec<u32> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return Vec::new();
    };
    tasks
        .flatten()
        .filter_map(|task| std::fs::read_to_string(task.path().join("children")).ok())
        .flat_map(|text| {
            text.split_whitespace()
                .filter_map(|p| p.parse().ok())
                .collect::<Vec<u32>>()
        })
        .collect()
}

/// The CPUs (a bit mask) the threads of process `pid` were last on (field 39 of each
/// thread's `stat`, the 37th after the command's closing parenthesis).
fn threads_cpus(pid: u32) -> u64 {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return 0;
    };
    tasks
        .flatten()
        .filter_map(|task| std::fs::read_to_string(task.path().join("stat")).ok())
        .filter_map(|stat| {
            let after = &stat[stat.rfind(')')? + 1..];
            after.split_whitespace().nth(36)?.parse::<u32>().ok()
        })
        .fold(0, |mask, cpu| mask | cpu_bit(cpu as usize))
}

/// Wake-ups of a `SCHED_FIFO` 99 thread on `cpu` more than 2 ms late: each a stall within
/// the wake-up before and this one. None where the machine refuses the priority.
fn watch_cpu(cpu: usize, stop: &AtomicBool, seen: &Mutex<Seen>) {
    use runtime::clock::{monotonic_ns, sleep_until_ns};
    // SAFETY: plain system calls on the calling thread, with parameters owned here.
    let raised = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        assert_eq!(
            libc::sched_setaffinity(0, std::mem::size_of_val(&set), &set),
            0
        );
        let param = libc::sched_param { sched_priority: 99 };
        libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0
    };
    if !raised {
        return;
    }
    let mut woke = monotonic_ns();
    while !stop.load(Ordering::Relaxed) {
        let (before, due) = (woke, woke + 10 * MS);
        sleep_until_ns(due);
        woke = monotonic_ns();
        if woke > due + 2 * MS {
            lock(seen).stalls.push(Stall {
                cpu,
                from: before,
                to: woke,
                late_wakeup: true,
            });
        }
    }
}
