//! One scoring (issue 41): on the same short native dive, `subnav run`'s text summary, its
//! `--format json` output and the report it writes (`--report`: the recording decoded again and
//! scored against the truth it is given) give the same heading and position figures, and the
//! report says what it scores.

use std::process::Command;

fn subnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_subnav"))
}

/// The number after `key` in `text` (up to the next space, comma or unit).
fn after(text: &str, key: &str) -> String {
    let i = text.find(key).unwrap_or_else(|| panic!("{key:?} not in:\n{text}")) + key.len();
    text[i..].trim_start().split([' ', ',', ')', '|']).next().unwrap().to_string()
}

/// The last word before `key` in `text`.
fn before(text: &str, key: &str) -> String {
    let i = text.find(key).unwrap_or_else(|| panic!("{key:?} not in:\n{text}"));
    text[..i].split_whitespace().last().unwrap().to_string()
}

/// The value cell of the report's table row `name`.
fn row(md: &str, name: &str) -> String {
    let line = md.lines().find(|l| l.starts_with(&format!("| {name} |"))).unwrap_or_else(|| panic!("no row {name:?} in:\n{md}"));
    line.split('|').nth(2).unwrap().trim().split(' ').next().unwrap().to_string()
}

#[test]
fn cli_text_json_and_report_give_the_same_figures() {
    let dir = tempfile::tempdir().unwrap();
    let rep = dir.path().join("rep");
    let dive = ["run", "--native", "--quiet", "--duration-s", "240", "--seed", "3"];
    let text = subnav().args(dive).arg("--report").arg(&rep).output().unwrap();
    assert!(text.status.success(), "{}", String::from_utf8_lossy(&text.stderr));
    let text = String::from_utf8(text.stdout).unwrap();
    let json = subnav().args(["--format", "json"]).args(dive).output().unwrap();
    assert!(json.status.success(), "{}", String::from_utf8_lossy(&json.stderr));
    let j: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();

    let heading = text.lines().find(|l| l.starts_with("heading ")).unwrap();
    let position = text.lines().find(|l| l.starts_with("horizontal position")).unwrap();
    let depth = text.lines().find(|l| l.starts_with("depth ")).unwrap();
    let jf = |k: &str, digits: usize| format!("{:.*}", digits, j[k].as_f64().unwrap_or_else(|| panic!("{k} in {j}")));
    let jp = |k: &str| format!("{:.1}", 100.0 * j[k].as_f64().unwrap());
    // (text, JSON, report) for each figure, at the digits the text prints.
    let figures = [
        ("heading RMSE", after(heading, "RMSE"), jf("heading_rmse_deg", 3), row(&md, "heading RMSE (converged)")),
        ("heading max", after(heading, "max"), jf("heading_max_abs_err_deg", 3), row(&md, "heading max (converged)")),
        (
            "heading within 3 sigma",
            before(heading, "% within"),
            jp("heading_within_3_sigma"),
            row(&md, "heading within 3 sigma (converged)"),
        ),
        (
            "heading RMSE all aided",
            after(heading, "all aided: RMSE"),
            jf("heading_rmse_all_aided_deg", 2),
            row(&md, "heading RMSE (all aided)"),
        ),
        ("horizontal RMS", after(position, "RMS"), jf("horizontal_rms_err_m", 2), row(&md, "horizontal RMS")),
        ("horizontal final", after(position, "final"), jf("horizontal_final_err_m", 2), row(&md, "horizontal final")),
        ("horizontal max", after(position, "max"), jf("horizontal_max_err_m", 2), row(&md, "horizontal max")),
        ("horizontal within 3 sigma", before(position, "% within"), jp("within_3_sigma"), row(&md, "horizontal within 3 sigma (N and E)")),
        ("depth RMSE", after(depth, "RMSE"), jf("depth_rmse_m", 3), row(&md, "depth RMSE")),
    ];
    for (what, t, js, r) in &figures {
        assert!(t == js && js == r, "{what}: text {t}, JSON {js}, report {r}\n{text}\n{md}");
    }
    // Something was scored, the heading converged, and the figures are numbers.
    assert!(j["scored"].as_u64().unwrap() > 1000, "{j}");
    assert!(figures.iter().all(|f| f.1.parse::<f64>().is_ok_and(f64::is_finite)), "{figures:?}");
    // The report says what it scores.
    let n = j["scored"].as_u64().unwrap();
    assert!(md.contains(&format!("({n} aided solutions scored)")), "{md}");
    assert!(md.contains("the alignment before them left out") && md.contains("converged"), "{md}");
}
