//! Where the autopilot is: `udpout:HOST:PORT` (we send there, replies come back to our port),
//! `udpin:HOST:PORT` (we listen; we answer whoever spoke last), `tcp:HOST:PORT` (client),
//! `serial:PATH:BAUD` (or `PATH:BAUD` for a path under /dev).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs, UdpSocket};
use std::sync::Mutex;
use std::time::Duration;

use anyhow::{Context, Result, bail};

/// Read timeout of every transport: the bridge's periodic work runs at least this often.
pub const POLL: Duration = Duration::from_millis(50);

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    UdpOut(String),
    UdpIn(String),
    Tcp(String),
    Serial { path: String, baud: u32 },
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Endpoint::UdpOut(a) => write!(f, "udpout:{a}"),
            Endpoint::UdpIn(a) => write!(f, "udpin:{a}"),
            Endpoint::Tcp(a) => write!(f, "tcp:{a}"),
            Endpoint::Serial { path, baud } => write!(f, "serial:{path}:{baud}"),
        }
    }
}

/// Parse an endpoint (for clap: the error says which forms exist).
pub fn parse_endpoint(s: &str) -> Result<Endpoint, String> {
    let forms = "udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or serial:PATH:BAUD";
    let host_port = |a: &str| -> Result<String, String> {
        match a.rsplit_once(':') {
            Some((h, p)) if !h.is_empty() && p.parse::<u16>().is_ok() => Ok(a.to_string()),
            _ => Err(format!("{s:?}: expected {forms}")),
        }
    };
    let serial = |rest: &str| -> Result<Endpoint, String> {
        match rest.rsplit_once(':') {
            Some((path, baud)) if !path.is_empty() => match baud.parse::<u32>() {
                Ok(b) if (1200..=4_000_000).contains(&b) => Ok(Endpoint::Serial { path: path.to_string(), baud: b }),
                _ => Err(format!("{s:?}: the baud rate must be a number in 1200..=4000000")),
            },
            _ => Err(format!("{s:?}: expected serial:PATH:BAUD, e.g. serial:/dev/ttyACM0:115200")),
        }
    };
    if let Some(a) = s.strip_prefix("udpout:") {
        Ok(Endpoint::UdpOut(host_port(a)?))
    } else if let Some(a) = s.strip_prefix("udpin:") {
        Ok(Endpoint::UdpIn(host_port(a)?))
    } else if let Some(a) = s.strip_prefix("tcp:").or_else(|| s.strip_prefix("tcpout:")) {
        Ok(Endpoint::Tcp(host_port(a)?))
    } else if let Some(rest) = s.strip_prefix("serial:") {
        serial(rest)
    } else if s.starts_with("/dev/") {
        serial(s)
    } else {
        Err(format!("{s:?}: expected {forms}"))
    }
}

/// An open endpoint: send whole frames, receive bytes (with [`POLL`] as the read timeout).
pub enum Transport {
    Udp { sock: UdpSocket, peer: Mutex<Option<SocketAddr>>, listening: bool },
    Stream { reader: Mutex<Box<dyn Read + Send>>, writer: Mutex<Box<dyn Write + Send>> },
}

fn resolve(a: &str) -> Result<SocketAddr> {
    a.to_socket_addrs()
        .with_context(|| format!("{a} is not an address (HOST:PORT)"))?
        .next()
        .with_context(|| format!("{a} resolves to no address"))
}

impl Transport {
    pub fn open(e: &Endpoint) -> Result<Transport> {
        Ok(match e {
            Endpoint::UdpOut(a) => {
                let peer = resolve(a)?;
                let bind = if peer.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
                let sock = UdpSocket::bind(bind).context("binding a UDP socket")?;
                sock.set_read_timeout(Some(POLL))?;
                Transport::Udp { sock, peer: Mutex::new(Some(peer)), listening: false }
            }
            Endpoint::UdpIn(a) => {
                let sock = UdpSocket::bind(resolve(a)?).with_context(|| format!("listening on UDP {a}"))?;
                sock.set_read_timeout(Some(POLL))?;
                Transport::Udp { sock, peer: Mutex::new(None), listening: true }
            }
            Endpoint::Tcp(a) => {
                let s = TcpStream::connect_timeout(&resolve(a)?, Duration::from_secs(10))
                    .with_context(|| format!("connecting to the autopilot at tcp:{a}"))?;
                s.set_read_timeout(Some(POLL))?;
                s.set_nodelay(true)?;
                let r = s.try_clone()?;
                Transport::Stream { reader: Mutex::new(Box::new(r)), writer: Mutex::new(Box::new(s)) }
            }
            Endpoint::Serial { path, baud } => {
                let port = serialport::new(path, *baud)
                    .timeout(POLL)
                    .open()
                    .with_context(|| format!("opening the serial port {path} (check the path and permissions)"))?;
                let r = port.try_clone().context("cloning the serial port")?;
                Transport::Stream { reader: Mutex::new(Box::new(r)), writer: Mutex::new(Box::new(port)) }
            }
        })
    }

    /// The local address of a UDP endpoint (for tests and messages).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match self {
            Transport::Udp { sock, .. } => sock.local_addr().ok(),
            Transport::Stream { .. } => None,
        }
    }

    /// Send one frame. `Ok(false)`: nowhere to send yet (udpin before anyone spoke).
    pub fn send(&self, frame: &[u8]) -> std::io::Result<bool> {
        match self {
            Transport::Udp { sock, peer, .. } => {
                let Some(to) = *peer.lock().unwrap_or_else(|e| e.into_inner()) else { return Ok(false) };
                sock.send_to(frame, to)?;
                Ok(true)
            }
            Transport::Stream { writer, .. } => {
                let mut w = writer.lock().unwrap_or_else(|e| e.into_inner());
                w.write_all(frame)?;
                w.flush()?;
                Ok(true)
            }
        }
    }

    /// Receive what is there (waits up to [`POLL`]). Returns (bytes, is a whole datagram);
    /// `Ok((0, _))` on a timeout.
    pub fn recv(&self, buf: &mut [u8]) -> std::io::Result<(usize, bool)> {
        let quiet = |e: &std::io::Error| matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut);
        match self {
            Transport::Udp { sock, peer, listening } => match sock.recv_from(buf) {
                Ok((n, from)) => {
                    if *listening {
                        *peer.lock().unwrap_or_else(|e| e.into_inner()) = Some(from);
                    }
                    Ok((n, true))
                }
                Err(e) if quiet(&e) => Ok((0, true)),
                Err(e) => Err(e),
            },
            Transport::Stream { reader, .. } => match reader.lock().unwrap_or_else(|e| e.into_inner()).read(buf) {
                Ok(0) => Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "the autopilot closed the connection")),
                Ok(n) => Ok((n, false)),
                Err(e) if quiet(&e) => Ok((0, false)),
                Err(e) => Err(e),
            },
        }
    }
}

/// Refuse an endpoint that cannot work before starting anything.
pub fn check(e: &Endpoint) -> Result<()> {
    if let Endpoint::Serial { path, .. } = e
        && !std::path::Path::new(path).exists()
    {
        bail!("the serial port {path} does not exist");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoint_forms() {
        assert_eq!(parse_endpoint("udpout:127.0.0.1:14550"), Ok(Endpoint::UdpOut("127.0.0.1:14550".into())));
        assert_eq!(parse_endpoint("udpin:0.0.0.0:14551"), Ok(Endpoint::UdpIn("0.0.0.0:14551".into())));
        assert_eq!(parse_endpoint("tcp:192.168.2.2:5760"), Ok(Endpoint::Tcp("192.168.2.2:5760".into())));
        assert_eq!(parse_endpoint("serial:/dev/ttyACM0:115200"), Ok(Endpoint::Serial { path: "/dev/ttyACM0".into(), baud: 115_200 }));
        assert_eq!(parse_endpoint("/dev/ttyUSB0:57600"), Ok(Endpoint::Serial { path: "/dev/ttyUSB0".into(), baud: 57_600 }));
        for bad in ["udp:1.2.3.4:5", "udpout:1.2.3.4", "udpout::5", "tcp:host:99999", "serial:/dev/x:12", "serial:/dev/x", ""] {
            assert!(parse_endpoint(bad).is_err(), "{bad}");
        }
    }
}
