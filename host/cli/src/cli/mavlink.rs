//! `--mavlink ENDPOINT` (on `run`, `qemu`, `record`, `attach`) and `subnav mavlink --from SOURCE
//! --to ENDPOINT`: the head's solution to an autopilot over MAVLink 2 (`subnav_mavlink`), its GPS
//! back to the head. One code path: the options here, [`start`] (or [`start_reading`] for the
//! commands that only read the head's link: `record`, `qemu`, `attach`), [`observe`] for each
//! link event and [`finish`]; `subnav mavlink --from native` is `subnav run --native --mavlink`,
//! a recording is replayed at its pace, a live head (TCP, serial) is read and its downlink
//! written on the same connection.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use subnav_mavlink::{Bridge, BridgeConfig, Endpoint, Geodetic, GpsInput, HeadClock, OdometryFrame, StampClock};
use subnav_wire::Uplink;

use super::Format;

/// The bridge's options (shared by `run --mavlink` and `subnav mavlink`).
#[derive(clap::Args, Debug, Clone)]
pub struct BridgeOpts {
    /// The vehicle's MAVLink system id (the autopilot's; our messages carry it too). Frames from
    /// other systems are counted and ignored.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..))]
    pub mavlink_system_id: u8,
    /// Our component id (197: MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY).
    #[arg(long, default_value_t = subnav_mavlink::bridge::DEFAULT_COMPONENT_ID, value_parser = clap::value_parser!(u8).range(1..))]
    pub mavlink_component_id: u8,
    /// No velocity is sent while the head's horizontal velocity 1-sigma is above this, m/s
    /// (never zeros instead).
    #[arg(long, default_value_t = 0.3, value_parser = super::args::f64_positive_upto(100.0))]
    pub mavlink_max_velocity_sigma_mps: f64,
    /// The head's NED origin `LAT,LON[,ALT_M]` (degrees), for GPS fixes and re-basing on the
    /// autopilot's origin (a simulated run knows it from its scenario).
    #[arg(long, value_name = "LAT,LON[,ALT]", value_parser = parse_origin)]
    pub mavlink_origin: Option<Geodetic>,
    /// ODOMETRY's pose frame: local-frd (what ArduPilot accepts) or local-ned (PX4: north-aligned).
    #[arg(long, value_enum, default_value_t = OdometryFrame::LocalFrd)]
    pub mavlink_odometry_frame: OdometryFrame,
    /// The clock of the time stamps (each the measurement's time of validity): companion (ours,
    /// the one we answer TIMESYNC with; PX4 maps it with its own TIMESYNC, ArduPilot's jitter
    /// correction takes any clock) or autopilot (mapped by our TIMESYNC estimate; PX4 would map
    /// it twice).
    #[arg(long, value_enum, default_value_t = StampClock::Companion)]
    pub mavlink_stamp_clock: StampClock,
    /// Messages to send (comma-separated): vision-position, vision-speed, odometry,
    /// global-vision-position. ArduSub: pick one position form (e.g. vision-position,vision-speed).
    #[arg(long, value_delimiter = ',', default_value = "vision-position,vision-speed,odometry,global-vision-position")]
    pub mavlink_messages: Vec<MessageKind>,
    /// Which of the autopilot's positions becomes fixes for the head at the surface.
    #[arg(long, value_enum, default_value_t = GpsInput::RawInt)]
    pub mavlink_gps: GpsInput,
    /// Write the bridge's summary (JSON) here at the end.
    #[arg(long)]
    pub mavlink_summary: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MessageKind {
    VisionPosition,
    VisionSpeed,
    Odometry,
    GlobalVisionPosition,
}

fn parse_origin(s: &str) -> Result<Geodetic, String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| format!("{s:?}: {e}"))?;
    let g = match v.as_slice() {
        [lat, lon] => Geodetic::checked(*lat, *lon, 0.0),
        [lat, lon, alt] => Geodetic::checked(*lat, *lon, *alt),
        _ => None,
    };
    g.ok_or_else(|| format!("{s:?}: expected LAT,LON[,ALT_M] in degrees (|lat| <= 90, |lon| <= 180, not 0,0)"))
}

/// `--mavlink ENDPOINT` on the live commands.
#[derive(clap::Args, Debug, Clone)]
pub struct MavlinkArgs {
    /// Bridge the head's solution to an autopilot over MAVLink 2 (ardupilotmega dialect):
    /// udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or serial:PATH:BAUD. See `subnav mavlink --help`.
    #[arg(long, value_name = "ENDPOINT", value_parser = subnav_mavlink::parse_endpoint)]
    pub mavlink: Option<Endpoint>,
    #[command(flatten)]
    pub bridge: BridgeOpts,
}

/// Start the bridge if an endpoint was given.
pub fn start(
    endpoint: Option<&Endpoint>,
    o: &BridgeOpts,
    scenario_origin: Option<Geodetic>,
    clock: HeadClock,
) -> Result<Option<Arc<Bridge>>> {
    let Some(e) = endpoint else { return Ok(None) };
    let mut cfg = BridgeConfig::new(e.clone());
    cfg.vehicle_system_id = o.mavlink_system_id;
    cfg.component_id = o.mavlink_component_id;
    cfg.max_velocity_sigma_mps = o.mavlink_max_velocity_sigma_mps as f32;
    cfg.head_origin = o.mavlink_origin.or(scenario_origin);
    cfg.odometry_frame = o.mavlink_odometry_frame;
    cfg.stamp_clock = o.mavlink_stamp_clock;
    let has = |k| o.mavlink_messages.contains(&k);
    cfg.send_vision_position = has(MessageKind::VisionPosition);
    cfg.send_vision_speed = has(MessageKind::VisionSpeed);
    cfg.send_odometry = has(MessageKind::Odometry);
    cfg.send_global_vision_position = has(MessageKind::GlobalVisionPosition);
    cfg.gps = o.mavlink_gps;
    let b = Bridge::start(cfg, clock).with_context(|| format!("starting the MAVLink bridge to {e}"))?;
    eprintln!("mavlink: bridging to {e} (system {}, component {})", o.mavlink_system_id, o.mavlink_component_id);
    Ok(Some(Arc::new(b)))
}

/// The bridge of a command that only reads the head's link (`record`, `qemu`, `attach`): nothing
/// goes back to the head, so the autopilot's GPS is not taken.
pub fn start_reading(args: &MavlinkArgs, origin: Option<Geodetic>) -> Result<Option<Arc<Bridge>>> {
    let bridge = start(args.mavlink.as_ref(), &args.bridge, origin, HeadClock::estimated(10.0))?;
    if let Some(b) = &bridge {
        b.set_gps_input(GpsInput::Off);
    }
    Ok(bridge)
}

/// What a live command does with each event of the head's link: the viewer and the autopilot.
pub fn observe(live: Option<&subnav_link::live_view::LiveView>, bridge: Option<&Arc<Bridge>>, e: &subnav_link::LinkEvent) {
    super::live::link_event(live, e);
    if let subnav_link::LinkEvent::Message(m) = e {
        on_uplink(bridge, m);
    }
}

/// Stop the bridge, print its summary (stderr) and write it where asked.
pub fn finish(bridge: Option<Arc<Bridge>>, o: &BridgeOpts) -> Result<()> {
    let Some(b) = bridge else { return Ok(()) };
    let s = b.finish();
    for l in s.lines() {
        eprintln!("{l}");
    }
    if let Some(p) = &o.mavlink_summary {
        subnav_link::output::write_atomic(p, serde_json::to_string_pretty(&s)?).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// The bridge's fixes as downlink frames for a simulated head's modem (polled with head time).
pub fn downlink_source(b: &Arc<Bridge>) -> subnav_sil::chips::modem::LiveSource {
    let b = b.clone();
    Box::new(move |_t_us| {
        b.take_commands()
            .into_iter()
            .filter_map(|d| {
                let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
                subnav_wire::encode(&d, &mut buf).ok().map(|f| f.to_vec())
            })
            .collect()
    })
}

/// The origin of a scenario's NED frame.
pub fn scenario_origin(sc: &subnav_sil::Scenario) -> Option<Geodetic> {
    // The head is given the origin rounded to 1e-7 deg (`board_args`): the same here.
    let r = |x: f64| (x * 1e7).round() * 1e-7;
    Geodetic::checked(r(sc.lat_deg), r(sc.lon_deg), 0.0)
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Where the head's telemetry comes from: `native` (the main job, simulated in this process
    /// at --speed, fixes delivered to it), `native:SCENARIO.json`, `file:REC.snrec` (a recording
    /// replayed at its pace; nothing goes back), `tcp:HOST:PORT` or `serial:PATH:BAUD` (a live
    /// head; its position fixes go back on the same connection).
    #[arg(long)]
    pub from: String,
    /// The autopilot: udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or serial:PATH:BAUD.
    #[arg(long, value_parser = subnav_mavlink::parse_endpoint)]
    pub to: Endpoint,
    #[command(flatten)]
    pub bridge: BridgeOpts,
    /// Simulated and replayed sources: seconds of dive per second (1 = real time, what an
    /// autopilot expects; 0.1..=1000).
    #[arg(long, default_value_t = 1.0, value_parser = super::args::f64_in(super::args::MIN_SPEED..=1e3))]
    pub speed: f64,
    /// native: the scenario's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// native: the scenario's length, s.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// native: write the truth here (CSV, as `subnav run --truth`).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// native: write the recording here (the fixes the bridge sent are in its downlink stream).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// native: the telemetry's delay from the head to the bridge, ms.
    #[arg(long, value_parser = super::args::f64_positive_upto(10_000.0))]
    pub link_delay_ms: Option<f64>,
    /// Live sources: stop after this many seconds.
    #[arg(long, value_parser = super::args::f64_positive_upto(365.0 * 86_400.0))]
    pub live_duration_s: Option<f64>,
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if let Some(rest) = args.from.strip_prefix("native") {
        let scenario = match rest {
            "" => None,
            r => Some(PathBuf::from(
                r.strip_prefix(':').with_context(|| format!("--from {}: expected native or native:SCENARIO.json", args.from))?,
            )),
        };
        let run_args = super::run::Args {
            scenario,
            seed: args.seed,
            duration_s: args.duration_s,
            no_map_fixes: false,
            report: None,
            elf: None,
            native: true,
            record: args.record,
            truth: args.truth,
            timeout_s: 1800,
            quiet: true,
            seeds: None,
            live: super::live::FoxgloveArgs::default(),
            speed: Some(args.speed),
            link_delay_ms: args.link_delay_ms,
            mavlink: MavlinkArgs { mavlink: Some(args.to), bridge: args.bridge },
        };
        return super::run::run(run_args, format);
    }
    if let Some(path) = args.from.strip_prefix("file:") {
        return replay(PathBuf::from(path), &args);
    }
    let (link, write): (Box<dyn std::io::Read + Send>, Box<dyn std::io::Write + Send>) = if let Some(a) = args.from.strip_prefix("tcp:") {
        let s = std::net::TcpStream::connect(a).with_context(|| format!("connecting to the head at tcp:{a}"))?;
        s.set_read_timeout(Some(subnav_link::source::READ_TIMEOUT))?;
        (Box::new(s.try_clone()?), Box::new(s))
    } else if let Some(rest) = args.from.strip_prefix("serial:") {
        let (path, baud) = rest.rsplit_once(':').context("--from serial:PATH:BAUD")?;
        let baud: u32 = baud.parse().with_context(|| format!("--from {}: the baud rate", args.from))?;
        let p = serialport::new(path, baud).timeout(Duration::from_millis(200)).open().with_context(|| format!("opening {path}"))?;
        (Box::new(p.try_clone()?), Box::new(p))
    } else {
        bail!("--from {}: expected native, native:SCENARIO.json, file:REC.snrec, tcp:HOST:PORT or serial:PATH:BAUD", args.from);
    };
    live(link, write, &args)
}

/// A recording replayed at its pace (host receive times); the head's clock estimated from the
/// arrivals as on a live link. Nothing goes back to a recording: GPS input is off.
fn replay(path: PathBuf, args: &Args) -> Result<ExitCode> {
    let (session, _) = super::export::load_session(&path, None)?;
    let events = subnav_link::export::events(&session);
    // The recording's arrivals, replayed at --speed: the head's clock runs --speed times ours.
    let bridge = start(Some(&args.to), &args.bridge, None, HeadClock::estimated_at(10.0, args.speed))?.context("bridge")?;
    bridge.set_gps_input(GpsInput::Off);
    let Some(&(t0, _)) = events.first() else { bail!("{}: no telemetry", path.display()) };
    let started = Instant::now();
    for (t, ev) in &events {
        let due = Duration::from_secs_f64(t.saturating_sub(t0) as f64 * 1e-6 / args.speed);
        if let Some(wait) = due.checked_sub(started.elapsed()) {
            std::thread::sleep(wait);
        }
        if let subnav_link::export::Event::Msg(m) = ev {
            bridge.on_uplink(m);
        }
    }
    finish(Some(bridge), &args.bridge)?;
    Ok(ExitCode::SUCCESS)
}

/// A live head: uplink decoded and bridged, the bridge's fixes written back as downlink frames.
fn live(mut link: Box<dyn std::io::Read + Send>, mut write: Box<dyn std::io::Write + Send>, args: &Args) -> Result<ExitCode> {
    let bridge = start(Some(&args.to), &args.bridge, None, HeadClock::estimated(10.0))?.context("bridge")?;
    let mut dec = subnav_link::UplinkDecoder::new();
    let started = Instant::now();
    let mut write_error = None;
    let r = subnav_link::source::pump(&mut *link, None, |bytes| {
        dec.feed(bytes, |e| {
            if let subnav_link::LinkEvent::Message(m) = e {
                bridge.on_uplink(&m);
            }
        });
        for d in bridge.take_commands() {
            let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
            if let Ok(f) = subnav_wire::encode(&d, &mut buf)
                && let Err(e) = write.write_all(f)
            {
                write_error = Some(e);
            }
        }
        args.live_duration_s.is_none_or(|d| started.elapsed().as_secs_f64() < d)
    });
    finish(Some(bridge), &args.bridge)?;
    if let Some(e) = write_error {
        eprintln!("mavlink: writing fixes to the head failed: {e}");
    }
    r?;
    Ok(ExitCode::SUCCESS)
}

/// Forward an uplink message to the bridge (the live commands' observers).
pub fn on_uplink(bridge: Option<&Arc<Bridge>>, m: &Uplink) {
    if let Some(b) = bridge {
        b.on_uplink(m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use subnav_wire::{NavMode, NavSolution};

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        mavlink: MavlinkArgs,
    }

    /// The path `record`, `qemu` and `attach` share, from the head's bytes to the autopilot:
    /// the options parsed as on those commands, [`start_reading`], the link decoded and each event
    /// given to [`observe`], as `attach` does with what it reads over RTT.
    #[test]
    fn a_decoded_link_event_reaches_the_autopilot_through_the_shared_path() {
        let autopilot = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        autopilot.set_read_timeout(Some(Duration::from_millis(200))).unwrap();
        let port = autopilot.local_addr().unwrap().port();
        let to = format!("udpout:127.0.0.1:{port}");
        let cli = Cli::try_parse_from(["attach", "--mavlink", to.as_str(), "--mavlink-messages", "vision-position"]).unwrap();
        let bridge = start_reading(&cli.mavlink, None).unwrap().expect("a bridge");
        let nav = NavSolution {
            t_us: 20_000_000,
            mode: NavMode::Aided,
            pos_ned_m: [12.0, -3.0, 4.0],
            vel_ned_mps: [0.5, 0.0, 0.0],
            att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
            sigma_pos_m: [0.5, 0.5, 0.05],
            sigma_vel_mps: [0.02; 3],
            sigma_att_rad: [0.01; 3],
            cov_ne_m2: 0.0,
        };
        let mut buf = [0u8; subnav_wire::MAX_UPLINK_FRAME];
        let frame = subnav_wire::encode(&Uplink::Nav(nav), &mut buf).unwrap().to_vec();
        let mut dec = subnav_link::UplinkDecoder::new();
        let mut events = 0;
        dec.feed(&frame, |e| {
            events += 1;
            observe(None, Some(&bridge), &e)
        });
        assert_eq!(events, 1);
        // The autopilot receives a MAVLink 2 VISION_POSITION_ESTIMATE (id 102) with the position.
        let started = Instant::now();
        let mut got = None;
        let mut b = [0u8; 512];
        while got.is_none() && started.elapsed() < Duration::from_secs(5) {
            let Ok(n) = autopilot.recv(&mut b) else { continue };
            let f = &b[..n];
            if n > 12 && f[0] == 0xFD && u32::from_le_bytes([f[7], f[8], f[9], 0]) == 102 {
                // Payload: usec (u64), then x, y, z (f32).
                let x = f32::from_le_bytes(f[18..22].try_into().unwrap());
                got = Some(x);
            }
        }
        assert_eq!(got, Some(12.0), "no VISION_POSITION_ESTIMATE at the autopilot");
        let s = bridge.finish();
        assert_eq!(s.sent.get("VISION_POSITION_ESTIMATE"), Some(&1), "{s:?}");
    }
}
