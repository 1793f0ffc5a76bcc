//! A run of a scenario: in process ([`inprocess`], stepping [`closed_loop::ClosedLoop`]) or
//! as supervised role processes ([`multiproc`]: launch, the clock, supervision, swaps),
//! on this host or others ([`remote`], [`agent`]); which roles there are ([`roles`]); the
//! built-in scenarios and the one way to a validated scenario ([`scenarios`]); what a run
//! records, through which sinks ([`sinks`]); what stops a command ([`stop`]).

pub mod agent;
pub mod awake;
pub mod children;
pub mod closed_loop;
pub mod fleet;
pub mod inprocess;
pub mod multiproc;
pub mod pace;
pub mod remote;
pub mod roles;
pub mod scenarios;
pub mod scheduling;
pub mod sinks;
pub mod status_line;
pub mod stop;
pub mod swap_client;
pub mod watch;
