//! What every role's task may ask of the executor that runs it (docs/design.md,
//! "Roles and tasks").
//!
//! Each role crate exports one task: a value holding the role's whole behaviour (what it
//! takes from its inputs, when it has what a step needs, the step, its faults, the headers
//! of its outputs). Three executors run the same task values: the in-process loop of the
//! orchestrator, the role runtime of a process ([`crate::runtime`], lockstep and real
//! time) and, through the same runtime, a process on another host. A task never reads a
//! clock nor knows which one runs: it asks the [`Context`] it is stepped with.

use crate::clock::RunClock;
use crate::messages::Message;

/// What a task is told when it is stepped.
pub trait Context {
    /// The run's clock.
    fn clock(&self) -> &RunClock;

    /// Whether this task's outputs for `tick` are the ones its consumers take (not while
    /// it warms up as a replacement).
    fn is_active(&self, _tick: u64) -> bool {
        true
    }

    /// Whether the executor's supervisor is gone: the robot is to be brought to rest.
    fn orphaned(&self) -> bool {
        false
    }

    /// How late the newest clock event (a lockstep grant) reached the task, ns.
    fn clock_latency_ns(&self) -> u64 {
        0
    }
}

/// In process every task is active, never orphaned, and hears the clock at once.
impl Context for RunClock {
    fn clock(&self) -> &RunClock {
        self
    }
}

/// Keeps in `newest` the sample with the highest tick offered so far (a replay or a late
/// sample of an older tick does not replace a newer one).
pub fn keep_newest<T: Message>(newest: &mut Option<T>, sample: T) {
    if newest.is_none_or(|n| sample.header().tick >= n.header().tick) {
        *newest = Some(sample);
    }
}

/// A latency in the `u32` of a header, ns (saturating).
pub fn header_latency(latency_ns: u64) -> u32 {
    latency_ns.min(u64::from(u32::MAX)) as u32
}
