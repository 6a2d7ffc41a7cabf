//! `subnav replay` on native software-in-the-loop recordings: the firmware's application core
//! replayed on a recording's raw samples and downlink commands reproduces every Nav solution it
//! sent, and recordings it cannot replay are refused with the cause (never a panic).
//!
//! Native recording and replay run the same code on the same CPU, so the Nav solutions must be
//! bit-identical (the QEMU recording's bound, 1e-5 relative, is in `tests/tests/qemu_replay.rs`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use subnav_link::record::{Meta, Stream, Writer};
use subnav_sil::replay::{ReplayReport, replay_file};
use subnav_sil::run::{HeadRun, RunOutput as NativeRun};
use subnav_sil::{FaultPlan, Scenario};
use subnav_wire::{self as wire, Boot, Decoded, Fault, FaultKind, FaultSource, FrameDecoder, MAX_UPLINK_FRAME, RawSample, Uplink};

const TOL: f64 = 1e-5;

/// 80 s: rest 15 s, descent, survey; a position fix every 5 s from 20 s on (sent 5 s ahead,
/// queued by the firmware); IMU NACKs for 0.5 s at 40 s (coasting), 5 % of the depth reads
/// NACKed, unit 2 occluded 50-55 s: the commands, the failed-read and the occlusion paths run.
fn scenario() -> Scenario {
    let faults = FaultPlan {
        imu_nack_s: Some((40.0, 40.5)),
        occluded_unit: Some((50.0, 55.0, 2)),
        depth_nack_probability: 0.05,
        ..FaultPlan::default()
    };
    Scenario { seed: 3, duration_s: 80.0, faults, ..Scenario::default() }
}

fn native() -> &'static (Scenario, NativeRun) {
    static RUN: OnceLock<(Scenario, NativeRun)> = OnceLock::new();
    RUN.get_or_init(|| {
        let sc = scenario();
        let run = HeadRun::native(&sc).keep_all().run().unwrap();
        (sc, run)
    })
}

fn frames_of(run: &NativeRun) -> Vec<(u64, Vec<u8>)> {
    run.frames.clone()
}

fn decode(frame: &[u8]) -> Uplink {
    let mut dec = FrameDecoder::<MAX_UPLINK_FRAME>::new();
    let mut out = None;
    for &b in frame {
        if let Decoded::Message(m) = dec.push::<Uplink>(b) {
            out = Some(m);
        }
    }
    out.expect("a frame the firmware wrote decodes")
}

fn encode(m: &Uplink) -> Vec<u8> {
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    wire::encode(m, &mut buf).expect("encodes").to_vec()
}

/// Write a recording of `frames` (and the run's downlink) with the scenario's start arguments.
fn write(dir: &Path, name: &str, frames: Vec<(u64, Vec<u8>)>) -> PathBuf {
    let (sc, run) = native();
    let p = dir.join(name);
    let modified = NativeRun {
        messages: Vec::new(),
        frames,
        downlink: run.downlink.clone(),
        exit_code: Some(0),
        corrupt_frames: 0,
        bus_transactions: 0,
        map: None,
        recordings: Vec::new(),
    };
    modified.write_recording(&p, sc).expect("writing the recording");
    p
}

fn replay(p: &Path) -> ReplayReport {
    let r = replay_file(p, TOL).expect("replays");
    eprintln!("{}", serde_json::to_string(&r).unwrap());
    r
}

fn replay_err(p: &Path) -> String {
    match replay_file(p, TOL) {
        Ok(r) => panic!("expected an error, got {}", serde_json::to_string(&r).unwrap()),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn a_native_dive_is_reproduced_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (sc, run) = native();
    let p = dir.path().join("dive.snrec");
    run.write_recording(&p, sc).unwrap();
    let r = replay(&p);
    let navs = run.messages.iter().filter(|m| matches!(m, Uplink::Nav(_))).count();
    assert_eq!(navs, 801, "10 Hz for 80 s");
    assert_eq!(r.nav_recorded, navs);
    assert_eq!(r.nav_compared, navs, "every Nav compared");
    assert_eq!(r.nav_identical, navs, "bit-identical: {r:?}");
    assert!(r.reproduced(), "{r:?}");
    assert_eq!(r.diverged, None);
    assert!(r.limitations.is_empty(), "{:?}", r.limitations);
    // Two start commands (time, origin) and a fix every 5 s from 20 s to 80 s.
    assert_eq!(r.commands_applied, 2 + run.downlink.len() - r.commands_unacked);
    assert!(r.commands_applied >= 2 + 12, "{r:?}");
    assert_eq!(r.ack_mismatches, 0);
    assert_eq!(r.compass_differ, 0);
    assert_eq!((r.faults_extra, r.faults_missing), (0, 0), "fault reports reproduced too");
    let raw = run.messages.iter().filter(|m| matches!(m, Uplink::Raw(_))).count();
    assert_eq!(r.raw_samples, raw);
    // The fault paths ran: IMU reads failed (coasting) and depth reads failed.
    let faults: Vec<&Fault> = run.messages.iter().filter_map(|m| if let Uplink::Fault(f) = m { Some(f) } else { None }).collect();
    assert!(faults.iter().any(|f| f.source == FaultSource::Imu), "{faults:?}");
    assert!(faults.iter().any(|f| f.source == FaultSource::Depth), "{faults:?}");
    assert!(faults.iter().any(|f| f.kind == FaultKind::Occluded), "{faults:?}");
}

/// The comparison can fail: one IMU sample changed by 0.01 rad/s (or one sample dropped) in the
/// middle of the dive makes the replayed solutions differ from the recorded ones, and the first
/// difference is reported at or after that sample.
#[test]
fn a_changed_or_missing_raw_sample_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let (_, run) = native();
    let at = |frames: &[(u64, Vec<u8>)]| {
        frames.iter().position(|(t, f)| *t >= 30_000_000 && matches!(decode(f), Uplink::Raw(RawSample::Imu(_)))).unwrap()
    };
    let mut frames = frames_of(run);
    let k = at(&frames);
    let Uplink::Raw(RawSample::Imu(mut s)) = decode(&frames[k].1) else { unreachable!() };
    s.gyro_radps[2] += 0.01;
    frames[k].1 = encode(&Uplink::Raw(RawSample::Imu(s)));
    let r = replay(&write(dir.path(), "changed.snrec", frames));
    assert!(!r.reproduced());
    assert!(r.nav_beyond_tolerance > 0);
    let m = r.first_mismatch.as_ref().unwrap();
    assert!(m.t_us >= 30_000_000, "{m:?}");

    let mut frames = frames_of(run);
    let k = at(&frames);
    frames.remove(k);
    let r = replay(&write(dir.path(), "missing.snrec", frames));
    assert!(!r.reproduced(), "a lost sample is a failed read in the replay, the estimator differs");
}

#[test]
fn bad_inputs_are_refused_with_the_cause() {
    let dir = tempfile::tempdir().unwrap();
    let (sc, run) = native();

    let p = dir.path().join("text.snrec");
    std::fs::write(&p, b"hello, not a recording").unwrap();
    assert!(replay_err(&p).contains("not a subnav recording"), "{}", replay_err(&p));

    let p = dir.path().join("none.snrec");
    assert!(replay_err(&p).contains("reading"), "{}", replay_err(&p));

    // Damage in the middle: a flipped byte.
    let good = dir.path().join("good.snrec");
    run.write_recording(&good, sc).unwrap();
    let mut bytes = std::fs::read(&good).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0xFF;
    let p = dir.path().join("damaged.snrec");
    std::fs::write(&p, &bytes).unwrap();
    assert!(replay_err(&p).contains("damaged at offset"), "{}", replay_err(&p));

    // No Boot (the recording started after the firmware's reset).
    let frames: Vec<_> = frames_of(run).into_iter().filter(|(_, f)| !matches!(decode(f), Uplink::Boot(_))).collect();
    let e = replay_err(&write(dir.path(), "noboot.snrec", frames));
    assert!(e.contains("does not start at the firmware's boot"), "{e}");

    // Raw streaming off.
    let frames: Vec<_> = frames_of(run).into_iter().filter(|(_, f)| !matches!(decode(f), Uplink::Raw(_))).collect();
    let e = replay_err(&write(dir.path(), "noraw.snrec", frames));
    assert!(e.contains("no raw samples"), "{e}");

    // Telemetry dropped by the firmware (its output was full): samples are missing.
    let mut frames = frames_of(run);
    let k = frames.len() / 2;
    let t = frames[k].0;
    frames
        .insert(k, (t, encode(&Uplink::Fault(Fault { t_us: t, source: FaultSource::Link, kind: FaultKind::TelemetryDropped, count: 3 }))));
    let e = replay_err(&write(dir.path(), "dropped.snrec", frames));
    assert!(e.contains("dropped 3 telemetry frames"), "{e}");

    // Corrupt uplink frames.
    let mut frames = frames_of(run);
    let k = frames.len() / 3;
    let n = frames[k].1.len();
    frames[k].1[n / 2] ^= 0x55;
    let e = replay_err(&write(dir.path(), "corrupt.snrec", frames));
    assert!(e.contains("corrupt"), "{e}");

    // A recording that does not say how the board was started (no start arguments).
    let p = dir.path().join("nometa.snrec");
    let mut w = Writer::create(&p, &Meta::new("test")).unwrap();
    for (t, f) in &run.frames {
        w.chunk(Stream::Uplink, *t, f).unwrap();
    }
    w.flush().unwrap();
    drop(w);
    let e = replay_err(&p);
    assert!(e.contains("seq-0") && e.contains("how the board was started"), "{e}");
}

#[test]
fn a_truncated_recording_or_a_reboot_is_replayed_up_to_there_and_reported() {
    let dir = tempfile::tempdir().unwrap();
    let (sc, run) = native();
    let good = dir.path().join("good.snrec");
    run.write_recording(&good, sc).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    // Cut in the middle of a chunk.
    let p = dir.path().join("cut.snrec");
    std::fs::write(&p, &bytes[..bytes.len() / 2 + 7]).unwrap();
    let r = replay(&p);
    assert!(r.limitations.iter().any(|l| l.contains("cut short")), "{:?}", r.limitations);
    assert!(r.reproduced(), "what is there is reproduced: {r:?}");
    assert!(r.nav_compared > 300 && r.nav_compared < 801, "{}", r.nav_compared);

    // A second Boot (the firmware rebooted) at 50 s.
    let mut frames = frames_of(run);
    let k = frames.iter().position(|(t, _)| *t >= 50_000_000).unwrap();
    let Uplink::Boot(b) = decode(&frames[0].1) else { panic!("the first frame is the Boot") };
    frames.insert(k, (50_000_000, encode(&Uplink::Boot(Boot { t_us: 0, ..b }))));
    let r = replay(&write(dir.path(), "reboot.snrec", frames));
    assert!(r.limitations.iter().any(|l| l.contains("rebooted")), "{:?}", r.limitations);
    assert!(r.reproduced(), "{r:?}");
    assert_eq!(r.nav_compared, 500, "0..49.9 s at 10 Hz");
}
