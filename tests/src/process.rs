//! Child `amstack` processes for the tests that need a second process: started from the
//! binary next to the test executable, stderr collected line by line, stopped on drop
//! (Ctrl-C first, so the process closes its logs and services, then SIGKILL).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Generous: these bound a hang, they are not what a test measures.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// The `amstack` binary of this build.
///
/// # Panics
/// If it is not built.
pub fn amstack() -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_else(|e| panic!("current_exe: {e}"));
    // target/<profile>/deps/<test>-… → target/<profile>/amstack
    let bin = exe
        .parent()
        .and_then(Path::parent)
        .map(|dir| dir.join("amstack"))
        .unwrap_or_default();
    assert!(
        bin.is_file(),
        "{} is missing: run `cargo build --bin amstack` (cargo test --workspace builds it)",
        bin.display()
    );
    bin
}

/// A child `amstack` process whose stderr is collected line by line as it comes.
#[derive(Debug)]
pub struct Proc {
    name: String,
    child: Child,
    lines: Arc<Mutex<Vec<String>>>,
    status: Option<ExitStatus>,
}

impl Proc {
    /// Starts `amstack ARGS…`; `name` names it in failures.
    pub fn start(name: &str, args: &[&str]) -> Self {
        let mut child = Command::new(amstack())
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        let lines = Arc::new(Mutex::new(Vec::new()));
        if let Some(stderr) = child.stderr.take() {
            let sink = Arc::clone(&lines);
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                    sink.lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .push(line);
                }
            });
        }
        Self {
            name: name.to_owned(),
            child,
            lines,
            status: None,
        }
    }

    pub fn stderr(&self) -> String {
        self.lines
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .join("\n")
    }

    /// The first stderr line containing `needle`, waiting for it.
    pub fn wait_for(&mut self, needle: &str) -> String {
        let started = Instant::now();
        loop {
            let found = self
                .lines
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .iter()
                .find(|l| l.contains(needle))
                .cloned();
            if let Some(line) = found {
                return line;
            }
            let exited = self.status.is_some() || matches!(self.child.try_wait(), Ok(Some(_)));
            if exited || started.elapsed() > PATIENCE {
                // The reader may still be draining the last lines of an exited process.
                std::thread::sleep(Duration::from_millis(200));
                if let Some(line) = self.stderr().lines().find(|l| l.contains(needle)) {
                    return line.to_owned();
                }
                panic!(
                    "{}: no line with {needle:?} ({}):\n{}",
                    self.name,
                    if exited { "it exited" } else { "timed out" },
                    self.stderr()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    pub fn wait(&mut self) -> ExitStatus {
        if let Some(s) = self.status {
            return s;
        }
        let started = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(s)) => {
                    // Let the reader catch the last lines.
                    std::thread::sleep(Duration::from_millis(100));
                    self.status = Some(s);
                    return s;
                }
                Ok(None) if started.elapsed() < PATIENCE => {
                    std::thread::sleep(Duration::from_millis(5));
                }
                _ => panic!("{} did not exit:\n{}", self.name, self.stderr()),
            }
        }
    }

    /// Ctrl-C (SIGINT): the process closes its logs and services and exits.
    pub fn interrupt(&self) {
        let _ = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status();
    }

    /// A crash: SIGKILL, nothing cleaned up by the process itself.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        self.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if self.status.is_some() || matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        // Ctrl-C first (the process closes its logs and services), then SIGKILL.
        self.interrupt();
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(3) {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
