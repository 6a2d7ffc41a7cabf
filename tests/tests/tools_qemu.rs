//! Host tools on a real QEMU run: `subnav qemu --record` (through the library: the same
//! `QemuRecorder`) writes a lossless recording with the uplink and defmt streams; decoding it
//! gives exactly what the live run printed; `export` writes MCAP that an independent reader (the
//! `mcap` Python package from the peer venv) reads back with the expected channels, schemas and
//! message counts. Needs `SUBNAV_FIRMWARE_QEMU_ELF` and `SUBNAV_PEER_PYTHON` (`cargo xtask test`).

use std::collections::BTreeMap;
use std::time::Duration;

use subnav_link::LinkEvent;
use subnav_link::defmt_log::DefmtTable;
use subnav_link::export::{TimeBase, mcap::write, schema};
use subnav_link::qemu::{QemuConfig, QemuEvent, run};
use subnav_link::record::{Stream, read_file, session::Session, tap::QemuRecorder};
use subnav_wire::Uplink;

#[test]
fn qemu_recording_exports_to_mcap_that_an_independent_reader_reads_back() {
    let elf = subnav_tests::qemu_elf();
    let dir = std::env::temp_dir().join(format!("subnav-tools-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rec = dir.join("run.snrec");
    let mut cfg = QemuConfig::new(&elf);
    cfg.run_ms = Some(3_000);
    cfg.timeout = Duration::from_secs(90);
    let recorder = QemuRecorder::start(&mut cfg, &rec).unwrap();
    let (mut live, mut live_logs) = (vec![], vec![]);
    let outcome = run(&cfg, |e, _| match e {
        QemuEvent::Link(LinkEvent::Message(m)) => live.push(m),
        QemuEvent::Link(other) => panic!("unexpected link event {other:?}"),
        QemuEvent::Log(l) => live_logs.push(l.message),
    })
    .unwrap();
    cfg.raw_tap = None;
    let written = recorder.finish().unwrap();
    assert!(outcome.success(), "{outcome:?}");
    assert_eq!(written, [rec.clone()], "one recording: the host lived through the run");

    // Lossless: the recording decodes to exactly what the live run saw, logs included.
    let loaded = read_file(&rec).unwrap();
    assert!(loaded.damage.is_empty());
    let (up, defmt) = (loaded.stream(Stream::Uplink).count(), loaded.stream(Stream::Defmt).count());
    assert!(up > 0 && defmt > 0, "uplink and defmt chunks recorded: {up}, {defmt}");
    let table = DefmtTable::from_elf_path(&elf).unwrap();
    let s = Session::decode(&loaded, Some(&table));
    let got: Vec<_> = s.messages.iter().map(|m| m.item).collect();
    assert_eq!(format!("{got:?}"), format!("{live:?}")); // as text: NaN fields
    let logs: Vec<_> = s.logs.iter().map(|l| l.item.message.clone()).collect();
    assert_eq!(logs, live_logs);
    assert!(logs.iter().any(|l| l.contains("booting")));

    let mcap_path = dir.join("run.mcap");
    let summary = write(&s, std::io::BufWriter::new(std::fs::File::create(&mcap_path).unwrap()), TimeBase::Sensor, |_, _| {}).unwrap();
    let mut expected: BTreeMap<String, u64> = BTreeMap::new();
    for m in &s.messages {
        *expected.entry(format!("/subnav/{}", m.item.kind())).or_insert(0) += 1;
    }
    // The derived topics (`subnav_link::export::topics`): pose and its covariance per nav
    // message, a health summary per health message, a log entry per fault, a compass fix per
    // report with a heading.
    if let Some(n) = expected.get("/subnav/nav").copied() {
        expected.insert("/subnav/pose".into(), n);
        expected.insert("/subnav/pose/covariance".into(), n);
    }
    if let Some(n) = expected.get("/subnav/health").copied() {
        expected.insert("/subnav/health/summary".into(), n);
    }
    if let Some(n) = expected.get("/subnav/fault").copied() {
        expected.insert("/subnav/faults".into(), n);
    }
    let fixes = s.messages.iter().filter(|m| matches!(m.item, Uplink::Compass(c) if c.heading_rad.is_some())).count() as u64;
    if fixes > 0 {
        expected.insert("/subnav/compass/fix".into(), fixes);
    }
    expected.insert("/subnav/log".into(), s.logs.len() as u64);
    assert_eq!(summary.topics, expected);
    assert!(expected["/subnav/nav"] >= 25, "3 s at 10 Hz: {expected:?}");

    let out = std::process::Command::new(subnav_tests::peer_python())
        .arg(subnav_tests::peers_dir().join("tools_mcap_read.py"))
        .arg(&mcap_path)
        .output()
        .unwrap();
    assert!(out.status.success(), "python mcap reader: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let topics = v["topics"].as_object().unwrap();
    assert_eq!(topics.len(), expected.len(), "{v}");
    for (topic, n) in &expected {
        let t = &topics[topic];
        assert_eq!(t["count"].as_u64(), Some(*n), "{topic}: {t}");
        assert_eq!(t["schema_encoding"], "jsonschema", "{topic}");
        assert_eq!(t["message_encoding"], "json", "{topic}");
        let want = match topic.as_str() {
            "/subnav/pose" => "foxglove.PoseInFrame".to_string(),
            "/subnav/log" | "/subnav/faults" => "foxglove.Log".to_string(),
            "/subnav/pose/covariance" => "subnav.PoseCovariance".to_string(),
            "/subnav/health/summary" => "subnav.HealthSummary".to_string(),
            "/subnav/compass/fix" => "subnav.CompassFix".to_string(),
            k => schema::for_kind(k.trim_start_matches("/subnav/")).unwrap().0,
        };
        assert_eq!(t["schema"], want.as_str(), "{topic}");
    }
    assert_eq!(v["message_count"].as_u64(), Some(expected.values().sum::<u64>()));
    assert_eq!(topics["/subnav/pose"]["keys"], serde_json::json!(["frame_id", "pose", "timestamp"]));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A character device `c 1 minor` (3 = null, 7 = full) made with `mknod` in `dir`, or, where
/// this process may not make device nodes, the system's own (only written to, and checked to
/// be a device afterwards).
fn device(dir: &std::path::Path, minor: u32) -> std::path::PathBuf {
    let p = dir.join(format!("dev{minor}"));
    let made = std::process::Command::new("mknod").arg(&p).args(["c", "1", &minor.to_string()]).status().is_ok_and(|s| s.success());
    if made { p } else { std::path::PathBuf::from(if minor == 3 { "/dev/null" } else { "/dev/full" }) }
}

fn is_char_device(p: &std::path::Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(p).is_ok_and(|m| m.file_type().is_char_device())
}

/// Issue 40: `qemu --record NODE` renamed a temporary file over a device node (it became a
/// regular file) and a `/dev/full` node reported success. Now the recording is written into the
/// device in place, which stays a device; a full one is an error naming it, before QEMU starts.
#[test]
fn a_qemu_recording_onto_a_device_keeps_the_device_and_a_full_one_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let (null, full) = (device(dir.path(), 3), device(dir.path(), 7));
    let mut cfg = QemuConfig::new(subnav_tests::qemu_elf());
    cfg.run_ms = Some(300);
    cfg.timeout = Duration::from_secs(60);
    let e = format!("{:#}", QemuRecorder::start(&mut cfg, &full).err().expect("a full device is an error"));
    assert!(e.contains(&full.display().to_string()) && e.contains("No space left"), "{e}");
    let recorder = QemuRecorder::start(&mut cfg, &null).unwrap();
    let outcome = run(&cfg, |_, _| {}).unwrap();
    cfg.raw_tap = None;
    assert_eq!(recorder.finish().unwrap(), [null.clone()]);
    assert!(outcome.success(), "{outcome:?}");
    for p in [&null, &full] {
        assert!(is_char_device(p), "{} is no longer a device", p.display());
    }
    if null.starts_with(dir.path()) {
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, "a temporary file was left behind");
    }
}
