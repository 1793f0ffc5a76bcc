//! Keeping the cores awake through a real-time run (`scmpc run --mode realtime
//! --keep-cores-awake`).
//!
//! On a virtual machine a core with nothing to run halts, and the host takes it back:
//! the process that wakes on it next runs slower for a while and wakes later
//! (docs/performance.md, "Idle cores"). Real-time Linux keeps its cores out of idle states
//! (`idle=poll`, or the `/dev/cpu_dma_latency` request, which a guest without a cpuidle
//! driver ignores); a user process can do the same with a spinner per core at
//! `SCHED_IDLE`, the policy that runs only when nothing else on the core can: any role,
//! the orchestrator, or any other process that wakes takes the core at once. The price is
//! every idle moment of every core the run may use: full CPU (and power) for the whole
//! run.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

/// The spinners, one per core this process may run on; dropped: stopped and joined.
pub struct AwakeCores {
    stop: Arc<AtomicBool>,
    spinners: Vec<JoinHandle<()>>,
}

impl AwakeCores {
    /// Starts a spinner on each core of this process's affinity mask, pinned to it at
    /// `SCHED_IDLE`. An error (a core that cannot be pinned to, a policy refused) stops
    /// the spinners started before it.
    pub fn start() -> std::io::Result<AwakeCores> {
        let mut awake = AwakeCores {
            stop: Arc::new(AtomicBool::new(false)),
            spinners: Vec::new(),
        };
        for core in allowed_cores()? {
            let stop = Arc::clone(&awake.stop);
            let (placed, placement) = std::sync::mpsc::channel();
            let spinner = std::thread::Builder::new()
                .name(format!("awake-{core}"))
                .spawn(move || {
                    let result = pin_at_idle_policy(core);
                    let spin = result.is_ok();
                    let _ = placed.send(result);
                    while spin && !stop.load(Ordering::Relaxed) {
                        std::hint::spin_loop();
                    }
                })?;
            awake.spinners.push(spinner);
            placement
                .recv()
                .map_err(|_| std::io::Error::other("a spinner ended before it was placed"))??;
        }
        Ok(awake)
    }

    /// Number of cores kept awake.
    pub fn cores(&self) -> usize {
        self.spinners.len()
    }
}

impl Drop for AwakeCores {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for spinner in self.spinners.drain(..) {
            let _ = spinner.join();
        }
    }
}

/// The cores this process may run on.
fn allowed_cores() -> std::io::Result<Vec<usize>> {
    // SAFETY: `set` is a plain bit set the call fills; its size is passed with it.
    let set = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        set
    };
    // SAFETY: `CPU_ISSET` reads a bit of the set, below its size.
    Ok((0..libc::CPU_SETSIZE as usize)
        .filter(|&core| unsafe { libc::CPU_ISSET(core, &set) })
        .collect())
}

/// Pins the calling thread to `core` and gives it the `SCHED_IDLE` policy.
fn pin_at_idle_policy(core: usize) -> std::io::Result<()> {
    // SAFETY: plain system calls on the calling thread (`0`), with a bit set and a
    // parameter owned here.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(core, &mut set);
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        let param = libc::sched_param { sched_priority: 0 };
        if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `(core it may run on, policy)` of each live thread of this process named
    /// `awake-*`. A thread that ends while it is read is left out.
    fn spinners() -> Vec<(String, String)> {
        let mut found = Vec::new();
        for task in std::fs::read_dir("/proc/self/task").unwrap() {
            let dir = task.unwrap().path();
            let name = std::fs::read_to_string(dir.join("comm")).unwrap_or_default();
            if !name.starts_with("awake-") {
                continue;
            }
            let (Ok(status), Ok(sched)) = (
                std::fs::read_to_string(dir.join("status")),
                std::fs::read_to_string(dir.join("sched")),
            ) else {
                continue;
            };
            let field = |text: &str, key: &str| {
                text.lines()
                    .find(|l| l.starts_with(key))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, value)| value.trim().to_string())
            };
            if field(&status, "State").is_some_and(|s| s.starts_with('Z') || s.starts_with('X')) {
                continue;
            }
            found.push((
                field(&status, "Cpus_allowed_list").unwrap(),
                field(&sched, "policy").unwrap(),
            ));
        }
        found.sort();
        found
    }

    /// `spinners()` once it is `expected`, or as it is after `timeout`. The kernel's
    /// listing lags the threads: a joined thread has returned but is listed under
    /// `/proc/self/task` until it is released, and a CI run at e1e37bf listed one placed
    /// spinner of two just after `start` returned.
    fn spinners_once(
        expected: &[(String, String)],
        timeout: std::time::Duration,
    ) -> Vec<(String, String)> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let found = spinners();
            if found == expected || std::time::Instant::now() > deadline {
                return found;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }

    #[test]
    fn every_core_gets_one_idle_policy_spinner_until_dropped() {
        let cores = allowed_cores().unwrap();
        let awake = AwakeCores::start().unwrap();
        assert_eq!(awake.cores(), cores.len());
        let mut expected: Vec<(String, String)> = cores
            .iter()
            .map(|c| (c.to_string(), libc::SCHED_IDLE.to_string()))
            .collect();
        expected.sort();
        let timeout = std::time::Duration::from_secs(5);
        assert_eq!(spinners_once(&expected, timeout), expected);
        drop(awake);
        assert_eq!(
            spinners_once(&[], timeout),
            Vec::new(),
            "the spinners are joined at drop"
        );
    }
}
