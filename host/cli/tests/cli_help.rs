//! Every `subnav` subcommand (and nested subcommand) has a non-empty, correct about line, and
//! the commands `--help` lists are exactly the expected ones (a new subcommand without an entry
//! here fails). "Correct" is checked against a keyword per command: its own keyword is in its
//! about line, and no sibling's keyword is (this catches a doc comment attached to the wrong
//! variant, e.g. `ice` described as "Flash a board's firmware").

use std::collections::BTreeMap;
use std::process::Command;

/// (command path, a keyword its about line must contain and its siblings' must not).
const EXPECTED: &[(&str, &str)] = &[
    ("fgo", "Factor-graph INS/DVL/USBL navigation"),
    ("fgo replay", "JSON-lines sensor log"),
    ("fgo simulate", "simulated AUV mission"),
    ("fgo monte-carlo", "gated vs ungated"),
    ("fgo pyfg", "PyFactorGraph"),
    ("decode", "Decode telemetry"),
    ("qemu", "Boot a firmware ELF in QEMU"),
    ("bathy", "Bathymetric graph SLAM"),
    ("bathy run", "CSV soundings"),
    ("bathy simulate", "simulated surveys"),
    ("filter", "navigation filter on the host"),
    ("filter simulate", "Write a simulated dive"),
    ("filter replay", "Replay a CSV sensor log"),
    ("filter monte-carlo", "AUKF vs plain UKF"),
    ("sun", "solar zenith"),
    ("compass", "Polarization compass"),
    ("compass simulate", "Heading Monte Carlo"),
    ("compass geolocate", "geolocation"),
    ("compass csv", "CSV of raw channel counts"),
    ("compass envelope", "operating envelope"),
    ("compass field", "downwelling Stokes field"),
    ("compass departure-table", "AoP departure table"),
    ("record", "Record telemetry"),
    ("export", "Export a recording"),
    ("sim", "simulated dive scenario"),
    ("run", "firmware in the loop"),
    ("mavlink", "autopilot over MAVLink"),
    ("report", "Mission report"),
    ("report recording", "Report on a recording"),
    ("report simulate", "Simulate a dive"),
    ("lmnn", "LMNN metric learning"),
    ("lmnn fit", "Learn the metric"),
    ("lmnn eval", "kNN accuracy"),
    ("map", "Topological map"),
    ("map simulate", "Simulated survey with revisits"),
    ("map build", "Build a map"),
    ("ice", "Under-ice odometry"),
    ("ice run", "data directory"),
    ("ice simulate", "simulated under-ice runs"),
    ("phasecorr", "phase correlation"),
    ("replay", "firmware's estimator"),
    ("calibrate", "Calibrate a simulated head"),
    ("calibrate head", "Record the calibration sequence"),
    ("calibrate compare", "Mis-built heads"),
];

/// Commands that exist only in builds with the debug-probe feature.
const PROBE_ONLY: &[(&str, &str)] = &[("flash", "Flash a board's firmware"), ("attach", "Attach to a running board")];

/// PENDING MERGE: `replay` is added on another branch. Until that branch is merged it may be
/// absent; when present it is checked like every other entry. Remove it from this list at merge.
const PENDING_MERGE: &[&str] = &[];

fn subnav(args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_subnav")).args(args).output().unwrap();
    assert!(o.status.success(), "subnav {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// The `Commands:` section of a help text: (name, about) in order, without clap's `help`.
fn commands(help: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut lines = help.lines().skip_while(|l| l.trim() != "Commands:");
    lines.next();
    for l in lines.take_while(|l| !l.trim().is_empty()) {
        let l = l.trim();
        let (name, about) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
        if name != "help" {
            out.push((name.to_string(), about.trim().to_string()));
        }
    }
    out
}

/// Walks the command tree from `path` (empty: the root): every listed command's about line,
/// keyed by its path ("ice simulate").
fn walk(path: &[&str], found: &mut BTreeMap<String, String>) {
    let mut args = path.to_vec();
    args.push("--help");
    for (name, about) in commands(&subnav(&args)) {
        let mut sub = path.to_vec();
        sub.push(&name);
        let key = sub.join(" ");
        // The about line of `<path> <name> --help` (first line) is the one listed by the parent.
        let mut h = sub.clone();
        h.push("--help");
        let own = subnav(&h);
        let first = own.lines().next().unwrap_or("").trim().trim_end_matches('.');
        assert_eq!(first, about.trim_end_matches('.'), "`subnav {key} --help` begins with another about line than the listing");
        assert!(found.insert(key, about).is_none());
        walk(&sub, found);
    }
}

#[test]
fn every_subcommand_has_a_correct_about_line() {
    let mut expected: BTreeMap<&str, &str> = EXPECTED.iter().copied().collect();
    if cfg!(feature = "probe") {
        expected.extend(PROBE_ONLY.iter().copied());
    }
    let mut found = BTreeMap::new();
    walk(&[], &mut found);
    for p in PENDING_MERGE {
        if !found.contains_key(*p) {
            eprintln!("note: `{p}` is not in this build (pending merge)");
            expected.retain(|k, _| k != p && !k.starts_with(&format!("{p} ")));
        }
    }
    let listed: Vec<&str> = found.keys().map(String::as_str).collect();
    let wanted: Vec<&str> = expected.keys().copied().collect();
    assert_eq!(listed, wanted, "the commands in `subnav --help` (and nested) differ from the expected table");
    for (path, about) in &found {
        assert!(!about.is_empty(), "`subnav {path}` has no about line");
        let keyword = expected[path.as_str()];
        assert!(about.contains(keyword), "`subnav {path}`: about line {about:?} does not contain {keyword:?}");
        let parent = path.rsplit_once(' ').map_or("", |(p, _)| p);
        // Siblings include the probe-only commands in every build, so that their description
        // on another command is caught without the probe feature too.
        for (other, other_keyword) in EXPECTED.iter().chain(PROBE_ONLY) {
            let other_parent = other.rsplit_once(' ').map_or("", |(p, _)| p);
            if other != path && other_parent == parent {
                assert!(!about.contains(other_keyword), "`subnav {path}`: about line {about:?} describes `{other}` ({other_keyword:?})");
            }
        }
    }
    // Without the probe feature nothing mentions flashing.
    if !cfg!(feature = "probe") {
        for (path, about) in &found {
            assert!(!about.contains("Flash"), "`subnav {path}`: about line {about:?} mentions flashing in a build without probe");
        }
    }
}
