//! The MAVLink transports: UDP (povins' own sockets, so that nothing listens beyond what is
//! asked) and serial (the `mavlink` crate's).
//!
//! | address | what |
//! |---|---|
//! | `udpout:HOST:PORT` | send to HOST:PORT (PX4 SITL's onboard port 14540, mavlink-router); the socket is bound to an ephemeral port on the interface that reaches HOST (loopback for a loopback HOST) and *connected*, so only HOST:PORT's replies (TIMESYNC) are read |
//! | `udpin:ADDR:PORT` | listen on ADDR:PORT and send to whoever sent last (nothing is sent before) |
//! | `serial:DEVICE:BAUD` | a serial port (e.g. `serial:/dev/ttyTHS1:921600`), 8N1 |

use crate::error::IoError;
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::{MavConnection, MavHeader, MavlinkReader};
use std::io::ErrorKind;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::sync::Mutex;
use std::time::Duration;

/// Where the messages go (see the module doc for the syntax).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// Send to this address.
    UdpOut(SocketAddr),
    /// Listen here; reply to the last sender.
    UdpIn(SocketAddr),
    /// A serial device and its baud rate.
    Serial(String, u32),
}

impl Endpoint {
    /// Parses `udpout:HOST:PORT`, `udpin:ADDR:PORT` or `serial:DEVICE:BAUD`.
    pub fn parse(s: &str) -> Result<Endpoint, String> {
        let bad = |why: &str| {
            format!(
                "MAVLink address `{s}`: {why} (expected udpout:HOST:PORT, udpin:ADDR:PORT or \
                 serial:DEVICE:BAUD)"
            )
        };
        let (kind, rest) = s.split_once(':').ok_or_else(|| bad("no transport"))?;
        match kind {
            "udpout" | "udpin" => {
                let addr = rest
                    .to_socket_addrs()
                    .map_err(|e| bad(&format!("`{rest}` is not HOST:PORT: {e}")))?
                    .next()
                    .ok_or_else(|| bad(&format!("`{rest}` resolves to no address")))?;
                Ok(if kind == "udpout" {
                    Endpoint::UdpOut(addr)
                } else {
                    Endpoint::UdpIn(addr)
                })
            }
            "serial" => {
                let (dev, baud) = rest.rsplit_once(':').ok_or_else(|| bad("no baud rate"))?;
                let baud = baud
                    .parse::<u32>()
                    .map_err(|_| bad(&format!("baud rate `{baud}` is not a number")))?;
                Ok(Endpoint::Serial(dev.to_string(), baud))
            }
            _ => Err(bad(&format!("unknown transport `{kind}`"))),
        }
    }
}

/// An open link: sends whole MAVLink 2 frames, receives messages.
pub enum Link {
    /// A UDP socket; `peer` is where frames go (`None` for `udpin` before anyone spoke).
    Udp {
        /// The socket.
        socket: UdpSocket,
        /// The destination.
        peer: Mutex<Option<SocketAddr>>,
        /// Whether the socket is connected (`udpout`): `send`, not `send_to`.
        connected: bool,
    },
    /// A serial port, through the `mavlink` crate.
    Serial(::mavlink::Connection<MavMessage>),
}

/// How long a receive waits, so that the receiving thread sees the stop flag.
pub const RECV_TIMEOUT: Duration = Duration::from_millis(100);

impl Link {
    /// Opens `ep`.
    pub fn open(ep: &Endpoint) -> Result<Link, IoError> {
        let io = |what: String, e: std::io::Error| IoError::Io {
            path: what.into(),
            source: e,
        };
        match ep {
            Endpoint::UdpOut(peer) => {
                let local: SocketAddr = match peer {
                    SocketAddr::V4(a) if a.ip().is_loopback() => "127.0.0.1:0",
                    SocketAddr::V4(_) => "0.0.0.0:0",
                    SocketAddr::V6(a) if a.ip().is_loopback() => "[::1]:0",
                    SocketAddr::V6(_) => "[::]:0",
                }
                .parse()
                .map_err(|_| io(format!("udpout:{peer}"), ErrorKind::InvalidInput.into()))?;
                let socket =
                    UdpSocket::bind(local).map_err(|e| io(format!("udpout:{peer} (bind)"), e))?;
                socket
                    .connect(peer)
                    .map_err(|e| io(format!("udpout:{peer} (connect)"), e))?;
                socket
                    .set_read_timeout(Some(RECV_TIMEOUT))
                    .map_err(|e| io(format!("udpout:{peer}"), e))?;
                Ok(Link::Udp {
                    socket,
                    peer: Mutex::new(Some(*peer)),
                    connected: true,
                })
            }
            Endpoint::UdpIn(addr) => {
                let socket =
                    UdpSocket::bind(addr).map_err(|e| io(format!("udpin:{addr} (bind)"), e))?;
                socket
                    .set_read_timeout(Some(RECV_TIMEOUT))
                    .map_err(|e| io(format!("udpin:{addr}"), e))?;
                Ok(Link::Udp {
                    socket,
                    peer: Mutex::new(None),
                    connected: false,
                })
            }
            Endpoint::Serial(dev, baud) => {
                let conn = ::mavlink::connect::<MavMessage>(&format!("serial:{dev}:{baud}"))
                    .map_err(|e| io(format!("serial:{dev}:{baud}"), e))?;
                Ok(Link::Serial(conn))
            }
        }
    }

    /// Sends one message; `Ok(false)` when there is nowhere to send yet (`udpin` before a
    /// peer spoke).
    pub fn send(&self, header: MavHeader, msg: &MavMessage) -> std::io::Result<bool> {
        match self {
            Link::Udp {
                socket,
                peer,
                connected,
            } => {
                let mut buf = Vec::with_capacity(280);
                ::mavlink::write_v2_msg(&mut buf, header, msg)
                    .map_err(|e| std::io::Error::other(e.to_string()))?;
                if *connected {
                    // A refused send (nobody listening yet on a loopback port) is not fatal.
                    match socket.send(&buf) {
                        Err(e) if e.kind() == ErrorKind::ConnectionRefused => Ok(false),
                        r => r.map(|_| true),
                    }
                } else {
                    let to = *peer.lock().map_err(|_| std::io::Error::other("poisoned"))?;
                    match to {
                        Some(to) => socket.send_to(&buf, to).map(|_| true),
                        None => Ok(false),
                    }
                }
            }
            Link::Serial(c) => c
                .send(&header, msg)
                .map(|_| true)
                .map_err(|e| std::io::Error::other(e.to_string())),
        }
    }

    /// Receives the messages of one datagram (or one message from a serial port) into `out`,
    /// left empty after [`RECV_TIMEOUT`] without any. Frames that do not parse are counted in `bad`.
    pub fn recv(
        &self,
        buf: &mut [u8],
        out: &mut Vec<(MavHeader, MavMessage)>,
        bad: &mut u64,
    ) -> std::io::Result<()> {
        out.clear();
        match self {
            Link::Udp {
                socket,
                peer,
                connected,
            } => {
                let (n, from) = match socket.recv_from(buf) {
                    Ok(x) => x,
                    Err(e)
                        if matches!(
                            e.kind(),
                            ErrorKind::WouldBlock
                                | ErrorKind::TimedOut
                                | ErrorKind::ConnectionRefused
                        ) =>
                    {
                        return Ok(())
                    }
                    Err(e) => return Err(e),
                };
                if !*connected {
                    if let Ok(mut p) = peer.lock() {
                        *p = Some(from);
                    }
                }
                let mut reader = MavlinkReader::new(buf.get(..n).unwrap_or(&[]));
                loop {
                    match reader.read_any_message::<MavMessage>() {
                        Ok(m) => out.push(m),
                        Err(::mavlink::error::MessageReadError::Io(_)) => break,
                        Err(_) => *bad += 1,
                    }
                }
                Ok(())
            }
            Link::Serial(c) => {
                match c.recv() {
                    Ok(m) => out.push(m),
                    Err(::mavlink::error::MessageReadError::Io(e))
                        if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                    Err(::mavlink::error::MessageReadError::Io(e)) => return Err(e),
                    Err(_) => *bad += 1,
                }
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_parse_and_errors_name_the_problem() {
        assert_eq!(
            Endpoint::parse("udpout:127.0.0.1:14540").unwrap(),
            Endpoint::UdpOut("127.0.0.1:14540".parse().unwrap())
        );
        assert_eq!(
            Endpoint::parse("udpin:0.0.0.0:14550").unwrap(),
            Endpoint::UdpIn("0.0.0.0:14550".parse().unwrap())
        );
        assert_eq!(
            Endpoint::parse("serial:/dev/ttyTHS1:921600").unwrap(),
            Endpoint::Serial("/dev/ttyTHS1".into(), 921_600)
        );
        for (bad, says) in [
            ("127.0.0.1:14540", "unknown transport"),
            ("udpout:127.0.0.1", "HOST:PORT"),
            ("serial:/dev/ttyS0", "baud"),
            ("serial:/dev/ttyS0:fast", "fast"),
            ("tcp:1.2.3.4:5", "unknown transport `tcp`"),
        ] {
            let e = Endpoint::parse(bad).unwrap_err();
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn udpout_binds_loopback_for_a_loopback_peer() {
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        let link = Link::open(&Endpoint::UdpOut(rx.local_addr().unwrap())).unwrap();
        let Link::Udp { socket, .. } = &link else {
            panic!("not UDP")
        };
        assert!(socket.local_addr().unwrap().ip().is_loopback());
    }
}
