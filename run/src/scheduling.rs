//! The real-time scheduling of a run, as the orchestrator sees it (docs/running.md,
//! "Real-time scheduling"): checked and warned of once before the run, its own recording
//! tier put in force while the run lasts, and what each process runs under read from the
//! kernel. Each role process puts its own in force ([`runtime::realtime`]).

use protocol::RealtimeConfig;
use runtime::clock::RunMode;
use runtime::realtime::{InForce, Policy, Tier, allowed_cpus};

/// Before a real-time run starts: every CPU of `realtime.cpus` must be one this process
/// may run on (an error names the first that is not); what the machine refuses of the
/// policy is printed once, as a warning, and the run goes on without it.
pub fn check(realtime: &RealtimeConfig) -> Result<(), String> {
    let allowed = allowed_cpus().map_err(|e| format!("realtime.cpus: {e}"))?;
    if let Some(cpu) = realtime.cpus.iter().find(|cpu| !allowed.contains(cpu)) {
        return Err(format!(
            "realtime.cpus: CPU {cpu} is not one this process may run on ({})",
            allowed
                .iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let (_, Some(refusal)) = Policy::for_this_process(realtime, Tier::Recording) {
        eprintln!("warning: real-time scheduling: {refusal}");
    }
    Ok(())
}

/// The orchestrator's recording tier, in force until dropped (`None`: the machine refuses
/// it, or `realtime.priority = "off"`, warned of by [`check`]).
pub fn orchestrator(realtime: &RealtimeConfig) -> Option<InForce> {
    let (policy, _) = Policy::for_this_process(realtime, Tier::Recording);
    let wanted = policy.fifo_priority.is_some() || !policy.cpus.is_empty();
    match wanted.then(|| policy.apply_while_held()) {
        Some(Ok(held)) => Some(held),
        Some(Err(e)) => {
            tracing::warn!("the orchestrator's real-time policy is not in force: {e}");
            None
        }
        None => None,
    }
}

/// The `SCHED_FIFO` priority of a host's bridge in a run of `mode`: the control tier's in
/// real time where the machine grants it (`None`: the normal policy; what is refused is
/// warned of by [`check`] on the orchestrator's host).
pub fn bridge_priority(realtime: &RealtimeConfig, mode: RunMode) -> Option<u8> {
    (mode == RunMode::Realtime)
        .then(|| {
            Policy::for_this_process(realtime, Tier::Control)
                .0
                .fifo_priority
        })
        .flatten()
}

/// How process `pid`'s main thread is scheduled, from `/proc` (`None`: it is gone).
pub fn observe(pid: u32) -> Option<record::Scheduling> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let (policy, priority) = runtime::realtime::scheduling_in_stat(&stat)?;
    let policy = match policy {
        libc::SCHED_OTHER => "other",
        libc::SCHED_FIFO => "fifo",
        libc::SCHED_RR => "rr",
        libc::SCHED_BATCH => "batch",
        libc::SCHED_IDLE => "idle",
        _ => "unknown",
    };
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .map(|v| v.trim().to_string())
    };
    let locked_kib: u64 = field("VmLck:")?
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(record::Scheduling {
        policy: policy.into(),
        priority,
        memory_locked: locked_kib > 0,
        cpus: field("Cpus_allowed_list:")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_reads_as_the_normal_policy_on_the_cpus_it_may_use() {
        let seen = observe(std::process::id()).expect("this process is alive");
        assert_eq!((seen.policy.as_str(), seen.priority), ("other", 0));
        let cpus = allowed_cpus().unwrap();
        let listed = if cpus.len() == 1 {
            cpus[0].to_string()
        } else {
            format!("{}-{}", cpus[0], cpus[cpus.len() - 1])
        };
        if cpus.windows(2).all(|w| w[1] == w[0] + 1) {
            assert_eq!(seen.cpus, listed);
        }
    }

    #[test]
    fn a_cpu_this_process_may_not_use_is_refused_by_number() {
        let config = RealtimeConfig {
            priority: protocol::Priority::Off,
            cpus: vec![protocol::CPU_SET_SIZE - 1],
        };
        let e = check(&config).unwrap_err();
        assert!(e.starts_with("realtime.cpus: CPU 1023 is not one"), "{e}");
    }
}
