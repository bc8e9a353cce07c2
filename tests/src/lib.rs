//! Cross-crate functional tests of amstack, and what they share.
//!
//! The tests fly whole stacks — hover and tracking in the twin, the paper's actuator
//! experiment, determinism of runs and their logs, the logs read back by an independent
//! reader — and start and stop any second process they need themselves (`tests/`).
//!
//! This library holds the support they share: the independent MCAP reader and the Python
//! peers (the PyPI `mcap` and `pymavlink` packages, installed into a virtualenv by
//! `scripts/setup-python.sh`), and the child `amstack` processes ([`process`]).

pub mod process;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

/// The repository's `scripts/` folder.
pub fn scripts_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts")
}

/// The virtualenv's python, set up on first use by `scripts/setup-python.sh` (idempotent;
/// needs PyPI the first time).
///
/// # Panics
/// If the setup script fails: the tests that need it cannot run.
pub fn python() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        let script = scripts_dir().join("setup-python.sh");
        let out = Command::new("bash")
            .arg(&script)
            .stderr(Stdio::inherit())
            .output();
        match out {
            Ok(out) if out.status.success() => {
                let stdout = String::from_utf8_lossy(&out.stdout);
                PathBuf::from(stdout.lines().last().unwrap_or_default().trim())
            }
            other => panic!("{} failed: {other:?}", script.display()),
        }
    })
}

/// Runs `scripts/mcap_check.py FILE --json ARGS…` and returns its exit code and report.
///
/// # Panics
/// If the script cannot start or prints no JSON.
pub fn mcap_check(file: &Path, args: &[&str]) -> (i32, serde_json::Value) {
    let out = Command::new(python())
        .arg(scripts_dir().join("mcap_check.py"))
        .arg(file)
        .arg("--json")
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run mcap_check.py: {e}"));
    let report = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "mcap_check.py printed no JSON ({e}): {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    (out.status.code().unwrap_or(-1), report)
}

/// The Foxglove WebSocket test client (`scripts/foxglove_ws_client.py`) with `args`, run by
/// the virtualenv's python.
pub fn ws_client(args: &[&str]) -> Command {
    let mut c = Command::new(python());
    c.arg(scripts_dir().join("foxglove_ws_client.py"))
        .args(args);
    c
}

/// Waits until `path` exists (the client's `--ready-file`: it has subscribed).
///
/// # Panics
/// If the client exits first, or after 120 s.
pub fn wait_for_file(path: &Path, client: &mut std::process::Child) {
    let started = std::time::Instant::now();
    while !path.exists() {
        if let Ok(Some(status)) = client.try_wait() {
            panic!("the client exited ({status}) before it subscribed");
        }
        assert!(
            started.elapsed() < std::time::Duration::from_secs(120),
            "the client never subscribed"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}
