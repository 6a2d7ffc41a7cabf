//! Printing decoded telemetry and logs as human text or JSON lines (shared by `decode`, `qemu`).

use serde_json::json;
use subnav_wire::{RawSample, Uplink};

use super::Format;
use subnav_link::defmt_log::LogLine;
use subnav_link::uplink::{LinkEvent, LinkStats, describe};

fn secs(t_us: u64) -> String {
    format!("{:>10.6}", t_us as f64 * 1e-6)
}

fn v3(v: &[f32; 3]) -> String {
    format!("[{:.3}, {:.3}, {:.3}]", v[0], v[1], v[2])
}

/// One line of human-readable text for a message.
pub fn text(m: &Uplink) -> String {
    match m {
        Uplink::Boot(b) => format!(
            "boot    t={} board={:?} firmware={}.{}.{} protocol={} schema={:#018x} reset={:?} store={:?} stored: config={} imu={} dvl={} polarization_units={:#06b}",
            secs(b.t_us),
            b.board,
            b.firmware_version[0],
            b.firmware_version[1],
            b.firmware_version[2],
            b.protocol_version,
            b.schema_fingerprint,
            b.reset_cause,
            b.calibration.store,
            b.calibration.config_stored,
            b.calibration.imu_stored,
            b.calibration.dvl_stored,
            b.calibration.polarization_units_stored
        ),
        Uplink::Nav(n) => format!(
            "nav     t={} mode={:?} pos_ned_m={} vel_ned_mps={} sigma_pos_m={}",
            secs(n.t_us),
            n.mode,
            v3(&n.pos_ned_m),
            v3(&n.vel_ned_mps),
            v3(&n.sigma_pos_m)
        ),
        Uplink::Raw(RawSample::Imu(s)) => {
            format!("imu     t={} gyro_radps={} accel_mps2={}", secs(s.t_us), v3(&s.gyro_radps), v3(&s.accel_mps2))
        }
        Uplink::Raw(RawSample::Polarization(s)) => format!("polar   t={} unit={} counts={:?}", secs(s.t_us), s.unit, s.counts),
        Uplink::Raw(RawSample::Depth(s)) => {
            format!("depth   t={} pressure_pa={:.1} depth_m={:.3} temp_c={:.2}", secs(s.t_us), s.pressure_pa, s.depth_m, s.temp_c)
        }
        Uplink::Raw(RawSample::Dvl(d)) => format!(
            "dvl     t={} rx={} {:?} valid={} vel_dvl_mps={} fom_mps={:.3} altitude_m={:.2}",
            secs(d.t_us),
            secs(d.rx_us),
            d.tracking,
            d.valid,
            v3(&d.vel_dvl_mps),
            d.fom_mps,
            d.altitude_m
        ),
        Uplink::Trigger(t) => format!("camera  t={} frame={}", secs(t.t_us), t.frame),
        Uplink::Compass(c) => format!(
            "compass t={} heading_deg={} sigma_deg={:.3} units={} no_fix_reason={}",
            secs(c.t_us),
            c.heading_rad.map(|h| format!("{:.3}", h.to_degrees())).unwrap_or_else(|| "none".into()),
            c.sigma_heading_rad.to_degrees(),
            c.units_used,
            c.no_fix_reason
        ),
        Uplink::Health(h) => format!(
            "health  t={} cpu={:.1}% lambda={:.3} imu_q_scale={:.1} {} pd_repairs={} cov_unrepairable={} gate_rejects={} nonfinite={} late_fused={} late_refused={} resets heading={} position={}",
            secs(h.t_us),
            h.cpu_load_permille as f32 / 10.0,
            h.lambda,
            h.imu_q_scale,
            subnav_wire::AidSource::ALL
                .iter()
                .map(|s| {
                    let a = h.aid.get(*s);
                    format!(
                        "{}: ratio={:.2} fused={}/{} resets={}",
                        s.name(),
                        a.test_ratio,
                        a.fused_count,
                        a.fused_count + a.refused_count,
                        a.resets
                    )
                })
                .collect::<Vec<_>>()
                .join(", "),
            h.pd_repairs,
            h.cov_unrepairable,
            h.gate_rejects,
            h.nonfinite_rejects,
            h.late_fused,
            h.late_refused,
            h.heading_resets,
            h.position_resets
        ),
        Uplink::Fault(f) => format!("FAULT   t={} {}: {} count={}", secs(f.t_us), f.source, f.kind, f.count),
        Uplink::Record(r) => match &r.stored {
            Some(rec) => format!("record  t={} {}: {rec:?}", secs(r.t_us), r.key),
            None => format!("record  t={} {}: nothing stored (defaults in use)", secs(r.t_us), r.key),
        },
        Uplink::Ack(a) => format!("ack     seq={} {}", a.seq, a.result.map_or_else(|r| format!("refused: {r}"), |()| "ok".to_string())),
    }
}

pub fn event(e: &LinkEvent, format: Format) {
    match (e, format) {
        (LinkEvent::Message(m), Format::Text) => println!("{}", text(m)),
        (LinkEvent::Message(m), Format::Json) => println!("{}", json!({"type": "message", "kind": m.kind(), "msg": m})),
        (LinkEvent::Corrupt(err), Format::Text) => println!("corrupt frame: {err}"),
        (LinkEvent::Corrupt(err), Format::Json) => println!("{}", json!({"type": "corrupt", "error": err.to_string()})),
        (LinkEvent::Incompatible(c), Format::Text) => eprintln!("warning: {}", describe(c)),
        (LinkEvent::Incompatible(c), Format::Json) => println!("{}", json!({"type": "incompatible", "detail": describe(c)})),
    }
}

pub fn log(l: &LogLine, format: Format) {
    match format {
        Format::Text => println!("log     {l}"),
        Format::Json => println!("{}", json!({"type": "log", "level": l.level, "timestamp": l.timestamp, "message": l.message})),
    }
}

pub fn summary(stats: &LinkStats, trailing: usize, format: Format) {
    match format {
        Format::Text => {
            eprintln!(
                "summary: {} bytes, {} frames decoded, {} corrupt, {} boot(s), {} incompatible, {} trailing bytes of an unfinished frame",
                stats.bytes, stats.frames_ok, stats.frames_bad, stats.boots, stats.incompatible_boots, trailing
            );
            let note = stats.coverage_note();
            if !note.is_empty() {
                eprintln!("coverage: {note}");
            }
        }
        Format::Json => println!("{}", json!({"type": "summary", "stats": stats, "trailing_bytes": trailing})),
    }
}
