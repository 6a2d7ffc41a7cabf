//! Flash / RAM use per board binary, read from the ELF section headers, and the check that no
//! heap allocator is linked.

use std::path::Path;

use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, ObjectSymbol, SectionFlags, elf};

use crate::firmware::Board;

pub struct Report {
    pub board: Board,
    pub flash_bytes: u64,
    pub ram_static_bytes: u64,
    pub heap_symbols: Vec<String>,
}

/// Budget of the STM32F405 (and of the QEMU board, which mirrors it).
const FLASH_BUDGET: u64 = 1024 * 1024;
const RAM_BUDGET: u64 = 128 * 1024;

/// Symbols that only exist when something allocates.
const HEAP_MARKERS: &[&str] = &["__rust_alloc", "__rg_alloc", "__rust_alloc_error_handler", "malloc", "_ZN5alloc5alloc"];

pub fn report(board: Board, elf_path: &Path) -> Result<Report> {
    let data = std::fs::read(elf_path).with_context(|| format!("reading {}", elf_path.display()))?;
    let file = object::File::parse(&*data).context("parsing ELF")?;
    let (mut flash, mut ram) = (0u64, 0u64);
    for s in file.sections() {
        let SectionFlags::Elf { sh_flags } = s.flags() else { continue };
        if sh_flags & u64::from(elf::SHF_ALLOC) == 0 || s.size() == 0 {
            continue;
        }
        let name = s.name().unwrap_or("");
        let is_nobits = matches!(s.kind(), object::SectionKind::UninitializedData);
        // .data occupies flash (its initial image) and RAM; .bss/.uninit only RAM; the rest flash.
        if name == ".data" {
            flash += s.size();
            ram += s.size();
        } else if is_nobits || s.address() >= 0x2000_0000 {
            ram += s.size();
        } else {
            flash += s.size();
        }
    }
    let heap_symbols = heap_symbols(&file);
    Ok(Report { board, flash_bytes: flash, ram_static_bytes: ram, heap_symbols })
}

fn heap_symbols(file: &object::File) -> Vec<String> {
    file.symbols().filter_map(|s| s.name().ok().map(str::to_owned)).filter(|n| HEAP_MARKERS.iter().any(|m| n.starts_with(m))).collect()
}

pub fn print(reports: &[Report]) {
    println!("| board | flash (bytes) | flash % of 1 MiB | static RAM (bytes) | RAM % of 128 KiB | heap allocator |");
    println!("|---|---:|---:|---:|---:|---|");
    for r in reports {
        println!(
            "| {} | {} | {:.1} | {} | {:.1} | {} |",
            r.board.bin(),
            r.flash_bytes,
            100.0 * r.flash_bytes as f64 / FLASH_BUDGET as f64,
            r.ram_static_bytes,
            100.0 * r.ram_static_bytes as f64 / RAM_BUDGET as f64,
            if r.heap_symbols.is_empty() { "none".to_string() } else { r.heap_symbols.join(", ") }
        );
    }
    println!("(static RAM = .data + .bss + .uninit; the stack takes the rest of RAM)");
}

pub fn check(reports: &[Report]) -> Result<()> {
    for r in reports {
        if !r.heap_symbols.is_empty() {
            bail!("{}: heap allocator symbols linked: {:?}", r.board.bin(), r.heap_symbols);
        }
        if r.flash_bytes > FLASH_BUDGET || r.ram_static_bytes > RAM_BUDGET {
            bail!("{}: over budget (flash {} B, RAM {} B)", r.board.bin(), r.flash_bytes, r.ram_static_bytes);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    /// The check must be able to fail: this (std, allocating) xtask binary links an allocator.
    #[test]
    fn detects_an_allocator_in_a_binary_that_has_one() {
        let exe = std::env::current_exe().unwrap();
        let data = std::fs::read(exe).unwrap();
        let file = object::File::parse(&*data).unwrap();
        let found = super::heap_symbols(&file);
        assert!(!found.is_empty(), "no allocator symbol found in a std binary");
    }
}
