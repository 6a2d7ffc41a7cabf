//! `subnav report` on a simulated dive (the host dive simulator through the shared navigation
//! filter, written as a recording with its truth): the figures and pages exist, every PNG decodes
//! (png crate: signature, chunk CRCs, zlib stream, size) and is not blank, the page links them,
//! and the error statistics are there and plausible.

use std::process::Command;

fn decode_png(path: &std::path::Path) -> (u32, u32, usize) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = dec.read_info().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let px = &buf[..info.buffer_size()];
    // Count distinct colours (a blank image has one).
    let step = info.color_type.samples();
    let mut colours: Vec<&[u8]> = px.chunks(step).collect();
    colours.sort_unstable();
    colours.dedup();
    (info.width, info.height, colours.len())
}

#[test]
fn report_on_a_simulated_dive_writes_valid_figures_and_pages() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["--format", "json", "report", "simulate", "--seed", "7", "--duration-s", "90", "--images", "both", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let stats = &v["report"]["stats"];
    assert!(stats["scored"].as_u64().unwrap() > 800, "{stats}"); // 10 Hz over 90 s
    let h = stats["horizontal_rms_err_m"].as_f64().unwrap();
    assert!(h > 0.0 && h < 5.0, "horizontal RMSE {h} m on a 90 s DVL-aided dive");
    let hd = stats["heading_rmse_deg"].as_f64().unwrap();
    assert!(hd > 0.0 && hd < 5.0, "heading RMSE {hd} deg");

    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for name in ["trajectory", "heading", "position_error", "health", "faults"] {
        let png = out.join(format!("{name}.png"));
        let (w, hgt, colours) = decode_png(&png);
        assert!(w >= 800 && hgt >= 200, "{name}: {w}x{hgt}");
        assert!(colours > 4, "{name}.png looks blank ({colours} colours)");
        let svg = std::fs::read_to_string(out.join(format!("{name}.svg"))).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{name}.svg");
        assert!(md.contains(&format!("]({name}.png)")), "report.md does not link {name}");
        assert!(html.contains(&format!("src=\"{name}.png\"")), "report.html does not link {name}");
    }
    assert!(md.contains("horizontal RMS |"));
    // The injected NaN depth samples (60 s, 61 s) show up as faults in the recording.
    assert!(md.contains("2 fault messages"), "{md}");
}

#[test]
fn report_without_anything_to_plot_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("empty.snrec");
    subnav_link::record::Writer::create(&rec, &subnav_link::record::Meta::new("test")).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_subnav"))
        .args(["report", "recording"])
        .arg(&rec)
        .arg("--out")
        .arg(dir.path().join("r"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nothing to report"), "{}", String::from_utf8_lossy(&o.stderr));
}
