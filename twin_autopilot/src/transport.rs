//! Where the autopilot's bytes go: a UDP socket (replying to every peer heard from) or a
//! serial device.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

/// A peer not heard from for this long stops receiving telemetry.
pub const PEER_TIMEOUT: Duration = Duration::from_secs(10);

/// The autopilot's endpoint, as given on the command line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// `udp:HOST:PORT`: bind there; telemetry goes to every peer that sent a frame.
    Udp(SocketAddr),
    /// `serial:DEVICE:BAUD`.
    Serial {
        /// Device path, e.g. /dev/ttyUSB0.
        device: String,
        /// Baud rate, bit/s.
        baud: u32,
    },
}

impl Endpoint {
    /// Parses `udp:HOST:PORT` or `serial:DEVICE:BAUD`.
    pub fn parse(s: &str) -> Result<Self, String> {
        if let Some(addr) = s.strip_prefix("udp:") {
            let resolved = addr
                .to_socket_addrs()
                .map_err(|e| format!("'{s}': cannot resolve '{addr}' as HOST:PORT ({e})"))?
                .next()
                .ok_or_else(|| format!("'{s}': '{addr}' resolves to no address"))?;
            return Ok(Self::Udp(resolved));
        }
        if let Some(rest) = s.strip_prefix("serial:") {
            let (device, baud) = rest
                .rsplit_once(':')
                .ok_or_else(|| format!("'{s}': expected serial:DEVICE:BAUD"))?;
            let baud: u32 = baud
                .parse()
                .ok()
                .filter(|&b| b > 0)
                .ok_or_else(|| format!("'{s}': baud '{baud}' is not a positive integer"))?;
            if device.is_empty() {
                return Err(format!("'{s}': empty device"));
            }
            return Ok(Self::Serial {
                device: device.to_owned(),
                baud,
            });
        }
        Err(format!(
            "'{s}': expected udp:HOST:PORT or serial:DEVICE:BAUD"
        ))
    }
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Udp(a) => write!(f, "udp:{a}"),
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

/// What a receive returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Incoming {
    /// A UDP datagram of this many bytes from this address.
    Datagram {
        /// Bytes.
        len: usize,
        /// Sender.
        from: SocketAddr,
    },
    /// Serial bytes.
    Stream(usize),
}

/// An open endpoint.
pub enum Transport {
    /// UDP and its peers (address, last heard).
    Udp {
        /// The bound socket.
        socket: UdpSocket,
        /// Peers and when they were last heard.
        peers: Vec<(SocketAddr, Instant)>,
    },
    /// A serial port.
    Serial(Box<dyn tokio_serial::SerialPort>),
}

impl std::fmt::Debug for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Udp { socket, peers } => f
                .debug_struct("Udp")
                .field("local", &socket.local_addr().ok())
                .field("peers", peers)
                .finish(),
            Self::Serial(p) => f.debug_tuple("Serial").field(&p.name()).finish(),
        }
    }
}

impl Transport {
    /// Opens the endpoint.
    pub fn open(endpoint: &Endpoint) -> Result<Self, String> {
        match endpoint {
            Endpoint::Udp(addr) => {
                let socket =
                    UdpSocket::bind(addr).map_err(|e| format!("cannot bind udp:{addr}: {e}"))?;
                Ok(Self::Udp {
                    socket,
                    peers: Vec::new(),
                })
            }
            Endpoint::Serial { device, baud } => tokio_serial::new(device, *baud)
                .timeout(Duration::from_millis(1))
                .open()
                .map(Self::Serial)
                .map_err(|e| format!("cannot open serial:{device}:{baud}: {e}")),
        }
    }

    /// The local UDP address (None for serial).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match self {
            Self::Udp { socket, .. } => socket.local_addr().ok(),
            Self::Serial(_) => None,
        }
    }

    /// Whether anyone listens (a UDP peer heard recently; serial: always).
    pub fn has_peers(&self) -> bool {
        match self {
            Self::Udp { peers, .. } => !peers.is_empty(),
            Self::Serial(_) => true,
        }
    }

    /// Receives into `buf`, waiting up to `wait`. Errors of the medium are returned; nothing
    /// there is `Ok(None)`.
    pub fn recv(&mut self, buf: &mut [u8], wait: Duration) -> std::io::Result<Option<Incoming>> {
        let wait = wait.max(Duration::from_micros(50));
        match self {
            Self::Udp { socket, .. } => {
                socket.set_read_timeout(Some(wait))?;
                match socket.recv_from(buf) {
                    Ok((len, from)) => Ok(Some(Incoming::Datagram { len, from })),
                    Err(e) if is_quiet(&e) => Ok(None),
                    Err(e) => Err(e),
                }
            }
            Self::Serial(port) => {
                port.set_timeout(wait)
                    .map_err(|e| std::io::Error::other(e.to_string()))?;
                match port.read(buf) {
                    Ok(0) => Ok(None),
                    Ok(n) => Ok(Some(Incoming::Stream(n))),
                    Err(e) if is_quiet(&e) => Ok(None),
                    Err(e) => Err(e),
                }
            }
        }
    }

    /// Counts `from` as a peer (it sent a frame the autopilot accepted): telemetry goes to it
    /// for [`PEER_TIMEOUT`]. True for a new peer.
    pub fn note_peer(&mut self, from: SocketAddr) -> bool {
        let Self::Udp { peers, .. } = self else {
            return false;
        };
        let now = Instant::now();
        peers.retain(|(_, t)| now.duration_since(*t) < PEER_TIMEOUT);
        match peers.iter_mut().find(|(a, _)| *a == from) {
            Some(p) => {
                p.1 = now;
                false
            }
            None => {
                peers.push((from, now));
                true
            }
        }
    }

    /// Sends to every peer the bytes `pick` chooses for it (its address; None for serial), e.g.
    /// MAVLink 1 frames to a MAVLink 1 peer; returns how many sends failed.
    pub fn send_each<'a>(&mut self, pick: impl Fn(Option<SocketAddr>) -> &'a [u8]) -> u64 {
        match self {
            Self::Udp { socket, peers } => peers
                .iter()
                .filter(|(addr, _)| {
                    let bytes = pick(Some(*addr));
                    !bytes.is_empty() && socket.send_to(bytes, addr).is_err()
                })
                .count() as u64,
            Self::Serial(port) => {
                let bytes = pick(None);
                u64::from(!bytes.is_empty() && port.write_all(bytes).is_err())
            }
        }
    }

    /// Sends `bytes` to every peer; returns how many sends failed.
    pub fn send(&mut self, bytes: &[u8]) -> u64 {
        if bytes.is_empty() {
            return 0;
        }
        match self {
            Self::Udp { socket, peers } => peers
                .iter()
                .filter(|(addr, _)| socket.send_to(bytes, addr).is_err())
                .count() as u64,
            Self::Serial(port) => u64::from(port.write_all(bytes).is_err()),
        }
    }
}

/// Nothing arrived (or a UDP peer's port was closed, which Linux reports on the next read).
fn is_quiet(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::WouldBlock
            | ErrorKind::TimedOut
            | ErrorKind::Interrupted
            | ErrorKind::ConnectionRefused
    )
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn endpoints_parse_or_say_what_is_wrong() {
        assert_eq!(
            Endpoint::parse("udp:127.0.0.1:14540"),
            Ok(Endpoint::Udp("127.0.0.1:14540".parse().unwrap()))
        );
        assert_eq!(
            Endpoint::parse("serial:/dev/ttyUSB0:921600"),
            Ok(Endpoint::Serial {
                device: "/dev/ttyUSB0".to_owned(),
                baud: 921_600
            })
        );
        for bad in [
            "tcp:1.2.3.4:5",
            "udp:nonsense",
            "serial:/dev/x",
            "serial:/dev/x:0",
            "serial::9600",
        ] {
            let e = Endpoint::parse(bad).unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }
}
