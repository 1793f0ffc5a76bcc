//! The warm-up of a role before an input it expects, in real time: when it starts, how
//! long it goes on, and how the first one's length times the next
//! ([`Member::run_warming`](crate::process::Member)(crate::process::Member)). The role warms up through
//! [`Task::warm_up`](protocol::task::Task::warm_up); lockstep never warms up.

use crate::clock::RunClock;
use crate::wait::SPIN_BUDGET_NS;

/// How long before an expected input [`Member::run_warming`](crate::process::Member) warms its role up at the
/// earliest, in inner ticks: half a tick, after the last tick of the sample before (when
/// the plant, the estimator and the DFL are idle too). The first warm-up comes then;
/// later ones as late as their length allows ([`warm_up_window_ns`]).
pub const WARM_UP_LEAD_TICKS: f64 = 0.5;

/// How long before an expected input comes the first warm-up for it aims to have ended,
/// ns: the sleep before it ends late now and then (on this VM, with 250 µs, 10-30 % of
/// the paper's samples had no warm-up at all; 0.5-5 % with 500 µs), and a warm-up can
/// take longer than the last one. The time left until the input comes is filled with
/// more warm-ups ([`Member::run_warming`](crate::process::Member)).
pub const WARM_UP_MARGIN_NS: u64 = 500_000;

/// When to warm up for an input due at run time `due_s` and published `arrival_lag_ns`
/// after its due time ([`next_arrival_lag_ns`]): from and until, monotonic ns; `None` in
/// lockstep and before the clock has started. What a warm-up brings into the caches is
/// gone again within a millisecond or so on a virtual machine, even on a core kept busy
/// (docs/performance.md, "The warm-up, just in time"), so the role warms up until the
/// input comes (its warm-up looks for it), and at the latest until [`SPIN_BUDGET_NS`]
/// after it is expected (then it polls for it, [`spin_wait`]). The first warm-up
/// starts [`WARM_UP_MARGIN_NS`] and as long as the last first one took (`last_ns`), and an
/// eighth more, before the input is expected; never more than [`WARM_UP_LEAD_TICKS`]
/// before the due time, where it starts without a last length.
pub(crate) fn warm_up_window_ns(
    clock: &RunClock,
    due_s: f64,
    arrival_lag_ns: u64,
    last_ns: Option<u64>,
) -> Option<(u64, u64)> {
    let lead_s = WARM_UP_LEAD_TICKS * clock.dt_s();
    let earliest = clock.at_ns(due_s - lead_s)?;
    let arrival = clock.at_ns(due_s)? + arrival_lag_ns;
    let from = last_ns.map_or(earliest, |last_ns| {
        arrival
            .saturating_sub(last_ns + last_ns / 8 + WARM_UP_MARGIN_NS)
            .max(earliest)
    });
    Some((from, arrival + SPIN_BUDGET_NS))
}

/// The warm-ups of a role before its expected inputs ([`Member::run_warming`](crate::process::Member)): the input
/// they are for (its due time, s), until when (monotonic ns), whether the first one for it
/// is still to come, and how long the first one for the last input took (ns), which times
/// the next window ([`warm_up_window_ns`]).
#[derive(Debug, Default)]
pub(crate) struct WarmUps {
    due_s: Option<f64>,
    pub(crate) until_ns: u64,
    first_to_come: bool,
    first_took_ns: Option<u64>,
}

/// What a pass of a role warming up does before the input it expects ([`WarmUps::next`]).
#[derive(Debug, PartialEq)]
pub(crate) enum WarmUpPass {
    /// The first pass expecting the input: sleep to the window's start (monotonic ns).
    SleepTo(u64),
    /// Warm up: the window is open and the input has not come (the step of this pass
    /// would have taken it).
    WarmUp,
    /// Nothing: lockstep, the clock not started, or the window over (the role then polls
    /// or waits for the input).
    Wait,
}

impl WarmUps {
    /// What this pass does before the input due at run time `due_s`, `now_ns` monotonic.
    pub(crate) fn next(
        &mut self,
        clock: &RunClock,
        due_s: f64,
        arrival_lag_ns: u64,
        now_ns: u64,
    ) -> WarmUpPass {
        if self.due_s != Some(due_s) {
            self.due_s = Some(due_s);
            self.first_to_come = true;
            let window = warm_up_window_ns(clock, due_s, arrival_lag_ns, self.first_took_ns);
            self.until_ns = window.map_or(0, |(_, until)| until);
            return window.map_or(WarmUpPass::Wait, |(from, _)| WarmUpPass::SleepTo(from));
        }
        if now_ns < self.until_ns {
            WarmUpPass::WarmUp
        } else {
            WarmUpPass::Wait
        }
    }

    /// After a warm-up from `started_ns` to `ended_ns`, `came`: whether the input has come.
    /// The first one for an input times the next window; one cut short (at the window's
    /// end, or by the input) would have taken longer, so it counts twice.
    pub(crate) fn warmed(&mut self, started_ns: u64, ended_ns: u64, came: bool) {
        if std::mem::take(&mut self.first_to_come) {
            let took_ns = ended_ns.saturating_sub(started_ns);
            let cut = ended_ns >= self.until_ns || came;
            self.first_took_ns = Some(if cut { 2 * took_ns } else { took_ns });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::RunMode;

    #[test]
    fn the_first_warm_up_comes_half_a_tick_before_an_expected_input_in_real_time_only() {
        let dt_s = 0.005;
        let mut realtime = RunClock::new(RunMode::Realtime, dt_s);
        assert_eq!(
            warm_up_window_ns(&realtime, 1.0, 0, None),
            None,
            "not started"
        );
        realtime.start(1_000_000_000);
        // Due at 1 s of run time (2 s monotonic), coming 0.2 ms later: from 2.5 ms before
        // the due time until polling for the input would give up.
        assert_eq!(
            warm_up_window_ns(&realtime, 1.0, 200_000, None),
            Some((1_997_500_000, 2_000_200_000 + SPIN_BUDGET_NS))
        );
        let mut lockstep = RunClock::new(RunMode::Lockstep, dt_s);
        lockstep.grant(199);
        assert_eq!(warm_up_window_ns(&lockstep, 1.0, 0, Some(100_000)), None);
    }

    #[test]
    fn warm_ups_start_their_margin_and_the_last_ones_length_before_the_input_comes() {
        let mut realtime = RunClock::new(RunMode::Realtime, 0.005);
        realtime.start(1_000_000_000);
        // Due at 2 s monotonic, coming 0.2 ms later; the last first warm-up took 160 µs:
        // from 180 µs and the margin before the input comes, until polling would give up.
        let arrival = 2_000_200_000;
        let until = arrival + SPIN_BUDGET_NS;
        assert_eq!(
            warm_up_window_ns(&realtime, 1.0, 200_000, Some(160_000)),
            Some((arrival - 180_000 - WARM_UP_MARGIN_NS, until))
        );
        // A long one starts no earlier than half a tick before the due time.
        assert_eq!(
            warm_up_window_ns(&realtime, 1.0, 200_000, Some(2_400_000)),
            Some((1_997_500_000, until))
        );
    }

    #[test]
    fn warm_ups_repeat_until_their_window_ends_and_the_first_ones_length_times_the_next() {
        let mut realtime = RunClock::new(RunMode::Realtime, 0.005);
        realtime.start(1_000_000_000);
        let lag = 200_000;
        let mut warm_ups = WarmUps::default();
        // The input due at 1 s of run time (2 s monotonic) comes 0.2 ms later. The first
        // pass expecting it sleeps to half a tick before its due time.
        let arrival = 2_000_200_000;
        assert_eq!(
            warm_ups.next(&realtime, 1.0, lag, 1_990_000_000),
            WarmUpPass::SleepTo(1_997_500_000)
        );
        // From there every pass warms up, until polling for the input would give up.
        assert_eq!(
            warm_ups.next(&realtime, 1.0, lag, 1_997_500_000),
            WarmUpPass::WarmUp
        );
        warm_ups.warmed(1_997_500_000, 1_997_660_000, false);
        assert_eq!(
            warm_ups.next(&realtime, 1.0, lag, 1_997_700_000),
            WarmUpPass::WarmUp
        );
        warm_ups.warmed(1_997_700_000, 1_997_750_000, true);
        assert_eq!(
            warm_ups.next(&realtime, 1.0, lag, arrival + SPIN_BUDGET_NS),
            WarmUpPass::Wait
        );
        // The next input's window starts by the first warm-up's 160 µs (the later one,
        // cut short by the input, does not count), an eighth more and the margin.
        let arrival = arrival + 500_000_000;
        assert_eq!(
            warm_ups.next(&realtime, 1.5, lag, arrival - 3_000_000),
            WarmUpPass::SleepTo(arrival - 180_000 - WARM_UP_MARGIN_NS)
        );
        // A first warm-up cut short by the input counts twice its 100 µs.
        warm_ups.warmed(arrival - 500_000, arrival - 400_000, true);
        let arrival = arrival + 500_000_000;
        assert_eq!(
            warm_ups.next(&realtime, 2.0, lag, arrival - 3_000_000),
            WarmUpPass::SleepTo(arrival - 225_000 - WARM_UP_MARGIN_NS)
        );
        // Lockstep never warms up.
        let mut lockstep = RunClock::new(RunMode::Lockstep, 0.005);
        lockstep.grant(199);
        let mut warm_ups = WarmUps::default();
        assert_eq!(warm_ups.next(&lockstep, 1.0, 0, 0), WarmUpPass::Wait);
        assert_eq!(warm_ups.next(&lockstep, 1.0, 0, 0), WarmUpPass::Wait);
    }
}
