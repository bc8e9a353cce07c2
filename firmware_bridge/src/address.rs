//! Where the autopilot is: `udp:HOST:PORT`, `udpin:HOST:PORT`, `tcp:HOST:PORT`,
//! `serial:DEVICE:BAUD`.
//!
//! - `udp:HOST:PORT` — the bridge binds an ephemeral local port and sends to the autopilot's
//!   port HOST:PORT (as MAVSDK's `udpout`; the twin's `twin serve --mavlink udp:...` listens
//!   there). It accepts datagrams from any sender, and answers only HOST:PORT.
//! - `udpin:HOST:PORT` — the bridge listens on HOST:PORT, as a PX4 companion computer does
//!   (PX4's `mavlink start -o <port>` sends to it); it answers whoever sent the last valid
//!   frame from the autopilot's system, and sends nothing until it has heard one.
//! - `tcp:HOST:PORT` — the bridge connects to a TCP server (PX4 SITL's 4560-style links,
//!   mavlink-router's TCP server).
//! - `serial:DEVICE:BAUD` — a serial device (`serial:/dev/ttyACM0:921600`), 8N1, no flow
//!   control.

use std::fmt;

/// A parsed link address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Address {
    /// Send to the autopilot's UDP port `host:port`.
    Udp {
        /// Host name or IP.
        host: String,
        /// Port.
        port: u16,
    },
    /// Listen on `host:port` for the autopilot.
    UdpIn {
        /// Address to bind.
        host: String,
        /// Port to bind.
        port: u16,
    },
    /// Connect to a TCP server.
    Tcp {
        /// Host name or IP.
        host: String,
        /// Port.
        port: u16,
    },
    /// A serial device.
    Serial {
        /// Device path.
        device: String,
        /// Baud rate.
        baud: u32,
    },
}

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Udp { host, port } => write!(f, "udp:{host}:{port}"),
            Self::UdpIn { host, port } => write!(f, "udpin:{host}:{port}"),
            Self::Tcp { host, port } => write!(f, "tcp:{host}:{port}"),
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

impl Address {
    /// Parses an address; the error names what is wrong and the accepted forms.
    pub fn parse(text: &str) -> Result<Self, String> {
        let forms = "expected udp:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or serial:DEVICE:BAUD";
        let (scheme, rest) = text
            .split_once(':')
            .ok_or_else(|| format!("'{text}': {forms}"))?;
        // The last ':' separates the port or baud (a device path or IPv6 host may hold more).
        let (first, last) = rest
            .rsplit_once(':')
            .ok_or_else(|| format!("'{text}': {forms}"))?;
        if first.is_empty() {
            return Err(format!("'{text}': empty host or device; {forms}"));
        }
        let port = || {
            last.parse::<u16>()
                .ok()
                .filter(|&p| p != 0)
                .ok_or_else(|| format!("'{text}': port '{last}' is not a number in 1..=65535"))
        };
        let host = first
            .trim_start_matches('[')
            .trim_end_matches(']')
            .to_owned();
        match scheme {
            "udp" | "udpout" => Ok(Self::Udp {
                host,
                port: port()?,
            }),
            "udpin" => Ok(Self::UdpIn {
                host,
                port: port()?,
            }),
            "tcp" | "tcpout" => Ok(Self::Tcp {
                host,
                port: port()?,
            }),
            "serial" => {
                let baud = last.parse::<u32>().ok().filter(|&b| b > 0).ok_or_else(|| {
                    format!("'{text}': baud rate '{last}' is not a positive number")
                })?;
                Ok(Self::Serial {
                    device: first.to_owned(),
                    baud,
                })
            }
            other => Err(format!("'{text}': unknown scheme '{other}'; {forms}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_four_forms_parse() {
        assert_eq!(
            Address::parse("udp:127.0.0.1:14540"),
            Ok(Address::Udp {
                host: "127.0.0.1".into(),
                port: 14540
            })
        );
        assert_eq!(
            Address::parse("udpin:0.0.0.0:14541"),
            Ok(Address::UdpIn {
                host: "0.0.0.0".into(),
                port: 14541
            })
        );
        assert_eq!(
            Address::parse("tcp:localhost:5760"),
            Ok(Address::Tcp {
                host: "localhost".into(),
                port: 5760
            })
        );
        assert_eq!(
            Address::parse("serial:/dev/ttyACM0:921600"),
            Ok(Address::Serial {
                device: "/dev/ttyACM0".into(),
                baud: 921_600
            })
        );
        let a = Address::parse("udp:127.0.0.1:14540").map(|a| a.to_string());
        assert_eq!(a.as_deref(), Ok("udp:127.0.0.1:14540"));
    }

    #[test]
    fn bad_addresses_say_what_is_wrong() {
        for (text, says) in [
            ("udp:127.0.0.1", "expected"),
            ("udp:127.0.0.1:0", "port '0'"),
            ("udp:127.0.0.1:99999", "port '99999'"),
            ("serial:/dev/ttyUSB0:fast", "baud rate 'fast'"),
            ("http:host:80", "unknown scheme 'http'"),
            ("udp::14540", "empty host"),
            ("14540", "expected"),
        ] {
            match Address::parse(text) {
                Ok(a) => panic!("{text} parsed as {a:?}"),
                Err(e) => assert!(e.contains(says), "{text}: {e}"),
            }
        }
    }
}
