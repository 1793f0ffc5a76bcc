//! What stops a command from outside: Ctrl-C (SIGINT), `kill`, `timeout`, systemd or a
//! container runtime (SIGTERM), and a closed terminal or SSH session (SIGHUP) all end it
//! the same way. The command sees a stop flag, stops its processes in order, closes its
//! records and writes a summary with outcome `interrupted` naming the signal
//! ([`received`]).
//!
//! The processes a command starts run in process groups of their own
//! ([`crate::children`]), so the terminal's signals reach the command alone and the
//! command stops them; a signal sent to one of them directly (SIGINT, SIGTERM) still ends
//! that process cleanly.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// The signals that stop a command.
pub const STOP_SIGNALS: [i32; 3] = [
    signal_hook::consts::SIGINT,
    signal_hook::consts::SIGTERM,
    signal_hook::consts::SIGHUP,
];

/// The number of the last stop signal received (0: none).
fn last_signal() -> &'static Arc<AtomicUsize> {
    static LAST: OnceLock<Arc<AtomicUsize>> = OnceLock::new();
    LAST.get_or_init(|| Arc::new(AtomicUsize::new(0)))
}

/// A flag that every [`STOP_SIGNALS`] sets. A second signal does not kill the command:
/// it is already stopping, and stopping is what removes its shared memory.
pub fn on_signals() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    for signal in STOP_SIGNALS {
        // The signal's number is stored before the flag is set (handlers of a signal run
        // in the order they were registered), so a command that sees the flag can name it.
        let registered =
            signal_hook::flag::register_usize(signal, Arc::clone(last_signal()), signal as usize)
                .and_then(|_| signal_hook::flag::register(signal, Arc::clone(&stop)));
        if let Err(e) = registered {
            tracing::warn!("cannot handle {}: {e}", signal_name(signal));
        }
    }
    stop
}

/// The stop signal this process received last, by name (`SIGTERM`), if any.
pub fn received() -> Option<&'static str> {
    match last_signal().load(Ordering::Relaxed) {
        0 => None,
        n => Some(signal_name(n as i32)),
    }
}

fn signal_name(signal: i32) -> &'static str {
    signal_hook::low_level::signal_name(signal).unwrap_or("a signal")
}

/// A command stopped before it was done.
#[derive(Debug, thiserror::Error)]
#[error("interrupted by {0}")]
pub struct Interrupted(pub &'static str);

/// `Err` once `stop` is set: a batch that must not go on, or report itself done, after it.
pub fn check(stop: &AtomicBool) -> Result<(), Interrupted> {
    if stop.load(Ordering::Relaxed) {
        Err(Interrupted(received().unwrap_or("its caller")))
    } else {
        Ok(())
    }
}
