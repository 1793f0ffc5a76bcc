//! A `scmpc host` agent (docs/hosts.md) for the tests that place roles on another host.

use super::{leftovers, scmpc, wait_for};
use std::process::{Child, Stdio};
use std::sync::mpsc::Receiver;
use std::time::Duration;

/// A `scmpc host` agent listening on a free loopback port, stopped with the test.
pub struct Agent {
    pub child: Child,
    pub endpoint: String,
    /// The agent's stderr, line by line.
    lines: Receiver<String>,
}

impl Agent {
    /// Starts agent `name` with extra `args` and environment `env`; waits until it listens.
    pub fn start(name: &str, scheme: &str, args: &[&str], env: &[(&str, &str)]) -> Agent {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("no free port")
            .port();
        let endpoint = format!("{scheme}/127.0.0.1:{port}");
        let mut child = scmpc()
            .args(["host", "--name", name, "--listen", &endpoint])
            .args(args)
            .envs(env.iter().copied())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("cannot start scmpc host");
        let lines = super::lines_of(child.stderr.take().expect("stderr piped"));
        let agent = Agent {
            child,
            endpoint,
            lines,
        };
        agent.wait_for_line("listening on");
        agent
    }

    pub fn plain(name: &str) -> Agent {
        Agent::start(name, "tcp", &[], &[])
    }

    /// Waits (30 s at most) for a line of the agent's stderr that contains `text`.
    pub fn wait_for_line(&self, text: &str) -> String {
        let mut seen = Vec::new();
        while let Ok(line) = self.lines.recv_timeout(Duration::from_secs(30)) {
            if line.contains(text) {
                return line;
            }
            seen.push(line);
        }
        panic!("the agent never said `{text}`: {seen:#?}");
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// iceoryx2 files of the agent's runs still on this machine.
    pub fn leftovers(&self) -> Vec<std::path::PathBuf> {
        leftovers(&format!("scmpc{}x", self.pid()))
    }

    /// Asserts that no iceoryx2 file of the agent's runs is left `within` the given time
    /// (the agent, or the run's orphaned processes, remove them).
    pub fn assert_left_nothing(&self, within: Duration) {
        assert!(
            wait_for(within, || self.leftovers().is_empty()),
            "the agent's runs left {:?}",
            self.leftovers()
        );
    }
}

impl Drop for Agent {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_some() {
            return;
        }
        // SAFETY: signalling the agent this test started, still running (not reaped).
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        let ended = wait_for(Duration::from_secs(5), || {
            self.child.try_wait().ok().flatten().is_some()
        });
        if !ended {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
