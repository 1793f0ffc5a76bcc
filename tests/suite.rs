//! The cross-process tests, one module a subject, built as one test binary: the modules
//! share `common` and the iceoryx2 and Zenoh code it instantiates, and the machine
//! (`common::machine_alone`): a real-time test runs with no other test beside it, any
//! other beside one other test at most (the harness's threads, one a core).
//!
//! `cargo test --release --test suite hosts::` runs one module's tests. The counting
//! allocator of `no_allocation.rs` is a binary of its own.

mod common;

mod actuator;
mod arrival;
mod bad_input;
mod bench;
mod deadlines;
mod figures;
mod fleet;
mod fuzz;
mod hosts;
mod instructions;
mod live;
mod map;
mod moving;
mod multiprocess;
mod paper_scenario;
mod planner;
mod python;
mod reach;
mod realtime;
mod ros2_robot;
mod ros2_wire;
mod safety;
mod study;
mod supervision;
mod swap;
mod validation;
