//! The `scmpc` command line ([`cli`]): it parses every command and calls the crate that
//! does it: `run` (a run in process or as supervised processes), `record` (what a run
//! leaves and its judge), `study` (sweeps, fuzzing, figures, benchmarks).

pub mod cli;
