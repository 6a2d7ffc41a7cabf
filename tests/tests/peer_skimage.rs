//! Peer check of `subnav_ice::phasecorr` (phase correlation, DFT-upsampled sub-pixel peak)
//! against scikit-image 0.26.0 `phase_cross_correlation` with the same upsample factor, on 120
//! image pairs (64x64 and 63x80 textures, sub-pixel Fourier shifts of up to +-12 px, additive
//! noise). The bound: agreement within 0.01 px on every pair. Both must also be near the
//! known shift, so a common mistake cannot pass.

use std::io::Write;
use std::process::Command;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subnav_ice::phasecorr::{Gray, PhaseCorrelator, Refinement, fourier_shift};

const UPSAMPLE: usize = 100;
const MAX_DIFF_PX: f64 = 0.01 + 1e-9;

fn texture(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> Gray {
    let waves: Vec<[f64; 4]> = (0..16)
        .map(|_| [rng.random_range(-0.4..0.4), rng.random_range(-0.4..0.4), rng.random_range(0.0..6.3), rng.random_range(0.2..1.0)])
        .collect();
    let mut data = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        for c in 0..cols {
            let v: f64 = waves.iter().map(|w| w[3] * (w[0] * r as f64 + w[1] * c as f64 + w[2]).cos()).sum();
            data.push(v + 0.5 * rng.random::<f64>());
        }
    }
    Gray::new(rows, cols, data).unwrap()
}

fn run_case(rows: usize, cols: usize, n: usize, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pairs = Vec::new();
    let mut truth = Vec::new();
    for _ in 0..n {
        let a = texture(rows, cols, &mut rng);
        let (dy, dx) = (rng.random_range(-12.0..12.0), rng.random_range(-12.0..12.0));
        let mut b = fourier_shift(&a, dy, dx);
        let sigma = rng.random_range(0.0..0.3);
        for v in &mut b.data {
            *v += sigma * (rng.random::<f64>() - 0.5) * 3.46;
        }
        pairs.push((a, b));
        truth.push((-dy, -dx));
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pairs.f64");
    let mut f = std::fs::File::create(&path).unwrap();
    for (a, b) in &pairs {
        for v in a.data.iter().chain(&b.data) {
            f.write_all(&v.to_le_bytes()).unwrap();
        }
    }
    drop(f);
    let out = Command::new(subnav_tests::peer_python())
        .arg(subnav_tests::peers_dir().join("skimage_phasecorr.py"))
        .args([path.to_str().unwrap(), &n.to_string(), &rows.to_string(), &cols.to_string(), &UPSAMPLE.to_string()])
        .output()
        .expect("run the skimage peer");
    assert!(out.status.success(), "peer failed: {}", String::from_utf8_lossy(&out.stderr));
    let peer: Vec<(f64, f64)> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let mut it = l.split(',').map(|x| x.trim().parse::<f64>().unwrap());
            (it.next().unwrap(), it.next().unwrap())
        })
        .collect();
    assert_eq!(peer.len(), n);
    let mut pc = PhaseCorrelator::new(rows, cols);
    let (mut worst, mut worst_truth) = (0.0f64, 0.0f64);
    for (i, ((a, b), (py, px))) in pairs.iter().zip(&peer).enumerate() {
        let s = pc.register(a, b, UPSAMPLE, Refinement::CoarseToFine).unwrap();
        let d = (s.rows_px - py).abs().max((s.cols_px - px).abs());
        assert!(d <= MAX_DIFF_PX, "pair {i}: ours ({}, {}) vs skimage ({py}, {px})", s.rows_px, s.cols_px);
        worst = worst.max(d);
        worst_truth = worst_truth.max((s.rows_px - truth[i].0).abs().max((s.cols_px - truth[i].1).abs()));
    }
    eprintln!("{rows}x{cols}: {n} pairs, max |ours - skimage| = {worst:.4} px, max |ours - truth| = {worst_truth:.4} px");
    assert!(worst_truth < 0.3, "shift estimates far from the known shifts: {worst_truth}");
}

#[test]
fn phase_correlation_matches_skimage_64x64() {
    run_case(64, 64, 80, 0x5C1_0064);
}

#[test]
fn phase_correlation_matches_skimage_63x80() {
    run_case(63, 80, 40, 0x5C1_6380);
}
