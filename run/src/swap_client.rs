//! `scmpc swap`: asks a running `scmpc run` to replace one role process by another
//! command, make-before-break, and waits for the outcome.

use crate::multiproc::RunInfo;
use anyhow::{Context, bail};
use protocol::{Role, SwapReply, SwapRequest};
use runtime::ipc::{self, open_run_topic};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How long `scmpc swap` waits for the orchestrator's answer.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(30);

/// Why a swap request could not even be sent: bad input (exit code 2).
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    #[error("no role `{0}` to swap: expected estimator, mpc, dfl or planner")]
    Role(String),
    #[error("the plant is the simulated robot: it cannot be swapped")]
    Plant,
    #[error("{0}: no run is going there ({1})")]
    NotRunning(String, String),
    #[error(
        "the command line is longer than {} bytes or holds a NUL byte",
        protocol::MAX_COMMAND_BYTES
    )]
    Command,
}

/// The role named `name`, if it can be swapped.
pub fn swappable_role(name: &str) -> Result<Role, RequestError> {
    match Role::from_name(name) {
        Some(Role::Plant) => Err(RequestError::Plant),
        Some(role) => Ok(role),
        None => Err(RequestError::Role(name.to_string())),
    }
}

/// The request for `role`; a relative program path is made absolute, since the
/// orchestrator starts it from its own working directory (the other arguments are passed
/// as they are). Symbolic links are kept: a venv's `bin/python` is a link to the
/// interpreter, and only called by its own path does it use the venv.
pub fn build_request(role: Role, command: &[String]) -> Result<SwapRequest, RequestError> {
    let mut command = command.to_vec();
    if let Some(program) = command.first_mut()
        && program.contains('/')
        && let Ok(absolute) = std::path::absolute(&*program)
    {
        *program = absolute.to_string_lossy().into_owned();
    }
    let id = (u64::from(std::process::id()) << 32) | (runtime::clock::monotonic_ns() & 0xffff_ffff);
    SwapRequest::new(id, role, &command).ok_or(RequestError::Command)
}

/// Sends `request` to the run in `run_dir` and waits for its answer, or until `stop` is set.
pub fn send(run_dir: &Path, request: &SwapRequest, stop: &AtomicBool) -> anyhow::Result<SwapReply> {
    let shown = run_dir.display().to_string();
    let info = RunInfo::read(run_dir)
        .map_err(|e| RequestError::NotRunning(shown.clone(), format!("{e:#}")))?;
    if run_dir.join("summary.json").exists() {
        return Err(RequestError::NotRunning(shown, "it has ended".into()).into());
    }
    if !ipc::process_alive(info.orchestrator_pid) {
        let why = format!("its orchestrator, pid {}, is gone", info.orchestrator_pid);
        return Err(RequestError::NotRunning(shown, why).into());
    }
    let node = ipc::create_node(
        &info.iceoryx2_prefix,
        &format!("swap-{}", std::process::id()),
        false,
    )?;
    // Subscribe to the answers (the orchestrator's alone) before asking.
    let replies = open_run_topic::<SwapReply>(&node, ipc::SWAP_REPLY)?.receiver()?;
    let orchestrator = u128::from_str_radix(&info.swap_reply_publisher, 16)
        .with_context(|| format!("{shown}: swap_reply_publisher is not a hexadecimal id"))?;
    replies.pin_to(orchestrator);
    let requests = open_run_topic::<SwapRequest>(&node, ipc::SWAP)?.sender(0)?;
    let waitset = ipc::waitset(false)?;
    let _guard = replies.attach(&waitset)?;
    requests.send(*request)?;
    let deadline = Instant::now() + REPLY_TIMEOUT;
    loop {
        let mut answer = None;
        replies.drain(|r, _| {
            if r.request_id == request.request_id && r.requester == requests.publisher_id() {
                answer = Some(r);
            }
        })?;
        if let Some(reply) = answer {
            return Ok(reply);
        }
        if !ipc::process_alive(info.orchestrator_pid) {
            bail!("the run ended before it answered");
        }
        if Instant::now() > deadline {
            bail!("no answer within {REPLY_TIMEOUT:?}");
        }
        ipc::wait(&waitset, Duration::from_millis(100)).context("waiting for the answer")?;
        if stop.load(Ordering::Relaxed) {
            bail!(
                "interrupted by {} before the run answered",
                crate::stop::received().unwrap_or("its caller")
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_relative_program_is_made_absolute_without_resolving_links() {
        let request = build_request(
            Role::Estimator,
            &["venv/bin/python".into(), "estimator.py".into()],
        )
        .unwrap();
        let cwd = std::env::current_dir().unwrap();
        assert_eq!(
            request.command(),
            [
                cwd.join("venv/bin/python").to_string_lossy().into_owned(),
                "estimator.py".into()
            ]
        );
    }
}
