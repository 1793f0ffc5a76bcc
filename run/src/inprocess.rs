//! `scmpc run --in-process`: the [`ClosedLoop`] stepped to the end of the run, every tick
//! recorded.

use crate::closed_loop::{ClosedLoop, Ended, Tick};
use crate::sinks::Recording;
use protocol::Validated;
use protocol::task::GoalChange;
use record::Summary;
use record::event::{Event, Restart};
use record::judge::Outcome;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Runs the scenario to its end (or an early outcome, or `stop`) and writes `out` (and
/// what `recording` asks for).
pub fn run(
    scenario: &Validated,
    out: &Path,
    recording: Recording,
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    run_observed(scenario, out, recording, stop, |_| {})
}

/// A goal a sink took from outside (a live view's client), the `goals_set`th, set for every
/// task and the record ([`GoalChange::set_at`]).
pub(crate) fn set_requested_goal(
    recorder: &mut record::Recorder,
    closed_loop: &mut ClosedLoop,
    goals_set: &mut u32,
) -> std::io::Result<()> {
    if let Some(goal) = recorder.requested_goal() {
        *goals_set += 1;
        let inner_steps = closed_loop.inner_steps();
        let change = GoalChange::set_at(*goals_set, goal, closed_loop.tick(), inner_steps);
        closed_loop.set_goal(change);
        recorder.goal_set(&change)?;
    }
    Ok(())
}

/// Records one tick of the closed loop: the outcome, if the tick ends the run.
pub(crate) fn record_tick(
    recorder: &mut record::Recorder,
    tick: &Tick,
) -> std::io::Result<Option<Outcome>> {
    if let Some((role, topic)) = tick.restarted {
        recorder.event(Event::Restarted(Restart::InProcess {
            role,
            reason: format!("{topic} refused"),
        }))?;
    }
    if let Some(plan) = &tick.plan {
        recorder.plan(plan)?;
    }
    if let Some(verdict) = &tick.verdict {
        recorder.verdict(verdict)?;
    }
    let mut no_route = None;
    if let Some(route) = &tick.route {
        no_route = recorder.route(route)?;
    }
    if let Some(tracks) = &tick.tracks {
        recorder.tracks(tracks)?;
    }
    for data in &tick.recorded {
        recorder.data(data)?;
    }
    let outcome = recorder.tick(&tick.truth, None, &tick.estimate, &tick.actuation)?;
    Ok(outcome.or(no_route))
}

/// [`run`], handing every tick to `observe` after it is recorded.
pub fn run_observed(
    scenario: &Validated,
    out: &Path,
    recording: Recording,
    stop: &AtomicBool,
    mut observe: impl FnMut(&Tick),
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let mut recorder = crate::sinks::recorder(scenario, out, recording)?;
    let mut closed_loop = ClosedLoop::new(scenario)?;
    let mut outcome = None;
    let mut pace = crate::pace::Pace::of(scenario, recording);
    let mut goals_set = 0;
    while outcome.is_none() && !closed_loop.is_done() {
        if stop.load(Ordering::Relaxed) {
            outcome = Some(Outcome::Interrupted);
            break;
        }
        if let Some(pace) = &mut pace {
            pace.wait(closed_loop.tick());
        }
        set_requested_goal(&mut recorder, &mut closed_loop, &mut goals_set)?;
        let tick = match closed_loop.step() {
            Ok(tick) => tick,
            Err(Ended::Aborted { role, topic }) => {
                recorder.event(Event::Aborted {
                    role,
                    reason: format!("{topic} refused, no restart left"),
                })?;
                outcome = Some(Outcome::Aborted);
                break;
            }
            Err(stalled) => return Err(stalled.into()),
        };
        outcome = record_tick(&mut recorder, &tick)?;
        observe(&tick);
    }
    let outcome = match outcome {
        Some(o) => o,
        None => recorder.end_of_run(closed_loop.final_truth().as_ref()),
    };
    let summary = recorder.finish(
        scenario,
        "in-process",
        outcome,
        started.elapsed().as_secs_f64(),
        None,
        crate::stop::received(),
    )?;
    Ok(summary)
}
