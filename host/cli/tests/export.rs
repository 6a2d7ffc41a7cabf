//! `subnav export`: a recording with every message kind, corrupt frames and a damaged chunk
//! -> MCAP read back with the mcap crate's reader (channels, schemas, message counts, content)
//! and CSV files with one row per message.

use std::collections::BTreeMap;
use std::process::Command;

use subnav_link::export::schema;
use subnav_link::record::{Meta, Stream, Writer};
use subnav_wire::*;

fn messages() -> Vec<Uplink> {
    let mut v = vec![Uplink::Boot(boot_message(
        Board::QemuMps2An386,
        [0, 1, 0],
        0,
        subnav_wire::CalibrationInUse::NO_STORE,
        subnav_wire::ResetCause::PowerOn,
    ))];
    for i in 0..40u64 {
        let t_us = 100_000 * (i + 1);
        v.push(Uplink::Nav(NavSolution {
            t_us,
            mode: if i < 5 { NavMode::Uninitialised } else { NavMode::Aided },
            pos_ned_m: [i as f32, -(i as f32), 3.0],
            vel_ned_mps: [1.0, 0.0, 0.0],
            att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
            sigma_pos_m: [0.5; 3],
            sigma_vel_mps: [0.1; 3],
            sigma_att_rad: [0.01; 3],
            cov_ne_m2: 0.0,
        }));
        if i % 4 == 0 {
            v.push(Uplink::Health(FilterHealth {
                t_us,
                aid: subnav_wire::AidStatuses {
                    heading: subnav_wire::AidStatus {
                        nis: 1.0,
                        test_ratio: 0.1,
                        noise_var: 1e-4,
                        fused: true,
                        fused_count: 3,
                        ..Default::default()
                    },
                    depth: subnav_wire::AidStatus { nis: f32::NAN, ..Default::default() },
                    ..Default::default()
                },
                imu_q_scale: 1.0,
                lambda: 1.0,
                q_diag: [1e-6; 5],
                pd_repairs: 0,
                cov_unrepairable: 0,
                gate_rejects: 1,
                nonfinite_rejects: 0,
                late_fused: 0,
                late_refused: 0,
                heading_resets: 0,
                position_resets: 0,
                cpu_load_permille: 100,
            }));
            v.push(Uplink::Raw(RawSample::Imu(ImuSample { t_us, gyro_radps: [0.0; 3], accel_mps2: [0.0, 0.0, -9.8], temp_c: 20.0 })));
            v.push(Uplink::Raw(RawSample::Depth(DepthSample { t_us, pressure_pa: 1.3e5, temp_c: 10.0, depth_m: 3.0 })));
            v.push(Uplink::Raw(RawSample::Polarization(PolarizationSample { t_us, unit: 1, counts: [1, 2, 3, 4] })));
            v.push(Uplink::Compass(CompassReport {
                t_us,
                heading_rad: (i % 8 == 0).then_some(0.5),
                sigma_heading_rad: 0.02,
                sun_rel_azimuth_rad: 0.1,
                sun_elevation_rad: 0.7,
                no_fix_reason: 0,
                units_used: 4,
            }));
        }
    }
    v.push(Uplink::Fault(Fault { t_us: 1_000_000, source: FaultSource::Polarization { unit: 2 }, kind: FaultKind::BusNack, count: 1 }));
    v.push(Uplink::Fault(Fault { t_us: 2_000_000, source: FaultSource::Imu, kind: FaultKind::Stuck, count: 1 }));
    v.push(Uplink::Ack(CommandAck { seq: 1, result: Err(Refusal::OutOfRange) }));
    v.push(Uplink::Ack(CommandAck { seq: 2, result: Ok(()) }));
    v
}

/// A recording of `messages()` in uneven chunks, with 3 corrupt frames (after messages 10, 40, 70); returns (path, counts per kind).
fn recording(dir: &std::path::Path) -> (std::path::PathBuf, BTreeMap<&'static str, u64>) {
    let mut bytes = vec![];
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let mut counts = BTreeMap::new();
    for (i, m) in messages().iter().enumerate() {
        bytes.extend_from_slice(encode(m, &mut buf).unwrap());
        *counts.entry(m.kind()).or_insert(0u64) += 1;
        if i % 30 == 10 {
            bytes.extend_from_slice(&[0x03, 0x11, 0x22, 0x00]); // a corrupt frame
        }
    }
    let path = dir.join("rec.snrec");
    let mut w = Writer::create(&path, &Meta::new("test")).unwrap();
    for (k, part) in bytes.chunks(97).enumerate() {
        w.chunk(Stream::Uplink, 1_700_000_000_000_000 + k as u64 * 1000, part).unwrap();
    }
    w.chunk(Stream::Truth, 1_700_000_000_000_000, b"t_s,n_m,e_m,d_m,yaw_rad\n0,0,0,3,0\n").unwrap();
    (path, counts)
}

#[test]
fn mcap_export_reads_back_with_expected_channels_schemas_and_counts() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, counts) = recording(dir.path());
    let out = dir.path().join("dive.mcap");
    let csv = dir.path().join("csv");
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["--format", "json", "export"])
        .arg(&rec)
        .arg("--mcap")
        .arg(&out)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["corrupt_frames"], 3);

    let bytes = std::fs::read(&out).unwrap();
    let mut got: BTreeMap<String, (String, String, String, u64)> = BTreeMap::new();
    let mut nav_json = vec![];
    let mut last_seq: BTreeMap<String, u32> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let topic = m.channel.topic.clone();
        let s = m.channel.schema.as_ref().expect("every channel has a schema");
        let e = got.entry(topic.clone()).or_insert((s.name.clone(), s.encoding.clone(), m.channel.message_encoding.clone(), 0));
        e.3 += 1;
        // Sequence numbers count up per channel.
        let prev = last_seq.insert(topic.clone(), m.sequence).unwrap_or(0);
        assert_eq!(m.sequence, prev + 1);
        let v: serde_json::Value = serde_json::from_slice(&m.data).expect("JSON message");
        // The schema lists every field the message has.
        let schema: serde_json::Value = serde_json::from_slice(&s.data).unwrap();
        for k in v.as_object().unwrap().keys() {
            assert!(schema["properties"].get(k).is_some(), "{topic}: field {k} not in schema {}", s.name);
        }
        if topic == "/subnav/nav" {
            nav_json.push(v);
        }
    }
    for (kind, n) in &counts {
        let (name, enc, msg_enc, count) = got.get(&format!("/subnav/{kind}")).unwrap_or_else(|| panic!("no channel for {kind}: {got:?}"));
        assert_eq!(count, n, "{kind}");
        assert_eq!(enc, "jsonschema");
        assert_eq!(msg_enc, "json");
        assert_eq!(name, &schema::for_kind(kind).unwrap().0);
    }
    assert_eq!(got["/subnav/pose"], ("foxglove.PoseInFrame".into(), "jsonschema".into(), "json".into(), counts["nav"]));
    assert_eq!(got["/subnav/link/corrupt"].3, 3);
    // The derived topics of the shared definition (`subnav_link::export::topics`), as live.
    assert_eq!(got["/subnav/pose/covariance"].3, counts["nav"]);
    assert_eq!(got["/subnav/pose/covariance"].0, "subnav.PoseCovariance");
    assert_eq!(got["/subnav/health/summary"].3, counts["health"]);
    assert_eq!(got["/subnav/faults"], ("foxglove.Log".into(), "jsonschema".into(), "json".into(), counts["fault"]));
    assert!(got["/subnav/trajectory"].3 >= 2, "{got:?}");
    let derived = [
        "/subnav/pose",
        "/subnav/pose/covariance",
        "/subnav/trajectory",
        "/subnav/health/summary",
        "/subnav/faults",
        "/subnav/link/corrupt",
    ];
    let compass_fixes = got.get("/subnav/compass/fix").map_or(0, |_| 1);
    assert_eq!(got.len(), counts.len() + derived.len() + compass_fixes, "{got:?}");
    for (topic, (name, ..)) in &got {
        assert_eq!(&subnav_link::export::topics::schema_of(topic).unwrap().0, name, "{topic}");
    }
    // Content survives: the 10th nav message's position.
    assert_eq!(nav_json[10]["pos_ned_m"], serde_json::json!([10.0, -10.0, 3.0]));
    // The summary section has the statistics the readers use.
    let summary = mcap::Summary::read(&bytes).unwrap().expect("summary section");
    let total: u64 = got.values().map(|v| v.3).sum();
    assert_eq!(summary.stats.unwrap().message_count, total);

    // CSV: one file per kind, one row per message.
    for (kind, n) in &counts {
        let text = std::fs::read_to_string(csv.join(format!("{kind}.csv"))).unwrap();
        assert_eq!(text.lines().count() as u64, n + 1, "{kind}.csv");
    }
    let fault = std::fs::read_to_string(csv.join("fault.csv")).unwrap();
    assert!(fault.lines().next().unwrap().contains("source.Polarization.unit"), "{fault}");
}

#[test]
fn export_errors_say_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, _) = recording(dir.path());
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).arg("export").arg(&rec).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--mcap"));
    let raw = dir.path().join("raw.bin");
    std::fs::write(&raw, [1u8, 2, 3, 0]).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).arg("export").arg(&raw).args(["--mcap", "/tmp/x.mcap"]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a subnav recording"), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn decode_reads_a_recording_like_a_raw_file() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, counts) = recording(dir.path());
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).args(["--format", "json", "decode", "--file"]).arg(&rec).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8(o.stdout).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let n = lines.iter().filter(|l| l["type"] == "message").count() as u64;
    assert_eq!(n, counts.values().sum::<u64>());
    assert_eq!(lines.iter().filter(|l| l["type"] == "corrupt").count(), 3);
}
