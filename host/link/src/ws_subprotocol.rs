//! `foxglove.websocket.v1` for every client: a thin TCP layer in front of the `foxglove` crate's
//! server.
//!
//! The crate (0.30) speaks the classic Foxglove WebSocket protocol (JSON advertisements, binary
//! message frames) but only under the subprotocol names `foxglove.sdk.v1` / `foxglove.sdk.v1.1`;
//! a client that offers only `foxglove.websocket.v1` (the `@foxglove/ws-protocol` npm client,
//! Lichtblick) gets HTTP 400. This layer accepts the connection, reads the HTTP upgrade request,
//! and when the client offers `foxglove.websocket.v1` and no `foxglove.sdk.*`, asks the server
//! for `foxglove.sdk.v1` and names the answer back `foxglove.websocket.v1`; every other request
//! passes unchanged. After the handshake it copies bytes both ways: it holds no queue of its
//! own, so a stalled viewer still only costs the server's lossy per-client outbox.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{Context, Result};

/// The classic protocol's name, as ws-protocol clients offer it.
pub const LEGACY: &str = "foxglove.websocket.v1";
/// The name the `foxglove` crate gives the same protocol.
pub const SDK_V1: &str = "foxglove.sdk.v1";
/// Longest HTTP header block accepted.
const MAX_HEADER: usize = 16 * 1024;

/// A running layer: listens on [`Self::addr`], forwards to the server.
pub struct Proxy {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    accept: Option<JoinHandle<()>>,
}

impl Proxy {
    /// Listen on `listen` (port 0: any) and forward every connection to `upstream`.
    pub fn start(listen: SocketAddr, upstream: SocketAddr) -> Result<Proxy> {
        let l = TcpListener::bind(listen).with_context(|| format!("listening on {listen}"))?;
        l.set_nonblocking(true)?;
        let addr = l.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let st = stop.clone();
        let accept = std::thread::Builder::new().name("foxglove-accept".into()).spawn(move || {
            while !st.load(Ordering::Relaxed) {
                match l.accept() {
                    Ok((c, _)) => {
                        let _ = std::thread::Builder::new().name("foxglove-conn".into()).spawn(move || {
                            let _ = serve(c, upstream);
                        });
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(20)),
                }
            }
        })?;
        Ok(Proxy { addr, stop, accept: Some(accept) })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stop accepting (open connections end when the server closes them).
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.accept.take() {
            let _ = h.join();
        }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Read an HTTP header block (through the blank line); returns it and any bytes after it.
fn read_header(s: &mut TcpStream) -> Result<(Vec<u8>, Vec<u8>)> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 2048];
    loop {
        if let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = buf.split_off(end + 4);
            return Ok((buf, rest));
        }
        anyhow::ensure!(buf.len() <= MAX_HEADER, "HTTP header over {MAX_HEADER} bytes");
        let n = s.read(&mut chunk)?;
        anyhow::ensure!(n > 0, "connection closed in the HTTP header");
        buf.extend_from_slice(&chunk[..n]);
    }
}

/// The request with its subprotocol offer rewritten when it offers only the legacy name;
/// returns (request, rewritten).
pub fn rewrite_request(req: &str) -> (String, bool) {
    let mut rewritten = false;
    let lines: Vec<String> = req
        .split("\r\n")
        .map(|line| match line.split_once(':') {
            Some((k, v)) if k.trim().eq_ignore_ascii_case("sec-websocket-protocol") => {
                let offered: Vec<&str> = v.split(',').map(str::trim).collect();
                if offered.contains(&LEGACY) && !offered.iter().any(|p| p.starts_with("foxglove.sdk.")) {
                    rewritten = true;
                    format!("{}: {SDK_V1}", k.trim())
                } else {
                    line.to_string()
                }
            }
            _ => line.to_string(),
        })
        .collect();
    (lines.join("\r\n"), rewritten)
}

/// The server's answer with the chosen subprotocol named back as the legacy one.
pub fn rewrite_response(resp: &str) -> String {
    resp.split("\r\n")
        .map(|line| match line.split_once(':') {
            Some((k, v)) if k.trim().eq_ignore_ascii_case("sec-websocket-protocol") && v.trim() == SDK_V1 => {
                format!("{}: {LEGACY}", k.trim())
            }
            _ => line.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\r\n")
}

fn serve(mut client: TcpStream, upstream: SocketAddr) -> Result<()> {
    client.set_nonblocking(false)?;
    client.set_read_timeout(Some(Duration::from_secs(10)))?;
    let (req, early) = read_header(&mut client)?;
    let (req, legacy) = rewrite_request(&String::from_utf8_lossy(&req));
    let mut server = TcpStream::connect_timeout(&upstream, Duration::from_secs(5))?;
    server.set_nodelay(true)?;
    client.set_nodelay(true)?;
    server.write_all(req.as_bytes())?;
    server.write_all(&early)?;
    server.set_read_timeout(Some(Duration::from_secs(10)))?;
    let (resp, rest) = read_header(&mut server)?;
    let resp = String::from_utf8_lossy(&resp).to_string();
    let resp = if legacy { rewrite_response(&resp) } else { resp };
    client.write_all(resp.as_bytes())?;
    client.write_all(&rest)?;
    client.set_read_timeout(None)?;
    server.set_read_timeout(None)?;
    let (mut c2, mut s2) = (client.try_clone()?, server.try_clone()?);
    let up = std::thread::Builder::new().name("foxglove-up".into()).spawn(move || {
        let _ = std::io::copy(&mut c2, &mut s2);
        let _ = s2.shutdown(Shutdown::Write);
    })?;
    let _ = std::io::copy(&mut server, &mut client);
    let _ = client.shutdown(Shutdown::Both);
    let _ = server.shutdown(Shutdown::Both);
    let _ = up.join();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_legacy_only_offer_is_rewritten() {
        let req = "GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n";
        let (r, w) = rewrite_request(req);
        assert!(w && r.contains("Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n") && r.ends_with("\r\n\r\n"), "{r}");
        let both = "GET / HTTP/1.1\r\nsec-websocket-protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n";
        assert_eq!(rewrite_request(both), (both.to_string(), false));
        let none = "GET / HTTP/1.1\r\nHost: x\r\n\r\n";
        assert_eq!(rewrite_request(none), (none.to_string(), false));
        let resp = "HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n";
        assert!(rewrite_response(resp).contains("Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n"));
    }
}
