//! How much slower an MPC step is after the process has been idle, as every step of a
//! real-time run is (the MPC waits `Ts` = 50 ms for the next estimate):
//! `cargo run --release -p mpc --example idle_gap`.
//!
//! Steps the MPC over the first 200 samples of the paper run, once back to back, once
//! after sleeping before every step, and once after sleeping and then spinning (the core
//! awake, its caches as the sleep left them). Prints each case's percentiles.

use mpc::Mpc;
use protocol::Scenario;
use std::time::{Duration, Instant};

const SAMPLES: usize = 200;

fn main() -> Result<(), mpc::MpcError> {
    let scenario = Scenario::default();
    let states = paper_states(&scenario)?;
    for (sleep_ms, spin_us) in [(0, 0), (50, 0), (50, 100), (50, 2000)] {
        let mut mpc = Mpc::new(&scenario)?;
        let mut step_us: Vec<f64> = states
            .iter()
            .enumerate()
            .map(|(k, &x_bar)| {
                std::thread::sleep(Duration::from_millis(sleep_ms));
                let spin = Instant::now();
                while spin.elapsed() < Duration::from_micros(spin_us) {
                    std::hint::spin_loop();
                }
                let started = Instant::now();
                mpc.step(k as u64, x_bar, 0.0);
                started.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        step_us.sort_by(f64::total_cmp);
        let at = |q: f64| step_us[((step_us.len() - 1) as f64 * q).round() as usize];
        println!(
            "sleep {sleep_ms:>2} ms, spin {spin_us:>4} µs: step p50 {:>4.0} µs, p90 {:>4.0} µs",
            at(0.5),
            at(0.9)
        );
    }
    Ok(())
}

/// The estimates `x_bar` of the paper run's first samples, the robot following each
/// plan's first predicted state exactly.
fn paper_states(scenario: &Scenario) -> Result<Vec<[f64; 4]>, mpc::MpcError> {
    let mut mpc = Mpc::new(scenario)?;
    let [x, y, theta] = scenario.robot.start;
    let mut x_bar = [x, y, theta, scenario.robot.zeta0];
    let mut states = Vec::with_capacity(SAMPLES);
    for k in 0..SAMPLES {
        states.push(x_bar);
        let z = mpc.step(k as u64, x_bar, 0.0).z[1];
        x_bar = protocol::phi_inverse(z, x_bar[2]);
    }
    Ok(states)
}
