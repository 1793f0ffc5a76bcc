//! Time: the system-wide monotonic clock, comparable across processes (`CLOCK_MONOTONIC`),
//! and [`RunClock`], a run's time in either of its clocks.
//!
//! On a host of its own a process's monotonic clock is not the orchestrator's: its agent
//! estimates the difference and hands its role processes the correction
//! ([`ENV_CLOCK_CORRECTION_NS`]), so that every time stamp and deadline of a run is on the
//! orchestrator's clock, on every host. [`ENV_CLOCK_OFFSET_MS`] shifts a process's clock on
//! purpose, to test that on one machine, where the clocks agree anyway.

use protocol::task::{Context, SimulatedTime};
use std::sync::OnceLock;

/// Environment: an artificial offset of this process's monotonic clock, ms (a test of a
/// host whose clock differs).
pub const ENV_CLOCK_OFFSET_MS: &str = "SCMPC_CLOCK_OFFSET_MS";
/// Environment: what to add to this host's clock to read the orchestrator's, ns (set by
/// the host's agent for the role processes it starts).
pub const ENV_CLOCK_CORRECTION_NS: &str = "SCMPC_CLOCK_CORRECTION_NS";

/// The shift of this process's clock from `CLOCK_MONOTONIC`, ns, from its environment
/// ([`ENV_CLOCK_OFFSET_MS`] and [`ENV_CLOCK_CORRECTION_NS`]); an error names the variable
/// whose value is not a number.
pub fn clock_shift_from_env() -> Result<i64, String> {
    let read = |name: &str, scale: f64| -> Result<i64, String> {
        match std::env::var(name) {
            Err(_) => Ok(0),
            Ok(text) if text.trim().is_empty() => Ok(0),
            Ok(text) => text
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .map(|v| (v * scale).round() as i64)
                .ok_or_else(|| format!("{name}={text}: not a number")),
        }
    };
    Ok(read(ENV_CLOCK_OFFSET_MS, 1e6)? + read(ENV_CLOCK_CORRECTION_NS, 1.0)?)
}

/// This process's clock shift, ns (read once; an unreadable environment was refused by
/// the command before it got here, and counts as no shift).
fn shift_ns() -> i64 {
    static SHIFT: OnceLock<i64> = OnceLock::new();
    *SHIFT.get_or_init(|| clock_shift_from_env().unwrap_or(0))
}

/// `CLOCK_MONOTONIC`, ns.
fn raw_monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Now on the run's monotonic clock, ns: `CLOCK_MONOTONIC` shifted as the environment
/// says (the orchestrator's clock on every host).
pub fn monotonic_ns() -> u64 {
    raw_monotonic_ns().saturating_add_signed(shift_ns())
}

/// The inner tick (of `dt_s` seconds) the monotonic clock is in at `now_ns`, counted from
/// a real-time run's tick 0 at `start_ns` (0 before it).
pub fn tick_at(start_ns: u64, now_ns: u64, dt_s: f64) -> u64 {
    (now_ns.saturating_sub(start_ns) as f64 / (dt_s * 1e9)) as u64
}

/// Sleeps until the absolute time `deadline_ns` on the run's clock ([`monotonic_ns`]; no
/// drift across periods). Returns early if a signal interrupts the sleep.
pub fn sleep_until_ns(deadline_ns: u64) {
    let deadline_ns = deadline_ns.saturating_add_signed(-shift_ns());
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

/// How a run is clocked (docs/design.md, "Clocks").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunMode {
    /// Simulated time: every process waits for its inputs of the tick; deterministic.
    Lockstep,
    /// Every process paced by the monotonic wall clock with absolute deadlines.
    Realtime,
}

impl RunMode {
    /// The name of the mode on the command line, in `summary.json` and `SCMPC_MODE`.
    pub fn as_str(self) -> &'static str {
        match self {
            RunMode::Lockstep => "lockstep",
            RunMode::Realtime => "realtime",
        }
    }
}

/// A run's time, as the orchestrator, the role runtime and every task tell it: the one
/// place that knows how the two clocks differ (docs/design.md, "Clocks"). Times are seconds since
/// tick 0 (`t_j = j Ts / M`).
///
/// - **Lockstep** (simulated): time is the newest tick granted and moves only with the
///   next grant; while a tick is computed its time stands at `t_j`, so no time is ever
///   *past* before every input of the tick has come, and a computation takes no time
///   unless it overruns its period ([`RunClock::arrival_after_ns`]).
/// - **Real time**: the monotonic clock, tick 0 at `start_ns`.
///
/// Before the run's clock has started (no grant, no start time) no time is reached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunClock {
    mode: RunMode,
    dt_s: f64,
    /// Lockstep: the newest tick granted.
    granted: Option<u64>,
    /// Real time: the monotonic time of tick 0, ns.
    start_ns: Option<u64>,
}

impl RunClock {
    /// A clock of `mode` with inner tick `dt_s`, not started.
    pub fn new(mode: RunMode, dt_s: f64) -> RunClock {
        RunClock {
            mode,
            dt_s,
            granted: None,
            start_ns: None,
        }
    }

    /// A lockstep clock standing at `tick` (the in-process loop's).
    pub fn simulated_at(tick: u64, dt_s: f64) -> RunClock {
        RunClock {
            granted: Some(tick),
            ..RunClock::new(RunMode::Lockstep, dt_s)
        }
    }

    pub fn mode(&self) -> RunMode {
        self.mode
    }

    /// The inner tick, s.
    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    /// Lockstep: tick `tick` is granted (a grant never moves the clock back).
    pub fn grant(&mut self, tick: u64) {
        self.granted = self.granted.max(Some(tick));
    }

    /// Real time: tick 0 is at monotonic `start_ns`.
    pub fn start(&mut self, start_ns: u64) {
        self.start_ns = Some(start_ns);
    }

    /// Whether the clock runs (lockstep: a tick was granted; real time: the start is
    /// known).
    pub fn started(&self) -> bool {
        match self.mode {
            RunMode::Lockstep => self.granted.is_some(),
            RunMode::Realtime => self.start_ns.is_some(),
        }
    }

    /// The tick the run is in: the newest granted, or the wall clock's.
    pub fn now_tick(&self) -> Option<u64> {
        match self.mode {
            RunMode::Lockstep => self.granted,
            RunMode::Realtime => self
                .start_ns
                .map(|start| tick_at(start, monotonic_ns(), self.dt_s)),
        }
    }

    /// The newest tick a producer can have published by now, against which a consumer
    /// judges every sample ([`crate::ipc::TickLimit`]): in lockstep `heard`, the newest
    /// tick the consumer has been told of plus the grants that may be in flight to it; in
    /// real time the wall clock's tick plus [`crate::ipc::TICK_SLACK`].
    pub fn newest_publishable(&self, heard: Option<u64>) -> Option<u64> {
        match self.mode {
            RunMode::Lockstep => heard,
            RunMode::Realtime => self.now_tick().map(|t| t + crate::ipc::TICK_SLACK),
        }
    }

    /// Lockstep: the simulated time of the newest tick granted.
    fn simulated(&self) -> Option<SimulatedTime> {
        self.granted.map(|tick| SimulatedTime::at(tick, self.dt_s))
    }

    /// Real time: the monotonic time of run time `t_s`, ns (`None` in lockstep, and
    /// before the start).
    pub fn at_ns(&self, t_s: f64) -> Option<u64> {
        match self.mode {
            RunMode::Lockstep => None,
            RunMode::Realtime => self
                .start_ns
                .map(|start| start + (t_s.max(0.0) * 1e9) as u64),
        }
    }

    /// Whether the run's time has reached `t_s` (lockstep: the tick of `t_s` or a later
    /// one is granted).
    pub fn has_reached(&self, t_s: f64) -> bool {
        match self.mode {
            RunMode::Lockstep => self.simulated().is_some_and(|s| s.has_reached(t_s)),
            RunMode::Realtime => self.at_ns(t_s).is_some_and(|at| monotonic_ns() >= at),
        }
    }

    /// Whether the run's time is past `t_s`: an input still missing for `t_s` is not
    /// coming in time. In lockstep the time of the tick being computed is never past.
    pub fn is_past(&self, t_s: f64) -> bool {
        match self.mode {
            RunMode::Lockstep => self.simulated().is_some_and(|s| s.is_past(t_s)),
            RunMode::Realtime => self.at_ns(t_s).is_some_and(|at| monotonic_ns() > at),
        }
    }

    /// How long after run time `t_s` a sample that took `production_ns` to make reaches
    /// its consumer now, ns, for a producer of period `period_s`. Real time: measured (0
    /// before the start). Lockstep: at once if it was made within its period, else
    /// [`SimulatedTime::arrival_after_ns`]: whole periods late, so that timing violations behave as they would
    /// in real time (docs/design.md, "Deadlines and fallback").
    pub fn arrival_after_ns(&self, t_s: f64, production_ns: u64, period_s: f64) -> u64 {
        match self.mode {
            RunMode::Lockstep => {
                SimulatedTime::at(0, self.dt_s).arrival_after_ns(t_s, production_ns, period_s)
            }
            RunMode::Realtime => self
                .at_ns(t_s)
                .map_or(0, |at| monotonic_ns().saturating_sub(at)),
        }
    }

    /// Real time: holds what follows `ns` (an output of a slow step,
    /// [`Publish::hold_ns`](protocol::task::Publish)). Lockstep: nothing, since a
    /// computation's time is modelled by its production time
    /// ([`RunClock::arrival_after_ns`]), never slept.
    pub fn hold(&self, ns: u64) {
        if self.mode == RunMode::Realtime && ns > 0 {
            std::thread::sleep(std::time::Duration::from_nanos(ns));
        }
    }
}

/// A task asks the run's clock ([`protocol::task::Context`]); in process every task is
/// active, never orphaned, and hears the clock at once.
impl protocol::task::Context for RunClock {
    fn has_reached(&self, t_s: f64) -> bool {
        RunClock::has_reached(self, t_s)
    }
    fn is_past(&self, t_s: f64) -> bool {
        RunClock::is_past(self, t_s)
    }
    fn now_tick(&self) -> Option<u64> {
        RunClock::now_tick(self)
    }
    fn arrival_after_ns(&self, t_s: f64, production_ns: u64, period_s: f64) -> u64 {
        RunClock::arrival_after_ns(self, t_s, production_ns, period_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_lockstep_plans_within_the_period_are_on_time_and_slower_ones_late_by_whole_periods() {
        let clock = RunClock::simulated_at(7, 0.005);
        assert_eq!(clock.arrival_after_ns(0.0, 125_000_000, 0.05), 150_000_000);
        assert_eq!(clock.arrival_after_ns(0.0, 30_000, 0.05), 0);
    }

    #[test]
    fn in_lockstep_the_time_of_the_tick_granted_is_reached_but_never_past() {
        let mut clock = RunClock::new(RunMode::Lockstep, 0.005);
        assert!(!clock.started() && !clock.has_reached(0.0) && !clock.is_past(-1.0));
        clock.grant(10);
        let t = 10.0 * 0.005;
        assert!(clock.has_reached(t) && !clock.is_past(t) && clock.is_past(9.0 * 0.005));
        assert!(!clock.has_reached(11.0 * 0.005));
        clock.grant(3);
        assert_eq!(
            clock.now_tick(),
            Some(10),
            "a grant never moves the clock back"
        );
    }

    #[test]
    fn in_real_time_the_clock_is_the_monotonic_clock_from_tick_0() {
        let mut clock = RunClock::new(RunMode::Realtime, 0.005);
        assert!(!clock.has_reached(0.0) && clock.now_tick().is_none());
        clock.start(monotonic_ns() - 1_000_000_000);
        assert!(clock.is_past(0.9) && !clock.has_reached(1.1));
        assert!(clock.now_tick().is_some_and(|t| (200..210).contains(&t)));
        let arrival = clock.arrival_after_ns(0.5, 0, 0.05);
        assert!((500_000_000..600_000_000).contains(&arrival), "{arrival}");
    }

    #[test]
    fn sleep_until_does_not_wake_before_the_deadline() {
        let deadline = monotonic_ns() + 2_000_000;
        sleep_until_ns(deadline);
        assert!(monotonic_ns() >= deadline);
    }
}
