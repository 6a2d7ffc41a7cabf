//! `subnav export`: a recording -> MCAP (open it in Foxglove) and/or one CSV per message kind.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use serde_json::json;

use super::Format;
use subnav_link::defmt_log::DefmtTable;
use subnav_link::export::{self, TimeBase};
use subnav_link::record::session::Session;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The recording (from `subnav record` or `subnav qemu --record`).
    pub recording: PathBuf,
    /// Write an MCAP file here.
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Write one CSV per message kind into this directory.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Firmware ELF to decode the defmt log stream (default: the ELF named in the recording).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Clock for message times.
    #[arg(long, value_enum, default_value_t = TimeBase::Host)]
    pub time: TimeBase,
    /// Serve the recording to Foxglove (see --foxglove) on the MCAP topics, at --speed.
    #[command(flatten)]
    pub live: super::live::FoxgloveArgs,
    /// With --foxglove: seconds of recording served per second (1 = as recorded, at least 1).
    #[arg(long, default_value_t = 1.0, requires = "foxglove", value_parser = parse_speed)]
    pub speed: f64,
}

fn parse_speed(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (1.0..=1e6).contains(&v) => Ok(v),
        _ => Err(format!("{s:?}: a speed in [1, 1e6] (1 = as recorded)")),
    }
}

/// Decode a recording, with the defmt table of `elf` (or the recording's ELF, when it exists).
pub fn load_session(recording: &std::path::Path, elf: Option<&std::path::Path>) -> Result<(Session, Option<String>)> {
    let loaded = subnav_link::record::read_file(recording)?;
    let elf_path = elf.map(|p| p.to_path_buf()).or_else(|| loaded.meta.elf.as_ref().map(PathBuf::from));
    let mut note = None;
    if let Some(e) = &loaded.header_error {
        eprintln!("warning: {}: {e}; its metadata (source, ELF) is lost, the chunks after it are read", recording.display());
    }
    let table = match &elf_path {
        Some(p) if p.exists() => Some(DefmtTable::from_elf_path(p).with_context(|| {
            if elf.is_some() { "the --elf given".to_string() } else { format!("the ELF named in the header of {}", recording.display()) }
        })?),
        Some(p) => {
            note = Some(format!("defmt logs not decoded: the firmware ELF {} is not there (give it with --elf)", p.display()));
            None
        }
        None => None,
    };
    let s = Session::decode(&loaded, table.as_ref());
    if s.defmt_bytes > 0 && table.is_none() && note.is_none() {
        note = Some(format!("{} defmt bytes not decoded: give the firmware ELF with --elf", s.defmt_bytes));
    }
    Ok((s, note))
}

/// Refuses an output directory whose `NAME.csv` files could overwrite an input (an input that
/// is a `.csv` file inside it).
fn refuse_dir_holding_inputs(what: &str, dir: &std::path::Path, inputs: &[&std::path::Path]) -> Result<()> {
    for input in inputs {
        let (Some(parent), Some(ext)) = (input.parent(), input.extension()) else { continue };
        let parent = if parent.as_os_str().is_empty() { std::path::Path::new(".") } else { parent };
        if ext == "csv" && subnav_link::output::same_file(parent, dir) {
            bail!(
                "{what} {} holds the input {}, which the export could overwrite; choose another directory",
                dir.display(),
                input.display()
            );
        }
    }
    Ok(())
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    if args.mcap.is_none() && args.csv.is_none() && args.live.foxglove.is_none() {
        bail!("say what to write: --mcap FILE.mcap and/or --csv DIRECTORY (or serve it with --foxglove)");
    }
    let inputs: Vec<&std::path::Path> = std::iter::once(args.recording.as_path()).chain(args.elf.as_deref()).collect();
    if let Some(p) = &args.mcap {
        subnav_link::output::refuse_input_as_output("--mcap", p, &inputs)?;
    }
    if let Some(d) = &args.csv {
        refuse_dir_holding_inputs("--csv", d, &inputs)?;
    }
    let (session, note) = load_session(&args.recording, args.elf.as_deref())?;
    if let Some(n) = &note {
        eprintln!("note: {n}");
    }
    let mut result = json!({"recording": args.recording.display().to_string(), "messages": session.messages.len(), "corrupt_frames": session.corrupt.len(), "log_lines": session.logs.len(), "damaged_regions": session.damage.len()});
    if let Some(path) = &args.mcap {
        // Under a temporary name until complete: a failure (a full disk) leaves no truncated MCAP.
        let mut f = subnav_link::output::AtomicFile::create(path)?;
        let bar = super::record::progress_bar(0, "writing MCAP");
        let summary = export::mcap::write(&session, std::io::BufWriter::new(&mut f), args.time, |done, total| {
            bar.set_length(total);
            bar.set_position(done);
        })
        .with_context(|| format!("writing the MCAP file {}", path.display()))?;
        f.commit()?;
        bar.finish_and_clear();
        match format {
            Format::Text => {
                println!("{}: {} messages", path.display(), summary.messages);
                for (t, n) in &summary.topics {
                    println!("  {t:<28} {n}");
                }
            }
            Format::Json => result["mcap"] = json!({"path": path.display().to_string(), "summary": summary}),
        }
    }
    if let Some(dir) = &args.csv {
        let files = export::csv::write(&session, dir)?;
        match format {
            Format::Text => {
                for (p, n) in &files {
                    println!("{}: {n} rows", p.display());
                }
            }
            Format::Json => {
                result["csv"] = json!(files.iter().map(|(p, n)| json!({"path": p.display().to_string(), "rows": n})).collect::<Vec<_>>())
            }
        }
    }
    if args.live.foxglove.is_some() {
        let live = super::live::start(&args.live, args.time)?;
        if let Some(l) = &live {
            let events = export::events(&session);
            let span_s = match (events.first(), events.last()) {
                (Some(a), Some(b)) => b.0.saturating_sub(a.0) as f64 * 1e-6,
                _ => 0.0,
            };
            eprintln!("foxglove: serving {} events ({span_s:.1} s recorded) at {}x", events.len(), args.speed);
            subnav_link::live_view::serve_events(l, &events, args.speed);
        }
        super::live::finish(live);
    }
    if format == Format::Json {
        println!("{result}");
    }
    Ok(ExitCode::SUCCESS)
}
