//! Phase correlation with DFT-upsampled sub-pixel refinement (Guizar-Sicairos, Thurman & Fienup,
//! "Efficient subpixel image registration algorithms", Opt. Lett. 33, 2008): the translation
//! between two equally sized images from the normalized cross-power spectrum
//! `C = F1 conj(F2) / |F1 conj(F2)|`, its inverse FFT's integer peak, then a matrix-multiply DFT
//! of `C` evaluated on a `1/upsample` grid in a 1.5 px neighbourhood of that peak.
//!
//! Conventions follow scikit-image's `phase_cross_correlation` (our peer in
//! `tests/tests/peer_skimage.rs`): the result is the (row, col) shift that registers `moving`
//! with `reference`, i.e. if `moving(y, x) = reference(y - dy, x - dx)` the result is `(-dy, -dx)`;
//! shifts wrap into `[-n/2, n/2]` per axis; the neighbourhood is `ceil(1.5 upsample)` samples wide.
//!
//! Why our own code: rustfft gives the FFTs; no maintained crate does the upsampled-DFT refinement.
//! Speed: [`Refinement::CoarseToFine`] (the default) evaluates the same upsampled DFT on the same
//! grid, but first every `upsample/10`-th sample and then the full grid only within one coarse step
//! of the coarse maximum. Near the peak the correlation magnitude is unimodal, so both find the same
//! grid point (unit test below; the skimage peer checks the default) at about a tenth of the work.

use std::sync::Arc;

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

/// A grey image, row-major, `f64` samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Gray {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

impl Gray {
    pub fn new(rows: usize, cols: usize, data: Vec<f64>) -> Result<Self, PhaseCorrError> {
        if rows == 0 || cols == 0 || data.len() != rows * cols {
            return Err(PhaseCorrError::Shape { rows, cols, len: data.len() });
        }
        Ok(Self { rows, cols, data })
    }
    pub fn zeros(rows: usize, cols: usize) -> Self {
        Self { rows, cols, data: vec![0.0; rows * cols] }
    }
    pub fn at(&self, r: usize, c: usize) -> f64 {
        self.data[r * self.cols + c]
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum PhaseCorrError {
    Shape { rows: usize, cols: usize, len: usize },
    Mismatch { a: (usize, usize), b: (usize, usize) },
    UpsampleZero,
    NonFinite,
}

impl std::error::Error for PhaseCorrError {}

impl std::fmt::Display for PhaseCorrError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Shape { rows, cols, len } => write!(f, "image of {rows}x{cols} needs {} samples, got {len}", rows * cols),
            Self::Mismatch { a, b } => write!(f, "images differ in size: {}x{} vs {}x{}", a.0, a.1, b.0, b.1),
            Self::UpsampleZero => write!(f, "upsample factor must be >= 1"),
            Self::NonFinite => write!(f, "image contains NaN or infinite samples"),
        }
    }
}

/// How the sub-pixel neighbourhood is searched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Refinement {
    /// Every sample of the `ceil(1.5 upsample)`-wide grid (what scikit-image does).
    Full,
    /// Coarse grid, then the full grid within one coarse step of the coarse maximum (same grid).
    #[default]
    CoarseToFine,
}

/// The measured translation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Shift {
    /// Row shift registering `moving` with `reference`, pixels.
    pub rows_px: f64,
    /// Column shift, pixels.
    pub cols_px: f64,
    /// Peak of the phase correlation divided by the number of pixels: 1 for a pure circular shift,
    /// near 0 for unrelated images. A tracking-quality figure.
    pub peak: f64,
}

/// Reusable FFT plans and buffers for one image size.
pub struct PhaseCorrelator {
    rows: usize,
    cols: usize,
    row_fwd: Arc<dyn Fft<f64>>,
    col_fwd: Arc<dyn Fft<f64>>,
    row_inv: Arc<dyn Fft<f64>>,
    col_inv: Arc<dyn Fft<f64>>,
    a: Vec<Complex64>,
    b: Vec<Complex64>,
    t: Vec<Complex64>,
    scratch: Vec<Complex64>,
}

impl PhaseCorrelator {
    pub fn new(rows: usize, cols: usize) -> Self {
        let mut planner = FftPlanner::new();
        let row_fwd = planner.plan_fft_forward(cols);
        let col_fwd = planner.plan_fft_forward(rows);
        let row_inv = planner.plan_fft_inverse(cols);
        let col_inv = planner.plan_fft_inverse(rows);
        let scratch_len = [&row_fwd, &col_fwd, &row_inv, &col_inv].iter().map(|f| f.get_inplace_scratch_len()).max().unwrap_or(0);
        let n = rows * cols;
        Self {
            rows,
            cols,
            row_fwd,
            col_fwd,
            row_inv,
            col_inv,
            a: vec![Complex64::ZERO; n],
            b: vec![Complex64::ZERO; n],
            t: vec![Complex64::ZERO; n],
            scratch: vec![Complex64::ZERO; scratch_len],
        }
    }

    /// 2-D FFT of `buf` (row-major rows x cols) in place: rows, transpose, columns, transpose back.
    fn fft2(&mut self, which: u8, inverse: bool) {
        let (rows, cols) = (self.rows, self.cols);
        let buf = if which == 0 { &mut self.a } else { &mut self.b };
        let (rf, cf) = if inverse { (&self.row_inv, &self.col_inv) } else { (&self.row_fwd, &self.col_fwd) };
        rf.process_with_scratch(buf, &mut self.scratch);
        transpose(buf, &mut self.t, rows, cols);
        cf.process_with_scratch(&mut self.t, &mut self.scratch);
        transpose(&self.t, buf, cols, rows);
    }

    /// The shift registering `moving` with `reference` (see the module doc for the sign).
    pub fn register(&mut self, reference: &Gray, moving: &Gray, upsample: usize, mode: Refinement) -> Result<Shift, PhaseCorrError> {
        if reference.rows != moving.rows || reference.cols != moving.cols {
            return Err(PhaseCorrError::Mismatch { a: (reference.rows, reference.cols), b: (moving.rows, moving.cols) });
        }
        if reference.rows != self.rows || reference.cols != self.cols {
            *self = Self::new(reference.rows, reference.cols);
        }
        if upsample == 0 {
            return Err(PhaseCorrError::UpsampleZero);
        }
        if reference.data.iter().chain(&moving.data).any(|v| !v.is_finite()) {
            return Err(PhaseCorrError::NonFinite);
        }
        for (d, s) in self.a.iter_mut().zip(&reference.data) {
            *d = Complex64::new(*s, 0.0);
        }
        for (d, s) in self.b.iter_mut().zip(&moving.data) {
            *d = Complex64::new(*s, 0.0);
        }
        self.fft2(0, false);
        self.fft2(1, false);
        // Normalized cross-power spectrum into `a`; a copy stays in `b` for the refinement.
        let floor = 100.0 * f64::EPSILON;
        for (x, y) in self.a.iter_mut().zip(self.b.iter_mut()) {
            let p = *x * y.conj();
            // sqrt(re^2 + im^2) instead of hypot: no overflow risk at image magnitudes, much cheaper.
            let q = p / p.norm_sqr().sqrt().max(floor);
            *x = q;
            *y = q;
        }
        self.fft2(0, true);
        let (mut best, mut best_i) = (-1.0, 0usize);
        for (i, v) in self.a.iter().enumerate() {
            let m = v.norm_sqr();
            if m > best {
                best = m;
                best_i = i;
            }
        }
        let best = best.sqrt();
        let n_px = (self.rows * self.cols) as f64;
        let wrap = |idx: usize, n: usize| if idx > n / 2 { idx as f64 - n as f64 } else { idx as f64 };
        let mut sr = wrap(best_i / self.cols, self.rows);
        let mut sc = wrap(best_i % self.cols, self.cols);
        if upsample == 1 {
            return Ok(Shift { rows_px: sr, cols_px: sc, peak: best / n_px });
        }
        let up = upsample as f64;
        let region = (1.5 * up).ceil() as usize;
        let dftshift = (region / 2) as f64;
        let off_r = dftshift - sr * up;
        let off_c = dftshift - sc * up;
        let all: Vec<usize> = (0..region).collect();
        let (kr, kc, peak) = match mode {
            Refinement::Full => self.upsampled_argmax(&all, &all, off_r, off_c, up),
            Refinement::CoarseToFine => {
                let step = (upsample / 10).max(1);
                let centre = region / 2;
                let coarse: Vec<usize> = coarse_grid(centre, step, region);
                let (cr, cc, _) = self.upsampled_argmax(&coarse, &coarse, off_r, off_c, up);
                let fine_r: Vec<usize> = (cr.saturating_sub(step)..=(cr + step).min(region - 1)).collect();
                let fine_c: Vec<usize> = (cc.saturating_sub(step)..=(cc + step).min(region - 1)).collect();
                self.upsampled_argmax(&fine_r, &fine_c, off_r, off_c, up)
            }
        };
        sr += (kr as f64 - dftshift) / up;
        sc += (kc as f64 - dftshift) / up;
        Ok(Shift { rows_px: sr, cols_px: sc, peak: peak / n_px })
    }

    /// Magnitude of the upsampled inverse DFT of the cross-power spectrum (kept in `b`) at grid
    /// samples `(k, l)` for `k in ks`, `l in ls`: `sum_uv C[u,v] exp(i 2 pi ((k-off_r) f_u + (l-off_c) f_v))`
    /// with `f = fftfreq(n, upsample)`. Returns the first maximum in row-major order.
    fn upsampled_argmax(&mut self, ks: &[usize], ls: &[usize], off_r: f64, off_c: f64, up: f64) -> (usize, usize, f64) {
        let (rows, cols) = (self.rows, self.cols);
        let kernel = |idx: &[usize], off: f64, n: usize| -> Vec<Complex64> {
            // exp(i 2 pi (i - off) f_u) with f_u = s_u / (n up), s_u the signed bin: powers of one
            // phasor (one sin_cos per row instead of per entry), negative bins from the positive
            // powers times exp(-i 2 pi (i - off) / up). Re-anchored every 16 steps against drift.
            let mut k = vec![Complex64::ZERO; idx.len() * n];
            let half = n.div_ceil(2);
            for (row, &i) in k.chunks_exact_mut(n).zip(idx) {
                let alpha = 2.0 * std::f64::consts::PI * (i as f64 - off) / (n as f64 * up);
                let step = Complex64::from_polar(1.0, alpha);
                let wrap = Complex64::from_polar(1.0, -alpha * n as f64);
                let mut z = Complex64::new(1.0, 0.0);
                for (u, slot) in row.iter_mut().enumerate() {
                    if u % 16 == 0 {
                        z = Complex64::from_polar(1.0, alpha * u as f64);
                    }
                    *slot = if u < half { z } else { z * wrap };
                    z *= step;
                }
            }
            k
        };
        let kc = kernel(ls, off_c, cols);
        let kr = kernel(ks, off_r, rows);
        // T[u, l] = sum_v C[u, v] Kc[l, v]
        let nl = ls.len();
        let mut t = vec![Complex64::ZERO; rows * nl];
        for u in 0..rows {
            let row = &self.b[u * cols..(u + 1) * cols];
            for (li, krow) in kc.chunks_exact(cols).enumerate() {
                let mut acc = Complex64::ZERO;
                for (x, k) in row.iter().zip(krow) {
                    acc += x * k;
                }
                t[u * nl + li] = acc;
            }
        }
        let (mut best, mut arg) = (-1.0, (ks[0], ls[0]));
        for (ki, krow) in kr.chunks_exact(rows).enumerate() {
            let mut acc = vec![Complex64::ZERO; nl];
            for (u, k) in krow.iter().enumerate() {
                let trow = &t[u * nl..(u + 1) * nl];
                for (a, x) in acc.iter_mut().zip(trow) {
                    *a += k * x;
                }
            }
            for (li, a) in acc.iter().enumerate() {
                let m = a.norm_sqr();
                if m > best {
                    best = m;
                    arg = (ks[ki], ls[li]);
                }
            }
        }
        (arg.0, arg.1, best.sqrt())
    }
}

/// `centre + j step` inside `[0, region)`, ascending.
fn coarse_grid(centre: usize, step: usize, region: usize) -> Vec<usize> {
    let below = centre / step;
    (0..).map(|j| centre - below * step + j * step).take_while(|&k| k < region).collect()
}

/// numpy's `fftfreq(n)[u]`: the signed frequency of bin `u`, cycles/sample.
fn fftfreq(u: usize, n: usize) -> f64 {
    let s = if u < n.div_ceil(2) { u as f64 } else { u as f64 - n as f64 };
    s / n as f64
}

fn transpose(src: &[Complex64], dst: &mut [Complex64], rows: usize, cols: usize) {
    for r in 0..rows {
        for c in 0..cols {
            dst[c * rows + r] = src[r * cols + c];
        }
    }
}

/// One-shot convenience: [`PhaseCorrelator::register`] with the default refinement.
pub fn phase_correlate(reference: &Gray, moving: &Gray, upsample: usize) -> Result<Shift, PhaseCorrError> {
    PhaseCorrelator::new(reference.rows, reference.cols).register(reference, moving, upsample, Refinement::default())
}

/// `image` translated by `(dy, dx)` pixels (circularly, by a phase ramp in the Fourier domain):
/// `out(y, x) = image(y - dy, x - dx)`. Used to make test pairs with exactly known sub-pixel shifts.
pub fn fourier_shift(image: &Gray, dy: f64, dx: f64) -> Gray {
    let (rows, cols) = (image.rows, image.cols);
    let mut pc = PhaseCorrelator::new(rows, cols);
    for (d, s) in pc.a.iter_mut().zip(&image.data) {
        *d = Complex64::new(*s, 0.0);
    }
    pc.fft2(0, false);
    for r in 0..rows {
        for c in 0..cols {
            let ph = -2.0 * std::f64::consts::PI * (dy * fftfreq(r, rows) + dx * fftfreq(c, cols));
            pc.a[r * cols + c] *= Complex64::new(ph.cos(), ph.sin());
        }
    }
    pc.fft2(0, true);
    let n = (rows * cols) as f64;
    Gray { rows, cols, data: pc.a.iter().map(|v| v.re / n).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A smooth random texture (sum of a few random cosines plus speckle).
    pub(crate) fn texture(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> Gray {
        let waves: Vec<(f64, f64, f64, f64)> = (0..12)
            .map(|_| (rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), rng.random_range(0.0..6.3), rng.random_range(0.2..1.0)))
            .collect();
        let mut data = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                let v: f64 = waves.iter().map(|(fy, fx, p, a)| a * (fy * r as f64 + fx * c as f64 + p).cos()).sum();
                data.push(v + 0.3 * rng.random::<f64>());
            }
        }
        Gray { rows, cols, data }
    }

    #[test]
    fn integer_shift_is_exact_and_signed_like_skimage() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let a = texture(32, 48, &mut rng);
        // moving(y, x) = a(y - 3, x + 5): a circular roll by (+3, -5); registering shift is (-3, +5).
        let mut b = Gray::zeros(32, 48);
        for r in 0..32 {
            for c in 0..48 {
                b.data[r * 48 + c] = a.at((r + 32 - 3) % 32, (c + 5) % 48);
            }
        }
        let s = phase_correlate(&a, &b, 1).unwrap();
        assert_eq!((s.rows_px, s.cols_px), (-3.0, 5.0));
        assert!((s.peak - 1.0).abs() < 1e-9, "pure circular shift has a unit peak, got {}", s.peak);
    }

    #[test]
    fn subpixel_shift_recovered_to_the_grid() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..10 {
            let a = texture(41, 37, &mut rng); // odd sizes: no Nyquist bin, so the Fourier shift is exact
            let (dy, dx) = (rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0));
            let b = fourier_shift(&a, dy, dx);
            let s = phase_correlate(&a, &b, 100).unwrap();
            assert!((s.rows_px + dy).abs() <= 0.011 && (s.cols_px + dx).abs() <= 0.011, "({dy}, {dx}) -> {s:?}");
        }
    }

    #[test]
    fn coarse_to_fine_finds_the_full_grid_maximum() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut pc = PhaseCorrelator::new(32, 32);
        for i in 0..20 {
            let a = texture(32, 32, &mut rng);
            let mut b = fourier_shift(&a, rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0));
            for v in &mut b.data {
                *v += 0.2 * (rng.random::<f64>() - 0.5);
            }
            let up = [20, 50, 100][i % 3];
            let full = pc.register(&a, &b, up, Refinement::Full).unwrap();
            let fast = pc.register(&a, &b, up, Refinement::CoarseToFine).unwrap();
            assert_eq!((full.rows_px, full.cols_px), (fast.rows_px, fast.cols_px), "upsample {up}");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let a = Gray::zeros(8, 8);
        let b = Gray::zeros(8, 9);
        assert!(matches!(phase_correlate(&a, &b, 10), Err(PhaseCorrError::Mismatch { .. })));
        let mut c = Gray::zeros(8, 8);
        c.data[3] = f64::NAN;
        assert_eq!(phase_correlate(&a, &c, 10), Err(PhaseCorrError::NonFinite));
        assert_eq!(phase_correlate(&a, &a, 0), Err(PhaseCorrError::UpsampleZero));
        assert!(Gray::new(2, 2, vec![0.0; 3]).is_err());
    }

    #[test]
    fn coarse_grid_covers_the_region() {
        assert_eq!(coarse_grid(75, 10, 150), vec![5, 15, 25, 35, 45, 55, 65, 75, 85, 95, 105, 115, 125, 135, 145]);
        assert_eq!(coarse_grid(1, 1, 3), vec![0, 1, 2]);
    }
}
