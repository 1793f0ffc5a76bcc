//! The role processes the orchestrator started: spawning them with the run's environment,
//! retiring, killing and reaping them.

use super::{
    ENV_CONTROL_PUBLISHER, ENV_EPOCH, ENV_MODE, ENV_PREFIX, ENV_ROLE, ENV_SCENARIO, ENV_SUPERVISOR,
};
use anyhow::Context;
use protocol::Role;
use protocol::clock::RunMode;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// One process the orchestrator started.
pub(super) struct Proc {
    pub(super) role: Role,
    pub(super) epoch: u32,
    pub(super) child: Child,
    /// Set when the process is being stopped on purpose (replaced): its exit is not a
    /// crash, and it is killed if still alive at this instant.
    pub(super) retire_by: Option<Instant>,
}

/// The run's processes; killed and reaped on drop whatever happened.
pub(super) struct Children {
    pub(super) exe: std::path::PathBuf,
    pub(super) scenario_file: std::path::PathBuf,
    pub(super) prefix: String,
    pub(super) mode: &'static str,
    /// The orchestrator's control publisher, which the processes take control from.
    pub(super) control_publisher: u128,
    pub(super) list: Vec<Proc>,
    /// The epoch the process started last has (each start takes the next).
    epoch: u32,
}

impl Children {
    /// Starts a process for each of `roles`.
    pub(super) fn spawn(
        scenario_file: &Path,
        roles: impl Iterator<Item = Role>,
        prefix: &str,
        mode: RunMode,
        control_publisher: u128,
    ) -> anyhow::Result<Children> {
        let mut children = Children {
            exe: std::env::current_exe().context("locating the scmpc executable")?,
            scenario_file: scenario_file.to_path_buf(),
            prefix: prefix.to_string(),
            mode: mode.as_str(),
            control_publisher,
            list: Vec::new(),
            epoch: 0,
        };
        for role in roles {
            children.spawn_role(role, 0, &[])?;
        }
        Ok(children)
    }

    /// The producer epoch of the next process to start (a restart or a replacement).
    pub(super) fn take_epoch(&mut self) -> u32 {
        self.epoch += 1;
        self.epoch
    }

    /// Starts a process for `role` with producer epoch `epoch`: `command` (program and
    /// arguments; a program named `scmpc` is this executable), or the built-in role
    /// process when it is empty. Returns its pid.
    pub(super) fn spawn_role(
        &mut self,
        role: Role,
        epoch: u32,
        command: &[String],
    ) -> anyhow::Result<u32> {
        let builtin = [role.as_str().to_string()];
        let (program, args) = match command.split_first() {
            None => (self.exe.as_os_str(), &builtin[..]),
            Some((p, args)) if p == "scmpc" => (self.exe.as_os_str(), args),
            Some((p, args)) => (std::ffi::OsStr::new(p), args),
        };
        let child = Command::new(program)
            .args(args)
            .env(ENV_SCENARIO, &self.scenario_file)
            .env(ENV_PREFIX, &self.prefix)
            .env(ENV_MODE, self.mode)
            .env(ENV_EPOCH, epoch.to_string())
            .env(ENV_ROLE, role.as_str())
            .env(ENV_SUPERVISOR, std::process::id().to_string())
            .env(
                ENV_CONTROL_PUBLISHER,
                format!("{:x}", self.control_publisher),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| {
                format!(
                    "starting the {} process `{}`",
                    role.as_str(),
                    program.to_string_lossy()
                )
            })?;
        let pid = child.id();
        self.list.push(Proc {
            role,
            epoch,
            child,
            retire_by: None,
        });
        Ok(pid)
    }

    pub(super) fn pid(&self, role: Role, epoch: u32) -> Option<u32> {
        self.list
            .iter()
            .find(|p| p.role == role && p.epoch == epoch)
            .map(|p| p.child.id())
    }

    /// Asks the process of `role` and `epoch` to exit (SIGTERM; a role process leaves its
    /// loop and closes its ports), and kills it after `grace`.
    pub(super) fn retire(&mut self, role: Role, epoch: u32, grace: Duration) {
        if let Some(p) = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)
        {
            p.retire_by = Some(Instant::now() + grace);
            if let Ok(pid) = libc::pid_t::try_from(p.child.id()) {
                // SAFETY: kill(2) on the pid of a child not reaped yet (so not reused).
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
        }
    }

    /// Kills the process of `role` and `epoch` if it is still running; returns its pid
    /// then.
    pub(super) fn kill_running(&mut self, role: Role, epoch: u32) -> Option<u32> {
        let p = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)?;
        if p.child.try_wait().ok().flatten().is_some() {
            return None;
        }
        p.child.kill().ok().map(|()| p.child.id())
    }

    /// Whether a process of `role` is being stopped.
    pub(super) fn retiring(&self, role: Role) -> bool {
        self.list
            .iter()
            .any(|p| p.role == role && p.retire_by.is_some())
    }

    /// Kills retiring processes that outlived their grace period.
    pub(super) fn kill_overdue(&mut self) {
        let now = Instant::now();
        for p in &mut self.list {
            if p.retire_by.is_some_and(|by| now > by) {
                let _ = p.child.kill();
            }
        }
    }

    /// A child that has exited (reaped and forgotten), with its status.
    pub(super) fn take_exited(&mut self) -> Option<(Proc, std::process::ExitStatus)> {
        let index = self
            .list
            .iter_mut()
            .position(|p| p.child.try_wait().ok().flatten().is_some())?;
        let mut proc = self.list.remove(index);
        let status = proc.child.try_wait().ok().flatten()?;
        Some((proc, status))
    }

    /// Waits up to `timeout` for every child to exit, then kills the rest; reaps all.
    /// Returns each role's exit status and whether it had to be killed.
    pub(super) fn shut_down(&mut self, timeout: Duration) -> Vec<(Role, u32, String, bool)> {
        let deadline = Instant::now() + timeout;
        let mut ended = Vec::new();
        for p in &mut self.list {
            let child = &mut p.child;
            while child.try_wait().ok().flatten().is_none() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(5));
            }
            let killed = child.try_wait().ok().flatten().is_none();
            if killed {
                let _ = child.kill();
            }
            let status = child
                .wait()
                .map_or_else(|e| e.to_string(), |s| s.to_string());
            ended.push((p.role, p.epoch, status, killed));
        }
        self.list.clear();
        ended
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        let _ = self.shut_down(Duration::ZERO);
    }
}
