//! `scmpc run --in-process`: the four roles stepped in one process, in the order of the
//! data flow, with the tick semantics of DESIGN.md section 3 in lockstep.
//!
//! Per inner tick `j` (time `t_j = j Ts / M`): the plant publishes its measurement; the
//! estimator predicts with the actuation of tick `j - 1` and updates; on a sample boundary
//! (`j = k M`) the MPC solves plan(k); plans whose arrival sample has come are offered to
//! the DFL; the DFL commands `[t_j, t_j+1)`; the plant integrates over it. A plan whose
//! measured solve time exceeds Ts arrives `ceil(solve / Ts)` samples late, as it would in
//! real time.

use crate::monitor::Outcome;
use crate::record::{Recorder, Summary};
use anyhow::Context;
use dfl::{DeadlineMonitor, Dfl, PlanInbox};
use estimator::Estimator;
use mpc::Mpc;
use plant::Plant;
use protocol::{GroundTruth, Header, Scenario};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Samples a plan arrives late in lockstep: 0 if solved within `Ts`, else `ceil(solve / Ts)`.
pub fn late_samples(solve_ns: u64, ts_s: f64) -> u64 {
    let solve_s = solve_ns as f64 * 1e-9;
    if solve_s <= ts_s {
        0
    } else {
        (solve_s / ts_s).ceil() as u64
    }
}

/// Number of inner ticks in a run of `duration_s`.
pub fn tick_count(scenario: &Scenario) -> u64 {
    let dt = scenario.timing.ts_s / scenario.timing.inner_steps as f64;
    (scenario.duration_s / dt).round() as u64
}

/// Runs the scenario to its end (or an early outcome, or `stop`) and writes `out`.
pub fn run(scenario: &Scenario, out: &Path, stop: &AtomicBool) -> anyhow::Result<Summary> {
    let started = Instant::now();
    let m = scenario.timing.inner_steps as u64;
    let dt = scenario.timing.ts_s / m as f64;
    let mut recorder =
        Recorder::create(out, scenario).with_context(|| format!("creating {}", out.display()))?;
    let mut plant = Plant::new(scenario);
    let mut estimator = Estimator::new(scenario);
    let mut mpc = Mpc::new(scenario).context("setting up the MPC")?;
    let mut dfl = Dfl::new(scenario);
    let mut inbox = PlanInbox::new(true, scenario.timing.ts_s);
    let mut deadlines = DeadlineMonitor::new(scenario.timing.ts_s);
    let mut applied: Option<[f64; 2]> = None;
    let mut outcome = None;
    let ticks = tick_count(scenario);
    for tick in 0..ticks {
        if stop.load(Ordering::Relaxed) {
            outcome = Some(Outcome::Interrupted);
            break;
        }
        let header = Header {
            tick,
            time_s: tick as f64 * dt,
            ..Header::default()
        };
        let truth = GroundTruth {
            header,
            pose: plant.pose(),
        };
        let y = plant.measure();
        let estimate = estimator.step(applied, dt, y, dfl.zeta(), header);
        let sample = tick / m;
        if tick.is_multiple_of(m) {
            let mut plan = mpc.step(sample, estimate.state, estimate.position_sigma());
            mpc.inject_faults(&mut plan, &scenario.fault);
            plan.header = header;
            inbox.receive(&plan);
            deadlines.on_plan(
                &plan,
                (inbox.late(&plan) as f64 * scenario.timing.ts_s * 1e9) as u64,
            );
            recorder.plan(&plan);
        }
        inbox.release(sample, &mut dfl);
        let mut act = dfl.step(&estimate, tick);
        if tick.is_multiple_of(m)
            && let Some(mode) = act.mode()
            && let Some(verdict) = deadlines.sample_started(sample, mode)
        {
            recorder.verdict(&verdict)?;
        }
        act.deadline_misses = deadlines.misses();
        if let Some(o) = recorder.tick(&truth, &estimate, &act)? {
            outcome = Some(o);
            break;
        }
        plant.step(act.u1, act.u2, dt);
        // The estimator is driven by the command it hears, as over IPC.
        applied = Some([act.u1, act.u2]);
    }
    let outcome = match outcome {
        Some(o) => o,
        None => {
            let header = Header {
                tick: ticks,
                time_s: ticks as f64 * dt,
                ..Header::default()
            };
            let end = recorder.final_pose(&GroundTruth {
                header,
                pose: plant.pose(),
            });
            end.unwrap_or_else(|| recorder.monitor.final_outcome())
        }
    };
    let summary = recorder.finish(
        scenario,
        "in-process",
        outcome,
        started.elapsed().as_secs_f64(),
        None,
    )?;
    Ok(summary)
}
