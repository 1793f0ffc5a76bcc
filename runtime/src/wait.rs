//! How a role process waits for an input: polling shared memory in lockstep, a short
//! scheduled spin around a periodic input's known arrival time in real time, and how long
//! it waits without one ([`silent_since`]).

use crate::clock::{RunClock, monotonic_ns, sleep_until_ns};
use crate::ipc::Input;
use crate::process::{INPUT_TIMEOUT, Next};
use std::time::{Duration, Instant};

/// Real time: how long before an expected sample a consumer starts polling for it, ns.
pub const SPIN_LEAD_NS: u64 = 50_000;
/// Real time: how long after the expected time a consumer keeps polling before it falls
/// back to blocking in its WaitSet, ns.
pub const SPIN_BUDGET_NS: u64 = 300_000;

/// Real time: how late a sleep of a role process ends on a virtual machine, ns (50 µs of
/// Linux's default timer slack and the wake-up): a spin aimed at an input's expected
/// publication starts this much earlier still, or it would start after the sample came.
pub const WAKE_LATENESS_NS: u64 = 100_000;

/// Real time: how long after its due time `due_ns` a periodic input is expected to be
/// published next, ns: from `lag_ns`, the estimate so far, and the publication time of the
/// sample taken for that due time, a low quantile of the lags (down to a shorter lag at
/// once, up by an eighth of a longer one), at most half an inner tick of `dt_s` s. A
/// sample is due at its tick's time but comes after its producer's chain has run (the
/// estimate 0.15-0.27 ms after the sample in the paper's real-time run): a consumer
/// spinning from the due time would take a core from that chain. A sample published more
/// than half a tick before its due time is an older one: not counted.
pub fn next_arrival_lag_ns(lag_ns: u64, published_ns: u64, due_ns: u64, dt_s: f64) -> u64 {
    let half_tick_ns = (0.5 * dt_s * 1e9) as u64;
    if published_ns + half_tick_ns < due_ns {
        return lag_ns;
    }
    let seen_ns = published_ns.saturating_sub(due_ns);
    let next = if seen_ns <= lag_ns {
        seen_ns
    } else {
        lag_ns + (seen_ns - lag_ns) / 8
    };
    next.min(half_tick_ns)
}

/// Lockstep: how long a process polls shared memory for its next input, yielding its
/// core between polls, before it blocks: longer than a lockstep tick with an MPC step
/// (the others take ~100 µs); 0.3 ms did worse, 3 ms no better (docs/performance.md).
pub const LOCKSTEP_POLL_NS: u64 = 1_000_000;

/// Lockstep: polls `ready` (which must not make a system call to be worth it) for at most
/// [`LOCKSTEP_POLL_NS`], yielding the core between polls, so that the process whose turn it
/// is runs at once; whether `ready` came to hold. With every process of a run in the
/// chain of a tick, one runs at a time: the others' polls cost it little.
pub fn lockstep_poll(ready: impl FnMut() -> bool) -> bool {
    poll_for(LOCKSTEP_POLL_NS, ready)
}

/// Polls `ready`, yielding the core between polls, for at most `budget_ns`; whether it
/// came to hold ([`lockstep_poll`]).
fn poll_for(budget_ns: u64, mut ready: impl FnMut() -> bool) -> bool {
    let give_up = monotonic_ns() + budget_ns;
    loop {
        if ready() {
            return true;
        }
        if monotonic_ns() >= give_up {
            return false;
        }
        std::thread::yield_now();
    }
}

/// Real time: sleeps until [`SPIN_LEAD_NS`] before `expected_ns`, then polls `ready` until it
/// holds or [`SPIN_BUDGET_NS`] past `expected_ns`. Waking from an event on an idle core
/// costs tens to hundreds of µs on a virtual machine; a short, scheduled spin around a
/// periodic input's known arrival time does not (measured: docs/design.md, "Clocks").
/// Under `SCHED_FIFO` ([`crate::realtime`]) each poll yields the core instead of spinning
/// on it, so that a process of the same priority waiting for the core (the input's
/// producer, say) runs at once.
pub fn spin_wait(expected_ns: u64, mut ready: impl FnMut() -> bool) -> bool {
    sleep_until_ns(expected_ns.saturating_sub(SPIN_LEAD_NS));
    let give_up = expected_ns + SPIN_BUDGET_NS;
    let yields = crate::realtime::fifo_in_force();
    while monotonic_ns() < give_up {
        if ready() {
            return true;
        }
        if yields {
            std::thread::yield_now();
        } else {
            std::hint::spin_loop();
        }
    }
    ready()
}

/// When the silence of a process whose wait timed out `now` began, or `None` when it gives
/// up: after [`INPUT_TIMEOUT`] without input since `last_input`. A process watched by its
/// orchestrator before the run's clock has started (`supervised_before_start`) waits for
/// the start however long it takes, and its silence counts from then at the latest: a
/// fleet's orchestrator starts the run once every robot's processes are ready, which on
/// two cores may take longer (each MPC builds its programs: about 7 s for `warehouse` with
/// lidars, docs/fleet.md), and it is looked at meanwhile ([`crate::process::SUPERVISOR_CHECK`]).
pub fn silent_since(
    last_input: Instant,
    now: Instant,
    supervised_before_start: bool,
) -> Option<Instant> {
    match supervised_before_start {
        true => Some(now),
        false => (now.duration_since(last_input) < INPUT_TIMEOUT).then_some(last_input),
    }
}

/// Real time: polls `input`, due at `at_ns` and published `arrival_lag_ns` after it, around
/// when it is expected ([`spin_wait`]); whether it came.
pub(crate) fn spin_for(input: &dyn Input, at_ns: u64, arrival_lag_ns: u64) -> bool {
    let expected_ns = at_ns + arrival_lag_ns.saturating_sub(WAKE_LATENESS_NS);
    spin_wait(expected_ns, || input.has_samples())
}

/// What a role's loop knows of its inputs (`process::Member::drive`).
pub(crate) struct Heard<'i> {
    /// When an input was last heard, and how many samples the inputs had taken then.
    pub(crate) last_input: Instant,
    pub(crate) taken_before: u64,
    /// Real time: how long after its due time the expected input is published
    /// ([`next_arrival_lag_ns`]; one lag, as every role expects one periodic input), ns.
    pub(crate) arrival_lag_ns: u64,
    /// The input polled for, with its due time (monotonic ns).
    pub(crate) polled: Option<(&'i dyn Input, u64)>,
}

impl<'i> Heard<'i> {
    /// After a step: whether its inputs took samples (then an input was heard now).
    pub(crate) fn count(&mut self, inputs: &[&dyn Input]) {
        let taken: u64 = inputs.iter().map(|input| input.taken()).sum();
        if taken != self.taken_before {
            self.taken_before = taken;
            self.last_input = Instant::now();
        }
    }

    /// How long to block for `next` (`None` inside: [`INPUT_TIMEOUT`]); `None` when the
    /// input it expects came while it was polled for in real time ([`spin_for`]).
    pub(crate) fn spin_or_timeout(
        &mut self,
        next: &Next<'i>,
        clock: &RunClock,
    ) -> Option<Option<Duration>> {
        match *next {
            Next::Wait(until_s) => Some(
                until_s
                    .and_then(|t| clock.at_ns(t))
                    .map(|at| Duration::from_nanos(at.saturating_sub(monotonic_ns()))),
            ),
            Next::Expect { input, at_s } => {
                self.polled = clock.at_ns(at_s).map(|at_ns| (input, at_ns));
                let lag_ns = self.arrival_lag_ns;
                if self
                    .polled
                    .is_some_and(|(_, at_ns)| spin_for(input, at_ns, lag_ns))
                {
                    self.last_input = Instant::now();
                    return None;
                }
                Some(None)
            }
            Next::At(_) => Some(None),
        }
    }

    /// After the pass that took the input polled for: its arrival lag, learned from it.
    pub(crate) fn learn_lag(&mut self, dt_s: f64) {
        if let Some((input, due_ns)) = self.polled.take()
            && let Some(published_ns) = input.newest_publish_ns()
        {
            self.arrival_lag_ns =
                next_arrival_lag_ns(self.arrival_lag_ns, published_ns, due_ns, dt_s);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lockstep_poll_returns_once_ready_and_gives_up_after_its_budget() {
        // A budget no preemption of a busy machine uses up (lockstep's 1 ms did, once in
        // CI, 2026-12-02: a yield took longer), so only the return is judged.
        let mut polls = 0;
        assert!(poll_for(60_000_000_000, || {
            polls += 1;
            polls == 3
        }));
        assert_eq!(polls, 3, "it returns at the first poll that is ready");
        let started = monotonic_ns();
        assert!(!lockstep_poll(|| false));
        assert!(monotonic_ns() - started >= LOCKSTEP_POLL_NS);
    }

    #[test]
    fn the_expected_lag_of_an_input_falls_at_once_rises_by_an_eighth_and_ignores_old_samples() {
        let (dt_s, due) = (0.005, 1_000_000_000);
        // Published 240 µs after its due time: the lag rises by an eighth of the gap.
        assert_eq!(next_arrival_lag_ns(0, due + 240_000, due, dt_s), 30_000);
        assert_eq!(
            next_arrival_lag_ns(30_000, due + 240_000, due, dt_s),
            56_250
        );
        // An earlier one: down to its lag at once (before the due time: 0).
        assert_eq!(next_arrival_lag_ns(56_250, due + 10_000, due, dt_s), 10_000);
        assert_eq!(next_arrival_lag_ns(56_250, due - 20_000, due, dt_s), 0);
        // A sample of an earlier tick says nothing of this one's lag.
        assert_eq!(
            next_arrival_lag_ns(56_250, due - 4_000_000, due, dt_s),
            56_250
        );
        // Never past half a tick, however late the producer.
        let mut lag = 0;
        for _ in 0..200 {
            lag = next_arrival_lag_ns(lag, due + 20_000_000, due, dt_s);
        }
        assert_eq!(lag, 2_500_000);
    }

    #[test]
    fn a_silent_process_gives_up_after_the_input_timeout_counted_from_the_start_when_watched() {
        let heard = Instant::now();
        let (soon, late) = (heard + INPUT_TIMEOUT / 2, heard + INPUT_TIMEOUT * 3);
        assert_eq!(silent_since(heard, soon, false), Some(heard));
        assert_eq!(silent_since(heard, heard + INPUT_TIMEOUT, false), None);
        assert_eq!(
            silent_since(heard, late, false),
            None,
            "unwatched, or started"
        );
        // Watched before the start: the silence begins anew at every wait, so once the
        // run starts the process gives up only 5 s after the start, not at once.
        assert_eq!(silent_since(heard, late, true), Some(late));
        assert_eq!(
            silent_since(late, late + INPUT_TIMEOUT / 2, false),
            Some(late)
        );
    }
}
