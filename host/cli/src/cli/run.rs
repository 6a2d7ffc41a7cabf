//! `subnav run`: run a dive scenario (from `subnav sim`) with the firmware in the loop, under
//! QEMU (`--elf`, the reference: the board binary with its buses bridged to the simulated chips)
//! or natively (`--native`: the same application core compiled for the host, ~20x faster);
//! record the telemetry and the truth, and print heading and position error statistics.
//!
//! Without a scenario file it runs the main job: [`Scenario::map_survey`], a 30-minute
//! cross-hatch survey with the camera and the topological map in the loop and no USBL.
//! `--report DIR` writes the recording, the truth and the report (HTML + PNGs, the map's
//! nodes and the loop closures the head accepted on the trajectory) into DIR.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};

use super::Format;
use subnav_link::export::TimeBase;
use subnav_link::record::session::{TruthRow, truth_csv};
use subnav_sil::Scenario;
use subnav_sil::dive::{DiveResult, LiveStatus, truth_rows};
use subnav_sil::run::HeadRun;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scenario JSON (`subnav sim --out`); default: the main job (`Scenario::map_survey`: a
    /// 30-minute cross-hatch survey, camera and map in the loop, no USBL).
    pub scenario: Option<PathBuf>,
    /// Seed of the default scenario (with a scenario file: replaces its seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Replace the scenario's length, s.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Run the map open loop: it builds the map and counts its fixes without sending them.
    #[arg(long)]
    pub no_map_fixes: bool,
    /// Write the recording (unless --record says where), the truth and the report into this
    /// directory.
    #[arg(long, conflicts_with = "seeds")]
    pub report: Option<PathBuf>,
    /// The QEMU board firmware ELF (`cargo xtask build` puts it in target/firmware/subnav-qemu.elf).
    #[arg(long, required_unless_present = "native", conflicts_with = "native")]
    pub elf: Option<PathBuf>,
    /// Run the firmware's application core natively instead of under QEMU.
    #[arg(long)]
    pub native: bool,
    /// Write the telemetry recording here (`subnav export` / `report` read it).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Write the truth here (CSV `t_s,n_m,e_m,d_m,yaw_rad` at 10 Hz, for `subnav report --truth`).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Wall-clock limit for a QEMU run, s (1..=604800).
    #[arg(long, default_value_t = 1800, value_parser = super::args::int_in(1u64..=super::args::MAX_TIMEOUT_S))]
    pub timeout_s: u64,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Run the scenario once per seed (`N`, `A..B`, `A..=B`; native only) and print one line
    /// per seed and the mean of each figure.
    #[arg(long, value_parser = super::args::parse_seeds, requires = "native", conflicts_with_all = ["record", "truth", "foxglove", "mavlink"])]
    pub seeds: Option<super::args::Seeds>,
    #[command(flatten)]
    pub live: super::live::FoxgloveArgs,
    #[command(flatten)]
    pub mavlink: super::mavlink::MavlinkArgs,
    /// Native runs: at most this many seconds of dive per second of wall time (e.g. 1 to watch
    /// in real time; default: as fast as it goes; 0.1..=1e6). The results are the same at any speed.
    #[arg(long, requires = "native", value_parser = super::args::f64_in(super::args::MIN_SPEED..=1e6))]
    pub speed: Option<f64>,
    /// Native runs at a --speed: the telemetry reaches the host this long after the head wrote
    /// it, ms (a serial or acoustic link's delay; the bridge stamps the time of validity).
    #[arg(long, requires = "native", value_parser = super::args::f64_positive_upto(10_000.0))]
    pub link_delay_ms: Option<f64>,
}

fn load(args: &Args) -> Result<Scenario> {
    let (mut sc, name) = match &args.scenario {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| format!("reading the scenario {}", path.display()))?;
            let sc: Scenario = serde_json::from_str(&text)
                .with_context(|| format!("{} is not a scenario (write one with `subnav sim --out {}`)", path.display(), path.display()))?;
            (sc, path.display().to_string())
        }
        None => (Scenario::map_survey(args.seed.unwrap_or(1)), "the default scenario".to_string()),
    };
    if let Some(seed) = args.seed {
        sc.seed = seed;
    }
    if let Some(d) = args.duration_s {
        if !(d > 0.0 && d <= 86_400.0) {
            bail!("--duration-s {d}: must be in (0, 86400] s");
        }
        sc.duration_s = d;
    }
    if args.no_map_fixes {
        match sc.camera.as_mut() {
            Some(c) => c.map_fixes = false,
            None => bail!("--no-map-fixes: {name} has no camera (write one with `subnav sim --camera`)"),
        }
    }
    sc.validate().with_context(|| format!("the scenario {name}"))?;
    Ok(sc)
}

/// The map columns of a run (dashes without a camera).
fn map_cells(r: &DiveResult) -> String {
    match &r.map {
        Some(m) => format!(
            "{:>5}  {:>5}/{:<5}  {:>9.3}  {:>6.3}",
            m.mapper.nodes,
            m.fixes_accepted,
            m.fixes_sent,
            m.score.precision.unwrap_or(f64::NAN),
            m.score.recall.unwrap_or(f64::NAN)
        ),
        None => format!("{:>5}  {:>11}  {:>9}  {:>6}", "-", "-", "-", "-"),
    }
}

/// `--seeds`: one native run per seed, a line each, then the means.
fn run_seeds(sc: &Scenario, seeds: &super::args::Seeds, format: Format) -> Result<ExitCode> {
    let mut rows = Vec::new();
    if format == Format::Text {
        println!(
            "seed  horiz RMS m  final m  max m  final % dist  within 3 sigma %  heading RMSE deg  nodes  fixes ok/sent  precision  recall"
        );
    }
    let mut ok = true;
    // Runs with no aided solution have no error statistics (NaN): an error, not a mean of NaN.
    let mut unaided = 0usize;
    for seed in seeds.range() {
        let sc = Scenario { seed, ..sc.clone() };
        let r = HeadRun::native(&sc).run()?.score(&sc)?;
        ok &= r.nonfinite_values == 0;
        unaided += usize::from(r.score.scored == 0);
        if format == Format::Text {
            println!(
                "{seed:>4}  {:>11.2}  {:>7.2}  {:>5.2}  {:>12.3}  {:>16.1}  {:>16.3}  {}",
                r.score.horizontal_rms_err_m,
                r.score.horizontal_final_err_m,
                r.score.horizontal_max_err_m,
                r.final_err_pct_of_distance,
                100.0 * r.score.within_3_sigma,
                r.score.heading_rmse_deg,
                map_cells(&r)
            );
        }
        rows.push((seed, r));
    }
    let n = rows.len().max(1) as f64;
    let mean = |f: &dyn Fn(&DiveResult) -> f64| rows.iter().map(|(_, r)| f(r)).sum::<f64>() / n;
    let means = serde_json::json!({
        "horizontal_rms_err_m": mean(&|r| r.score.horizontal_rms_err_m),
        "horizontal_final_err_m": mean(&|r| r.score.horizontal_final_err_m),
        "horizontal_max_err_m": mean(&|r| r.score.horizontal_max_err_m),
        "final_err_pct_of_distance": mean(&|r| r.final_err_pct_of_distance),
        "within_3_sigma": mean(&|r| r.score.within_3_sigma),
        "heading_rmse_deg": mean(&|r| r.score.heading_rmse_deg),
    });
    match format {
        Format::Json => {
            let runs: Vec<_> = rows.iter().map(|(s, r)| serde_json::json!({"seed": s, "result": r})).collect();
            println!("{}", serde_json::json!({"runs": runs, "mean": means}));
        }
        Format::Text => println!(
            "mean  {:>11.2}  {:>7.2}  {:>5.2}  {:>12.3}  {:>16.1}  {:>16.3}",
            means["horizontal_rms_err_m"].as_f64().unwrap_or(f64::NAN),
            means["horizontal_final_err_m"].as_f64().unwrap_or(f64::NAN),
            means["horizontal_max_err_m"].as_f64().unwrap_or(f64::NAN),
            means["final_err_pct_of_distance"].as_f64().unwrap_or(f64::NAN),
            100.0 * means["within_3_sigma"].as_f64().unwrap_or(f64::NAN),
            means["heading_rmse_deg"].as_f64().unwrap_or(f64::NAN),
        ),
    }
    if !ok {
        eprintln!("error: a run produced non-finite estimates");
    }
    if unaided > 0 {
        eprintln!(
            "error: {unaided} of {} runs had no aided navigation solution ({} s dives): no error statistics; run longer dives",
            seeds.count, sc.duration_s
        );
    }
    Ok(if ok && unaided == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if let (Some(_), Some(elf)) = (&args.seeds, &args.elf) {
        bail!("--elf {} with --seeds: seeded runs are native only; drop --elf or --seeds", elf.display());
    }
    let inputs: Vec<&std::path::Path> = args.scenario.as_deref().into_iter().chain(args.elf.as_deref()).collect();
    // The outputs, with the files --report writes where --record / --truth do not say.
    let report_rec = args.report.as_ref().filter(|_| args.record.is_none()).map(|d| d.join("dive.snrec"));
    let report_truth = args.report.as_ref().filter(|_| args.truth.is_none()).map(|d| d.join("truth.csv"));
    let outputs: Vec<(&str, &std::path::Path)> = [
        ("--record", args.record.as_deref()),
        ("--truth", args.truth.as_deref()),
        ("--report", report_rec.as_deref()),
        ("--report", report_truth.as_deref()),
        ("--mavlink-summary", args.mavlink.bridge.mavlink_summary.as_deref()),
    ]
    .into_iter()
    .filter_map(|(f, p)| Some((f, p?)))
    .collect();
    subnav_link::output::check_outputs(&outputs, &inputs)?;
    if let Some(dir) = &args.report {
        subnav_link::output::refuse_dir_holding_input("--report", dir, &inputs)?;
        if let Some(rec) = args.record.as_deref().filter(|p| subnav_link::output::is_special(p)) {
            bail!("--record {} is not a regular file, and --report reads the recording back; record to a file", rec.display());
        }
    }
    let sc = load(&args)?;
    if let Some(seeds) = &args.seeds {
        return run_seeds(&sc, seeds, format);
    }
    let record = match (&args.record, &args.report) {
        (Some(p), _) => Some(p.clone()),
        (None, Some(dir)) => {
            std::fs::create_dir_all(dir).with_context(|| format!("creating the report directory {}", dir.display()))?;
            Some(dir.join("dive.snrec"))
        }
        (None, None) => None,
    };
    let pb = if args.quiet || format == Format::Json { ProgressBar::hidden() } else { ProgressBar::new(sc.duration_s.ceil() as u64) };
    if let Ok(style) = ProgressStyle::with_template("[{bar:30}] {pos}/{len} s ({eta})  {msg}") {
        pb.set_style(style.progress_chars("=> "));
    }
    let kind = if args.native { "native" } else { "QEMU" };
    pb.set_message(format!("{kind} dive starting"));
    let progress = |s: &LiveStatus| {
        pb.set_position(s.t_s as u64);
        let map = if sc.camera.is_some() {
            format!("  map {} nodes, fixes {}/{} accepted", s.map_nodes, s.fixes_accepted, s.fixes_sent)
        } else {
            String::new()
        };
        pb.set_message(format!(
            "{kind} {:?}: heading sigma {:.2} deg, position sigma {:.2} m{map}",
            s.mode, s.sigma_heading_deg, s.sigma_horizontal_m
        ));
    };
    let live = super::live::start(&args.live, TimeBase::Host)?;
    let feed = live.as_ref().map(|l| super::live::SimFeed::new(l, &sc));
    let bridge = super::mavlink::start(
        args.mavlink.mavlink.as_ref(),
        &args.mavlink.bridge,
        super::mavlink::scenario_origin(&sc),
        subnav_mavlink::HeadClock::estimated(10.0),
    )?;
    // An autopilot needs the solution in real time: a bridged native run goes at 1x unless told.
    let speed = if bridge.is_some() && args.native { Some(args.speed.unwrap_or(1.0)) } else { args.speed };
    let result: DiveResult = if args.native {
        // Host time of a native run: the firmware time plus the scenario's start (as in its recording).
        let t0 = u64::try_from(sc.start_utc_unix_us).unwrap_or(0);
        let started = std::time::Instant::now();
        if let Some(b) = &bridge {
            // The simulated head's clock: head time t happens at start + t / speed (the pacing below).
            b.set_head_clock(subnav_mavlink::HeadClock::Known { start_us: b.now_us(), speed: speed.unwrap_or(1.0) });
        }
        let observe = |t_us: u64, m: &subnav_wire::Uplink, map: Option<&subnav_sil::map_loop::MapLoop>| {
            if let Some(f) = &feed {
                f.on_uplink(t0 + t_us, m, map);
            }
            if let (Some(speed), subnav_wire::Uplink::Nav(_)) = (speed, m) {
                // Pace on the navigation solutions: dive time ahead of wall time x speed waits.
                let due = Duration::from_secs_f64(t_us as f64 * 1e-6 / speed + args.link_delay_ms.unwrap_or(0.0) * 1e-3);
                if let Some(wait) = due.checked_sub(started.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
            // After the pacing: the bridge sees the message when the head would send it.
            super::mavlink::on_uplink(bridge.as_ref(), m);
        };
        let mut run = HeadRun::native(&sc).progress(&progress);
        if feed.is_some() || speed.is_some() || bridge.is_some() {
            run = run.observer(&observe);
        }
        if let Some(b) = &bridge {
            run = run.downlink(super::mavlink::downlink_source(b));
        }
        if let Some(p) = &record {
            run = run.record(p);
        }
        run.run()?.score(&sc)?
    } else {
        let elf = args.elf.as_ref().context("--elf is required without --native")?;
        if !elf.exists() {
            bail!("{} does not exist: build it with `cargo xtask build` (or use --native)", elf.display());
        }
        // Under QEMU nothing goes back to the head from the bridge (its modem carries the
        // scenario's fixes): the autopilot's GPS is not used.
        if let Some(b) = &bridge {
            b.set_gps_input(subnav_mavlink::GpsInput::Off);
        }
        let observe = |_t_us: u64, m: &subnav_wire::Uplink, map: Option<&subnav_sil::map_loop::MapLoop>| {
            if let Some(f) = &feed {
                f.on_uplink(subnav_link::record::now_unix_us(), m, map);
            }
            super::mavlink::on_uplink(bridge.as_ref(), m);
        };
        let mut run = HeadRun::qemu(&sc, elf).timeout(Duration::from_secs(args.timeout_s)).progress(&progress);
        if feed.is_some() || bridge.is_some() {
            run = run.observer(&observe);
        }
        if let Some(p) = &record {
            run = run.record(p);
        }
        run.run()?.score(&sc)?
    };
    pb.finish_and_clear();
    drop(feed);
    super::live::finish(live);
    super::mavlink::finish(bridge, &args.mavlink.bridge)?;
    let truth = truth_rows(&sc, 0.1);
    let truth_path = args.truth.clone().or_else(|| args.report.as_ref().map(|d| d.join("truth.csv")));
    if let Some(p) = &truth_path {
        subnav_link::output::write_atomic(p, truth_csv(&truth).as_bytes()).with_context(|| format!("writing the truth {}", p.display()))?;
    }
    match format {
        Format::Json => println!("{}", serde_json::to_string(&result)?),
        Format::Text => print_summary(&result),
    }
    if let (Some(dir), Some(rec)) = (&args.report, &record) {
        let html = write_report(dir, rec, &sc, &result, truth)?;
        if format == Format::Text {
            println!("report                {}", html.display());
        }
    }
    let ok = result.exit_code == Some(0) && result.nonfinite_values == 0;
    if !ok {
        eprintln!(
            "error: the firmware failed (exit {:?}) or produced non-finite estimates ({})",
            result.exit_code, result.nonfinite_values
        );
    }
    // Statistics from nothing ("RMS NaN m ... NaN % of -0 m") are not a result.
    let aided = result.score.scored > 0;
    if !aided {
        eprintln!(
            "error: no aided navigation solution in the {} s dive ({} navigation messages, none aided): no error statistics; run a longer dive",
            sc.duration_s, result.nav_messages
        );
    }
    Ok(if ok && aided { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// The report of a run: its recording with the truth, and the map's nodes and the closures the
/// head accepted. Returns the HTML page.
fn write_report(dir: &std::path::Path, rec: &std::path::Path, sc: &Scenario, r: &DiveResult, truth: Vec<TruthRow>) -> Result<PathBuf> {
    let (mut session, _note) = super::export::load_session(rec, None)?;
    // A host restarted mid-dive wrote the rest of the dive to the next recordings.
    for next in r.recordings.iter().skip(1) {
        session.append(super::export::load_session(&next.path, None)?.0);
    }
    let mut data = subnav_report::ReportData::from_session(&session, Some(truth));
    if let Some(m) = &r.map {
        data.map_nodes = m.nodes.iter().map(|n| n.pos_ned_m).collect();
        let accepted: std::collections::BTreeSet<u64> = m.fix_results.iter().filter(|(_, ok)| *ok).map(|(t, _)| *t).collect();
        // A closure links the head's estimate at the image's time to the node it recognised.
        data.closures = m
            .closures
            .iter()
            .filter(|c| accepted.contains(&c.t_us))
            .filter_map(|c| {
                let node = m.nodes.iter().find(|n| n.id == c.node)?;
                Some(subnav_report::ClosurePoint { t_s: c.t_us as f64 * 1e-6, node_ne_m: node.pos_ned_m, estimate_ne_m: c.vehicle_ne_m })
            })
            .collect();
    }
    let title = format!("subnav dive, seed {}", sc.seed);
    let written = subnav_report::write(&data, dir, subnav_report::ImageFormat::Png, &title, |_| {})?;
    Ok(written.html)
}

fn print_summary(r: &DiveResult) {
    println!("navigation messages   {} ({} aided, first at {:?} s)", r.nav_messages, r.score.scored, r.score.first_aided_s);
    if r.score.scored == 0 {
        println!("heading, position     no aided solution: no error statistics");
    } else {
        println!(
            "heading               RMSE {:.3} deg, max {:.3} deg, {:.1} % within 3 sigma (converged from {:?} s; all aided: RMSE {:.2} deg)",
            r.score.heading_rmse_deg,
            r.score.heading_max_abs_err_deg,
            100.0 * r.score.heading_within_3_sigma,
            r.score.heading_converged_s,
            r.score.heading_rmse_all_aided_deg
        );
        println!(
            "horizontal position   RMS {:.2} m, final {:.2} m ({}), max {:.2} m, {:.1} % within 3 sigma",
            r.score.horizontal_rms_err_m,
            r.score.horizontal_final_err_m,
            if r.distance_m > 0.0 {
                format!("{:.3} % of {:.0} m travelled", r.final_err_pct_of_distance, r.distance_m)
            } else {
                "no distance travelled".to_string()
            },
            r.score.horizontal_max_err_m,
            100.0 * r.score.within_3_sigma
        );
    }
    println!("depth                 RMSE {:.3} m (raw sensor {:.4} m)", r.score.depth_rmse_m, r.raw_depth_rmse_m);
    println!("compass alone         {} fixes, {} without, RMSE {:.2} deg", r.compass_fixes, r.compass_no_fix, r.compass_rmse_deg);
    println!("bus transactions      {}  corrupt frames {}  non-finite values {}", r.bus_transactions, r.corrupt_frames, r.nonfinite_values);
    for (source, kind, count) in &r.faults {
        println!("fault                 {source} {kind} x{count}");
    }
    if r.heading_resets + r.position_resets > 0 {
        println!("re-acquisitions       heading x{}, position x{}", r.heading_resets, r.position_resets);
    }
    for rec in &r.recordings {
        let how = match (rec.joined_running_head, rec.gap_before_s) {
            (true, Some(g)) => format!(", joined the running head {g:.1} s after the recording before ends"),
            (true, None) => ", joined a running head".to_string(),
            _ => String::new(),
        };
        println!("recording             {}: head time {:.1}-{:.1} s{how}", rec.path.display(), rec.first_head_s, rec.last_head_s);
    }
    if r.longest_nav_gap_s > 1.0 {
        println!("navigation gap        {:.1} s (the longest stretch the host received no solution)", r.longest_nav_gap_s);
    }
    let secs = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{x:.1} s"));
    for c in &r.fault_classes {
        println!(
            "fault class           {:<31} {:>12} reported {:<5} within 3 sigma after {:>7}, sigmas back after {:>7}  ({})",
            c.class,
            c.window_s.map_or("throughout".into(), |(a, b)| format!("{a:.0}-{b:.0} s")),
            c.reported,
            secs(c.recovery_s),
            secs(c.sigma_recovery_s),
            c.evidence
        );
    }
    if let Some(m) = &r.map {
        let s = &m.mapper;
        println!(
            "map                   {} nodes; {} frames, recognitions {} (precision {:.3}, recall {:.3}), gate refused {}",
            s.nodes,
            s.frames,
            s.recognitions,
            m.score.precision.unwrap_or(f64::NAN),
            m.score.recall.unwrap_or(f64::NAN),
            s.gate_refusals
        );
        println!(
            "camera frames         {} out of order, {} duplicated, {} missing, {} dark; gate too wide {}",
            s.frames_out_of_order, s.frames_duplicated, s.frames_missing, s.frames_without_features, s.gate_too_wide
        );
        println!(
            "map fixes             {} sent, {} accepted, {} refused by the head; frames without trigger {}, telemetry waits timed out {}",
            m.fixes_sent, m.fixes_accepted, m.fixes_refused, m.captures_without_trigger, m.nav_wait_timeouts
        );
    }
}
