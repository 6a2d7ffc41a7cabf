//! `cargo xtask`: build automation for subnav.
//!
//! - `cargo xtask test`  : install what is missing, build both firmware boards, check sizes and
//!   that no heap allocator is linked, set up the peer venv, run every test (the host tool with
//!   its default `probe` feature).
//! - `cargo xtask run`   : build the QEMU firmware and run the main job: the closed-loop dive
//!   (camera and map in the loop) with a live status, the error summary and the report.
//! - `cargo xtask build` : build the firmware boards (`--board qemu|stm32f4|all`).
//! - `cargo xtask size`  : flash / RAM per board binary and the no-heap check.
//! - `cargo xtask setup` : only install the toolchain pieces and the peer venv.
//! - `cargo xtask bench-target` : instruction counts of the shared core under QEMU `-icount`.
//!
//! The firmware toolchain is chosen automatically: a rustup toolchain that already has
//! `thumbv7em-none-eabihf` (a developer laptop), else Debian's `rustc-web` + `rust-web-src` with
//! `-Zbuild-std` and `ld.lld` (installed with apt when missing and we are root). Host crates
//! always build with the `cargo` that runs this xtask.

mod bench;
mod firmware;
mod setup;
mod size;

use std::path::PathBuf;
use std::process::{Command, ExitCode};

use anyhow::{Context, Result, bail};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).parent().map(PathBuf::from).unwrap_or_default()
}

pub fn run(cmd: &mut Command) -> Result<()> {
    eprintln!("xtask$ {cmd:?}");
    let status = cmd.status().with_context(|| format!("could not start {:?}", cmd.get_program()))?;
    if !status.success() {
        bail!("command failed ({status}): {cmd:?}");
    }
    Ok(())
}

fn usage() -> &'static str {
    "usage: cargo xtask <test|run|build|size|setup> [options]
  test                 install missing tools, build firmware, size check, all tests
  run [-- ARGS]        build the QEMU firmware and run the closed-loop dive (`subnav run`, 30 min, report in
                       target/subnav-run; ARGS go to subnav run, `-- --raw` shows raw telemetry lines instead)
  build [--board B]    build firmware: B = qemu | stm32f4 | all (default all)
  size                 flash/RAM report per board and the no-heap check
  setup                install toolchain pieces and the peer venv only
  bench-target         instruction counts per call of shared-core routines on the Cortex-M4F (QEMU -icount)"
}

fn main() -> ExitCode {
    match real_main() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn real_main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(cmd) = args.first() else {
        println!("{}", usage());
        return Ok(());
    };
    let rest = &args[1..];
    match cmd.as_str() {
        "setup" => {
            setup::ensure_system_packages()?;
            firmware::Toolchain::detect()?;
            setup::peer_venv()?;
            setup::peer_node()?;
            Ok(())
        }
        "build" => {
            let board = flag_value(rest, "--board").unwrap_or("all");
            let tc = firmware::Toolchain::detect()?;
            for b in firmware::boards(board)? {
                tc.build(b)?;
            }
            Ok(())
        }
        "size" => {
            let tc = firmware::Toolchain::detect()?;
            let mut reports = vec![];
            for b in firmware::boards("all")? {
                reports.push(size::report(b, &tc.build(b)?)?);
            }
            size::print(&reports);
            size::check(&reports)
        }
        "run" => {
            setup::ensure_system_packages()?;
            let tc = firmware::Toolchain::detect()?;
            let elf = tc.build(firmware::Board::Qemu)?;
            let extra: Vec<&String> = rest.iter().skip_while(|a| *a != "--").skip(1).collect();
            let mut c = host_cargo();
            c.args(["run", "--quiet", "-p", "subnav-host", "--bin", "subnav", "--"]);
            if extra.iter().any(|a| *a == "--raw") {
                // The raw telemetry lines of the board alone (no simulated sensors).
                c.args(["qemu", "--elf"]).arg(&elf);
                if !extra.iter().any(|a| a.starts_with("--run-ms")) {
                    c.args(["--run-ms", "5000"]);
                }
                c.args(extra.into_iter().filter(|a| *a != "--raw"));
            } else {
                // The main job: the closed-loop dive under QEMU with its report.
                c.args(["run", "--elf"]).arg(&elf);
                if !extra.iter().any(|a| a.starts_with("--report")) {
                    c.arg("--report").arg(root().join("target").join("subnav-run"));
                }
                c.args(extra);
            }
            run(&mut c)
        }
        "test" => test(rest),
        "bench-target" => {
            setup::ensure_system_packages()?;
            let tc = firmware::Toolchain::detect()?;
            let elf = tc.build(firmware::Board::QemuBench)?;
            bench::run(&elf)
        }
        other => bail!("unknown command {other:?}\n{}", usage()),
    }
}

fn flag_value<'a>(args: &'a [String], flag: &str) -> Option<&'a str> {
    args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).map(String::as_str)
}

/// The cargo that runs this xtask, for host builds.
pub fn host_cargo() -> Command {
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    c.current_dir(root());
    c
}

/// Whether `cargo nextest` is installed (it is on the CI machines; a laptop may not have it).
fn have_nextest() -> bool {
    host_cargo()
        .args(["nextest", "--version"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// The steps run one after the other: the firmware, the peers and the host test build side by
/// side were measured slower on the 2-core CI machine (docs/PERFORMANCE.md, "CI run time").
fn test(rest: &[String]) -> Result<()> {
    let started = std::time::Instant::now();
    setup::ensure_system_packages()?;
    let tc = firmware::Toolchain::detect()?;
    let mut elfs = vec![];
    let mut reports = vec![];
    for b in firmware::boards("all")? {
        let elf = tc.build(b)?;
        reports.push(size::report(b, &elf)?);
        elfs.push((b, elf));
    }
    size::print(&reports);
    size::check(&reports)?;
    let python = setup::peer_venv()?;
    let node_modules = setup::peer_node()?;

    let qemu_elf = elfs.iter().find(|(b, _)| *b == firmware::Board::Qemu).map(|(_, e)| e.clone()).context("no QEMU ELF")?;
    let passthrough: Vec<&String> = rest.iter().skip_while(|a| *a != "--").collect();
    if passthrough.is_empty() && have_nextest() {
        // cargo-nextest runs the test binaries side by side (cargo test runs them one after the
        // other, so a binary with one long QEMU dive leaves a core idle); it does not run
        // doctests, which follow.
        let mut c = host_cargo();
        c.args(["nextest", "run", "--workspace", "--no-fail-fast", "--final-status-level", "slow"]);
        c.env("SUBNAV_FIRMWARE_QEMU_ELF", &qemu_elf).env("SUBNAV_PEER_PYTHON", &python).env("SUBNAV_PEER_NODE_MODULES", &node_modules);
        run(&mut c)?;
        let mut c = host_cargo();
        c.args(["test", "--workspace", "--doc"]);
        run(&mut c)?;
    } else {
        // Without cargo-nextest, or with arguments for the test harness (`cargo xtask test -- X`).
        let mut c = host_cargo();
        c.args(["test", "--workspace"]);
        c.args(passthrough);
        c.env("SUBNAV_FIRMWARE_QEMU_ELF", &qemu_elf).env("SUBNAV_PEER_PYTHON", &python).env("SUBNAV_PEER_NODE_MODULES", &node_modules);
        run(&mut c)?;
    }
    eprintln!("xtask: all tests passed in {:.0} s", started.elapsed().as_secs_f64());
    Ok(())
}
