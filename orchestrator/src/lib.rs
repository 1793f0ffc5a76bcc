//! The `scmpc` command: scenario validation, the in-process run, recording and the summary.

pub mod agent;
pub mod awake;
pub mod bench;
pub mod children;
pub mod cli;
pub mod closed_loop;
pub mod figures;
pub mod fuzz;
pub mod inprocess;
pub mod judge;
pub mod multiproc;
pub mod record;
pub mod remote;
pub mod roles;
pub mod scenarios;
pub mod schema;
pub mod solve_times;
pub mod stop;
pub mod swap_client;
pub mod sweep;
