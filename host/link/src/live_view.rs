//! Watching a dive live in Foxglove: a Foxglove WebSocket server (the official `foxglove` crate;
//! clients offering `foxglove.websocket.v1` (ws-protocol, Lichtblick) or the crate's
//! `foxglove.sdk.v1`/`v1.1` (the Foxglove app) both connect, through [`crate::ws_subprotocol`]) that publishes a dive's events on the topics of
//! [`crate::export::topics`], the same topics and schemas as the MCAP export.
//!
//! The server never slows the link. The decoding or simulating thread hands each event to
//! [`LiveView::send`], which only tries to put it in a bounded queue: when the queue is full the
//! event is dropped and counted ([`LiveSummary::dropped_events`]), it never waits. A publisher
//! thread turns events into JSON messages ([`Projector`]) and logs them to the server, whose
//! per-client outbox is lossy too (the `foxglove` crate drops a slow client's oldest messages,
//! it does not count them for us). So a slow, stalled or absent client costs messages, never
//! time: the recording and the navigation do not depend on it.
//!
//! Channels are created when their first message comes. A client that subscribes to a channel
//! is sent that channel's latest message at once (for `/subnav/trajectory`: the whole trajectory
//! so far), so a viewer that joins during a dive sees the boot message, the map and the path.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, anyhow};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelId, Context, PartialMetadata, RawChannel, Schema, SinkId, WebSocketServer, WebSocketServerHandle};
use serde::Serialize;
use subnav_wire::Uplink;

use crate::defmt_log::LogLine;
use crate::export::TimeBase;
use crate::export::topics::{self, MapClosure, MapNode, Msg, Projector, schema_of};

/// Default address of `--foxglove`.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Events queued between the link and the publisher before new ones are dropped.
pub const DEFAULT_QUEUE: usize = 16_384;

/// Messages the server queues per client before it drops the oldest.
pub const CLIENT_BACKLOG: usize = 8192;

/// Longest wait for the clients' connections to close at the end of a session.
pub const SHUTDOWN_BOUND: Duration = Duration::from_secs(2);

/// One event of a dive, as the link or the simulation sees it.
#[derive(Debug, Clone)]
pub enum LiveEvent {
    Uplink {
        t_host_us: u64,
        msg: Uplink,
    },
    Log {
        t_host_us: u64,
        line: LogLine,
    },
    Corrupt {
        t_host_us: u64,
        error: String,
    },
    /// The simulator's truth at sensor time `t_sensor_us`.
    Truth {
        t_host_us: u64,
        t_sensor_us: u64,
        pos_ned_m: [f64; 3],
        yaw_rad: f64,
    },
    /// The whole map as it is now.
    Map {
        t_host_us: u64,
        nodes: Vec<MapNode>,
        closures: Vec<MapClosure>,
    },
}

/// What a live session did, reported at its end.
#[derive(Debug, Clone, Default, Serialize, PartialEq, Eq)]
pub struct LiveSummary {
    pub address: String,
    /// Events handed to the server, and those dropped because its queue was full.
    pub events: u64,
    pub dropped_events: u64,
    /// Messages published (to every subscribed client), and latest-message replays to clients
    /// that subscribed during the session.
    pub messages: u64,
    pub replays: u64,
    pub topics: Vec<String>,
    pub clients: u64,
}

impl LiveSummary {
    /// One line for the end of a run.
    pub fn line(&self) -> String {
        format!(
            "foxglove: {} clients on ws://{}; {} events, {} dropped (queue full), {} messages on {} topics",
            self.clients,
            self.address,
            self.events,
            self.dropped_events,
            self.messages,
            self.topics.len()
        )
    }
}

/// Subscriptions seen by the server (from its listener thread).
#[derive(Default)]
struct Shared {
    replay_requests: Mutex<Vec<(SinkId, ChannelId)>>,
    /// Clients connected so far, and the time of the latest subscription.
    state: Mutex<(u64, Option<Instant>)>,
    changed: Condvar,
}

struct Listener(Arc<Shared>);

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        if let Some(sink) = client.sink_id() {
            self.0.replay_requests.lock().unwrap_or_else(|e| e.into_inner()).push((sink, channel.id()));
        }
        self.0.state.lock().unwrap_or_else(|e| e.into_inner()).1 = Some(Instant::now());
        self.0.changed.notify_all();
    }
    fn on_client_connect(&self) {
        self.0.state.lock().unwrap_or_else(|e| e.into_inner()).0 += 1;
        self.0.changed.notify_all();
    }
}

enum Cmd {
    Event(Box<LiveEvent>),
    /// Everything before it is published; then keep answering new subscriptions until none
    /// came for a quarter of the linger (at most the linger).
    Stop(Duration),
}

/// A running live server. Cheap to [`send`](Self::send) to from the link's thread.
pub struct LiveView {
    addr: SocketAddr,
    tx: SyncSender<Cmd>,
    events: AtomicU64,
    dropped: AtomicU64,
    shared: Arc<Shared>,
    publisher: Option<JoinHandle<(u64, u64, Vec<String>)>>,
    server: Option<WebSocketServerHandle>,
    /// The listening side: `foxglove.websocket.v1` and the SDK's names ([`crate::ws_subprotocol`]).
    proxy: Option<crate::ws_subprotocol::Proxy>,
}

/// Parse `--foxglove`'s address (`HOST:PORT`).
pub fn parse_addr(s: &str) -> Result<SocketAddr, String> {
    use std::net::ToSocketAddrs;
    s.to_socket_addrs()
        .map_err(|e| format!("{s:?} is not an address (HOST:PORT, e.g. {DEFAULT_ADDR}): {e}"))?
        .next()
        .ok_or_else(|| format!("{s:?} resolves to no address"))
}

impl LiveView {
    /// Start the server on `addr` (port 0: any free port; see [`Self::addr`]). Messages are
    /// stamped with `time`.
    pub fn start(addr: SocketAddr, time: TimeBase, queue: usize) -> Result<LiveView> {
        let ctx = Context::new();
        let shared = Arc::new(Shared::default());
        let server = WebSocketServer::new()
            .context(&ctx)
            .name(format!("subnav {}", env!("CARGO_PKG_VERSION")))
            // The server itself listens on the loopback; clients come through the subprotocol
            // layer on `addr`.
            .bind("127.0.0.1", 0)
            .listener(Arc::new(Listener(shared.clone())))
            .message_backlog_size(CLIENT_BACKLOG)
            .start_blocking()
            .map_err(|e| anyhow!("starting the Foxglove server on {addr}: {e}"))?;
        let inner = SocketAddr::new(std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST), server.port());
        let proxy = crate::ws_subprotocol::Proxy::start(addr, inner).with_context(|| format!("starting the Foxglove server on {addr}"))?;
        let bound = proxy.addr();
        let (tx, rx) = sync_channel(queue.max(1));
        let sh = shared.clone();
        let publisher = std::thread::Builder::new()
            .name("foxglove".into())
            .spawn(move || publish(ctx, rx, sh, time))
            .context("starting the Foxglove publisher thread")?;
        Ok(LiveView {
            addr: bound,
            tx,
            events: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            shared,
            publisher: Some(publisher),
            server: Some(server),
            proxy: Some(proxy),
        })
    }

    /// The address the server listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Hand an event to the server; never blocks (a full queue drops it, counted).
    pub fn send(&self, ev: LiveEvent) {
        self.events.fetch_add(1, Ordering::Relaxed);
        match self.tx.try_send(Cmd::Event(Box::new(ev))) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Convenience: an uplink message.
    pub fn uplink(&self, t_host_us: u64, msg: &Uplink) {
        self.send(LiveEvent::Uplink { t_host_us, msg: msg.clone() });
    }

    /// Wait until a client has connected (up to `timeout`); true if one did.
    pub fn wait_for_client(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut s = self.shared.state.lock().unwrap_or_else(|e| e.into_inner());
        while s.0 == 0 {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            s = self.shared.changed.wait_timeout(s, left).map(|(g, _)| g).unwrap_or_else(|e| e.into_inner().0);
        }
        true
    }

    /// Clients connected so far.
    pub fn clients(&self) -> u64 {
        self.shared.state.lock().unwrap_or_else(|e| e.into_inner()).0
    }

    /// Publish what is queued, give connected clients up to `linger` to subscribe to the last
    /// channels and receive the last messages, then stop the server.
    pub fn finish(mut self, linger: Duration) -> LiveSummary {
        let linger = if self.clients() > 0 { linger } else { Duration::ZERO };
        self.stop(linger)
    }

    fn stop(&mut self, linger: Duration) -> LiveSummary {
        // The queue may be full: the stop must get through, so this one waits (for the
        // publisher, which never waits on anything).
        let _ = self.tx.send(Cmd::Stop(linger));
        let (messages, replays, topics) = self.publisher.take().and_then(|h| h.join().ok()).unwrap_or_default();
        if let Some(s) = self.server.take() {
            if !linger.is_zero() {
                // The clients' outboxes drain while the server still runs.
                std::thread::sleep(Duration::from_millis(200).min(linger));
            }
            // A graceful close, bounded: a client that stopped reading cannot complete one, and
            // when the bound passes, dropping the shutdown handle aborts its task.
            let shutdown = s.stop();
            if let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_time().build() {
                let _ = rt.block_on(async { tokio::time::timeout(SHUTDOWN_BOUND, shutdown.wait()).await });
            }
        }
        if let Some(mut p) = self.proxy.take() {
            p.stop();
        }
        LiveSummary {
            address: self.addr.to_string(),
            events: self.events.load(Ordering::Relaxed),
            dropped_events: self.dropped.load(Ordering::Relaxed),
            messages,
            replays,
            topics,
            clients: self.clients(),
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if self.publisher.is_some() {
            let _ = self.stop(Duration::ZERO);
        }
    }
}

struct Published {
    channel: Arc<RawChannel>,
    latest: Option<(u64, Vec<u8>)>,
}

/// The publisher thread: events -> messages -> channels; latest-message replays to new
/// subscribers. Returns (messages, replays, topics).
fn publish(ctx: Arc<Context>, rx: Receiver<Cmd>, shared: Arc<Shared>, time: TimeBase) -> (u64, u64, Vec<String>) {
    let mut projector = Projector::new(time);
    let mut channels: HashMap<String, Published> = HashMap::new();
    let mut by_id: HashMap<ChannelId, String> = HashMap::new();
    let (mut messages, mut replays) = (0u64, 0u64);
    let mut out: Vec<Msg> = Vec::new();
    let mut stopping: Option<(Instant, Duration)> = None;
    loop {
        let cmd = match stopping {
            None => rx.recv_timeout(Duration::from_millis(20)),
            Some(_) => {
                std::thread::sleep(Duration::from_millis(20));
                Err(RecvTimeoutError::Timeout)
            }
        };
        out.clear();
        let stop = match cmd {
            Ok(Cmd::Event(ev)) => {
                match *ev {
                    LiveEvent::Uplink { t_host_us, msg } => projector.uplink(t_host_us, &msg, &mut out),
                    LiveEvent::Log { t_host_us, line } => projector.log(t_host_us, &line, &mut out),
                    LiveEvent::Corrupt { t_host_us, error } => projector.corrupt(t_host_us, &error, &mut out),
                    LiveEvent::Truth { t_host_us, t_sensor_us, pos_ned_m, yaw_rad } => {
                        projector.truth(t_host_us, t_sensor_us, pos_ned_m, yaw_rad, &mut out)
                    }
                    LiveEvent::Map { t_host_us, nodes, closures } => projector.map(t_host_us, &nodes, &closures, &mut out),
                }
                false
            }
            Ok(Cmd::Stop(linger)) => {
                stopping = Some((Instant::now(), linger));
                false
            }
            Err(RecvTimeoutError::Disconnected) => true,
            Err(RecvTimeoutError::Timeout) => false,
        };
        for m in &out {
            let Ok(bytes) = serde_json::to_vec(&m.json) else { continue };
            let p = match channels.get_mut(&m.topic) {
                Some(p) => p,
                None => {
                    let Some((name, schema)) = schema_of(&m.topic) else { continue };
                    let Ok(data) = serde_json::to_vec(&schema) else { continue };
                    let built = ctx
                        .channel_builder(m.topic.clone())
                        .message_encoding("json")
                        .schema(Schema::new(name, "jsonschema", data))
                        .build_raw();
                    let Ok(channel) = built else { continue };
                    by_id.insert(channel.id(), m.topic.clone());
                    channels.entry(m.topic.clone()).or_insert(Published { channel, latest: None })
                }
            };
            let log_time = m.t_us.saturating_mul(1000);
            p.channel.log_with_meta(&bytes, PartialMetadata { log_time: Some(log_time) });
            p.latest = Some((log_time, bytes));
            messages += 1;
        }
        // New subscribers get the channel's latest message (the whole trajectory for the path).
        let requests: Vec<(SinkId, ChannelId)> = std::mem::take(&mut *shared.replay_requests.lock().unwrap_or_else(|e| e.into_inner()));
        for (sink, id) in requests {
            let Some(p) = by_id.get(&id).and_then(|t| channels.get(t)) else { continue };
            let latest = if p.channel.topic() == topics::TRAJECTORY {
                projector.trajectory_history().and_then(|m| Some((m.t_us.saturating_mul(1000), serde_json::to_vec(&m.json).ok()?)))
            } else {
                p.latest.clone()
            };
            if let Some((log_time, bytes)) = latest {
                p.channel.log_with_meta_to_sink(&bytes, PartialMetadata { log_time: Some(log_time) }, Some(sink));
                replays += 1;
            }
        }
        if let Some((since, linger)) = stopping {
            let last = shared.state.lock().unwrap_or_else(|e| e.into_inner()).1;
            let quiet = last.is_none_or(|t| t.elapsed() >= linger / 4) && since.elapsed() >= linger / 4;
            if quiet || since.elapsed() >= linger {
                break;
            }
        }
        if stop {
            break;
        }
    }
    let mut topics: Vec<String> = channels.into_keys().collect();
    topics.sort();
    (messages, replays, topics)
}

/// Serve a decoded recording at `speed` times its own pace (host receive times; 1 = as
/// recorded); returns the events sent. `events` in host-time order ([`crate::export::events`]).
pub fn serve_events(live: &LiveView, events: &[(u64, crate::export::Event<'_>)], speed: f64) -> u64 {
    let Some(&(t0, _)) = events.first() else { return 0 };
    let started = Instant::now();
    let mut sent = 0;
    for (t, ev) in events {
        let due = Duration::from_secs_f64(t.saturating_sub(t0) as f64 * 1e-6 / speed.max(1e-9));
        if let Some(wait) = due.checked_sub(started.elapsed()) {
            std::thread::sleep(wait);
        }
        let t_host_us = *t;
        live.send(match ev {
            crate::export::Event::Msg(m) => LiveEvent::Uplink { t_host_us, msg: (*m).clone() },
            crate::export::Event::Log(l) => LiveEvent::Log { t_host_us, line: (*l).clone() },
            crate::export::Event::Corrupt(c) => LiveEvent::Corrupt { t_host_us, error: c.to_string() },
        });
        sent += 1;
    }
    sent
}
