//! The `scmpc` executable; everything lives in the `orchestrator` crate.

/// Counts allocations, so a role process can show its steady state makes none
/// (`protocol::alloc_count`).
#[global_allocator]
static GLOBAL: protocol::alloc_count::Counting = protocol::alloc_count::Counting;

fn main() -> std::process::ExitCode {
    orchestrator::cli::main()
}
