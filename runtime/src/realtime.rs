//! Real-time scheduling of a process of a real-time run (`[realtime]`; docs/running.md,
//! "Real-time scheduling"): what the machine grants ([`Grant`]), the policy of a process
//! from its tier in the data path ([`Policy`]), and putting it in force ([`Policy::apply`]).
//!
//! The tiers follow the data path ([`Tier`]): the control loop (the plant, the estimator,
//! the MPC and the DFL) above the tracker, above the route planner, above the
//! orchestrator's recording. A role that polls for its periodic input
//! ([`crate::wait::spin_wait`]: the estimator, tracker, MPC and planner) polls for one made
//! in its own tier or a higher one: a producer of a higher tier preempts the poller on a
//! shared core, and under `SCHED_FIFO` every poll yields the core, so a producer of the
//! same priority waiting there runs within one poll. Every spin ends within a bound
//! ([`SPIN_BUDGET_NS`](crate::wait::SPIN_BUDGET_NS), the warm-up's window) and then
//! blocks: nothing at a real-time priority runs long enough to meet the kernel's
//! real-time throttling.
//!
//! Only the thread that runs the loop is real time: the policy is set with
//! `SCHED_RESET_ON_FORK`, so the threads and processes it starts later begin at the normal
//! policy (a robot's Zenoh threads, a swapped-in replacement).

pub use protocol::graph::Tier;
use protocol::{AUTO_TOP_PRIORITY, Priority, RealtimeConfig, TIERS_BELOW_TOP};

/// Linux's capability bits in `/proc/self/status`'s `CapEff`.
const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;
/// How much of its stack a real-time process touches once its memory is locked, so that
/// its loop never takes a page fault on it, bytes.
const PREFAULT_STACK_BYTES: usize = 256 * 1024;

/// What the machine grants this process (its capabilities and resource limits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grant {
    pub cap_sys_nice: bool,
    pub cap_ipc_lock: bool,
    /// `RLIMIT_RTPRIO`: the highest real-time priority without `CAP_SYS_NICE`.
    pub rtprio_limit: u64,
    /// `RLIMIT_MEMLOCK`, KiB (`None`: unlimited).
    pub memlock_limit_kib: Option<u64>,
}

impl Grant {
    /// This process's, read from the kernel.
    pub fn of_this_process() -> Grant {
        let caps = std::fs::read_to_string("/proc/self/status")
            .ok()
            .and_then(|status| {
                let line = status.lines().find(|l| l.starts_with("CapEff:"))?;
                u64::from_str_radix(line.split_whitespace().nth(1)?, 16).ok()
            })
            .unwrap_or(0);
        let has = |bit: u32| caps & (1 << bit) != 0;
        let memlock = limit(libc::RLIMIT_MEMLOCK);
        Grant {
            cap_sys_nice: has(CAP_SYS_NICE),
            cap_ipc_lock: has(CAP_IPC_LOCK),
            rtprio_limit: limit(libc::RLIMIT_RTPRIO).unwrap_or(u64::MAX),
            memlock_limit_kib: memlock.map(|bytes| bytes / 1024),
        }
    }

    /// The highest `SCHED_FIFO` priority the limits allow.
    fn max_priority(&self) -> u8 {
        if self.cap_sys_nice {
            protocol::MAX_FIFO_PRIORITY
        } else {
            self.rtprio_limit
                .min(u64::from(protocol::MAX_FIFO_PRIORITY)) as u8
        }
    }

    /// Whether all of the memory may be locked, the memory mapped later included.
    fn may_lock_memory(&self) -> bool {
        self.cap_ipc_lock || self.memlock_limit_kib.is_none()
    }
}

/// A resource limit's soft value (`None`: unlimited).
fn limit(resource: libc::__rlimit_resource_t) -> Option<u64> {
    let mut value = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `value` is a plain struct the call fills.
    let read = unsafe { libc::getrlimit(resource, &mut value) } == 0;
    (read && value.rlim_cur != libc::RLIM_INFINITY).then_some(value.rlim_cur)
}

/// How one process of a real-time run is scheduled.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Policy {
    /// Its `SCHED_FIFO` priority (`None`: the normal policy).
    pub fifo_priority: Option<u8>,
    /// Whether its memory is locked (`mlockall`) and its stack touched.
    pub lock_memory: bool,
    /// The CPUs it is pinned to (empty: not pinned).
    pub cpus: Vec<usize>,
}

/// What [`Policy::decide`] found the machine refuses, and how to grant it: one line for the
/// run's one warning.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal(pub String);

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}; the run goes on without it. To grant it: `ulimit -r 99 -l unlimited` \
             before the run, or `@realtime - rtprio 99` and `@realtime - memlock unlimited` \
             in /etc/security/limits.conf, or `setcap cap_sys_nice,cap_ipc_lock+ep` on the \
             scmpc executable; in a container, `--cap-add SYS_NICE --cap-add IPC_LOCK` \
             (docs/running.md, \"Real-time scheduling\")",
            self.0
        )
    }
}

impl Policy {
    /// The policy of a process of `tier` under `config`, on a machine that grants `grant`;
    /// with what is refused, if anything. `fifo_allowed` tries a priority for real (the
    /// kernel may refuse what the limits allow: a cgroup without a real-time budget).
    pub fn decide(
        config: &RealtimeConfig,
        tier: Tier,
        grant: &Grant,
        fifo_allowed: impl Fn(u8) -> bool,
    ) -> (Policy, Option<Refusal>) {
        let mut refused = Vec::new();
        let lowest_top = TIERS_BELOW_TOP + 1;
        let top = match config.priority {
            Priority::Off => None,
            Priority::Auto if grant.max_priority() < lowest_top => {
                refused.push(format!(
                    "no real-time scheduling: no CAP_SYS_NICE and RLIMIT_RTPRIO is {} \
                     (at least {lowest_top} needed)",
                    grant.rtprio_limit
                ));
                None
            }
            Priority::Auto => Some(AUTO_TOP_PRIORITY.min(grant.max_priority())),
            Priority::Top(n) => Some(n.clamp(1, 99) as u8),
        };
        let top = top.filter(|&top| {
            let allowed = top <= grant.max_priority() && fifo_allowed(top);
            if !allowed {
                refused.push(format!(
                    "SCHED_FIFO at priority {top} refused ({})",
                    if top > grant.max_priority() {
                        format!(
                            "no CAP_SYS_NICE and RLIMIT_RTPRIO is {}",
                            grant.rtprio_limit
                        )
                    } else {
                        "by the kernel, though the limits allow it: a cgroup without a \
                         real-time budget (cpu.rt_runtime_us)?"
                            .to_string()
                    }
                ));
            }
            allowed
        });
        let lock_memory = top.is_some() && grant.may_lock_memory();
        if top.is_some() && !lock_memory {
            refused.push(format!(
                "memory not locked: no CAP_IPC_LOCK and RLIMIT_MEMLOCK is {} KiB",
                grant.memlock_limit_kib.unwrap_or(0)
            ));
        }
        let policy = Policy {
            fifo_priority: top.map(|top| tier.priority(top)),
            lock_memory,
            cpus: config.cpus.clone(),
        };
        let refusal = (!refused.is_empty()).then(|| Refusal(refused.join("; ")));
        (policy, refusal)
    }

    /// [`Policy::decide`] for this process: its grant read, a priority tried on a thread
    /// of its own.
    pub fn for_this_process(config: &RealtimeConfig, tier: Tier) -> (Policy, Option<Refusal>) {
        Policy::decide(config, tier, &Grant::of_this_process(), fifo_allowed)
    }

    /// Puts the policy in force on the calling thread: pinned, memory locked and the stack
    /// touched, then `SCHED_FIFO` (with `SCHED_RESET_ON_FORK`). Call it after setup, when
    /// the process has mapped what it needs. An error names the call that failed.
    pub fn apply(&self) -> Result<(), std::io::Error> {
        if !self.cpus.is_empty() {
            pin_to(&self.cpus)?;
        }
        if self.lock_memory {
            // SAFETY: a plain system call.
            if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
                return Err(named("mlockall"));
            }
            prefault_stack();
        }
        if let Some(priority) = self.fifo_priority {
            raise_this_thread(priority)?;
            FIFO_IN_FORCE.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        Ok(())
    }
}

/// [`Policy::apply`] undone when dropped: the normal policy, the memory unlocked, the
/// pinning of before (for a process that goes on after its run: the orchestrator).
pub struct InForce {
    cpus_before: Vec<usize>,
}

impl Policy {
    /// [`Policy::apply`] until the [`InForce`] returned is dropped.
    pub fn apply_while_held(&self) -> Result<InForce, std::io::Error> {
        let held = InForce {
            cpus_before: allowed_cpus()?,
        };
        self.apply()?;
        Ok(held)
    }
}

impl Drop for InForce {
    fn drop(&mut self) {
        let _ = set_scheduler(0, libc::SCHED_OTHER, 0);
        // SAFETY: a plain system call.
        unsafe { libc::munlockall() };
        let _ = pin_to(&self.cpus_before);
    }
}

/// Whether this process's loop runs `SCHED_FIFO` ([`Policy::apply`]).
static FIFO_IN_FORCE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether this process's loop runs `SCHED_FIFO`: its polls then yield, so that a process
/// of the same priority waiting for the core runs at once.
pub fn fifo_in_force() -> bool {
    FIFO_IN_FORCE.load(std::sync::atomic::Ordering::Relaxed)
}

/// The last OS error, with the call that made it.
fn named(call: &str) -> std::io::Error {
    let e = std::io::Error::last_os_error();
    std::io::Error::new(e.kind(), format!("{call}: {e}"))
}

/// Whether the kernel lets a thread of this process run `SCHED_FIFO` at `priority`, tried
/// on a thread that ends at once.
fn fifo_allowed(priority: u8) -> bool {
    std::thread::spawn(move || raise_this_thread(priority).is_ok())
        .join()
        .unwrap_or(false)
}

/// The calling thread at `SCHED_FIFO` `priority` (with `SCHED_RESET_ON_FORK`), for as long
/// as it lives: a loop's, or a thread of a process's own that carries the loop's samples
/// (a host's bridge). An error names the call.
pub fn raise_this_thread(priority: u8) -> std::io::Result<()> {
    set_scheduler(0, libc::SCHED_FIFO | libc::SCHED_RESET_ON_FORK, priority)
}

/// `(policy, rt_priority)` of a thread or process from its `/proc/.../stat` line (the
/// fields after the command's name, which may hold spaces: `rt_priority` is the 40th
/// field of the line, `policy` the 41st).
pub fn scheduling_in_stat(stat: &str) -> Option<(i32, u32)> {
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    Some((
        fields.get(41 - 3)?.parse().ok()?,
        fields.get(40 - 3)?.parse().ok()?,
    ))
}

/// The names of Zenoh's runtime threads that read and write its links (zenoh-runtime's
/// `rx` and `tx` pools): the carriers of samples between hosts, and to a ROS 2 robot.
pub const ZENOH_CARRIER_THREADS: [&str; 2] = ["rx-", "tx-"];

/// Threads of this process that it did not start itself, at `SCHED_FIFO` until dropped,
/// then back to the normal policy: Zenoh's runtime threads (`rx-N`, `tx-N`), which carry
/// the samples between hosts. Without them at the loop's priority, a loop at
/// `SCHED_FIFO` on a shared core holds back the samples it waits for.
pub struct RaisedThreads {
    tids: Vec<libc::pid_t>,
}

/// The threads of this process whose name starts with one of `prefixes`, at `SCHED_FIFO`
/// `priority` (with `SCHED_RESET_ON_FORK`) until the value returned is dropped: those that
/// exist now (Zenoh's worker threads exist once its session is open); a thread started
/// later keeps the normal policy. An error names the call and the thread.
pub fn raise_threads(prefixes: &[&str], priority: u8) -> std::io::Result<RaisedThreads> {
    let mut raised = RaisedThreads { tids: Vec::new() };
    for entry in std::fs::read_dir("/proc/self/task")? {
        let path = entry?.path();
        let Some(tid) = path.file_name().and_then(|n| n.to_str()?.parse().ok()) else {
            continue;
        };
        // A thread that ended since the listing has no name left: skipped.
        let Ok(name) = std::fs::read_to_string(path.join("comm")) else {
            continue;
        };
        if !prefixes.iter().any(|p| name.starts_with(p)) {
            continue;
        }
        match set_scheduler(tid, libc::SCHED_FIFO | libc::SCHED_RESET_ON_FORK, priority) {
            Ok(()) => raised.tids.push(tid),
            // A thread that ended since its name was read (a runtime's idle helper).
            Err(_) if !path.exists() => {}
            Err(e) => {
                let named = format!("thread {}: {e}", name.trim());
                return Err(std::io::Error::new(e.kind(), named));
            }
        }
    }
    Ok(raised)
}

impl Drop for RaisedThreads {
    fn drop(&mut self) {
        for &tid in &self.tids {
            // A thread that has ended meanwhile: nothing to undo (and its id, if reused,
            // is another process's thread's, not one to lower).
            if std::path::Path::new(&format!("/proc/self/task/{tid}")).exists() {
                let _ = set_scheduler(tid, libc::SCHED_OTHER, 0);
            }
        }
    }
}

/// Thread `tid` (0: the calling one) under `policy` at `priority`.
fn set_scheduler(tid: libc::pid_t, policy: i32, priority: u8) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: a plain system call on a thread of this process, with a parameter owned here.
    if unsafe { libc::sched_setscheduler(tid, policy, &param) } != 0 {
        return Err(named("sched_setscheduler"));
    }
    Ok(())
}

/// The calling thread pinned to `cpus`.
fn pin_to(cpus: &[usize]) -> std::io::Result<()> {
    // SAFETY: `set` is a plain bit set, each CPU below its size (checked by the scenario's
    // validation, `CPU_SET` checks again); its size is passed with it.
    let pinned = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &cpu in cpus {
            libc::CPU_SET(cpu, &mut set);
        }
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    if pinned != 0 {
        return Err(named("sched_setaffinity"));
    }
    Ok(())
}

/// Touches [`PREFAULT_STACK_BYTES`] of the stack, so its pages are mapped (and locked).
#[inline(never)]
fn prefault_stack() {
    let mut block = [0u8; PREFAULT_STACK_BYTES];
    std::hint::black_box(&mut block);
}

/// The CPUs this process may run on.
pub fn allowed_cpus() -> std::io::Result<Vec<usize>> {
    // SAFETY: `set` is a plain bit set the call fills; its size is passed with it.
    let set = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Err(named("sched_getaffinity"));
        }
        set
    };
    // SAFETY: `CPU_ISSET` reads a bit of the set, below its size.
    Ok((0..libc::CPU_SETSIZE as usize)
        .filter(|&cpu| unsafe { libc::CPU_ISSET(cpu, &set) })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Role;
    use protocol::graph::{Graph, producer_of};

    fn root() -> Grant {
        Grant {
            cap_sys_nice: true,
            cap_ipc_lock: true,
            rtprio_limit: 0,
            memlock_limit_kib: Some(8192),
        }
    }

    fn config(priority: Priority) -> RealtimeConfig {
        RealtimeConfig {
            priority,
            cpus: Vec::new(),
        }
    }

    #[test]
    fn every_poll_is_for_an_input_of_its_own_tier_or_a_higher_one_and_recording_is_lowest() {
        use protocol::topics::{ESTIMATE, MEASUREMENT, SCAN, TRUTH};
        // The roles that poll for their periodic input (their task's first), and that input.
        for (consumer, topic) in [
            (Role::Estimator, MEASUREMENT),
            (Role::Lidar, TRUTH),
            (Role::Tracker, SCAN),
            (Role::Mpc, ESTIMATE),
            (Role::Planner, ESTIMATE),
        ] {
            let producer = producer_of(topic).expect("a data topic");
            let graph = Graph::of_roles(&Role::ALL, protocol::PlantKind::Sim);
            assert_eq!(
                graph.inputs_of(consumer).next(),
                Some(topic),
                "{consumer:?} polls `{topic}`"
            );
            assert!(
                Tier::of(producer) >= Tier::of(consumer),
                "{consumer:?} polls `{topic}` of {producer:?}"
            );
        }
        for role in Role::ALL {
            assert!(Tier::of(role) > Tier::Recording);
            assert!(Tier::of(role).priority(4) >= 2);
        }
        assert_eq!(Tier::Recording.priority(4), 1);
    }

    #[test]
    fn auto_takes_50_or_the_limit_below_it_and_off_takes_nothing() {
        let always = |_| true;
        let (policy, refusal) =
            Policy::decide(&config(Priority::Auto), Tier::Planning, &root(), always);
        assert_eq!(policy.fifo_priority, Some(48));
        assert!(policy.lock_memory);
        assert_eq!(refusal, None);
        let limited = Grant {
            cap_sys_nice: false,
            rtprio_limit: 20,
            ..root()
        };
        let (policy, _) = Policy::decide(&config(Priority::Auto), Tier::Control, &limited, always);
        assert_eq!(policy.fifo_priority, Some(20));
        let (policy, refusal) =
            Policy::decide(&config(Priority::Off), Tier::Control, &root(), always);
        assert_eq!(
            (policy.fifo_priority, policy.lock_memory, refusal),
            (None, false, None)
        );
    }

    #[test]
    fn a_refusal_names_what_is_missing_and_the_run_goes_on_without_it() {
        let unprivileged = Grant {
            cap_sys_nice: false,
            cap_ipc_lock: false,
            rtprio_limit: 0,
            memlock_limit_kib: Some(8192),
        };
        let (policy, refusal) = Policy::decide(
            &config(Priority::Auto),
            Tier::Control,
            &unprivileged,
            |_| true,
        );
        assert_eq!((policy.fifo_priority, policy.lock_memory), (None, false));
        let text = refusal.expect("refused").to_string();
        assert!(
            text.contains("no CAP_SYS_NICE and RLIMIT_RTPRIO is 0"),
            "{text}"
        );
        assert!(
            text.contains("ulimit -r") && text.contains("limits.conf") && text.contains("setcap")
        );
        // Allowed by the limits, refused by the kernel.
        let (policy, refusal) =
            Policy::decide(&config(Priority::Top(60)), Tier::Control, &root(), |_| {
                false
            });
        assert_eq!(policy.fifo_priority, None);
        assert!(refusal.unwrap().0.contains("cpu.rt_runtime_us"));
        // Real time without locked memory.
        let no_lock = Grant {
            cap_ipc_lock: false,
            ..root()
        };
        let (policy, refusal) =
            Policy::decide(&config(Priority::Top(60)), Tier::Tracking, &no_lock, |_| {
                true
            });
        assert_eq!(
            (policy.fifo_priority, policy.lock_memory),
            (Some(59), false)
        );
        assert!(refusal.unwrap().0.contains("RLIMIT_MEMLOCK is 8192 KiB"));
    }

    /// `(policy, priority)` of thread `tid` of this process.
    fn scheduling_of(tid: libc::pid_t) -> (i32, u32) {
        let stat = std::fs::read_to_string(format!("/proc/self/task/{tid}/stat")).unwrap();
        scheduling_in_stat(&stat).unwrap()
    }

    #[test]
    fn raised_threads_are_those_named_and_go_back_to_normal_when_dropped() {
        let started = |name: &str| {
            let (tid_tx, tid_rx) = std::sync::mpsc::channel();
            let (end_tx, end_rx) = std::sync::mpsc::channel::<()>();
            let thread = std::thread::Builder::new()
                .name(name.into())
                .spawn(move || {
                    // SAFETY: a plain system call.
                    tid_tx.send(unsafe { libc::gettid() }).unwrap();
                    let _ = end_rx.recv();
                })
                .unwrap();
            (tid_rx.recv().unwrap(), end_tx, thread)
        };
        let carrier = started("rx-carrier-test");
        let other = started("other-test");
        match raise_threads(&["rx-carrier-"], 7) {
            Ok(raised) => {
                assert_eq!(scheduling_of(carrier.0), (libc::SCHED_FIFO, 7));
                assert_eq!(scheduling_of(other.0), (libc::SCHED_OTHER, 0));
                drop(raised);
                assert_eq!(scheduling_of(carrier.0), (libc::SCHED_OTHER, 0));
            }
            // A machine without the grant: refused, naming the thread, nothing raised.
            Err(e) => {
                assert!(!fifo_allowed(7), "refused though allowed: {e}");
                assert!(e.to_string().contains("rx-carrier-test"), "{e}");
                assert_eq!(scheduling_of(carrier.0), (libc::SCHED_OTHER, 0));
            }
        }
        for (_, end, thread) in [carrier, other] {
            drop(end);
            thread.join().unwrap();
        }
    }
}
