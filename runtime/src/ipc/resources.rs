//! A run's iceoryx2 resources beyond its ports: the nodes of dead processes, the files a
//! run leaves, and the registry of running runs that lets the next run clean up after a
//! killed one.

use super::*;

/// Removes what dead nodes of the run left behind (their shared memory, their ports in
/// every service): iceoryx2's dead-node detection, which sees a process die whoever
/// started it. Returns the names of the nodes cleaned.
pub fn cleanup_dead_nodes(prefix: &str) -> Result<Vec<String>, IpcError> {
    cleanup_dead_nodes_of(prefix, |_| true)
}

/// [`cleanup_dead_nodes`] of the dead nodes whose name `ours` takes (a fleet's robot's
/// supervisor takes its robot's, [`role_of_node`], so that each sees its own deaths).
pub fn cleanup_dead_nodes_of(
    prefix: &str,
    ours: impl Fn(&str) -> bool,
) -> Result<Vec<String>, IpcError> {
    Ok(scan_nodes_of(prefix, ours)?.cleaned)
}

/// What one listing of a run's nodes found and did ([`scan_nodes_of`]).
#[derive(Debug, Default)]
pub struct NodeScan {
    /// The names of the dead nodes cleaned ([`cleanup_dead_nodes_of`]).
    pub cleaned: Vec<String>,
    /// The process ids of the living nodes whose name `ours` takes ([`node_pids`]).
    pub alive_pids: Vec<u32>,
}

/// [`cleanup_dead_nodes_of`] and the processes of the living nodes `ours` takes
/// ([`node_pids`]) in one listing of the run's nodes (a listing reads every node's
/// details: a supervisor that listed twice a second for each robot of `swap8` spent 15 %
/// of the orchestrator's time in it).
pub fn scan_nodes_of(prefix: &str, ours: impl Fn(&str) -> bool) -> Result<NodeScan, IpcError> {
    let config = run_config(prefix)?;
    let mut scan = NodeScan::default();
    let mut dead = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        // Inaccessible or inconsistent: nothing this process can watch or clean.
        match state {
            NodeState::Alive(view) => {
                if let Some(details) = view.details()
                    && ours(details.name().as_str())
                    && let Ok(pid) = u32::try_from(details.process_id().value())
                {
                    scan.alive_pids.push(pid);
                }
            }
            NodeState::Dead(view) => dead.push(view),
            _ => {}
        }
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    for view in dead {
        let name = view
            .details()
            .as_ref()
            .map_or_else(String::new, |d| d.name().as_str().to_string());
        if ours(&name) && view.try_remove_stale_resources().is_ok() {
            scan.cleaned.push(name);
        }
    }
    Ok(scan)
}

/// The process ids of the run's living nodes (iceoryx2's node listing, about 1 ms).
pub fn node_pids(prefix: &str) -> Result<Vec<u32>, IpcError> {
    let config = run_config(prefix)?;
    let mut pids = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        if let NodeState::Alive(view) = state
            && let Some(details) = view.details()
            && let Ok(pid) = u32::try_from(details.process_id().value())
        {
            pids.push(pid);
        }
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    Ok(pids)
}

/// The name of the node of robot `robot`'s process of `role` and `epoch`: `<role>-<epoch>`
/// for the first robot, `robot<id>-<role>-<epoch>` for the others of a fleet.
pub fn node_name(robot: u32, role: protocol::Role, epoch: u32) -> String {
    match robot {
        protocol::FIRST_ROBOT => format!("{}-{epoch}", role.as_str()),
        _ => format!("robot{robot}-{}-{epoch}", role.as_str()),
    }
}

/// The robot, role and epoch of a role process's node, from its name ([`node_name`]).
pub fn role_of_node(name: &str) -> Option<(u32, protocol::Role, u32)> {
    let (rest, epoch) = name.rsplit_once('-')?;
    let (robot, role) = match rest.split_once('-') {
        Some((robot, role)) => (robot.strip_prefix("robot")?.parse().ok()?, role),
        None => (protocol::FIRST_ROBOT, rest),
    };
    Some((robot, protocol::Role::from_name(role)?, epoch.parse().ok()?))
}

/// How long a finished run waits for the nodes of tools watching it (`scmpc echo`) to
/// leave before its resources are removed: they look every 100 ms.
const WATCHERS_GRACE: std::time::Duration = std::time::Duration::from_secs(1);

/// Removes a finished run: its resources ([`remove_run_resources`]) and then its entry in
/// the registry of running runs.
pub fn remove_run(prefix: &str) -> Result<(), IpcError> {
    remove_run_resources(prefix)?;
    unregister_run(prefix);
    Ok(())
}

/// Ends the run its orchestrator ran: its entry in the registry of running runs first (a
/// tool watching the run sees it end and leaves, [`is_registered`]), then, once every
/// node has left (at most [`WATCHERS_GRACE`]), its resources ([`remove_run_resources`]).
/// If they cannot be removed the entry is put back, for the next run to clean up.
pub fn end_run(prefix: &str) -> Result<(), IpcError> {
    let entry = std::fs::read(run_registry().join(prefix)).ok();
    unregister_run(prefix);
    let deadline = std::time::Instant::now() + WATCHERS_GRACE;
    while node_pids(prefix).is_ok_and(|pids| !pids.is_empty())
        && std::time::Instant::now() < deadline
    {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let removed = remove_run_resources(prefix);
    if removed.is_err()
        && let Some(entry) = entry
    {
        let _ = std::fs::write(run_registry().join(prefix), entry);
    }
    removed
}

/// Whether run `prefix` is registered: going on, or ended without its resources removed.
pub fn is_registered(prefix: &str) -> bool {
    run_registry().join(prefix).exists()
}

/// Removes every resource of a finished run: dead nodes' leftovers and, once no node of
/// the run is alive, the run's global node-counter segment (iceoryx2 keeps it by design;
/// the prefix is unique to the run, so nobody else can use it).
pub fn remove_run_resources(prefix: &str) -> Result<(), IpcError> {
    cleanup_dead_nodes(prefix)?;
    let config = run_config(prefix)?;
    let mut alive = 0;
    Node::<ipc::Service>::list(&config, |_| {
        alive += 1;
        CallbackProgression::Continue
    })
    .map_err(ctx("listing nodes"))?;
    if alive > 0 {
        return Err(IpcError(format!(
            "{alive} node(s) of the run are still alive"
        )));
    }
    for path in leftover_files(prefix) {
        if path.starts_with("/dev/shm") && path.to_string_lossy().ends_with(".global_mgmt") {
            std::fs::remove_file(&path).map_err(ctx(format!("removing {}", path.display())))?;
        }
    }
    Ok(())
}

/// Where every running run's prefix is registered with its orchestrator's pid: a file
/// named after the prefix, holding the pid. A prefix given with `--prefix` does not name
/// the pid, so this is how the next run finds it when its orchestrator was killed.
fn run_registry() -> std::path::PathBuf {
    std::env::temp_dir().join("scmpc-runs")
}

/// Registers run `prefix`, recorded into `dir`, as this process's, until
/// [`unregister_run`]: the file holds the pid, then the directory.
pub fn register_run(prefix: &str, dir: &std::path::Path) -> std::io::Result<()> {
    std::fs::create_dir_all(run_registry())?;
    let dir = std::path::absolute(dir)?;
    let entry = format!("{}\n{}\n", std::process::id(), dir.display());
    std::fs::write(run_registry().join(prefix), entry)
}

/// A run registered on this machine ([`register_run`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegisteredRun {
    pub prefix: String,
    /// Its orchestrator's (or a host's agent's) pid.
    pub pid: u32,
    /// Its run directory (an agent's: where it keeps the run's scenario and logs).
    pub dir: std::path::PathBuf,
}

/// Every registered run, alive or not, by prefix.
fn registered_runs() -> Vec<RegisteredRun> {
    let mut runs: Vec<RegisteredRun> = std::fs::read_dir(run_registry())
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|entry| {
            let text = std::fs::read_to_string(entry.path()).ok()?;
            let mut lines = text.lines();
            Some(RegisteredRun {
                prefix: entry.file_name().to_string_lossy().into_owned(),
                pid: lines.next()?.trim().parse().ok()?,
                dir: lines.next().unwrap_or("").into(),
            })
        })
        .collect();
    runs.sort_by(|a, b| a.prefix.cmp(&b.prefix));
    runs
}

/// The runs going on on this machine (their process is alive), by prefix.
pub fn running_runs() -> Vec<RegisteredRun> {
    let mut runs = registered_runs();
    runs.retain(|run| process_alive(run.pid));
    runs
}

/// Removes the registration of run `prefix` (once its resources are gone).
pub fn unregister_run(prefix: &str) {
    let _ = std::fs::remove_file(run_registry().join(prefix));
}

/// Prefixes of earlier runs whose orchestrator is gone (killed, say, with SIGKILL) but
/// whose iceoryx2 files may still be in `/dev/shm` or iceoryx2's directory: a registered
/// run ([`register_run`]) whose pid is dead, or files whose prefix names a dead pid
/// (`scmpc<pid>x…_`, the default prefix).
pub fn stale_run_prefixes() -> Vec<String> {
    let registered = (registered_runs().into_iter())
        .filter(|run| !process_alive(run.pid))
        .map(|run| run.prefix);
    let mut prefixes: Vec<String> = leftover_files(PREFIX_STEM)
        .iter()
        .filter_map(|path| {
            let name = path.file_name()?.to_string_lossy().into_owned();
            let start = name.find(PREFIX_STEM)?;
            let rest = &name[start..];
            let end = rest.find('_')?;
            let prefix = &rest[..=end];
            let pid: u32 = prefix[PREFIX_STEM.len()..]
                .split('x')
                .next()?
                .parse()
                .ok()?;
            (!process_alive(pid)).then(|| prefix.to_string())
        })
        .chain(registered)
        .collect();
    prefixes.sort();
    prefixes.dedup();
    prefixes
}

/// Whether process `pid` exists and is not a zombie (a killed process nobody reaped yet).
///
/// Allocation-free (a role process asks every 100 ms): the path and the file are read
/// through stack buffers.
pub fn process_alive(pid: u32) -> bool {
    use std::io::{Read, Write};
    use std::os::unix::ffi::OsStrExt;
    let mut path = [0u8; 32];
    let mut cursor = std::io::Cursor::new(&mut path[..]);
    if write!(cursor, "/proc/{pid}/stat").is_err() {
        return false;
    }
    let len = cursor.position() as usize;
    let path = std::path::Path::new(std::ffi::OsStr::from_bytes(&path[..len]));
    let mut stat = [0u8; 512];
    let Ok(read) = std::fs::File::open(path).and_then(|mut f| f.read(&mut stat)) else {
        return false;
    };
    // `pid (comm) S ...`: the state follows the last `) `.
    let stat = &stat[..read];
    stat.windows(2)
        .rposition(|w| w == b") ")
        .and_then(|at| stat.get(at + 2))
        .is_some_and(|state| *state != b'Z')
}

/// Paths in `/dev/shm` and under iceoryx2's root directory ([`ROOT_PATH`]) whose names
/// contain `prefix`: what a run leaves behind (empty after a clean run).
pub fn leftover_files(prefix: &str) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    // Each directory, and whether its directories are looked into.
    let mut stack = vec![
        (std::path::PathBuf::from("/dev/shm"), false),
        (std::path::PathBuf::from(ROOT_PATH), true),
    ];
    while let Some((dir, deep)) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if entry.file_name().to_string_lossy().contains(prefix) {
                found.push(path.clone());
            }
            if deep && entry.file_type().is_ok_and(|t| t.is_dir()) {
                stack.push((path, true));
            }
        }
    }
    found
}
