//! `cargo xtask bench-target`: runs the `qemu-bench` firmware under QEMU with
//! `-icount shift=0,align=off,sleep=off` and collects its `bench <name> <iterations> <instr>`
//! lines from UART0. Writes `target/bench-target.md` (a table for docs/PERFORMANCE.md).

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};

use crate::root;

pub fn run(elf: &Path) -> Result<()> {
    let out = root().join("target").join("bench-target.txt");
    let _ = std::fs::remove_file(&out);
    let status = Command::new("qemu-system-arm")
        .args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-display", "none", "-monitor", "none"])
        .arg("-serial")
        .arg(format!("file:{}", out.display()))
        .args(["-semihosting-config", "enable=on,target=native", "-icount", "shift=0,align=off,sleep=off", "-kernel"])
        .arg(elf)
        .stdout(std::process::Stdio::null())
        .status()
        .context("starting qemu-system-arm")?;
    let text = std::fs::read_to_string(&out).with_context(|| format!("reading {}", out.display()))?;
    if !status.success() || !text.contains("bench-done") {
        bail!("the bench firmware failed ({status}); output so far:\n{text}");
    }
    let mut table = String::from("| routine | iterations | instructions per call |\n|---|---:|---:|\n");
    for line in text.lines() {
        let parts: Vec<&str> = line.split_whitespace().collect();
        if line.starts_with("bench-error") {
            bail!("{line}");
        }
        if let ["bench", name, iters, instr] = parts.as_slice() {
            table.push_str(&format!("| `{name}` | {iters} | {instr} |\n"));
        }
    }
    print!("{table}");
    println!("(QEMU -icount shift=0: SysTick ticks x 40 = instructions, minus an empty-loop baseline; not cycles)");
    std::fs::write(root().join("target").join("bench-target.md"), &table)?;
    Ok(())
}
