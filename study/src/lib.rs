//! The study tools: a sweep of a scenario's keys ([`sweep`]), safety on random worlds
//! ([`fuzz`]), the paper's figures ([`figures`], [`solve_times`]) and the benchmarks
//! ([`bench`]). Every run they make is a run of the `run` crate, recorded by `record`.

pub mod bench;
pub mod figures;
pub mod fleet_fuzz;
pub mod foxglove_client;
pub mod fuzz;
pub mod identify;
pub mod solve_times;
pub mod sweep;
