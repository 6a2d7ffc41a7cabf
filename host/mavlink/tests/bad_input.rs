//! The bridge under bad input from the autopilot's side (a UDP peer written here with the
//! `mavlink` crate): random datagrams, frames of another system, an origin far away or out of
//! range, GPS without a fix, without accuracy, from the future, and a link that dies. Every
//! one is counted by reason, none reaches the head, and the bridge keeps sending.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use mavlink::MavHeader;
use mavlink::dialects::ardupilotmega::{self as mav, MavMessage};
use subnav_mavlink::bridge::companion_now_us;
use subnav_mavlink::scan::{Scanner, encode_v2};
use subnav_mavlink::{Bridge, BridgeConfig, Endpoint, Geodetic, HeadClock};
use subnav_wire::{NavMode, NavSolution, Uplink};

fn nav(t_us: u64) -> Uplink {
    Uplink::Nav(NavSolution {
        t_us,
        mode: NavMode::Aided,
        pos_ned_m: [1.0, 2.0, 0.1],
        vel_ned_mps: [0.5, 0.0, 0.0],
        att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
        sigma_pos_m: [1.0, 1.0, 0.02],
        sigma_vel_mps: [0.01, 0.01, 0.01],
        sigma_att_rad: [0.01, 0.01, 0.01],
        cov_ne_m2: 0.0,
    })
}

fn gps(t_us: u64, lat_e7: i32, fix: mav::GpsFixType, eph: u16, h_acc: u32) -> MavMessage {
    MavMessage::GPS_RAW_INT(mav::GPS_RAW_INT_DATA {
        time_usec: t_us,
        fix_type: fix,
        lat: lat_e7,
        lon: -20_000_000,
        eph,
        h_acc,
        satellites_visible: 10,
        ..Default::default()
    })
}

#[test]
#[allow(deprecated)]
fn bad_input_is_counted_never_fused_and_the_bridge_keeps_serving() {
    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    peer.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
    let mut cfg = BridgeConfig::new(Endpoint::UdpOut(peer.local_addr().unwrap().to_string()));
    cfg.head_origin = Geodetic::checked(44.0, -2.0, 0.0);
    cfg.link_timeout_s = 0.5;
    let start = companion_now_us();
    let bridge = Bridge::start(cfg, HeadClock::Known { start_us: start, speed: 1.0 }).unwrap();
    let ap_offset_us: i64 = -5_000_000; // the autopilot's clock: ours - 5 s
    let ap_now = || (companion_now_us() + ap_offset_us) as u64;
    let h = |sys: u32| MavHeader { system_id: sys, component_id: 1, sequence: 0 };
    let mut scanner = Scanner::default();
    let mut to: Option<std::net::SocketAddr> = None;
    let mut vpe_after_junk = 0;
    let mut junk_sent = false;
    let mut x = 0x9E37_79B9u32;
    let t0 = Instant::now();
    let mut next_nav = Duration::ZERO;
    while t0.elapsed() < Duration::from_millis(2500) {
        let el = t0.elapsed();
        if el >= next_nav {
            next_nav += Duration::from_millis(100);
            bridge.on_uplink(&nav((companion_now_us() - start) as u64));
        }
        let mut buf = [0u8; 2048];
        if let Ok((n, from)) = peer.recv_from(&mut buf) {
            to = Some(from);
            scanner.push(&buf[..n]);
            while let Some((_, m)) = scanner.next_frame() {
                match m {
                    // Answer TIMESYNC while the link lives (the first 1.2 s).
                    MavMessage::TIMESYNC(t) if t.tc1 == 0 && el < Duration::from_millis(1200) => {
                        let r = mav::TIMESYNC_DATA { tc1: ap_now() as i64 * 1000, ts1: t.ts1, target_system: 1, target_component: 197 };
                        peer.send_to(&encode_v2(h(1), &MavMessage::TIMESYNC(r)), from).unwrap();
                    }
                    MavMessage::VISION_POSITION_ESTIMATE(_) if junk_sent => vpe_after_junk += 1,
                    _ => {}
                }
            }
            scanner.end_of_datagram();
        }
        let Some(to) = to else { continue };
        if el < Duration::from_millis(1000) && el.as_millis() % 200 < 10 {
            let hb = mav::HEARTBEAT_DATA { autopilot: mav::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, ..Default::default() };
            peer.send_to(&encode_v2(h(1), &MavMessage::HEARTBEAT(hb)), to).unwrap();
        }
        if !junk_sent && el > Duration::from_millis(1300) {
            junk_sent = true;
            let now = ap_now();
            let fix3 = mav::GpsFixType::GPS_FIX_TYPE_3D_FIX;
            let bad: Vec<(u32, MavMessage)> = vec![
                // Another system's GPS and TIMESYNC reply.
                (42, gps(now, 440_000_000, fix3, 100, 1000)),
                (42, MavMessage::TIMESYNC(mav::TIMESYNC_DATA { tc1: 1, ts1: 2, target_system: 1, target_component: 197 })),
                // Origins: 100 km away, out of range.
                (
                    1,
                    MavMessage::SET_GPS_GLOBAL_ORIGIN(mav::SET_GPS_GLOBAL_ORIGIN_DATA {
                        latitude: 449_000_000,
                        longitude: -20_000_000,
                        target_system: 1,
                        ..Default::default()
                    }),
                ),
                (
                    1,
                    MavMessage::GPS_GLOBAL_ORIGIN(mav::GPS_GLOBAL_ORIGIN_DATA {
                        latitude: 910_000_000,
                        longitude: 0,
                        ..Default::default()
                    }),
                ),
                // GPS: no fix, no accuracy, from the future, too old, on the equator (far away).
                (1, gps(now, 440_000_000, mav::GpsFixType::GPS_FIX_TYPE_NO_FIX, 100, 1000)),
                (1, gps(now, 440_000_000, fix3, u16::MAX, 0)),
                (1, gps(now + 5_000_000, 440_000_000, fix3, 100, 1000)),
                (1, gps(now - 10_000_000, 440_000_000, fix3, 100, 1000)),
                (1, gps(now, 0, fix3, 100, 1000)),
            ];
            for (sys, m) in &bad {
                peer.send_to(&encode_v2(h(*sys), m), to).unwrap();
            }
            // 100 random datagrams (more could overflow the socket's buffer), many with start bytes.
            for _ in 0..100 {
                let d: Vec<u8> = (0..64)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 17;
                        x ^= x << 5;
                        if x.is_multiple_of(5) { 0xFD } else { x as u8 }
                    })
                    .collect();
                peer.send_to(&d, to).unwrap();
            }
            std::thread::sleep(Duration::from_millis(30));
            // And one good fix: the head (at 0.1 m depth) gets it.
            peer.send_to(&encode_v2(h(1), &gps(now - 100_000, 440_000_100, fix3, 100, 1500)), to).unwrap();
        }
    }
    let s = bridge.finish();
    let refused = |k: &str| s.gps_refused.get(k).copied().unwrap_or(0);
    assert!(s.timesync.converged(), "{s:?}");
    assert!((s.timesync.offset_us.unwrap() - ap_offset_us).abs() < 2_000, "{:?}", s.timesync.offset_us);
    assert_eq!(s.foreign_system, 2, "{s:?}");
    assert_eq!(s.origin_refused.get("far from the head's origin"), Some(&1), "{:?}", s.origin_refused);
    assert_eq!(s.origin_refused.get("bad coordinates"), Some(&1), "{:?}", s.origin_refused);
    assert!(s.origin.is_none() && s.origin_changes == 0 && s.reset_counter == 0);
    for k in ["no 3D fix", "no accuracy", "from the future", "too old", "far from the head's origin"] {
        assert_eq!(refused(k), 1, "{k}: {:?}", s.gps_refused);
    }
    assert_eq!(s.gps_sent, 1, "{s:?}");
    let cmds = bridge.take_commands();
    assert_eq!(cmds.len(), 1);
    match cmds[0].command {
        subnav_wire::Command::PositionFix { t_us, pos_ned_m, cov_ned_m2 } => {
            // 100e-7 deg north of the origin is 1.11 m; valid 0.1 s before it was sent.
            assert!((pos_ned_m[0] - 1.11).abs() < 0.01 && pos_ned_m[1].abs() < 0.01, "{pos_ned_m:?}");
            assert!((cov_ned_m2[0] - 2.25).abs() < 1e-3);
            let sent_head_us = 1_300_000u64;
            assert!(t_us > sent_head_us - 150_000 && t_us < sent_head_us + 200_000, "{t_us}");
        }
        ref c => panic!("{c:?}"),
    }
    assert!(s.scan.skipped_bytes > 1000 && s.scan.bad_crc + s.scan.malformed + s.scan.unknown_message > 0, "{:?}", s.scan);
    assert!(s.link_lost >= 1 && !s.link_alive, "{s:?}");
    assert!(vpe_after_junk >= 8, "{vpe_after_junk} poses after the junk");
}
