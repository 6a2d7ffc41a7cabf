//! Installing what a fresh machine lacks: Debian packages (as root) and the peer venv.

use std::path::PathBuf;
use std::process::Command;

use anyhow::{Context, Result, bail};

use crate::firmware::which;
use crate::{root, run};

fn is_root() -> bool {
    Command::new("id").arg("-u").output().map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0").unwrap_or(false)
}

/// `apt-get install` the packages that are not installed yet.
pub fn apt_install(packages: &[&str]) -> Result<()> {
    let missing: Vec<&str> = packages
        .iter()
        .copied()
        .filter(|p| {
            !Command::new("dpkg-query")
                .args(["-W", "-f=${Status}", p])
                .output()
                .map(|o| String::from_utf8_lossy(&o.stdout).contains("install ok installed"))
                .unwrap_or(false)
        })
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    if !which("apt-get") || !is_root() {
        bail!("missing packages {missing:?}: install them (apt-get install {}) and retry", missing.join(" "));
    }
    eprintln!("xtask: installing {missing:?}");
    run(Command::new("apt-get").args(["update", "-qq"]))?;
    run(Command::new("apt-get").env("DEBIAN_FRONTEND", "noninteractive").args(["install", "-y", "-qq"]).args(&missing))
}

/// Tools every run needs besides the compiler: QEMU for the emulated board.
pub fn ensure_system_packages() -> Result<()> {
    if !which("qemu-system-arm") {
        apt_install(&["qemu-system-arm"])?;
    }
    Ok(())
}

/// Create / update `target/peers-venv` from `tests/peers/requirements.txt`; returns its python.
pub fn peer_venv() -> Result<PathBuf> {
    let venv = root().join("target").join("peers-venv");
    let python = venv.join("bin").join("python");
    let req = root().join("tests").join("peers").join("requirements.txt");
    let wanted = std::fs::read_to_string(&req).with_context(|| format!("reading {}", req.display()))?;
    let stamp = venv.join("subnav-requirements.txt");
    if python.exists() && std::fs::read_to_string(&stamp).ok().as_deref() == Some(wanted.as_str()) {
        return Ok(python);
    }
    if !python.exists() {
        run(Command::new("python3").args(["-m", "venv"]).arg(&venv))
            .context("python3 -m venv failed (Debian: apt-get install python3-venv)")?;
    }
    run(Command::new(&python).args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check", "-r"]).arg(&req))?;
    std::fs::write(&stamp, wanted)?;
    Ok(python)
}

/// Install the npm peers of `tests/peers/node` (package.json + package-lock.json, pinned) into
/// `target/peers-node` with `npm ci`; returns its `node_modules` (for `NODE_PATH`). Redone only
/// when the lock file changes.
pub fn peer_node() -> Result<PathBuf> {
    let src = root().join("tests").join("peers").join("node");
    let dir = root().join("target").join("peers-node");
    let modules = dir.join("node_modules");
    let lock = std::fs::read_to_string(src.join("package-lock.json")).context("reading tests/peers/node/package-lock.json")?;
    let stamp = dir.join("subnav-package-lock.json");
    if modules.exists() && std::fs::read_to_string(&stamp).ok().as_deref() == Some(lock.as_str()) {
        return Ok(modules);
    }
    if !which("npm") || !which("node") {
        // The Foxglove ws-protocol peer needs them.
        apt_install(&["nodejs", "npm"])?;
    }
    std::fs::create_dir_all(&dir)?;
    for f in ["package.json", "package-lock.json"] {
        std::fs::copy(src.join(f), dir.join(f)).with_context(|| format!("copying tests/peers/node/{f}"))?;
    }
    run(Command::new("npm").current_dir(&dir).args(["ci", "--no-audit", "--no-fund", "--loglevel=error"]))?;
    std::fs::write(&stamp, lock)?;
    Ok(modules)
}
