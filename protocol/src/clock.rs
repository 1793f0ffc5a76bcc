//! The system-wide monotonic clock, comparable across processes (`CLOCK_MONOTONIC`).

/// Now on the monotonic clock, ns.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The inner tick (of `dt_s` seconds) the monotonic clock is in at `now_ns`, counted from
/// a real-time run's tick 0 at `start_ns` (0 before it).
pub fn tick_at(start_ns: u64, now_ns: u64, dt_s: f64) -> u64 {
    (now_ns.saturating_sub(start_ns) as f64 / (dt_s * 1e9)) as u64
}

/// Sleeps until the absolute monotonic time `deadline_ns` (no drift across periods).
/// Returns early if a signal interrupts the sleep.
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
    unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &ts,
            std::ptr::null_mut(),
        )
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sleep_until_does_not_wake_before_the_deadline() {
        let deadline = monotonic_ns() + 2_000_000;
        sleep_until_ns(deadline);
        assert!(monotonic_ns() >= deadline);
    }
}
