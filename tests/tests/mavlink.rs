//! Over real UDP loopback: `amstack fly --link mavlink:udp:...` (the flight stack through
//! `firmware_bridge`) against `amstack twin serve --mavlink udp:... --lockstep` (the twin as
//! a PX4-style autopilot), both real processes, started and stopped by the tests. Written
//! against the contract in `docs/mavlink.md`.
//!
//! The autopilot side lands on its own branch: until both are merged the tests that need it
//! are ignored (`cargo test -p tests --test mavlink -- --ignored` runs them). Build the
//! binary first: `cargo build --bin amstack`.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Generous: bounds a hang, not what a test measures.
const PATIENCE: Duration = Duration::from_secs(120);

fn amstack() -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_else(|e| panic!("current_exe: {e}"));
    let bin = exe
        .parent()
        .and_then(Path::parent)
        .map(|dir| dir.join("amstack"))
        .unwrap_or_default();
    assert!(
        bin.is_file(),
        "{} is missing: run `cargo build --bin amstack`",
        bin.display()
    );
    bin
}

/// One test at a time (two processes each on a small machine).
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A UDP port free right now on loopback.
fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .unwrap_or_else(|e| panic!("no free port: {e}"))
}

/// A child `amstack` whose stderr is collected as it comes; stopped (Ctrl-C, then kill) on
/// drop.
struct Proc {
    name: String,
    child: Child,
    lines: Arc<Mutex<Vec<String>>>,
}

impl Proc {
    fn start(name: &str, args: &[&str]) -> Self {
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
        }
    }

    fn stderr(&self) -> String {
        self.lines
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .join("\n")
    }

    fn wait(&mut self) -> ExitStatus {
        let started = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(s)) => {
                    std::thread::sleep(Duration::from_millis(100));
                    return s;
                }
                Ok(None) if started.elapsed() < PATIENCE => {
                    std::thread::sleep(Duration::from_millis(10));
                }
                _ => panic!("{} did not exit:\n{}", self.name, self.stderr()),
            }
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        let _ = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status();
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

fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn number(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("no number {key} in {v}"))
}

/// The twin's autopilot on `port`, lockstep, with `twin_flags` (the same flags as the
/// flight's: vehicle, disturbances, seed).
fn autopilot(port: u16, twin_flags: &[&str]) -> Proc {
    let address = format!("udp:127.0.0.1:{port}");
    let mut args = vec!["twin", "serve", "--mavlink", &address, "--lockstep"];
    args.extend_from_slice(twin_flags);
    Proc::start("twin serve --mavlink", &args)
}

/// `amstack fly` over MAVLink to `port`; returns the exit status and the JSON scores.
fn fly(port: u16, flags: &[&str], json: &Path) -> (ExitStatus, Option<serde_json::Value>, String) {
    let link = format!("mavlink:udp:127.0.0.1:{port}");
    let json_arg = json.to_string_lossy().into_owned();
    let mut args = vec![
        "fly",
        "--link",
        &link,
        "--connect-timeout-ms",
        "30000",
        "--json",
        &json_arg,
    ];
    args.extend_from_slice(flags);
    let mut p = Proc::start("fly --link mavlink", &args);
    let status = p.wait();
    let scores = json.is_file().then(|| read_json(json));
    (status, scores, p.stderr())
}

const FLIGHT: &[&str] = &[
    "--platform",
    "fa-hexa",
    "--disturbances",
    "saturation",
    "--seed",
    "3",
];

#[test]
#[ignore = "needs the twin autopilot (branch ap)"]
fn a_step_at_actuator_level_over_udp_matches_the_in_process_flight() {
    let _one = serial();
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let port = free_port();
    let _twin = autopilot(port, FLIGHT);
    let over = dir.path().join("mavlink.json");
    let mut flags = FLIGHT.to_vec();
    flags.extend_from_slice(&[
        "--trajectory",
        "step",
        "--duration",
        "4",
        "--level",
        "actuator",
    ]);
    let (status, scores, stderr) = fly(port, &flags, &over);
    assert!(status.success(), "fly failed:\n{stderr}");
    let scores = scores.unwrap_or_else(|| panic!("no scores:\n{stderr}"));
    // The same flight in process.
    let local = dir.path().join("local.json");
    let mut args = vec!["track", "--json"];
    let local_arg = local.to_string_lossy().into_owned();
    args.push(&local_arg);
    args.extend_from_slice(FLIGHT);
    args.extend_from_slice(&["--trajectory", "step", "--duration", "4"]);
    let mut track = Proc::start("track", &args);
    assert!(track.wait().success(), "track failed:\n{}", track.stderr());
    let reference = read_json(&local);
    // Lockstep from the same reset state, f32 on the wire: the same flight within 0.1 mm of
    // RMS error (the fixture of policy_runtime's MavlinkLink tests measured 6e-9 m).
    for key in ["ee_pos_rmse_m", "base_pos_rmse_m", "base_z_rmse_m"] {
        let (a, b) = (number(&scores, key), number(&reference, key));
        assert!(
            (a - b).abs() < 1e-4,
            "{key}: {a} over MAVLink vs {b} in process"
        );
    }
    assert_eq!(scores["ticks"], reference["ticks"]);
}

#[test]
#[ignore = "needs the twin autopilot (branch ap)"]
fn hover_at_attitude_level_holds_altitude() {
    let _one = serial();
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let port = free_port();
    let _twin = autopilot(port, FLIGHT);
    let out = dir.path().join("attitude.json");
    let mut flags = FLIGHT.to_vec();
    flags.extend_from_slice(&[
        "--trajectory",
        "hover",
        "--duration",
        "4",
        "--level",
        "attitude",
    ]);
    let (status, scores, stderr) = fly(port, &flags, &out);
    assert!(status.success(), "fly failed:\n{stderr}");
    let scores = scores.unwrap_or_else(|| panic!("no scores:\n{stderr}"));
    // The autopilot's own attitude loop and allocation hold the hover at 1 m: within 5 cm
    // RMS after the 2 s settling, and the base barely tilts.
    let z = number(&scores, "base_z_rmse_m");
    assert!(z < 0.05, "base z RMSE {z} m\n{stderr}");
    let tilt = number(&scores, "tilt_use_rad");
    assert!(tilt < 0.2, "tilt {tilt} rad\n{stderr}");
}

#[test]
fn a_flight_without_an_autopilot_stops_with_a_clear_error() {
    // Nobody on the port: the bridge waits for the first ODOMETRY, then says so (exit 1).
    let _one = serial();
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let port = free_port();
    let link = format!("mavlink:udp:127.0.0.1:{port}");
    let json = dir.path().join("none.json");
    let json_arg = json.to_string_lossy().into_owned();
    let mut p = Proc::start(
        "fly",
        &[
            "fly",
            "--link",
            &link,
            "--connect-timeout-ms",
            "300",
            "--json",
            &json_arg,
        ],
    );
    let status = p.wait();
    assert_eq!(status.code(), Some(1), "{}", p.stderr());
    assert!(
        p.stderr().contains(
            "no ODOMETRY (the vehicle's state at start) from the autopilot within 300 ms"
        ),
        "{}",
        p.stderr()
    );
    assert!(!json.exists());
}
