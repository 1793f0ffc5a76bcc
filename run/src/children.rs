//! The role processes of a run: started with the run's environment, here or on the host
//! the scenario places their role on ([`RemoteHosts`]), retired, killed and reaped. The
//! orchestrator and a host's agent (for the roles placed on its host) both keep theirs
//! here.

use crate::remote::RemoteHosts;
use anyhow::Context;
use protocol::Role;
use runtime::clock::RunMode;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Environment of every role process (docs/design.md, "Supervision"): a replacement
/// command needs nothing else to join the run.
pub const ENV_SCENARIO: &str = "SCMPC_SCENARIO";
pub const ENV_PREFIX: &str = "SCMPC_PREFIX";
/// `lockstep` or `realtime`.
pub const ENV_MODE: &str = "SCMPC_MODE";
/// The producer epoch the process must stamp on every sample.
pub const ENV_EPOCH: &str = "SCMPC_EPOCH";
/// The name of the role to play (`protocol::Role::as_str`).
pub const ENV_ROLE: &str = "SCMPC_ROLE";
/// The robot whose pipeline the process is part of (decimal; [`protocol::FIRST_ROBOT`]
/// when unset).
pub const ENV_ROBOT: &str = "SCMPC_ROBOT";
/// The pid of the process supervising it (the orchestrator, or the agent of its host): a
/// role process stops the robot and exits when it is gone.
pub const ENV_SUPERVISOR: &str = "SCMPC_SUPERVISOR_PID";
/// The iceoryx2 id of the publisher of control messages on its host (hexadecimal): a role
/// process takes control messages from it alone.
pub const ENV_CONTROL_PUBLISHER: &str = "SCMPC_CONTROL_PUBLISHER";

/// The directory of the role processes' logs in a run directory: each role's stderr,
/// every epoch's (restarts, replacements) appended to `<role>.log`.
pub const LOG_DIR: &str = "logs";

/// How a process is reached.
pub enum Handle {
    /// Started here.
    Local(Child),
    /// Started by the agent of `host`; `exit` once it reported the process's end.
    Remote {
        host: String,
        pid: u32,
        exit: Option<String>,
    },
}

/// One process started for the run.
pub struct Proc {
    pub role: Role,
    pub epoch: u32,
    pub handle: Handle,
    /// Set when the process is being stopped on purpose (replaced): its exit is not a
    /// crash, and it is killed if still alive at this instant.
    pub retire_by: Option<Instant>,
}

impl Proc {
    /// Its pid (on its host).
    pub fn pid(&self) -> u32 {
        match &self.handle {
            Handle::Local(child) => child.id(),
            Handle::Remote { pid, .. } => *pid,
        }
    }

    /// The host it runs on (`None`: this one).
    pub fn host(&self) -> Option<&str> {
        match &self.handle {
            Handle::Local(_) => None,
            Handle::Remote { host, .. } => Some(host),
        }
    }
}

/// The run's processes; killed and reaped on drop whatever happened.
pub struct Children {
    exe: std::path::PathBuf,
    scenario_file: std::path::PathBuf,
    pub prefix: String,
    mode: &'static str,
    /// The robot whose pipeline these processes are.
    robot: u32,
    /// The publisher of control messages on this host, which the processes take control
    /// from.
    control_publisher: u128,
    /// More environment for every process (an agent's: the run id, the clock correction).
    extra_env: Vec<(String, String)>,
    /// Where each role's stderr goes ([`Children::with_logs`]); `None`: this process's
    /// stderr (an agent's, whose run directory goes when the run ends).
    log_dir: Option<std::path::PathBuf>,
    pub list: Vec<Proc>,
    /// The epoch the process started last has (each start takes the next).
    epoch: u32,
    /// The other hosts of the run, when roles are placed on them.
    pub remote: Option<RemoteHosts>,
}

impl Children {
    /// No process yet.
    pub fn new(
        scenario_file: &Path,
        prefix: &str,
        robot: u32,
        mode: RunMode,
        control_publisher: u128,
        extra_env: Vec<(String, String)>,
        remote: Option<RemoteHosts>,
    ) -> anyhow::Result<Children> {
        Ok(Children {
            exe: std::env::current_exe().context("locating the scmpc executable")?,
            scenario_file: scenario_file.to_path_buf(),
            prefix: prefix.to_string(),
            mode: mode.as_str(),
            robot,
            control_publisher,
            extra_env,
            log_dir: None,
            list: Vec::new(),
            epoch: 0,
            remote,
        })
    }

    /// The robot whose pipeline these processes are.
    pub fn robot(&self) -> u32 {
        self.robot
    }

    /// Each role's stderr to `<dir>/<role>.log`, every epoch's appended after a line that
    /// names it (the orchestrator's: `logs/` of the run directory).
    pub fn with_logs(mut self, dir: &Path) -> Children {
        self.log_dir = Some(dir.to_path_buf());
        self
    }

    /// Starts a process (epoch 0) for each of `roles`.
    pub fn spawn_all(&mut self, roles: impl Iterator<Item = Role>) -> anyhow::Result<()> {
        for role in roles {
            self.spawn_role(role, 0, &[])?;
        }
        Ok(())
    }

    /// The producer epoch of the next process to start (a restart or a replacement).
    pub fn take_epoch(&mut self) -> u32 {
        self.epoch += 1;
        self.epoch
    }

    /// The host `role` runs on now (`None`: this one, also once its host was lost).
    pub fn host_of(&self, role: Role) -> Option<&str> {
        self.remote.as_ref().and_then(|r| r.host_of(role))
    }

    /// Starts a process for `role` with producer epoch `epoch`, on the host the role is
    /// placed on: `command` (program and arguments; a program named `scmpc` is this
    /// executable), or the built-in role process when it is empty. Returns its pid.
    pub fn spawn_role(
        &mut self,
        role: Role,
        epoch: u32,
        command: &[String],
    ) -> anyhow::Result<u32> {
        if let Some(host) = self.host_of(role).map(str::to_string)
            && let Some(remote) = &self.remote
        {
            let pid = remote.spawn(&host, role, epoch, command)?;
            self.list.push(Proc {
                role,
                epoch,
                handle: Handle::Remote {
                    host,
                    pid,
                    exit: None,
                },
                retire_by: None,
            });
            return Ok(pid);
        }
        let builtin = [role.as_str().to_string()];
        let (program, args) = match command.split_first() {
            None => (self.exe.as_os_str(), &builtin[..]),
            Some((p, args)) if p == "scmpc" => (self.exe.as_os_str(), args),
            Some((p, args)) => (std::ffi::OsStr::new(p), args),
        };
        // A group of its own: the terminal's signals (Ctrl-C, a closed terminal) reach the
        // orchestrator alone, which stops the run in order (crate::stop).
        let child = Command::new(program)
            .process_group(0)
            .args(args)
            .env(ENV_SCENARIO, &self.scenario_file)
            .env(ENV_PREFIX, &self.prefix)
            .env(ENV_MODE, self.mode)
            .env(ENV_EPOCH, epoch.to_string())
            .env(ENV_ROLE, role.as_str())
            .env(ENV_ROBOT, self.robot.to_string())
            .env(ENV_SUPERVISOR, std::process::id().to_string())
            .env(
                ENV_CONTROL_PUBLISHER,
                format!("{:x}", self.control_publisher),
            )
            .envs(self.extra_env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(self.stderr_of(role, epoch, program, args)?)
            .spawn()
            .with_context(|| {
                format!(
                    "starting the {} process `{}`",
                    role.as_str(),
                    program.to_string_lossy()
                )
            })?;
        let pid = child.id();
        let log = self.log_path(role);
        tracing::info!(
            "started the {} process, epoch {epoch}, pid {pid} (its stderr: {})",
            role.as_str(),
            log.as_ref()
                .map_or("this one's".into(), |p| p.display().to_string())
        );
        self.list.push(Proc {
            role,
            epoch,
            handle: Handle::Local(child),
            retire_by: None,
        });
        Ok(pid)
    }

    /// Where the stderr of the process of `role` and `epoch` goes: its log, opened to
    /// append after a line that says which process it is, or this process's stderr.
    fn stderr_of(
        &self,
        role: Role,
        epoch: u32,
        program: &std::ffi::OsStr,
        args: &[String],
    ) -> anyhow::Result<Stdio> {
        use std::io::Write;
        let Some(path) = self.log_path(role) else {
            return Ok(Stdio::inherit());
        };
        let opened = (path.parent().map_or(Ok(()), std::fs::create_dir_all)).and_then(|()| {
            let mut file = std::fs::File::options()
                .create(true)
                .append(true)
                .open(&path)?;
            let command = std::iter::once(program.to_string_lossy().into_owned())
                .chain(args.iter().cloned())
                .collect::<Vec<_>>()
                .join(" ");
            writeln!(
                file,
                "{EPOCH_HEADER}{} epoch {epoch}: {command}",
                role.as_str()
            )?;
            Ok(Stdio::from(file))
        });
        opened.with_context(|| format!("opening the log {}", path.display()))
    }

    /// The log of `role`, with logs.
    pub fn log_path(&self, role: Role) -> Option<std::path::PathBuf> {
        let dir = self.log_dir.as_ref()?;
        Some(dir.join(format!("{}.log", role.as_str())))
    }

    /// What the warning of the death of `process` adds: its last words ([`last_words`])
    /// and where its stderr is, this host's log or, for a process on another host, its
    /// agent's stderr there.
    pub fn death_notes(&self, process: &Proc) -> String {
        let (role, epoch) = (process.role, process.epoch);
        if let Some(host) = process.host() {
            return format!("; its stderr is in the stderr of host {host}'s agent");
        }
        let Some(log) = self.log_path(role) else {
            return String::new();
        };
        let words = (read_tail(&log, LAST_WORDS_READ_BYTES).ok())
            .and_then(|tail| last_words(&String::from_utf8_lossy(&tail), role, epoch))
            .map_or(String::new(), |w| format!("; its last words: {w}"));
        format!("{words}; its stderr is in {}", log.display())
    }

    /// The publishers the outputs of the process of `role` and `epoch` are pinned to on
    /// this host: those it `announced`, or, on another host, the relays carrying them.
    pub fn pins(&self, role: Role, epoch: u32, announced: [u128; 2]) -> [u128; 2] {
        let remote_host = self
            .list
            .iter()
            .find(|p| p.role == role && p.epoch == epoch)
            .and_then(Proc::host);
        match (remote_host, &self.remote) {
            (Some(_), Some(remote)) => remote.pins(role),
            _ => announced,
        }
    }

    pub fn pid(&self, role: Role, epoch: u32) -> Option<u32> {
        self.list
            .iter()
            .find(|p| p.role == role && p.epoch == epoch)
            .map(Proc::pid)
    }

    /// Asks the process of `role` and `epoch` to exit (SIGTERM; a role process leaves its
    /// loop and closes its ports), and kills it after `grace`.
    pub fn retire(&mut self, role: Role, epoch: u32, grace: Duration) {
        let remote = self.remote.as_ref();
        let Some(p) = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)
        else {
            return;
        };
        p.retire_by = Some(Instant::now() + grace);
        match &p.handle {
            Handle::Local(child) => signal(child, libc::SIGTERM),
            Handle::Remote { host, .. } => {
                if let Some(remote) = remote {
                    remote.terminate(host, role, epoch);
                }
            }
        }
    }

    /// Kills the process of `role` and `epoch` if it is still running; returns its pid
    /// then.
    pub fn kill_running(&mut self, role: Role, epoch: u32) -> Option<u32> {
        let remote = self.remote.as_ref();
        let p = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)?;
        kill(p, remote)
    }

    /// Whether a process of `role` is being stopped.
    pub fn retiring(&self, role: Role) -> bool {
        self.list
            .iter()
            .any(|p| p.role == role && p.retire_by.is_some())
    }

    /// Kills retiring processes that outlived their grace period.
    pub fn kill_overdue(&mut self) {
        let now = Instant::now();
        let remote = self.remote.as_ref();
        for p in &mut self.list {
            if p.retire_by.is_some_and(|by| now > by) {
                let _ = kill(p, remote);
            }
        }
    }

    /// A process that has exited (reaped and forgotten), with its exit status.
    pub fn take_exited(&mut self) -> Option<(Proc, String)> {
        if let Some(remote) = &self.remote {
            while let Some(exit) = remote.take_exit() {
                let found = self.list.iter_mut().find(|p| {
                    p.host() == Some(exit.host.as_str())
                        && p.role.as_str() == exit.role
                        && p.epoch == exit.epoch
                });
                if let Some(Proc {
                    handle: Handle::Remote { exit: status, .. },
                    ..
                }) = found
                {
                    *status = Some(exit.status);
                }
            }
        }
        let index = self.list.iter_mut().position(|p| exited(p).is_some())?;
        let mut proc = self.list.remove(index);
        let status = exited(&mut proc)?;
        Some((proc, status))
    }

    /// The processes on `host` (lost), forgotten as if they had exited.
    pub fn forget_host(&mut self, host: &str) -> Vec<Proc> {
        let (gone, kept) = std::mem::take(&mut self.list)
            .into_iter()
            .partition(|p| p.host() == Some(host));
        self.list = kept;
        gone
    }

    /// Waits up to `timeout` for every process to exit, then kills the rest; reaps all.
    /// Returns each one's role, epoch, exit status and whether it had to be killed.
    pub fn shut_down(&mut self, timeout: Duration) -> Vec<(Role, u32, String, bool)> {
        let deadline = Instant::now() + timeout;
        let mut ended = Vec::new();
        while !self.list.is_empty() {
            while let Some((p, status)) = self.take_exited() {
                ended.push((p.role, p.epoch, status, false));
            }
            if self.list.is_empty() || Instant::now() >= deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let remote = self.remote.as_ref();
        for mut p in std::mem::take(&mut self.list) {
            let _ = kill(&mut p, remote);
            let status = match &mut p.handle {
                Handle::Local(child) => child
                    .wait()
                    .map_or_else(|e| e.to_string(), |s| s.to_string()),
                Handle::Remote { .. } => "killed on its host".to_string(),
            };
            ended.push((p.role, p.epoch, status, true));
        }
        ended
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        let _ = self.shut_down(Duration::ZERO);
    }
}

/// How a process's part of its role's log begins: this, then the role, the epoch and the
/// command.
const EPOCH_HEADER: &str = "=== ";

/// How much of the end of a log [`Children::death_notes`] reads, in bytes: a panic's
/// place and message with a backtrace of some 60 frames after them.
const LAST_WORDS_READ_BYTES: u64 = 64 * 1024;

/// The whole lines within the last `bytes` bytes of the file at `path` (all of it if
/// shorter): a line the cut falls in is left out, its start being elsewhere, unless it
/// is the last line (one longer than `bytes`, the last thing the process wrote): then
/// its end is kept, after [`CUT`].
fn read_tail(path: &Path, bytes: u64) -> std::io::Result<Vec<u8>> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path)?;
    let start = file.metadata()?.len().saturating_sub(bytes);
    // From the byte before the cut: a newline there means the cut falls between lines.
    file.seek(SeekFrom::Start(start.saturating_sub(1)))?;
    let mut tail = Vec::new();
    file.read_to_end(&mut tail)?;
    if start > 0 {
        match tail.iter().position(|&b| b == b'\n') {
            Some(end) if end + 1 < tail.len() => drop(tail.drain(..=end)),
            _ => drop(tail.splice(..1, CUT.bytes())),
        }
    }
    Ok(tail)
}

/// What stands for the start of a line left out of the last words ([`read_tail`],
/// [`last_words`]).
const CUT: &str = "…";

/// A line of the last words longer than this is quoted by its end, in characters.
const LAST_WORD_CHARS: usize = 240;

/// `line`, or its last [`LAST_WORD_CHARS`] characters after [`CUT`] if it is longer.
fn line_end(line: &str) -> String {
    match line.char_indices().rev().nth(LAST_WORD_CHARS - 1) {
        Some((at, _)) if at > 0 => format!("{CUT}{}", &line[at..]),
        _ => line.to_string(),
    }
}

/// The last words of the process of `role` and `epoch` in (the end of) its role's log,
/// joined by ` | `: its last panic's place and message if it panicked (the backtrace
/// after them left out), else the last two lines that say something (an error's cause);
/// Rust's hints are left out. Its words are the lines after its own header
/// (`=== plant epoch 2: ...`), every other epoch's header left out: a swap's
/// replacement writes its header while the process it replaces still runs. Lines of the
/// replacement after that are taken too (the log does not say whose a line is). With
/// its header no longer in `log`, every line is taken. `None` when it said nothing.
fn last_words(log: &str, role: Role, epoch: u32) -> Option<String> {
    let header = format!("{EPOCH_HEADER}{} epoch {epoch}:", role.as_str());
    let own = log
        .rfind(&header)
        .map_or(log, |at| &log[at + header.len()..]);
    let said = |line: &&str| {
        !line.is_empty() && !line.starts_with("note: ") && !line.starts_with(EPOCH_HEADER)
    };
    let lines: Vec<&str> = (own.lines().skip(usize::from(own.len() < log.len())))
        .map(str::trim)
        .filter(said)
        .collect();
    let words = match lines
        .iter()
        .rposition(|line| line.contains(" panicked at "))
    {
        Some(panic) => &lines[panic..(panic + 2).min(lines.len())],
        None => &lines[lines.len().saturating_sub(2)..],
    };
    let words: Vec<String> = words.iter().map(|line| line_end(line)).collect();
    (!words.is_empty()).then(|| words.join(" | "))
}

/// Sends `signal` to a child not reaped yet.
fn signal(child: &Child, signal: libc::c_int) {
    if let Ok(pid) = libc::pid_t::try_from(child.id()) {
        // SAFETY: kill(2) on the pid of a child not reaped yet (so not reused).
        unsafe { libc::kill(pid, signal) };
    }
}

/// Kills `p` if it still runs; returns its pid then.
fn kill(p: &mut Proc, remote: Option<&RemoteHosts>) -> Option<u32> {
    let pid = p.pid();
    match &mut p.handle {
        Handle::Local(child) => {
            if child.try_wait().ok().flatten().is_some() {
                return None;
            }
            child.kill().ok().map(|()| pid)
        }
        Handle::Remote { host, exit, .. } => {
            if exit.is_some() {
                return None;
            }
            remote.map(|r| r.kill(host, p.role, p.epoch)).map(|()| pid)
        }
    }
}

/// The exit status of `p`, if it has exited.
fn exited(p: &mut Proc) -> Option<String> {
    match &mut p.handle {
        Handle::Local(child) => child.try_wait().ok().flatten().map(|s| s.to_string()),
        Handle::Remote { exit, .. } => exit.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::{last_words, read_tail};
    use protocol::Role;

    #[test]
    fn a_logs_tail_holds_whole_lines_or_the_end_of_the_last() {
        let path = std::env::temp_dir().join(format!("scmpc-tail-{}.log", std::process::id()));
        std::fs::write(&path, "first line\nsecond\nthird\n").unwrap();
        let tail = |bytes| String::from_utf8(read_tail(&path, bytes).unwrap()).unwrap();
        // The cut falls in "second", then just after its newline, then before the file.
        assert_eq!(tail(9), "third\n");
        assert_eq!(tail(6), "third\n");
        assert_eq!(tail(100), "first line\nsecond\nthird\n");
        // In the last line: its end is kept, marked as cut.
        assert_eq!(tail(3), "…rd\n");
        std::fs::write(&path, "started\nno newline at the end").unwrap();
        assert_eq!(tail(6), "…he end");
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_last_line_longer_than_the_tail_read_is_quoted_by_its_end() {
        let path = std::env::temp_dir().join(format!("scmpc-long-{}.log", std::process::id()));
        let long_line = format!("error: {}the state went bad", "é".repeat(40_000));
        std::fs::write(
            &path,
            format!("=== plant epoch 0: scmpc plant\n{long_line}\n"),
        )
        .unwrap();
        let tail = read_tail(&path, super::LAST_WORDS_READ_BYTES).unwrap();
        std::fs::remove_file(&path).unwrap();
        let words = last_words(&String::from_utf8_lossy(&tail), Role::Plant, 0).unwrap();
        assert!(words.starts_with(super::CUT), "{words}");
        assert!(words.ends_with("éthe state went bad"), "{words}");
        assert_eq!(words.chars().count(), 1 + super::LAST_WORD_CHARS);
        assert!(
            !words.contains('\u{fffd}'),
            "a character cut in two: {words}"
        );
    }

    #[test]
    fn the_last_words_are_a_panics_place_and_message_else_the_last_two_lines_of_the_epoch() {
        let log = "=== plant epoch 0: scmpc plant\n\
                   2026-12-04T16:17:20Z INFO plant: driving\n\
                   thread 'main' panicked at ros2/src/link.rs:88:5:\n\
                   no odometry\n\
                   note: run with `RUST_BACKTRACE=1` environment variable to display a backtrace\n\n";
        assert_eq!(
            last_words(log, Role::Plant, 0).as_deref(),
            Some("thread 'main' panicked at ros2/src/link.rs:88:5: | no odometry")
        );
        let silent_restart = format!("{log}=== plant epoch 1: scmpc plant\n");
        assert_eq!(last_words(&silent_restart, Role::Plant, 1), None);
        let with_backtrace = "=== plant epoch 2: scmpc plant\n\
                              thread 'net-0' panicked at link.rs:7:1:\n\
                              no route\n\
                              stack backtrace:\n   \
                              0: std::panicking::begin_panic\n   \
                              1: tokio::runtime::blocking::pool::Inner::run\n";
        let words = last_words(&format!("{log}{with_backtrace}"), Role::Plant, 2);
        assert_eq!(
            words.as_deref(),
            Some("thread 'net-0' panicked at link.rs:7:1: | no route")
        );
        let error_after_noise = "=== plant epoch 3: scmpc plant\nstarted\nlinked\nerror: gone\n";
        assert_eq!(
            last_words(error_after_noise, Role::Plant, 3).as_deref(),
            Some("linked | error: gone")
        );
    }

    #[test]
    fn a_process_replaced_by_a_swap_is_known_by_its_own_header_not_the_newest() {
        // The replacement (epoch 5) starts while epoch 4 still runs, then epoch 4 dies.
        let log = "=== mpc epoch 4: scmpc mpc\n\
                   solving\n\
                   === mpc epoch 5: scmpc mpc --swap\n\
                   error: the solver gave up\n";
        assert_eq!(
            last_words(log, Role::Mpc, 4).as_deref(),
            Some("solving | error: the solver gave up")
        );
        // Its header gone from the tail read: every line but the headers.
        let cut = &log["=== mpc epoch 4: scmpc mpc\n".len()..];
        assert_eq!(
            last_words(cut, Role::Mpc, 4).as_deref(),
            Some("solving | error: the solver gave up")
        );
        assert_eq!(
            last_words(log, Role::Mpc, 5).as_deref(),
            Some("error: the solver gave up")
        );
    }
}
