//! Issue 23, "careless input never crashes, hangs, lies or destroys data": the bad-input probes
//! of the issue against the `subnav` binary. Each must end quickly with a clear error that
//! names the input and its bound (never a panic, an abort or a hang), and must leave existing
//! files alone. Every probe here ended in a panic, a multi-gigabyte allocation, a hang, a
//! destroyed file or a silent wrong result before the fix; none of them runs a long job.

use std::io::Write;
use std::net::TcpListener;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

/// Runs and returns (output, stderr text).
fn run(c: &mut Command) -> (Output, String) {
    let o = c.output().unwrap();
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    (o, e)
}

/// The command fails without a panic and its stderr has every one of `needles`.
fn refused(c: &mut Command, needles: &[&str]) -> String {
    let t0 = Instant::now();
    let (o, e) = run(c);
    assert!(!o.status.success(), "{c:?} succeeded: {e}");
    assert!(!e.contains("panicked") && !e.contains("memory allocation"), "{c:?}: {e}");
    assert!(o.status.code().is_some(), "{c:?} died of a signal: {e}");
    for n in needles {
        assert!(e.contains(n), "{c:?}: {n:?} not in {e}");
    }
    assert!(t0.elapsed() < Duration::from_secs(30), "{c:?} took {:?}", t0.elapsed());
    e
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

/// A.2: flags that panicked (`Duration::from_secs_f64(-1)`, capacity overflow), now usage
/// errors naming the flag and the bound; `record` no longer truncates its output first.
#[test]
fn numbers_out_of_range_are_usage_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("x.snrec");
    std::fs::write(&rec, b"keep me").unwrap();
    for bad in ["-1", "nan", "inf", "1e300"] {
        refused(subnav().args(["record", "--tcp", "127.0.0.1:9", "-o"]).arg(&rec).arg(format!("--duration-s={bad}")), &["--duration-s"]);
        assert_eq!(std::fs::read(&rec).unwrap(), b"keep me");
    }
    let out = dir.path().join("r");
    refused(subnav().args(["report", "simulate", "--duration-s", "inf", "--out"]).arg(&out), &["--duration-s", "86400"]);
    refused(subnav().args(["filter", "simulate", "--duration-s", "inf", "--out"]).arg(dir.path().join("f.csv")), &["--duration-s"]);
    let train = dir.path().join("train.csv");
    std::fs::write(&train, "1,2,0\n2,3,0\n5,5,1\n6,5,1\n").unwrap();
    refused(
        subnav().args(["lmnn", "fit", "--k", "18446744073709551615", "--train"]).arg(&train).arg("--out").arg(dir.path().join("m.json")),
        &["--k", "1..=1000"],
    );
    refused(subnav().args(["phasecorr", "a.png", "b.png", "--upsample", "18446744073709551615"]), &["--upsample", "1..=1000"]);
}

/// A.3: sizes that asked for gigabytes, now refused with their bound before anything is
/// allocated.
#[test]
fn sizes_have_caps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    refused(subnav().args(["sim", "--fix-period-s", "1e-9", "--out"]).arg(d.join("s.json")), &["position_fixes.period_s", "0.1"]);
    assert!(!d.join("s.json").exists());
    refused(subnav().args(["qemu", "--elf", "x.elf", "--run-ms", "18446744073709551615"]), &["--run-ms", "86400000"]);
    refused(subnav().args(["report", "simulate", "--duration-s", "1e7", "--out"]).arg(d.join("r")), &["--duration-s"]);
    refused(subnav().args(["filter", "simulate", "--duration-s", "1e9", "--out"]).arg(d.join("f.csv")), &["--duration-s"]);
    refused(subnav().args(["filter", "monte-carlo", "--duration-s", "1e8"]), &["--duration-s"]);
    refused(subnav().args(["fgo", "simulate", "--duration-s", "1e7", "--out"]).arg(d.join("g.jsonl")), &["--duration-s"]);
    refused(subnav().args(["fgo", "monte-carlo", "--duration-s", "1e9"]), &["--duration-s"]);
    refused(subnav().args(["ice", "simulate", "--distance-m", "1e9"]), &["--distance-m", "10000"]);
    // A scenario file is checked field by field (`Scenario::validate`).
    let sc = d.join("dive.json");
    assert!(subnav().args(["sim", "--duration-s", "20", "--out"]).arg(&sc).status().unwrap().success());
    let text = std::fs::read_to_string(&sc).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["position_fixes"]["period_s"] = serde_json::json!(1e-20);
    std::fs::write(&sc, v.to_string()).unwrap();
    refused(subnav().args(["run", "--native"]).arg(&sc), &["dive.json", "position_fixes.period_s"]);
    v["position_fixes"]["period_s"] = serde_json::json!(5.0);
    v["survey"]["speed_mps"] = serde_json::json!(1e300);
    std::fs::write(&sc, v.to_string()).unwrap();
    refused(subnav().args(["run", "--native"]).arg(&sc), &["survey.speed_mps"]);
}

/// A.4: inputs that hung, now refused (or ended at their deadline).
#[test]
fn hangs_end() {
    let dir = tempfile::tempdir().unwrap();
    let sc = dir.path().join("dive.json");
    assert!(subnav().args(["sim", "--duration-s", "20", "--out"]).arg(&sc).status().unwrap().success());
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&sc).unwrap()).unwrap();
    v["survey"]["speed_mps"] = serde_json::json!(-1.0);
    std::fs::write(&sc, v.to_string()).unwrap();
    refused(subnav().args(["run", "--native"]).arg(&sc), &["survey.speed_mps must be > 0"]);
    refused(
        subnav().args(["compass", "simulate", "--min-elevation-deg", "70", "--max-elevation-deg", "20"]),
        &["--min-elevation-deg", "below --max-elevation-deg"],
    );
    refused(subnav().args(["compass", "simulate", "--min-elevation-deg", "95"]), &["--min-elevation-deg", "0..=90"]);
    refused(subnav().args(["compass", "simulate", "--min-elevation-deg", "nan"]), &["--min-elevation-deg"]);
    refused(subnav().args(["compass", "geolocate", "--track-s", "10000000000000"]), &["--track-s"]);
    // A leave-one-out check of the simulator's OSOAA table needs one of the table's cases.
    refused(
        subnav().args(["compass", "field", "--sun-zenith-deg", "45", "--depth-m", "10", "--water", "oceanic", "--leave-out", "depth"]),
        &["--leave-out", "no table case"],
    );
    refused(
        subnav().args(["compass", "field", "--sun-zenith-deg", "30", "--depth-m", "10", "--water", "clear", "--leave-out", "wind"]),
        &["--leave-out", "--water oceanic or turbid"],
    );

    // A peer that accepts and never sends: `record --duration-s` ends the recording on time
    // (nothing recorded: an error, no file), and `decode --tcp` ends at its idle timeout.
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let holder = std::thread::spawn(move || {
        let mut held = vec![];
        for _ in 0..2 {
            if let Ok((s, _)) = l.accept() {
                held.push(s);
            }
        }
        std::thread::sleep(Duration::from_secs(20));
    });
    let rec = dir.path().join("silent.snrec");
    let t0 = Instant::now();
    refused(subnav().args(["record", "--tcp", &addr, "--duration-s", "0.5", "-o"]).arg(&rec), &["sent no data", "not written"]);
    assert!(t0.elapsed() < Duration::from_secs(10), "record took {:?}", t0.elapsed());
    assert!(!rec.exists());
    assert_eq!(files_in(dir.path()), ["dive.json"]);
    let t0 = Instant::now();
    refused(subnav().args(["decode", "--tcp", &addr, "--idle-timeout-s", "0.5"]), &["no data", "idle timeout"]);
    assert!(t0.elapsed() < Duration::from_secs(10), "decode took {:?}", t0.elapsed());
    drop(holder);
}

/// A.5: a failed run leaves an old output alone; an output that names an input is refused.
#[test]
fn data_is_not_destroyed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A peer that closes at once: the old recording stays, byte for byte.
    let old = d.join("existing.snrec");
    std::fs::write(&old, b"an old recording").unwrap();
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let closer = std::thread::spawn(move || drop(l.accept()));
    refused(subnav().args(["record", "--tcp", &addr, "-o"]).arg(&old), &["sent no data"]);
    closer.join().unwrap();
    assert_eq!(std::fs::read(&old).unwrap(), b"an old recording");
    assert_eq!(files_in(d), ["existing.snrec"], "a temporary file was left behind");

    // Outputs that are inputs.
    let sc = d.join("scenario.json");
    assert!(subnav().args(["sim", "--duration-s", "5", "--out"]).arg(&sc).status().unwrap().success());
    let sc_text = std::fs::read(&sc).unwrap();
    refused(subnav().args(["run", "--native"]).arg(&sc).arg("--record").arg(&sc), &["--record", "also an input"]);
    refused(
        subnav().args(["run", "--native"]).arg(&sc).arg("--truth").arg(d.join(".").join("scenario.json")),
        &["--truth", "also an input"],
    );
    assert_eq!(std::fs::read(&sc).unwrap(), sc_text);
    let rec = d.join("r.snrec");
    let mut w = subnav_link::record::Writer::new(Vec::new(), &subnav_link::record::Meta::new("test")).unwrap();
    w.chunk(subnav_link::record::Stream::Uplink, 1, b"\x00").unwrap();
    std::fs::write(&rec, w.into_inner()).unwrap();
    let rec_bytes = std::fs::read(&rec).unwrap();
    refused(subnav().arg("export").arg(&rec).arg("--mcap").arg(&rec), &["--mcap", "also an input"]);
    assert_eq!(std::fs::read(&rec).unwrap(), rec_bytes);
    let train = d.join("train.csv");
    std::fs::write(&train, "1,2,0\n2,3,0\n5,5,1\n6,5,1\n").unwrap();
    refused(subnav().args(["lmnn", "fit", "--train"]).arg(&train).arg("--out").arg(&train), &["--out", "also an input"]);
    assert_eq!(std::fs::read_to_string(&train).unwrap(), "1,2,0\n2,3,0\n5,5,1\n6,5,1\n");
    let log = d.join("log.csv");
    std::fs::write(&log, "x\n").unwrap();
    refused(subnav().args(["filter", "replay"]).arg(&log).arg("--out").arg(&log), &["--out", "also an input"]);
    assert_eq!(std::fs::read_to_string(&log).unwrap(), "x\n");
}

/// A.5: one flipped bit in a recording's header costs the header, not the recording.
#[test]
fn a_flipped_bit_in_the_header_keeps_the_chunks() {
    use subnav_link::record::{Meta, Stream, Writer};
    let dir = tempfile::tempdir().unwrap();
    let mut w = Writer::new(Vec::new(), &Meta::new("test")).unwrap();
    use subnav_wire::{Fault, FaultKind, FaultSource, Uplink};
    let mut buf = [0u8; subnav_wire::MAX_UPLINK_FRAME];
    let msg = Uplink::Fault(Fault { t_us: 5, source: FaultSource::Depth, kind: FaultKind::BusNack, count: 1 });
    let frame = subnav_wire::frame::encode(&msg, &mut buf).unwrap().to_vec();
    for i in 0..20 {
        w.chunk(Stream::Uplink, i, &frame).unwrap();
    }
    let mut bytes = w.into_inner();
    bytes[20] ^= 0x08; // inside the metadata JSON
    let rec = dir.path().join("flipped.snrec");
    std::fs::write(&rec, &bytes).unwrap();
    let (o, e) = run(subnav().args(["--format", "json", "decode", "--file"]).arg(&rec));
    assert!(o.status.success(), "{e}");
    assert!(e.contains("header is damaged"), "{e}");
    let faults = String::from_utf8_lossy(&o.stdout).lines().filter(|l| l.contains("BusNack")).count();
    assert_eq!(faults, 20, "{}", String::from_utf8_lossy(&o.stdout));
}

/// C: files that are, or were, recordings are never decoded as raw uplink bytes.
#[test]
fn damaged_recordings_are_named_not_decoded_as_raw_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.snrec");
    std::fs::File::create(&empty).unwrap();
    refused(subnav().args(["decode", "--file"]).arg(&empty), &["empty.snrec", "is empty"]);
    let cut = dir.path().join("cut.snrec");
    std::fs::write(&cut, &subnav_link::record::MAGIC[..5]).unwrap();
    refused(subnav().args(["decode", "--file"]).arg(&cut), &["cut.snrec", "truncated"]);
    let mut w = subnav_link::record::Writer::new(Vec::new(), &subnav_link::record::Meta::new("test")).unwrap();
    w.chunk(subnav_link::record::Stream::Uplink, 1, b"\x00").unwrap();
    let crlf: Vec<u8> = w.into_inner().iter().copied().filter(|&b| b != b'\r').collect();
    let mangled = dir.path().join("mangled.snrec");
    let mut f = std::fs::File::create(&mangled).unwrap();
    f.write_all(&crlf).unwrap();
    refused(subnav().args(["decode", "--file"]).arg(&mangled), &["mangled.snrec", "text-mode copy"]);
}

/// A PNG of a few dozen bytes whose header declares `w` x `h` pixels (no real image data).
pub fn png_declaring(w: u32, h: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
            }
        }
        !c
    }
    let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        v.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend_from_slice(data);
        v.extend_from_slice(&body);
        v.extend_from_slice(&crc32(&body).to_be_bytes());
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit grey
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00]); // the decoder reads the header up to here
    chunk(b"IEND", &[]);
    v
}

/// A.3 and B: images and tables have size limits; table rows are not silently dropped and
/// features that overflow are refused instead of writing a model `eval` cannot read.
#[test]
fn images_and_tables_have_limits() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.png");
    std::fs::write(&big, png_declaring(60_000, 60_000)).unwrap();
    refused(subnav().arg("phasecorr").arg(&big).arg(&big), &["big.png", "60000 x 60000", "16384"]);

    let out = dir.path().join("m.json");
    let typo = dir.path().join("typo.csv");
    std::fs::write(&typo, "1,2.O,0\n1,2,0\n2,3,0\n2,2,0\n5,5,1\n6,5,1\n5,6,1\n6,6,1\n").unwrap();
    refused(subnav().args(["lmnn", "fit", "--train"]).arg(&typo).arg("--out").arg(&out), &["typo.csv", "line 1"]);
    let huge = dir.path().join("huge.csv");
    std::fs::write(&huge, "1e300,0\n-1e300,0\n1e300,0\n-1e300,0\n1e300,1\n-1e300,1\n1e300,1\n-1e300,1\n").unwrap();
    refused(subnav().args(["lmnn", "fit", "--train"]).arg(&huge).arg("--out").arg(&out), &["too large"]);
    let many = dir.path().join("many.csv");
    let rows: String = (0..10_001).map(|i| format!("{},{}\n", i, i % 2)).collect();
    std::fs::write(&many, rows).unwrap();
    refused(subnav().args(["lmnn", "fit", "--train"]).arg(&many).arg("--out").arg(&out), &["10001 rows", "10000"]);
    assert!(!out.exists());
}

/// A.3, A.5: a nav row far away (a grid of 4.8e17 bytes) and a sounding at 1e300 m (exit 0
/// with empty grids) are refused with their bound.
#[test]
fn bathy_surveys_have_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let nav = dir.path().join("nav.csv");
    let snd = dir.path().join("soundings.csv");
    let nav_rows = "t_s,north_m,east_m,depth_m,heading_rad\n0,0,0,10,0\n10,10,0,10,0\n20,1e15,0,10,0\n";
    std::fs::write(&nav, nav_rows).unwrap();
    let pings: String = (0..20).map(|t| format!("{t},-0.3,20\n{t},0,18\n{t},0.3,20\n")).collect();
    std::fs::write(&snd, format!("t_s,beam_angle_rad,range_m\n{pings}")).unwrap();
    let run_on = |out: &str| {
        let mut c = subnav();
        c.args(["bathy", "run", "--altitude-m", "18", "--no-plots", "--soundings"])
            .arg(&snd)
            .arg("--nav")
            .arg(&nav)
            .arg("--out")
            .arg(dir.path().join(out));
        c
    };
    refused(&mut run_on("a"), &["the survey spans", "cells"]);
    std::fs::write(&nav, nav_rows.replace("1e15", "20")).unwrap();
    std::fs::write(&snd, format!("t_s,beam_angle_rad,range_m\n0,0.1,1e300\n{pings}")).unwrap();
    refused(&mut run_on("b"), &["soundings.csv", "range_m must be in 0..=12000"]);
}

/// B: numbers that gave silently wrong results now have ranges; outputs that said nothing
/// useful are errors.
#[test]
fn silent_wrong_results_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (flag, v) in [("--temp-c", "-273.15"), ("--temp-c", "-300"), ("--pressure-hpa", "-1"), ("--elevation-m", "-1e6")] {
        refused(subnav().args(["sun", "--time", "2026-06-21T12:00:00Z", "--lat", "44", "--lon", "-2", flag, v]), &[flag]);
    }
    for (flag, v) in [("--depth-m", "-5"), ("--depth-m", "nan"), ("--draws", "0")] {
        refused(subnav().args(["compass", "simulate", flag, v]), &[flag]);
    }
    for (flag, v) in [("--trials", "0"), ("--track-s", "0"), ("--interval-s", "0")] {
        refused(subnav().args(["compass", "geolocate", flag, v]), &[flag]);
    }
    for (flag, v) in [("--every-s", "0"), ("--every-s", "-1"), ("--every-s", "nan")] {
        refused(subnav().args(["filter", "replay", "log.csv", "--out", "o.csv", flag, v]), &[flag]);
    }
    for v in ["0", "-1", "nan"] {
        refused(subnav().args(["filter", "monte-carlo", "--duration-s", v]), &["--duration-s"]);
        refused(subnav().args(["report", "simulate", "--duration-s", v, "--out"]).arg(d.join("r")), &["--duration-s"]);
    }
    refused(subnav().args(["sim", "--leg-m", "inf", "--out"]).arg(d.join("s.json")), &["leg_m"]);
    refused(subnav().args(["sim", "--imu-nack", "-5,-1", "--out"]).arg(d.join("s.json")), &["faults.imu_nack_s", "0 <= start"]);
    // Uniform or tiny images have no shift to measure.
    let grey_png = |path: &Path, side: u32| {
        let mut e = png::Encoder::new(std::fs::File::create(path).unwrap(), side, side);
        e.set_color(png::ColorType::Grayscale);
        e.set_depth(png::BitDepth::Eight);
        e.write_header().unwrap().write_image_data(&vec![0u8; (side * side) as usize]).unwrap();
    };
    let black = d.join("black.png");
    grey_png(&black, 64);
    refused(subnav().arg("phasecorr").arg(&black).arg(&black), &["black.png", "uniform"]);
    let tiny = d.join("tiny.png");
    grey_png(&tiny, 1);
    refused(subnav().arg("phasecorr").arg(&tiny).arg(&tiny), &["tiny.png", "at least 8"]);
}

/// C: SVG figures failed on every report (the font was registered only for PNG) and left
/// `trajectory.svg` behind; now they are drawn, and no temporary file stays.
#[test]
fn svg_reports_are_drawn() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
    let (o, e) = run(subnav().args(["report", "simulate", "--duration-s", "30", "--images", "svg", "--out"]).arg(&out));
    assert!(o.status.success(), "{e}");
    let names = files_in(&out);
    assert!(names.iter().any(|n| n == "trajectory.svg"), "{names:?}");
    assert!(names.iter().all(|n| !n.starts_with('.')), "temporary files left: {names:?}");
}

/// C: a recording whose header names a directory, a text file or `/dev/zero` as its ELF: the
/// error names the ELF and that it came from the header (and `/dev/zero` is not read until
/// out of memory).
#[test]
fn a_bad_elf_in_the_header_is_named() {
    use subnav_link::record::{Meta, Stream, Writer};
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not an ELF\n").unwrap();
    for (elf, why) in
        [(dir.path().to_path_buf(), "not a regular file"), (text, "not an ELF file"), ("/dev/zero".into(), "not a regular file")]
    {
        let mut meta = Meta::new("test");
        meta.elf = Some(elf.display().to_string());
        let mut w = Writer::new(Vec::new(), &meta).unwrap();
        w.chunk(Stream::Defmt, 1, b"\x01\x02").unwrap();
        let rec = dir.path().join("r.snrec");
        std::fs::write(&rec, w.into_inner()).unwrap();
        let elf_s = elf.display().to_string();
        refused(subnav().args(["decode", "--file"]).arg(&rec), &[&elf_s, why, "header of"]);
        refused(subnav().arg("export").arg(&rec).arg("--csv").arg(dir.path().join("csv")), &[&elf_s, why, "header of"]);
    }
}

/// B: a truth that does not overlap the recording gave no statistics and no warning.
#[test]
fn a_truth_that_does_not_overlap_is_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
    let (o, e) = run(subnav().args(["report", "simulate", "--duration-s", "30", "--out"]).arg(&out));
    assert!(o.status.success(), "{e}");
    let truth = dir.path().join("late_truth.csv");
    std::fs::write(&truth, "t_s,n_m,e_m,d_m,yaw_rad\n5000,0,0,0,0\n5001,0,0,0,0\n").unwrap();
    let (o, e) = run(subnav()
        .args(["report", "recording"])
        .arg(out.join("dive.snrec"))
        .arg("--truth")
        .arg(&truth)
        .arg("--out")
        .arg(dir.path().join("r2")));
    assert!(o.status.success(), "{e}");
    assert!(e.contains("does not overlap"), "{e}");
}

/// B: `ice run --input` on a data set with a camera of focal length, baseline or pixel noise 0
/// or a non-rotation `rot_bc` ("0 features used"), a still period longer than the data, empty
/// tracks or IMU samples 1 ns apart ("0 poses", exit 0): errors naming the file and the bound.
#[test]
fn ice_data_sets_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("ds");
    let (o, e) = run(subnav().args(["ice", "simulate", "--distance-m", "20", "--write"]).arg(&ds));
    assert!(o.status.success(), "{e}");
    let cam_text = std::fs::read_to_string(ds.join("camera.json")).unwrap();
    let cam: serde_json::Value = serde_json::from_str(&cam_text).unwrap();
    let ds_s = ds.display().to_string();
    for (field, v, needle) in [
        ("focal_px", serde_json::json!(0.0), "focal_px must be > 0"),
        ("baseline_m", serde_json::json!(0.0), "baseline_m must be > 0"),
        ("sigma_px", serde_json::json!(-1.0), "sigma_px must be > 0"),
        ("rot_bc", serde_json::json!([2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), "rot_bc must be a rotation"),
    ] {
        let mut c = cam.clone();
        c[field] = v;
        std::fs::write(ds.join("camera.json"), c.to_string()).unwrap();
        refused(subnav().args(["ice", "run", "--input"]).arg(&ds), &[&ds_s, needle]);
    }
    std::fs::write(ds.join("camera.json"), &cam_text).unwrap();
    std::fs::write(ds.join("meta.json"), "{\"still_s\": 1e9}").unwrap();
    refused(subnav().args(["ice", "run", "--input"]).arg(&ds), &["still_s must be in"]);
    std::fs::write(ds.join("meta.json"), "{\"still_s\": 2.0}").unwrap();
    let imu = std::fs::read_to_string(ds.join("imu.csv")).unwrap();
    let mut lines: Vec<String> = imu.lines().map(String::from).collect();
    lines[2] = lines[2].replacen("0.005000", "0.000000001", 1);
    std::fs::write(ds.join("imu.csv"), lines.join("\n") + "\n").unwrap();
    refused(subnav().args(["ice", "run", "--input"]).arg(&ds), &["imu.csv", "closer than 10 us"]);
    std::fs::write(ds.join("imu.csv"), &imu).unwrap();
    std::fs::write(ds.join("tracks.csv"), "t_s,frame_id,feature_id,ul,vl,ur,vr\n").unwrap();
    refused(subnav().args(["ice", "run", "--input"]).arg(&ds), &["tracks.csv"]);
}

// Issue 40, "careless input, round two": each test below is a finding of the issue's probe run
// that failed before and passes now.

/// A character device `c 1 minor` (3 = null, 7 = full) made with `mknod` in `dir`, or, where
/// this process may not make device nodes, the system's own (`/dev/null`, `/dev/full`: only
/// written to, and checked to be a device afterwards).
fn device(dir: &Path, minor: u32) -> std::path::PathBuf {
    let p = dir.join(format!("dev{minor}"));
    let made = Command::new("mknod").arg(&p).args(["c", "1", &minor.to_string()]).status().is_ok_and(|s| s.success());
    if made { p } else { std::path::PathBuf::from(if minor == 3 { "/dev/null" } else { "/dev/full" }) }
}

fn is_char_device(p: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(p).is_ok_and(|m| m.file_type().is_char_device())
}

/// A small recording with one uplink chunk.
fn tiny_recording(path: &Path) -> Vec<u8> {
    let mut w = subnav_link::record::Writer::new(Vec::new(), &subnav_link::record::Meta::new("test")).unwrap();
    w.chunk(subnav_link::record::Stream::Uplink, 1, b"\x00").unwrap();
    let bytes = w.into_inner();
    std::fs::write(path, &bytes).unwrap();
    bytes
}

/// Issue 40 (1): `run --record`, `export --mcap` and `filter replay --out` renamed a temporary
/// file over a device node (a `mknod NAME c 1 3` node became a 315,185-byte regular file), and
/// a `/dev/full` node reported success. Now a device is written in place and stays a device; a
/// full one is an error naming it.
#[test]
fn a_device_given_as_output_is_still_a_device_afterwards() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (null, full) = (device(d, 3), device(d, 7));
    let full_s = full.display().to_string();
    let rec = d.join("r.snrec");
    tiny_recording(&rec);
    let (o, e) = run(subnav().arg("export").arg(&rec).arg("--mcap").arg(&null));
    assert!(o.status.success(), "{e}");
    refused(subnav().arg("export").arg(&rec).arg("--mcap").arg(&full), &[&full_s, "No space left"]);
    let log = d.join("log.csv");
    assert!(subnav().args(["filter", "simulate", "--duration-s", "20", "--out"]).arg(&log).status().unwrap().success());
    let (o, e) = run(subnav().args(["filter", "replay"]).arg(&log).arg("--out").arg(&null));
    assert!(o.status.success(), "{e}");
    refused(subnav().args(["filter", "replay"]).arg(&log).arg("--out").arg(&full), &[&full_s, "No space left"]);
    let sc = d.join("dive.json");
    assert!(subnav().args(["sim", "--duration-s", "20", "--out"]).arg(&sc).status().unwrap().success());
    let (o, e) = run(subnav().args(["run", "--native", "--quiet"]).arg(&sc).arg("--record").arg(&null).arg("--truth").arg(&null));
    assert!(o.status.success(), "{e}");
    refused(subnav().args(["run", "--native", "--quiet"]).arg(&sc).arg("--record").arg(&full), &[&full_s, "No space left"]);
    refused(subnav().args(["run", "--native", "--quiet"]).arg(&sc).arg("--truth").arg(&full), &[&full_s, "No space left"]);
    for p in [&null, &full] {
        assert!(is_char_device(p), "{} is no longer a device", p.display());
    }
    let mut names = files_in(d);
    names.retain(|n| !n.starts_with("dev"));
    assert_eq!(names, ["dive.json", "log.csv", "r.snrec"], "a temporary file was left behind");
}

/// Issue 40 (1): two outputs of one command that are one file (`run --record X --truth X`,
/// `fgo replay --out X --decisions X`, `fgo simulate --out X --truth X`, `compass envelope
/// --png X --table X`, also through `..`) exited 0 with one output lost. Now refused before any
/// work, and an old file there is left byte for byte.
#[test]
fn two_outputs_that_are_one_file_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("sub")).unwrap();
    let x = d.join("x.out");
    std::fs::write(&x, b"old").unwrap();
    let via_dotdot = d.join("sub").join("..").join("x.out");
    let sc = d.join("dive.json");
    assert!(subnav().args(["sim", "--duration-s", "5", "--out"]).arg(&sc).status().unwrap().success());
    refused(
        subnav().args(["run", "--native"]).arg(&sc).arg("--record").arg(&x).arg("--truth").arg(&via_dotdot),
        &["--record", "--truth", "same file"],
    );
    refused(
        subnav().args(["run", "--native"]).arg(&sc).arg("--truth").arg(&x).arg("--mavlink-summary").arg(&x),
        &["--truth", "--mavlink-summary", "same file"],
    );
    refused(
        subnav().args(["fgo", "replay", "--input"]).arg(d.join("log.jsonl")).arg("--out").arg(&x).arg("--decisions").arg(&x),
        &["--out", "--decisions", "same file"],
    );
    refused(subnav().args(["fgo", "simulate", "--out"]).arg(&x).arg("--truth").arg(&via_dotdot), &["--out", "--truth", "same file"]);
    refused(subnav().args(["filter", "simulate", "--out"]).arg(&x).arg("--truth").arg(&x), &["same file"]);
    let png = d.join("e.png");
    refused(subnav().args(["compass", "envelope", "--png"]).arg(&png).arg("--table").arg(&png), &["--png", "--table", "same file"]);
    // Outputs that do not exist yet collide too.
    let new = d.join("new.csv");
    refused(subnav().args(["fgo", "simulate", "--out"]).arg(&new).arg("--truth").arg(d.join("./new.csv")), &["same file"]);
    assert!(!new.exists() && !png.exists());
    assert_eq!(std::fs::read(&x).unwrap(), b"old");
    // An output that is the reference it is compared with.
    let field = d.join("field.csv");
    std::fs::write(&field, "a reference\n").unwrap();
    refused(
        subnav()
            .args(["compass", "field", "--sun-zenith-deg", "30", "--depth-m", "10", "--output"])
            .arg(&field)
            .arg("--compare")
            .arg(&field),
        &["--output", "also an input"],
    );
    assert_eq!(std::fs::read_to_string(&field).unwrap(), "a reference\n");
    // The figure's format comes from its name ("ImageError(Unsupported(...))").
    refused(subnav().args(["compass", "envelope", "--png"]).arg(d.join("fig")), &["--png", "fig", "ending in .png"]);
}

/// Issue 40 (1): `report recording --out DIR` with the recording in DIR cut it from 474,045 to
/// 1,058 bytes; `bathy run --nav D/trajectory_corrected.csv --out D` rewrote its own input.
/// An output directory that holds an input is refused before anything is read.
#[test]
fn an_output_directory_holding_an_input_is_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let rec = d.join("dive.snrec");
    let bytes = tiny_recording(&rec);
    refused(subnav().args(["report", "recording"]).arg(&rec).arg("--out").arg(d), &["--out", "holds the input", "dive.snrec"]);
    refused(subnav().args(["report", "recording"]).arg(&rec).arg("--out").arg(d.join("x").join("..")), &["holds the input"]);
    assert_eq!(std::fs::read(&rec).unwrap(), bytes);
    let nav = d.join("trajectory_corrected.csv");
    let snd = d.join("soundings.csv");
    std::fs::write(&nav, "t_s,north_m,east_m,depth_m,heading_rad\n0,0,0,10,0\n").unwrap();
    std::fs::write(&snd, "t_s,beam_angle_rad,range_m\n0,0,18\n").unwrap();
    refused(
        subnav().args(["bathy", "run", "--no-plots", "--soundings"]).arg(&snd).arg("--nav").arg(&nav).arg("--out").arg(d),
        &["--out", "holds the input"],
    );
    assert_eq!(std::fs::read_to_string(&nav).unwrap(), "t_s,north_m,east_m,depth_m,heading_rad\n0,0,0,10,0\n");
    refused(subnav().args(["ice", "run", "--input"]).arg(d).arg("--out").arg(d), &["--out", "also an input"]);
    refused(subnav().args(["run", "--native"]).arg(d.join("sc.json")).arg("--report").arg(d), &["--report"]);
    assert_eq!(files_in(d), ["dive.snrec", "soundings.csv", "trajectory_corrected.csv"]);
    // A real dive's recording, reported on into its own directory.
    let sim = d.join("sim");
    let (o, e) = run(subnav().args(["report", "simulate", "--duration-s", "30", "--out"]).arg(&sim));
    assert!(o.status.success(), "{e}");
    let real = std::fs::read(sim.join("dive.snrec")).unwrap();
    let before = files_in(&sim);
    refused(subnav().args(["report", "recording"]).arg(sim.join("dive.snrec")).arg("--out").arg(&sim), &["holds the input"]);
    assert_eq!(std::fs::read(sim.join("dive.snrec")).unwrap(), real);
    assert_eq!(files_in(&sim), before);
}

/// Issue 40 (2): `calibrate head --flash FILE` and `qemu --flash FILE` took any existing file up
/// to 2 MiB as a flash image (a 9-byte text file became 2 MiB; `qemu` grew it even when its ELF
/// check then failed) and `--flash /dev/zero` read until 4.1 GB of memory. Now a file that is
/// not an image is refused untouched, a device before it is read.
#[test]
fn a_file_that_is_not_a_flash_image_is_refused_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let note = d.join("note.txt");
    std::fs::write(&note, b"my notes\n").unwrap();
    refused(subnav().args(["calibrate", "head", "--flash"]).arg(&note), &["note.txt", "9 bytes", "2097152", "--new-flash"]);
    let rec = d.join("dive.snrec");
    let bytes = tiny_recording(&rec);
    refused(subnav().args(["calibrate", "head", "--flash"]).arg(&rec), &["dive.snrec", "not a flash image"]);
    let t0 = Instant::now();
    refused(subnav().args(["calibrate", "head", "--flash", "/dev/zero"]), &["/dev/zero", "not a regular file"]);
    assert!(t0.elapsed() < Duration::from_secs(10));
    refused(subnav().args(["calibrate", "head", "--new-flash", "--flash", "/dev/zero"]), &["/dev/zero", "not a regular file"]);
    // `qemu` checks its ELF before it touches the image: neither grown nor created.
    let elf = d.join("fw.elf");
    std::fs::write(&elf, b"not an elf").unwrap();
    refused(subnav().args(["qemu", "--elf"]).arg(&elf).arg("--flash").arg(&note), &["fw.elf", "not an ELF"]);
    refused(subnav().args(["qemu", "--elf"]).arg(&elf).arg("--flash").arg(d.join("new.flash")), &["fw.elf", "not an ELF"]);
    refused(subnav().args(["qemu", "--elf"]).arg(&elf).arg("--flash").arg(&elf), &["fw.elf"]);
    assert_eq!(std::fs::read(&note).unwrap(), b"my notes\n");
    assert_eq!(std::fs::read(&rec).unwrap(), bytes);
    assert_eq!(std::fs::read(&elf).unwrap(), b"not an elf");
    assert_eq!(files_in(d), ["dive.snrec", "fw.elf", "note.txt"]);
}

/// Issue 40 (3): `fgo monte-carlo --seeds 0..18446744073709551615` panicked (capacity overflow,
/// exit 101); the same range on `run`, `filter monte-carlo`, `bathy simulate`, `ice simulate`,
/// `calibrate compare`, `phasecorr --time-repeat 100000000` and `run --speed 1e-9` ran until
/// killed. Now usage errors with the bound.
#[test]
fn counts_repeats_and_rates_have_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let all = "0..18446744073709551615";
    for cmd in [
        &["fgo", "monte-carlo", "--seeds", all][..],
        &["run", "--native", "--seeds", all],
        &["filter", "monte-carlo", "--seeds", all],
        &["bathy", "simulate", "--out", "b", "--seeds", all],
        &["ice", "simulate", "--seeds", all],
        &["calibrate", "compare", "--seeds", all],
    ] {
        refused(subnav().current_dir(dir.path()).args(cmd), &["--seeds", "10000"]);
    }
    refused(subnav().args(["phasecorr", "a.png", "b.png", "--time-repeat", "100000000"]), &["--time-repeat", "0..=10000"]);
    refused(subnav().args(["run", "--native", "--speed", "1e-9"]), &["--speed", "0.1"]);
    refused(subnav().args(["mavlink", "--from", "native", "--to", "udpout:127.0.0.1:9", "--speed", "1e-9"]), &["--speed", "0.1"]);
    refused(subnav().args(["qemu", "--elf", "x.elf", "--timeout-s", "0"]), &["--timeout-s", "1..=604800"]);
    refused(subnav().args(["qemu", "--elf", "x.elf", "--timeout-s", "18446744073709551615"]), &["--timeout-s"]);
    assert!(files_in(dir.path()).is_empty());
}

/// Issue 40 (4): NaN and negative sigmas and slopes were taken ("reported 1-sigma NaN deg"); one
/// `1e300` time in a `filter replay` log froze the position (exit 0); `ice run` with negative
/// frame numbers or 1e30 ids reported "0 poses ... ATE 0.000 m" as a success; `run --elf
/// --seeds` ignored `--elf`.
#[test]
fn nonsense_numbers_and_empty_results_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (flag, v) in [("--tilt-sigma-deg", "nan"), ("--tilt-sigma-deg", "-1"), ("--slope-rms", "-0.1"), ("--slope-rms", "inf")] {
        refused(subnav().args(["compass", "simulate", flag, v]), &[flag]);
    }
    refused(subnav().args(["compass", "geolocate", "--heading-sigma-deg", "-1"]), &["--heading-sigma-deg", "0..=180"]);
    // A track too short for any fix: no statistics, not "median NaN".
    refused(
        subnav().args(["compass", "geolocate", "--trials", "1", "--track-s", "1", "--interval-s", "1"]),
        &["no trial", "no statistics"],
    );
    let log = d.join("log.csv");
    assert!(subnav().args(["filter", "simulate", "--duration-s", "20", "--out"]).arg(&log).status().unwrap().success());
    let text = std::fs::read_to_string(&log).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    let at = lines.len() / 2;
    let damaged = lines[at].replacen(lines[at].split(',').next().unwrap(), "1e300", 1);
    lines[at] = &damaged;
    std::fs::write(&log, lines.join("\n")).unwrap();
    refused(
        subnav().args(["filter", "replay"]).arg(&log).arg("--out").arg(d.join("o.csv")),
        &["log.csv", &format!("line {}", at + 1), "0..=1e10"],
    );
    assert!(!d.join("o.csv").exists());

    let ds = d.join("ds");
    let (o, e) = run(subnav().args(["ice", "simulate", "--distance-m", "20", "--quiet", "--write"]).arg(&ds));
    let table = String::from_utf8_lossy(&o.stdout);
    // RPE over 50 m of a 20-m track has nothing behind it: "n/a", not "NaN [NaN]".
    assert!(o.status.success() && table.contains("n/a") && !table.contains("NaN"), "{e}{table}");
    let tracks = std::fs::read_to_string(ds.join("tracks.csv")).unwrap();
    for bad in ["-1", "1e30"] {
        let mut rows: Vec<String> = tracks.lines().map(String::from).collect();
        let f: Vec<&str> = rows[1].split(',').collect();
        rows[1] = [f[0], bad, &f[2..].join(",")].join(",");
        std::fs::write(ds.join("tracks.csv"), rows.join("\n") + "\n").unwrap();
        refused(subnav().args(["ice", "run", "--input"]).arg(&ds), &["tracks.csv", "frame_id", "data row 1"]);
    }
    // Tracks with no usable frame: an error, not "0 poses" as a success.
    std::fs::write(ds.join("tracks.csv"), "t_s,frame_id,feature_id,ul,vl,ur,vr\n0,0,0,0,0,0,0\n").unwrap();
    let (o, e) = run(subnav().args(["ice", "run", "--input"]).arg(&ds));
    assert!(!o.status.success() && !String::from_utf8_lossy(&o.stdout).contains("0 poses"), "{e}");

    refused(subnav().args(["run", "--elf", "fw.elf", "--seeds", "1..3"]), &["--elf", "--seeds"]);

    // A dive too short for an aided solution printed "RMS NaN m, final NaN m (NaN % of -0 m
    // travelled)" and exited 0.
    let sc = d.join("short.json");
    assert!(subnav().args(["sim", "--duration-s", "5", "--out"]).arg(&sc).status().unwrap().success());
    for extra in [&[][..], &["--seeds", "1..3"]] {
        let mut c = subnav();
        c.args(["run", "--native", "--quiet", "--duration-s", "1"]).arg(&sc).args(extra);
        let (o, e) = run(&mut c);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(!o.status.success() && e.contains("no aided navigation solution") && e.contains("no error statistics"), "{e}");
        assert!(!out.contains("NaN % of"), "{out}");
    }
}

/// Issue 40 (5): "version 0 is newer than this host reads (1)": a recording of format version 0
/// says what was found and what is expected.
#[test]
fn a_version_error_says_what_was_found_and_expected() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("v0.snrec");
    let mut bytes = tiny_recording(&rec);
    let m = subnav_link::record::MAGIC.len();
    bytes[m..m + 2].copy_from_slice(&0u16.to_le_bytes());
    let meta_len = u32::from_le_bytes(bytes[m + 2..m + 6].try_into().unwrap()) as usize;
    let end = m + 6 + meta_len;
    let crc = subnav_wire::frame::FRAME_CRC.checksum(&bytes[m..end]);
    bytes[end..end + 4].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(&rec, &bytes).unwrap();
    let (o, e) = run(subnav().args(["decode", "--file"]).arg(&rec));
    let all = format!("{e}{}", String::from_utf8_lossy(&o.stdout));
    assert!(all.contains("found version 0") && all.contains("expected 1..=1") && !all.contains("newer"), "{all}");
}
