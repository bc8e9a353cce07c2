//! Setpoint latency through the bridge on loopback: `Bridge::send` of one tick's actuator
//! setpoint (FA-Hexa: group 2 then group 0) → the peer holding the decoded group-0 frame,
//! which completes the tick. The peer is a UDP socket on another thread decoding with the
//! mavlink crate's reader. Paced at 250 Hz and 1 kHz for 10 s each.
//!
//! Run: `cargo bench -p firmware_bridge --bench setpoint_latency`
//! (`-- --seconds 3` for a shorter run).

use std::net::UdpSocket;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use firmware_bridge::{Address, Bridge, BridgeConfig, SetpointCodec};
use mavlink::dialects::common::MavMessage;
use mavlink::{MavlinkReader, MavlinkVersion};
use platform::{ActuatorCommand, Vehicle};

fn percentile(sorted: &[u64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i] as f64 / 1e3
}

fn run(rate_hz: f64, seconds: f64) -> Result<(), Box<dyn std::error::Error>> {
    let vehicle = Vehicle::builtin("fa-hexa")?;
    let codec = SetpointCodec::new(&vehicle, 1, 1)?;
    let peer = UdpSocket::bind("127.0.0.1:0")?;
    let port = peer.local_addr()?.port();
    let epoch = Instant::now();
    let (tx, rx) = mpsc::channel::<(u64, u64)>();
    let ticks = (rate_hz * seconds).round() as u64;
    std::thread::spawn(move || {
        let mut buf = [0u8; 512];
        peer.set_read_timeout(Some(Duration::from_secs(2))).ok();
        while let Ok((n, _)) = peer.recv_from(&mut buf) {
            let now = epoch.elapsed().as_nanos() as u64;
            if let Ok((_, MavMessage::SET_ACTUATOR_CONTROL_TARGET(d))) =
                MavlinkReader::new(&buf[..n]).read_message::<MavMessage>(MavlinkVersion::V2)
                && d.group_mlx == 0
                && tx.send((d.time_usec, now)).is_err()
            {
                break;
            }
        }
    });
    let config = BridgeConfig::new(Address::Udp {
        host: "127.0.0.1".into(),
        port,
    });
    let bridge = Bridge::connect(config, &vehicle)?;
    let command = ActuatorCommand {
        rotor_thrusts_n: vec![11.5; vehicle.rotors.len()],
        joint_targets: vehicle.initial_configuration(),
        direct_wrench_in_body: None,
    };
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let mut sent_ns = Vec::with_capacity(ticks as usize);
    let start = Instant::now();
    for k in 0..ticks {
        // Sleep to within 200 µs of the tick, then spin: a pure spin would take a core
        // from the bridge's and the peer's threads on a small machine.
        let due = start + period * k as u32;
        if let Some(wait) = due.checked_duration_since(Instant::now())
            && wait > Duration::from_micros(200)
        {
            std::thread::sleep(wait - Duration::from_micros(200));
        }
        while Instant::now() < due {
            std::hint::spin_loop();
        }
        let messages = codec.actuator_messages(k, &command)?;
        sent_ns.push(epoch.elapsed().as_nanos() as u64);
        bridge.send(messages)?;
    }
    let mut latencies = Vec::with_capacity(ticks as usize);
    while let Ok((k, at)) = rx.recv_timeout(Duration::from_millis(500)) {
        if let Some(&sent) = sent_ns.get(k as usize) {
            latencies.push(at.saturating_sub(sent));
        }
        if latencies.len() as u64 == ticks {
            break;
        }
    }
    latencies.sort_unstable();
    println!(
        "{rate_hz:>6.0} Hz: {} of {ticks} ticks received; send → peer receive: median {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs",
        latencies.len(),
        percentile(&latencies, 0.5),
        percentile(&latencies, 0.99),
        percentile(&latencies, 0.999),
        percentile(&latencies, 1.0),
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let seconds = args
        .iter()
        .position(|a| a == "--seconds")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok())
        .unwrap_or(10.0);
    for rate in [250.0, 1000.0] {
        run(rate, seconds)?;
    }
    Ok(())
}
