//! Stalls of the machine itself during a real-time run, and the run's faults they explain.
//!
//! A real-time test cannot promise what the host does not give: on a shared two-core
//! virtual machine the hypervisor now and then takes a CPU away for 4-60 ms (steal time),
//! and no priority in the guest beats that (docs/limitations.md). A real-time test watches
//! for such stalls while its run lasts ([`Stalls::watch`]) and accepts a fault of the run
//! (a tick without a command, a deadline miss) only inside one it saw ([`Seen`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

const MS: u64 = 1_000_000;
/// The inner tick of every scenario the tests run in real time, ns.
const DT_NS: u64 = 5 * MS;

/// Stalls of the machine itself, while it lives (a test holding the machine alone watches
/// them: [`crate::common::machine_alone`]): times when nothing of this system ran on
/// a CPU, which no priority of the pipeline can beat. Two watches:
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
pub struct Stalls {
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<Vec<(u64, u64)>>>,
    watchers: Vec<std::thread::JoinHandle<()>>,
}

impl Stalls {
    /// Watches until dropped.
    pub fn watch() -> Stalls {
        let stop = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Mutex::new(Vec::new()));
        let mut watchers = Vec::new();
        let (running, stalls) = (stop.clone(), seen.clone());
        watchers.push(std::thread::spawn(move || watch_steal(&running, &stalls)));
        for cpu in runtime::realtime::allowed_cpus().expect("the CPUs") {
            let (running, stalls) = (stop.clone(), seen.clone());
            watchers.push(std::thread::spawn(move || {
                watch_cpu(cpu, &running, &stalls)
            }));
        }
        Stalls {
            stop,
            seen,
            watchers,
        }
    }

    /// Every stall seen so far.
    pub fn seen(&self) -> Seen {
        Seen(
            self.seen
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .clone(),
        )
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

/// The stalls a [`Stalls`] saw, as `(from, to)` monotonic ns within which each fell.
#[derive(Debug)]
pub struct Seen(pub Vec<(u64, u64)>);

/// A fault of a real-time run: what it was and its tick, with what the record says of it.
#[derive(Debug)]
pub struct Fault {
    pub what: &'static str,
    pub tick: u64,
    pub detail: String,
}

impl Seen {
    /// Whether a fault at `tick` of a run whose tick 0 was at `tick0_ns` (monotonic) falls in
    /// a stall: one within the tick or the 4 before it (the DFL's silence of 3 ticks before
    /// it brakes, and one more).
    pub fn explains(&self, tick0_ns: u64, tick: u64) -> bool {
        let at = tick0_ns + tick * DT_NS;
        self.0
            .iter()
            .any(|&(from, to)| from < at + DT_NS && to + 4 * DT_NS > at)
    }

    /// The `faults` of the run of `events` that fall in no stall seen.
    pub fn unexplained<'a>(
        &self,
        events: &[serde_json::Value],
        faults: &'a [Fault],
    ) -> Vec<&'a Fault> {
        let tick0_ns = tick0_ns(events);
        faults
            .iter()
            .filter(|f| !self.explains(tick0_ns, f.tick))
            .collect()
    }

    /// The run of `events` lost no tick and missed no deadline but in a stall of the
    /// machine: each of its record gaps and deadline misses fell in one seen.
    pub fn assert_explains_every_fault(&self, events: &[serde_json::Value]) {
        let faults = faults(events);
        let unexplained = self.unexplained(events, &faults);
        assert!(
            unexplained.is_empty(),
            "not in a stall of the machine: {unexplained:?} (stalls {:?}, tick 0 at {} ns; \
             {} faults in all)",
            self.0,
            tick0_ns(events),
            faults.len()
        );
        if !faults.is_empty() {
            eprintln!(
                "{} faults, each in a stall of the machine: {faults:?}",
                faults.len()
            );
        }
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

/// The record gaps (ticks without a command, with the topics whose sample never came) and
/// deadline misses (at their sample's first tick) of the run of `events`.
pub fn faults(events: &[serde_json::Value]) -> Vec<Fault> {
    let tick = |e: &serde_json::Value, key: &str| e[key].as_u64().expect("a tick");
    events
        .iter()
        .filter_map(|e| match e["event"].as_str() {
            Some("record_gap") => Some(Fault {
                what: "tick without a command",
                tick: tick(e, "tick"),
                detail: format!("missing {}", e["missing"]),
            }),
            Some("deadline_miss") => Some(Fault {
                what: "deadline miss",
                tick: 10 * tick(e, "sample"),
                detail: e.to_string(),
            }),
            _ => None,
        })
        .collect()
}

/// Steal time that grew: within the 50 ms before it was seen.
fn watch_steal(stop: &AtomicBool, stalls: &Mutex<Vec<(u64, u64)>>) {
    let mut before = steal_jiffies();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(std::time::Duration::from_millis(20));
        let now = steal_jiffies();
        if now != before {
            let seen = runtime::clock::monotonic_ns();
            push(stalls, (seen - 50 * MS, seen));
        }
        before = now;
    }
}

fn push(stalls: &Mutex<Vec<(u64, u64)>>, stall: (u64, u64)) {
    stalls
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .push(stall);
}

/// Each CPU's steal time so far, jiffies (the 8th value of its `cpuN` line).
fn steal_jiffies() -> Vec<u64> {
    std::fs::read_to_string("/proc/stat")
        .expect("/proc/stat")
        .lines()
        .filter(|l| l.starts_with("cpu") && !l.starts_with("cpu "))
        .map(|l| {
            l.split_whitespace()
                .nth(8)
                .and_then(|v| v.parse().ok())
                .unwrap_or(0)
        })
        .collect()
}

/// Wake-ups of a `SCHED_FIFO` 99 thread on `cpu` more than 2 ms late: each a stall within
/// the wake-up before and this one. None where the machine refuses the priority.
fn watch_cpu(cpu: usize, stop: &AtomicBool, stalls: &Mutex<Vec<(u64, u64)>>) {
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
            push(stalls, (before, woke));
        }
    }
}
