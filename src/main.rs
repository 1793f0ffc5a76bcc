//! The `scmpc` executable; everything lives in the `orchestrator` crate.

/// Counts allocations, so a role process can show its steady state makes none
/// (`runtime::alloc_count`).
#[global_allocator]
static GLOBAL: runtime::alloc_count::Counting = runtime::alloc_count::Counting;

fn main() -> std::process::ExitCode {
    orchestrator::cli::main()
}
