//! Runs any role's [`Task`](protocol::task::Task): the one loop every role process runs
//! ([`process`]), the run's clocks in lockstep and real time ([`clock`]), the warm-up before
//! a periodic input, and iceoryx2 shared memory ([`ipc`]). The role crates know none of
//! this: a role is a task, and a process of it is [`process::serve`] of that task.

pub mod alloc_count;
pub mod clock;
pub mod ipc;
pub mod layout;
pub mod process;
pub mod realtime;
pub mod serve;
pub mod wait;
pub mod wakes;
pub mod warm_up;

pub use serve::serve;
