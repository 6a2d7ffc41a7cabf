//! `subnav lmnn` and `subnav map` end to end: outputs exist and are well formed, LMNN improves
//! on a problem where the Euclidean metric is misled by a noisy feature, and bad input gives
//! clear errors, never panics.

use std::fmt::Write as _;
use std::process::{Command, Output};

fn subnav(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_subnav")).args(args).output().unwrap()
}

fn ok(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn fails_cleanly(o: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(needle), "expected {needle:?} in {err}");
}

/// Three classes separated along feature 0, plus five noise features.
fn csv(n: usize, seed: u64) -> String {
    let mut s = String::from("signal,n1,n2,n3,n4,n5,label\n");
    let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut rnd = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (x >> 11) as f64 / (1u64 << 53) as f64
    };
    for i in 0..n {
        let c = i % 3;
        let _ = write!(s, "{}", c as f64 + 0.3 * (rnd() - 0.5));
        for _ in 0..5 {
            let _ = write!(s, ",{}", 6.0 * (rnd() - 0.5));
        }
        let _ = writeln!(s, ",{c}");
    }
    s
}

#[test]
fn lmnn_fit_eval_and_bad_input() {
    let d = tempfile::tempdir().unwrap();
    let (train, test, model) = (d.path().join("train.csv"), d.path().join("test.csv"), d.path().join("m.json"));
    std::fs::write(&train, csv(90, 1)).unwrap();
    std::fs::write(&test, csv(60, 2)).unwrap();
    let (tr, te, mo) = (train.to_str().unwrap(), test.to_str().unwrap(), model.to_str().unwrap());
    let v = ok(&subnav(&["lmnn", "fit", "--train", tr, "--k", "3", "--out", mo, "--format", "json"]));
    assert_eq!(v["samples"], 90);
    let v = ok(&subnav(&["lmnn", "eval", "--model", mo, "--test", te, "--format", "json"]));
    let (acc, eu) = (v["accuracy"].as_f64().unwrap(), v["euclidean_accuracy"].as_f64().unwrap());
    assert!(acc > 0.95 && acc > eu + 0.1, "learned {acc} vs Euclidean {eu}");

    std::fs::write(d.path().join("bad.csv"), "1,2,0\n3,oops,1\n").unwrap();
    fails_cleanly(&subnav(&["lmnn", "fit", "--train", d.path().join("bad.csv").to_str().unwrap(), "--out", mo]), "line 2");
    std::fs::write(d.path().join("small.csv"), "1,0\n2,0\n3,1\n4,1\n").unwrap();
    fails_cleanly(&subnav(&["lmnn", "fit", "--train", d.path().join("small.csv").to_str().unwrap(), "--out", mo]), "target neighbours");
    fails_cleanly(&subnav(&["lmnn", "eval", "--model", te, "--test", te]), "not an LMNN model");
    std::fs::write(d.path().join("wide.csv"), "1,2,3,0\n").unwrap();
    fails_cleanly(&subnav(&["lmnn", "eval", "--model", mo, "--test", d.path().join("wide.csv").to_str().unwrap()]), "features");
    fails_cleanly(&subnav(&["lmnn", "eval", "--model", "/nonexistent.json", "--test", te]), "nonexistent");
}

#[test]
fn map_simulate_writes_exports_and_build_reads_them() {
    let d = tempfile::tempdir().unwrap();
    let (out, img, built) = (d.path().join("out"), d.path().join("img"), d.path().join("built"));
    let v = ok(&subnav(&[
        "map",
        "simulate",
        "--laps",
        "2",
        "--quiet",
        "--format",
        "json",
        "--out-dir",
        out.to_str().unwrap(),
        "--images",
        img.to_str().unwrap(),
    ]));
    assert!(v["fixes"].as_u64().unwrap() > 0);
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
    assert_eq!(json["nodes"].as_array().unwrap().len() as u64, v["nodes"].as_u64().unwrap());
    let gml = std::fs::read_to_string(out.join("map.graphml")).unwrap();
    assert_eq!(gml.matches("<node ").count() as u64, v["nodes"].as_u64().unwrap());
    assert!(gml.contains("<edge "));
    assert_eq!(&std::fs::read(out.join("map.png")).unwrap()[1..4], b"PNG");
    // Position fixes decode as downlink PositionFix commands.
    let mut frames = std::fs::read(out.join("fixes.bin")).unwrap();
    let mut n = 0;
    for fr in frames.split_mut(|b| *b == 0).filter(|f| !f.is_empty()) {
        let mut buf = fr.to_vec();
        buf.push(0);
        let dl: subnav_wire::Downlink = subnav_wire::decode_in_place(&mut buf).expect("fix frame");
        assert!(matches!(dl.command, subnav_wire::Command::PositionFix { .. }));
        n += 1;
    }
    assert_eq!(n, v["fixes"].as_u64().unwrap());

    // The written mosaics + nav log through `map build`, plus one broken image that is skipped.
    std::fs::write(img.join("123.png"), b"broken").unwrap();
    let o = subnav(&[
        "map",
        "build",
        "--nav",
        img.join("nav.csv").to_str().unwrap(),
        "--images",
        img.to_str().unwrap(),
        "--quiet",
        "--format",
        "json",
        "--out-dir",
        built.to_str().unwrap(),
    ]);
    let v = ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("skipping image"));
    assert!(v["nodes"].as_u64().unwrap() > 5 && v["recognitions"].as_u64().unwrap() > 0, "{v}");
    assert!(built.join("map.graphml").exists());

    fails_cleanly(&subnav(&["map", "build", "--nav", img.join("nav.csv").to_str().unwrap(), "--images", "/nonexistent"]), "nonexistent");
    std::fs::write(d.path().join("nav.csv"), "t_s,north_m,east_m\n0,0,x\n").unwrap();
    fails_cleanly(
        &subnav(&["map", "build", "--nav", d.path().join("nav.csv").to_str().unwrap(), "--images", img.to_str().unwrap()]),
        "line 2",
    );
    fails_cleanly(&subnav(&["map", "simulate", "--laps=-1"]), "laps");

    // Issue 23: an image far outside the navigation's span is skipped with a warning (it used to
    // stretch the survey to 1.8e13 s), a NaN training time is refused, and navigation that
    // misses every image is an error naming both spans (it was "not enough node samples").
    std::fs::remove_file(img.join("123.png")).unwrap();
    let first = std::fs::read_dir(&img).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|x| x == "png")).unwrap();
    std::fs::copy(&first, img.join("18446744073709551615.png")).unwrap();
    let nav = img.join("nav.csv");
    let o = subnav(&["map", "build", "--nav", nav.to_str().unwrap(), "--images", img.to_str().unwrap(), "--quiet", "--format", "json"]);
    ok(&o);
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("1 of")
            && String::from_utf8_lossy(&o.stderr).contains("outside the navigation's time span")
    );
    fails_cleanly(
        &subnav(&["map", "build", "--nav", nav.to_str().unwrap(), "--images", img.to_str().unwrap(), "--train-after-s", "nan"]),
        "--train-after-s",
    );
    let shifted: String = std::fs::read_to_string(&nav)
        .unwrap()
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("{l}\n")
            } else {
                let (t, rest) = l.split_once(',').unwrap();
                format!("{},{rest}\n", t.parse::<f64>().unwrap() + 10_000.0)
            }
        })
        .collect();
    let far = d.path().join("far_nav.csv");
    std::fs::write(&far, shifted).unwrap();
    fails_cleanly(&subnav(&["map", "build", "--nav", far.to_str().unwrap(), "--images", img.to_str().unwrap()]), "none of the");
}
