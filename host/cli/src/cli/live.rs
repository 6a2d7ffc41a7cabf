//! `--foxglove [ADDR]`, shared by the commands with a live link or a live simulation (`qemu`,
//! `run`, `record`, `attach`) and by `export --foxglove` (a recording served at `--speed`): the
//! server of [`subnav_link::live_view`], started before the link and summarised at the end.

use std::net::SocketAddr;
use std::time::Duration;

use anyhow::Result;
use subnav_link::export::TimeBase;
use subnav_link::export::topics::{MapClosure, MapNode};
use subnav_link::live_view::{self, DEFAULT_QUEUE, LiveEvent, LiveView};
use subnav_sil::Scenario;
use subnav_sil::map_loop::MapLoop;
use subnav_wire::Uplink;

/// The layout file to open in Foxglove (in the repository).
pub const LAYOUT: &str = "docs/foxglove/subnav-layout.json";

#[derive(clap::Args, Debug, Clone, Default)]
pub struct FoxgloveArgs {
    /// Serve the dive live to Foxglove (WebSocket; subprotocol `foxglove.websocket.v1` or
    /// `foxglove.sdk.v1`) on ADDR (default
    /// 127.0.0.1:8765); in Foxglove: "Open connection", `ws://ADDR`, and the layout
    /// docs/foxglove/subnav-layout.json. Slow or absent viewers lose messages, never slow the run.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = live_view::DEFAULT_ADDR, value_parser = live_view::parse_addr)]
    pub foxglove: Option<SocketAddr>,
    /// With --foxglove: wait up to this many seconds for a viewer to connect before starting.
    #[arg(long, value_name = "S", requires = "foxglove", value_parser = parse_wait)]
    pub foxglove_wait_s: Option<f64>,
}

fn parse_wait(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=86_400.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?}: seconds in [0, 86400]")),
    }
}

/// Start the server if `--foxglove` was given (and wait for a viewer with `--foxglove-wait-s`).
pub fn start(args: &FoxgloveArgs, time: TimeBase) -> Result<Option<LiveView>> {
    let Some(addr) = args.foxglove else { return Ok(None) };
    let live = LiveView::start(addr, time, DEFAULT_QUEUE)?;
    eprintln!("foxglove: serving on ws://{} (Foxglove: Open connection; layout {LAYOUT})", live.addr());
    if let Some(s) = args.foxglove_wait_s {
        if live.wait_for_client(Duration::from_secs_f64(s)) {
            eprintln!("foxglove: a viewer connected");
        } else {
            eprintln!("foxglove: no viewer within {s} s; starting anyway");
        }
    }
    Ok(Some(live))
}

/// Stop the server and print its summary (stderr).
pub fn finish(live: Option<LiveView>) {
    if let Some(l) = live {
        eprintln!("{}", l.finish(Duration::from_secs(2)).line());
    }
}

/// Feeds a simulated dive to the server: every uplink message, the truth at each navigation
/// solution, and the map once per second of dive when it changed.
pub struct SimFeed<'a> {
    live: &'a LiveView,
    traj: subnav_base::trajectory::Trajectory,
    last_map: std::cell::Cell<(u64, (u64, u64, usize))>,
}

impl<'a> SimFeed<'a> {
    pub fn new(live: &'a LiveView, sc: &Scenario) -> Self {
        Self { live, traj: sc.trajectory(), last_map: std::cell::Cell::new((0, (0, 0, 0))) }
    }

    /// A message at host time `t_host_us`.
    pub fn on_uplink(&self, t_host_us: u64, m: &Uplink, map: Option<&MapLoop>) {
        self.live.uplink(t_host_us, m);
        let Uplink::Nav(n) = m else { return };
        let tr = self.traj.at(n.t_us as f64 * 1e-6);
        let p = tr.pos_ned_m;
        self.live.send(LiveEvent::Truth { t_host_us, t_sensor_us: n.t_us, pos_ned_m: [p.x, p.y, p.z], yaw_rad: tr.yaw_rad });
        let Some(map) = map else { return };
        let (t_last, counts) = self.last_map.get();
        if n.t_us < t_last.saturating_add(1_000_000) {
            return;
        }
        let now = map.counts();
        if now == counts {
            return;
        }
        self.last_map.set((n.t_us, now));
        let r = map.report();
        let accepted: std::collections::BTreeSet<u64> = r.fix_results.iter().filter(|(_, ok)| *ok).map(|(t, _)| *t).collect();
        let nodes: Vec<MapNode> = r.nodes.iter().map(|n| MapNode { id: n.id, pos_ne_m: n.pos_ned_m }).collect();
        let closures = r
            .closures
            .iter()
            .filter(|c| accepted.contains(&c.t_us))
            .filter_map(|c| {
                let node = r.nodes.iter().find(|n| n.id == c.node)?;
                Some(MapClosure { t_us: c.t_us, node_ne_m: node.pos_ned_m, estimate_ne_m: c.vehicle_ne_m })
            })
            .collect();
        self.live.send(LiveEvent::Map { t_host_us, nodes, closures });
    }
}

/// A link event (decoded message or corrupt frame) received now.
pub fn link_event(live: Option<&LiveView>, e: &subnav_link::LinkEvent) {
    let Some(live) = live else { return };
    let t_host_us = subnav_link::record::now_unix_us();
    match e {
        subnav_link::LinkEvent::Message(m) => live.uplink(t_host_us, m),
        subnav_link::LinkEvent::Corrupt(err) => live.send(LiveEvent::Corrupt { t_host_us, error: err.to_string() }),
        subnav_link::LinkEvent::Incompatible(_) => {}
    }
}

/// A decoded defmt log line received now.
pub fn log_line(live: Option<&LiveView>, l: &subnav_link::defmt_log::LogLine) {
    if let Some(live) = live {
        live.send(LiveEvent::Log { t_host_us: subnav_link::record::now_unix_us(), line: l.clone() });
    }
}
