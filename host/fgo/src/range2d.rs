//! Range-aided 2-D navigation (an AUV with dead reckoning and an acoustic modem / LBL, e.g.
//! GOATS): SE2 poses linked by odometry (between) factors and pose-to-beacon range factors, with
//! the beacons known (surveyed, fixed) or unknown (estimated: range-aided SLAM). Solved by batch
//! Levenberg-Marquardt (GTSAM's damping schedule) on a sparse Cholesky, with the ranges gated.
//!
//! Factors are GTSAM's, so that both reach the same optimum (`tests/tests/peer_gtsam_pyfg.rs`):
//! - between: `Logmap(measured^-1 (x_i^-1 x_j))` with GTSAM's Pose2 Logmap, covariance as given;
//! - range: `|t_i - b| - r`, variance as given.
//!
//! The gate (ranges): after each solve, `gamma = e^2 / var` of every range at the estimate is
//! tested against chi2(1, confidence) *after dividing by a robust scale of the residuals*
//! (`s = max(1, median(gamma) / median(chi2(1)))`), so that a noise model that is too tight for
//! the data (GOATS' per-beacon biases, sound speed) does not make every range abnormal; an
//! abnormal range gets `kappa = gamma / threshold` on its variance (the seed's inflation), and the
//! graph is solved again until the decisions stop changing. See [`crate::gating`] for the same
//! adaptive scale in the INS graph.
//!
//! Initial values: pose vertices of the file (`Init::File`) or the odometry composed from the
//! first pose's vertex (`Init::Odometry`). Known beacons: the trajectory is first moved rigidly
//! (x, y, heading) onto the ranges. Unknown beacons: each is multilaterated from the initial
//! trajectory, and a prior holds the first pose (the gauge).

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

use super::FgoError;
use super::pyfg::{Pose2, PyFg};

impl Pose2 {
    pub fn new(x_m: f64, y_m: f64, theta_rad: f64) -> Self {
        Self { x_m, y_m, theta_rad }
    }
    fn rot(&self) -> Matrix2<f64> {
        let (s, c) = self.theta_rad.sin_cos();
        Matrix2::new(c, -s, s, c)
    }
    pub fn t(&self) -> Vector2<f64> {
        Vector2::new(self.x_m, self.y_m)
    }
    /// `self^-1 other`
    pub fn between(&self, other: &Pose2) -> Pose2 {
        let d = self.rot().transpose() * (other.t() - self.t());
        Pose2::new(d.x, d.y, wrap(other.theta_rad - self.theta_rad))
    }
    /// `self other`
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let t = self.t() + self.rot() * other.t();
        Pose2::new(t.x, t.y, wrap(self.theta_rad + other.theta_rad))
    }
    /// GTSAM's `Pose2::Logmap` (x, y, theta).
    pub fn logmap(&self) -> Vector3<f64> {
        let w = wrap(self.theta_rad);
        if w.abs() < 1e-10 {
            return Vector3::new(self.x_m, self.y_m, w);
        }
        let (s, c) = w.sin_cos();
        let c1 = c - 1.0;
        let det = c1 * c1 + s * s;
        let t = self.t();
        let d = self.rot().transpose() * t - t;
        // rotate by +90 degrees
        let p = Vector2::new(-d.y, d.x);
        let v = p * (w / det);
        Vector3::new(v.x, v.y, w)
    }
}

/// GTSAM's between error `Logmap(m^-1 (a^-1 b))` and its Jacobians with respect to `(x, y,
/// theta)` of `a` and of `b` (the increments of [`Graph2`] are additive in these). Analytic:
/// `Logmap(q) = (V^-1(w) q_t, w)` with `V^-1 = [[al, w/2], [-w/2, al]]`, `al = (w/2) cot(w/2)`.
pub fn between_error(m: &Pose2, a: &Pose2, b: &Pose2) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let h = a.between(b);
    let q = m.between(&h);
    let w = q.theta_rad;
    let (al, dal) = if w.abs() < 1e-4 {
        (1.0 - w * w / 12.0 - w.powi(4) / 720.0, -w / 6.0 - w.powi(3) / 180.0)
    } else {
        let half = 0.5 * w;
        let (sh, ch) = half.sin_cos();
        (half * ch / sh, 0.5 * ch / sh - 0.5 * half / (sh * sh))
    };
    let vinv = Matrix2::new(al, 0.5 * w, -0.5 * w, al);
    let dvinv = Matrix2::new(dal, 0.5, -0.5, dal);
    let qt = q.t();
    let e = vinv * qt;
    // d e / d (q_t, w)
    let mut de = Matrix3::zeros();
    de.fixed_view_mut::<2, 2>(0, 0).copy_from(&vinv);
    de.fixed_view_mut::<2, 1>(0, 2).copy_from(&(dvinv * qt));
    de[(2, 2)] = 1.0;
    // q_t = Rm^T (Ra^T (t_b - t_a) - t_m), w = theta_b - theta_a - theta_m
    let rmt = m.rot().transpose();
    let rat = a.rot().transpose();
    let (sa, ca) = a.theta_rad.sin_cos();
    let drat = Matrix2::new(-sa, ca, -ca, -sa);
    let d = b.t() - a.t();
    let mut dqa = Matrix3::zeros();
    dqa.fixed_view_mut::<2, 2>(0, 0).copy_from(&(-rmt * rat));
    dqa.fixed_view_mut::<2, 1>(0, 2).copy_from(&(rmt * drat * d));
    dqa[(2, 2)] = -1.0;
    let mut dqb = Matrix3::zeros();
    dqb.fixed_view_mut::<2, 2>(0, 0).copy_from(&(rmt * rat));
    dqb[(2, 2)] = 1.0;
    (Vector3::new(e.x, e.y, w), de * dqa, de * dqb)
}

/// Angle in (-pi, pi].
pub fn wrap(a: f64) -> f64 {
    let mut r = a.rem_euclid(2.0 * std::f64::consts::PI);
    if r > std::f64::consts::PI {
        r -= 2.0 * std::f64::consts::PI;
    }
    r
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Beacons {
    Known,
    Unknown,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    /// The file's pose vertices.
    File,
    /// Odometry composed from the first pose vertex.
    Odometry,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeGate {
    pub enabled: bool,
    pub confidence: f64,
    /// Divide gamma by the robust residual scale (the default); false = the seed's fixed test.
    pub adaptive: bool,
    /// Gate/solve rounds at most.
    pub rounds: usize,
}

impl Default for RangeGate {
    fn default() -> Self {
        Self { enabled: true, confidence: 0.99, adaptive: true, rounds: 10 }
    }
}

/// The problem: variables (poses, and beacons when unknown) and factors.
#[derive(Debug, Clone)]
pub struct Graph2 {
    pub poses: Vec<Pose2>,
    pub beacons: Vec<Vector2<f64>>,
    pub beacons_mode: Beacons,
    pub odometry: Vec<(usize, usize, Pose2, Matrix3<f64>)>,
    /// (pose, beacon, range m, variance m^2 including the gate's inflation)
    pub ranges: Vec<(usize, usize, f64, f64)>,
    /// Nominal range variances (before the gate).
    pub range_var_nominal: Vec<f64>,
    /// Prior on pose 0: mean, sigmas (x m, y m, theta rad). Used for the gauge of unknown beacons.
    pub prior0: Option<(Pose2, [f64; 3])>,
    /// Per-beacon range biases (m, `r = |t - b| + bias`), estimated when `Some` (with a zero-mean
    /// prior of sigma [`BIAS_PRIOR_SIGMA_M`]); `None`: no bias (GTSAM's RangeFactor2D).
    pub range_bias_m: Option<Vec<f64>>,
}

/// Sigma of the zero-mean prior on each beacon's range bias, m.
pub const BIAS_PRIOR_SIGMA_M: f64 = 10.0;

/// Sigmas of the gauge prior on the first pose when the beacons are unknown.
pub const GAUGE_SIGMAS: [f64; 3] = [1e-3, 1e-3, 1e-4];

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions2 {
    pub max_iterations: usize,
    pub relative_tol: f64,
    pub absolute_tol: f64,
}

impl Default for LmOptions2 {
    fn default() -> Self {
        Self { max_iterations: 100, relative_tol: 1e-12, absolute_tol: 1e-12 }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lm2Report {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
}

fn inv_sqrt_lower(cov: &Matrix3<f64>) -> Result<Matrix3<f64>, FgoError> {
    let l = cov.cholesky().ok_or_else(|| FgoError::Input("covariance not positive definite".into()))?.l();
    l.try_inverse().ok_or_else(|| FgoError::Numeric("singular covariance".into()))
}

impl Graph2 {
    /// Build from a parsed file with the chosen initial values (see the module doc).
    pub fn from_pyfg(fg: &PyFg, beacons: Beacons, init: Init) -> Result<Self, FgoError> {
        let n = fg.poses.len();
        let poses = match init {
            Init::File => fg.poses.iter().map(|p| p.guess).collect(),
            Init::Odometry => dead_reckoning(fg)?,
        };
        let mut g = Graph2 {
            poses,
            beacons: fg.beacons.iter().map(|b| Vector2::new(b.pos_m[0], b.pos_m[1])).collect(),
            beacons_mode: beacons,
            odometry: fg.odometry.iter().map(|e| (e.i, e.j, e.measured, e.cov)).collect(),
            ranges: fg.ranges.iter().map(|r| (r.pose, r.beacon, r.range_m, r.var_m2)).collect(),
            range_var_nominal: fg.ranges.iter().map(|r| r.var_m2).collect(),
            prior0: None,
            range_bias_m: None,
        };
        debug_assert_eq!(g.poses.len(), n);
        match beacons {
            Beacons::Known => {
                if g.ranges.is_empty() {
                    return Err(FgoError::Input("known beacons but no EDGE_RANGE: nothing places the trajectory".into()));
                }
                g.align_to_known_beacons()?;
            }
            Beacons::Unknown => {
                g.prior0 = Some((g.poses[0], GAUGE_SIGMAS));
                g.multilaterate_beacons()?;
            }
        }
        Ok(g)
    }

    /// Estimate a range bias per beacon from now on.
    pub fn with_range_bias(mut self) -> Self {
        self.range_bias_m = Some(vec![0.0; self.beacons.len()]);
        self
    }

    fn bias_offset(&self) -> usize {
        3 * self.poses.len() + if self.beacons_mode == Beacons::Unknown { 2 * self.beacons.len() } else { 0 }
    }

    fn n_vars(&self) -> usize {
        self.bias_offset() + self.range_bias_m.as_ref().map_or(0, |b| b.len())
    }

    /// Whitened residuals and Jacobian entries (row, var, value) of every factor.
    fn linearize(&self, jac: Option<&mut Vec<(usize, usize, f64)>>) -> Result<DVector<f64>, FgoError> {
        let mut r = Vec::with_capacity(3 * self.odometry.len() + self.ranges.len() + 3);
        let mut jac = jac;
        let bo = 3 * self.poses.len();
        for (i, j, m, cov) in &self.odometry {
            let w = inv_sqrt_lower(cov)?;
            let (e, ja, jb) = between_error(m, &self.poses[*i], &self.poses[*j]);
            let row0 = r.len();
            r.extend((w * e).iter().copied());
            if let Some(jac) = jac.as_deref_mut() {
                for (key, jk) in [(*i, w * ja), (*j, w * jb)] {
                    for row in 0..3 {
                        for k in 0..3 {
                            jac.push((row0 + row, 3 * key + k, jk[(row, k)]));
                        }
                    }
                }
            }
        }
        for (p, b, range, var) in &self.ranges {
            let s = var.sqrt();
            let d = self.poses[*p].t() - self.beacons[*b];
            let dist = d.norm();
            let row = r.len();
            let bias = self.range_bias_m.as_ref().map_or(0.0, |v| v[*b]);
            r.push((dist + bias - range) / s);
            if let Some(jac) = jac.as_deref_mut() {
                if dist < 1e-9 {
                    return Err(FgoError::Numeric(format!("pose {p} is on beacon {b}: range Jacobian undefined")));
                }
                let u = d / dist / s;
                jac.push((row, 3 * p, u.x));
                jac.push((row, 3 * p + 1, u.y));
                if self.beacons_mode == Beacons::Unknown {
                    jac.push((row, bo + 2 * b, -u.x));
                    jac.push((row, bo + 2 * b + 1, -u.y));
                }
                if self.range_bias_m.is_some() {
                    jac.push((row, self.bias_offset() + b, 1.0 / s));
                }
            }
        }
        if let Some(biases) = &self.range_bias_m {
            let off = self.bias_offset();
            for (k, b) in biases.iter().enumerate() {
                if let Some(jac) = jac.as_deref_mut() {
                    jac.push((r.len(), off + k, 1.0 / BIAS_PRIOR_SIGMA_M));
                }
                r.push(b / BIAS_PRIOR_SIGMA_M);
            }
        }
        if let Some((mean, sig)) = &self.prior0 {
            // GTSAM's PriorFactor<Pose2>: Logmap(mean^-1 x)
            let (e, _, jx) = between_error(mean, &Pose2::new(0.0, 0.0, 0.0), &self.poses[0]);
            let row0 = r.len();
            r.extend((0..3).map(|k| e[k] / sig[k]));
            if let Some(jac) = jac.as_deref_mut() {
                for row in 0..3 {
                    for k in 0..3 {
                        jac.push((row0 + row, k, jx[(row, k)] / sig[row]));
                    }
                }
            }
        }
        let r = DVector::from_vec(r);
        if !r.iter().all(|x| x.is_finite()) {
            return Err(FgoError::Numeric("a factor evaluated to NaN/inf".into()));
        }
        Ok(r)
    }

    /// `sum 0.5 |W r|^2`
    pub fn cost(&self) -> Result<f64, FgoError> {
        Ok(0.5 * self.linearize(None)?.norm_squared())
    }

    fn retract(&self, dx: &DVector<f64>) -> Self {
        let mut g = self.clone();
        for (k, p) in g.poses.iter_mut().enumerate() {
            p.x_m += dx[3 * k];
            p.y_m += dx[3 * k + 1];
            p.theta_rad = wrap(p.theta_rad + dx[3 * k + 2]);
        }
        if g.beacons_mode == Beacons::Unknown {
            let bo = 3 * g.poses.len();
            for (k, b) in g.beacons.iter_mut().enumerate() {
                b.x += dx[bo + 2 * k];
                b.y += dx[bo + 2 * k + 1];
            }
        }
        let off = g.bias_offset();
        if let Some(biases) = &mut g.range_bias_m {
            for (k, b) in biases.iter_mut().enumerate() {
                *b += dx[off + k];
            }
        }
        g
    }

    /// Levenberg-Marquardt with GTSAM's schedule (lambda 1e-5, x10 / /10), in place.
    pub fn solve_lm(&mut self, opts: &LmOptions2) -> Result<Lm2Report, FgoError> {
        let nv = self.n_vars();
        let initial_cost = self.cost()?;
        let mut cost = initial_cost;
        let mut lambda = 1e-5;
        let mut iterations = 0;
        while iterations < opts.max_iterations {
            iterations += 1;
            let (coo, g) = self.normal_equations()?;
            let mut accepted = false;
            let mut done = false;
            while lambda <= 1e10 {
                let mut hd = coo.clone();
                for k in 0..nv {
                    hd.push(k, k, lambda);
                }
                let hd = CscMatrix::from(&hd);
                let Ok(chol) = CscCholesky::factor(&hd) else {
                    lambda *= 10.0;
                    continue;
                };
                let dx = -chol.solve(&g);
                let dx = DVector::from_iterator(nv, dx.column(0).iter().copied());
                let cand = self.retract(&dx);
                let new_cost = cand.cost()?;
                if new_cost.is_finite() && new_cost <= cost {
                    let decrease = cost - new_cost;
                    *self = cand;
                    done = decrease <= opts.absolute_tol || decrease <= opts.relative_tol * cost || dx.amax() < 1e-12;
                    cost = new_cost;
                    lambda = (lambda / 10.0).max(1e-16);
                    accepted = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted || done {
                break;
            }
        }
        Ok(Lm2Report { iterations, initial_cost, final_cost: cost })
    }

    /// `J^T J` (triplets, duplicates summed on conversion) and `J^T r` at the current estimate.
    fn normal_equations(&self) -> Result<(CooMatrix<f64>, DVector<f64>), FgoError> {
        let nv = self.n_vars();
        let mut jac = Vec::new();
        let r = self.linearize(Some(&mut jac))?;
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); r.len()];
        for (row, col, v) in jac {
            rows[row].push((col, v));
        }
        let mut coo = CooMatrix::new(nv, nv);
        let mut g = DVector::<f64>::zeros(nv);
        for (row, entries) in rows.iter().enumerate() {
            for (a, va) in entries {
                g[*a] += va * r[row];
                for (b, vb) in entries {
                    coo.push(*a, *b, va * vb);
                }
            }
        }
        Ok((coo, g))
    }

    /// Undamped Gauss-Newton steps with no cost test, from an LM optimum: where the cost is too
    /// flat for LM's cost comparisons to tell points 1e-6 m apart (a weakly observed beacon), the
    /// exact solve of the normal equations still finds the stationary point. Returns the last
    /// step's largest entry.
    pub fn polish_gauss_newton(&mut self, steps: usize) -> Result<f64, FgoError> {
        let mut last = f64::NAN;
        for _ in 0..steps {
            let (coo, g) = self.normal_equations()?;
            let chol = CscCholesky::factor(&CscMatrix::from(&coo))
                .map_err(|e| FgoError::Numeric(format!("information matrix not positive definite ({e:?})")))?;
            let dx = -chol.solve(&g);
            let dx = DVector::from_iterator(g.len(), dx.column(0).iter().copied());
            last = dx.amax();
            *self = self.retract(&dx);
        }
        Ok(last)
    }

    /// Range residuals `|t - b| - r` (m) at the current estimate.
    pub fn range_residuals_m(&self) -> Vec<f64> {
        let bias = |b: usize| self.range_bias_m.as_ref().map_or(0.0, |v| v[b]);
        self.ranges.iter().map(|(p, b, r, _)| (self.poses[*p].t() - self.beacons[*b]).norm() + bias(*b) - r).collect()
    }

    /// Solve, gate the ranges, re-solve until the decisions settle. Returns the last LM report and
    /// the gate's summary.
    pub fn solve_gated(&mut self, gate: &RangeGate, opts: &LmOptions2) -> Result<(Lm2Report, GateSummary), FgoError> {
        let mut report = self.solve_lm(opts)?;
        let mut summary = GateSummary { inflated: 0, rounds: 0, scale: 1.0 };
        if !gate.enabled {
            return Ok((report, summary));
        }
        let thr = subnav_base::chi2::chi2_quantile(1, gate.confidence)?;
        // median of chi2(1)
        const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;
        let mut last: Option<Vec<bool>> = None;
        for round in 0..gate.rounds {
            let e = self.range_residuals_m();
            let gammas: Vec<f64> = e.iter().zip(&self.range_var_nominal).map(|(e, v)| e * e / v).collect();
            let scale = if gate.adaptive { (median(&gammas) / CHI2_1_MEDIAN).max(1.0) } else { 1.0 };
            let abnormal: Vec<bool> = gammas.iter().map(|g| g / scale > thr).collect();
            summary = GateSummary { inflated: abnormal.iter().filter(|a| **a).count(), rounds: round + 1, scale };
            if last.as_ref() == Some(&abnormal) {
                break;
            }
            for (k, r) in self.ranges.iter_mut().enumerate() {
                let kappa = if abnormal[k] { gammas[k] / thr } else { 1.0 };
                r.3 = self.range_var_nominal[k] * kappa;
            }
            report = self.solve_lm(opts)?;
            last = Some(abnormal);
        }
        Ok((report, summary))
    }

    /// Noise adaptation (variance components): the file's odometry covariance and range variance
    /// scaled, each group by one factor, until the median whitened squared residual of the group
    /// equals the chi-square median of its dimension (a robust estimate of how much too tight the
    /// model is); never below the file's values. Returns (odometry scale, range scale) on the
    /// variances.
    pub fn adapt_noise(&mut self, opts: &LmOptions2, rounds: usize) -> Result<(f64, f64), FgoError> {
        const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;
        const CHI2_3_MEDIAN: f64 = 2.365_973_884_375_338;
        let odo_nominal: Vec<Matrix3<f64>> = self.odometry.iter().map(|o| o.3).collect();
        let rng_nominal = self.range_var_nominal.clone();
        let (mut so, mut sr) = (1.0f64, 1.0f64);
        for _ in 0..rounds {
            self.solve_lm(opts)?;
            let mut go = Vec::with_capacity(self.odometry.len());
            for (i, j, m, cov) in &self.odometry {
                let e = m.between(&self.poses[*i].between(&self.poses[*j])).logmap();
                let w = inv_sqrt_lower(cov)?;
                go.push((w * e).norm_squared());
            }
            let gr: Vec<f64> = self.range_residuals_m().iter().zip(&self.ranges).map(|(e, r)| e * e / r.3).collect();
            let (new_so, new_sr) = ((so * median(&go) / CHI2_3_MEDIAN).max(1.0), (sr * median(&gr) / CHI2_1_MEDIAN).max(1.0));
            let settled = (new_so / so - 1.0).abs() < 0.01 && (new_sr / sr - 1.0).abs() < 0.01;
            (so, sr) = (new_so, new_sr);
            for (o, n) in self.odometry.iter_mut().zip(&odo_nominal) {
                o.3 = n * so;
            }
            for ((r, v), n) in self.ranges.iter_mut().zip(self.range_var_nominal.iter_mut()).zip(&rng_nominal) {
                *v = n * sr;
                r.3 = *v;
            }
            if settled {
                break;
            }
        }
        Ok((so, sr))
    }

    /// Move the initial trajectory rigidly onto the known beacons' ranges: for headings on a
    /// 5-degree grid, the translation by linear least squares, then Gauss-Newton on (x, y,
    /// heading) with a truncated cost; the lowest cost wins.
    fn align_to_known_beacons(&mut self) -> Result<(), FgoError> {
        let pts: Vec<(Vector2<f64>, Vector2<f64>, f64)> =
            self.ranges.iter().map(|(p, b, r, _)| (self.poses[*p].t(), self.beacons[*b], *r)).collect();
        let trunc = 10.0f64;
        let cost = |phi: f64, t: &Vector2<f64>| -> f64 {
            let rot = Pose2::new(0.0, 0.0, phi).rot();
            pts.iter().map(|(p, b, r)| ((rot * p + t - b).norm() - r).powi(2).min(trunc * trunc)).sum()
        };
        let mut best: Option<(f64, f64, Vector2<f64>)> = None;
        for k in 0..72 {
            let mut phi = (k as f64) * 5f64.to_radians();
            // |q + t|^2 = r^2 with q = R p - b: 2 q.t + |t|^2 = r^2 - |q|^2, linear in (t, |t|^2)
            let rot = Pose2::new(0.0, 0.0, phi).rot();
            let mut a = DMatrix::zeros(pts.len(), 3);
            let mut y = DVector::zeros(pts.len());
            for (i, (p, b, r)) in pts.iter().enumerate() {
                let q = rot * p - b;
                a[(i, 0)] = 2.0 * q.x;
                a[(i, 1)] = 2.0 * q.y;
                a[(i, 2)] = 1.0;
                y[i] = r * r - q.norm_squared();
            }
            let Ok(sol) = a.clone().svd(true, true).solve(&y, 1e-12) else { continue };
            let mut t = Vector2::new(sol[0], sol[1]);
            // Gauss-Newton on (tx, ty, phi), ranges beyond the truncation ignored
            for _ in 0..20 {
                let rot = Pose2::new(0.0, 0.0, phi).rot();
                let drot = Matrix2::new(-phi.sin(), -phi.cos(), phi.cos(), -phi.sin());
                let mut h = Matrix3::zeros();
                let mut g = Vector3::zeros();
                for (p, b, r) in &pts {
                    let d = rot * p + t - b;
                    let n = d.norm();
                    let e = n - r;
                    if n < 1e-9 || e.abs() > trunc {
                        continue;
                    }
                    let u = d / n;
                    let j = Vector3::new(u.x, u.y, u.dot(&(drot * p)));
                    h += j * j.transpose();
                    g += j * e;
                }
                let Some(step) = (h + Matrix3::identity() * 1e-9).cholesky().map(|c| c.solve(&(-g))) else { break };
                t += Vector2::new(step.x, step.y);
                phi += step.z;
                if step.amax() < 1e-9 {
                    break;
                }
            }
            let c = cost(phi, &t);
            if c.is_finite() && best.is_none_or(|(bc, _, _)| c < bc) {
                best = Some((c, phi, t));
            }
        }
        let (_, phi, t) = best.ok_or_else(|| FgoError::Numeric("no rigid placement of the trajectory fits the ranges".into()))?;
        let tf = Pose2::new(t.x, t.y, wrap(phi));
        for p in &mut self.poses {
            *p = tf.compose(p);
        }
        Ok(())
    }

    /// Each beacon from the ranges to it at the initial trajectory: linear least squares on
    /// `|p - b|^2 = r^2` (differenced against the mean equation), then Gauss-Newton.
    fn multilaterate_beacons(&mut self) -> Result<(), FgoError> {
        for k in 0..self.beacons.len() {
            let obs: Vec<(Vector2<f64>, f64)> =
                self.ranges.iter().filter(|r| r.1 == k).map(|(p, _, r, _)| (self.poses[*p].t(), *r)).collect();
            if obs.len() < 3 {
                return Err(FgoError::Input(format!("beacon {k} has {} ranges: at least 3 are needed to estimate it", obs.len())));
            }
            // 2 p.b - |b|^2 = |p|^2 - r^2: unknowns (bx, by, |b|^2)
            let mut a = DMatrix::zeros(obs.len(), 3);
            let mut y = DVector::zeros(obs.len());
            for (i, (p, r)) in obs.iter().enumerate() {
                a[(i, 0)] = 2.0 * p.x;
                a[(i, 1)] = 2.0 * p.y;
                a[(i, 2)] = -1.0;
                y[i] = p.norm_squared() - r * r;
            }
            let sol = a.svd(true, true).solve(&y, 1e-12).map_err(|e| FgoError::Numeric(format!("beacon {k}: {e}")))?;
            let mut b = Vector2::new(sol[0], sol[1]);
            for _ in 0..50 {
                let mut h = Matrix2::zeros();
                let mut g = Vector2::zeros();
                for (p, r) in &obs {
                    let d = b - p;
                    let n = d.norm();
                    if n < 1e-9 {
                        continue;
                    }
                    let u = d / n;
                    h += u * u.transpose();
                    g += u * (n - r);
                }
                let Some(step) = (h + Matrix2::identity() * 1e-9).cholesky().map(|c| c.solve(&(-g))) else { break };
                b += step;
                if step.amax() < 1e-9 {
                    break;
                }
            }
            if !b.iter().all(|x| x.is_finite()) {
                return Err(FgoError::Numeric(format!("beacon {k}: multilateration failed")));
            }
            self.beacons[k] = b;
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GateSummary {
    /// Ranges whose variance the gate inflated (last round).
    pub inflated: usize,
    pub rounds: usize,
    /// Robust residual scale the test divided by (1 = none).
    pub scale: f64,
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let n = s.len();
    if n % 2 == 1 { s[n / 2] } else { 0.5 * (s[n / 2 - 1] + s[n / 2]) }
}

/// Dead reckoning: the odometry composed outward from the first pose's vertex (breadth first).
pub fn dead_reckoning(fg: &PyFg) -> Result<Vec<Pose2>, FgoError> {
    let n = fg.poses.len();
    let mut out: Vec<Option<Pose2>> = vec![None; n];
    out[0] = Some(fg.poses[0].guess);
    let mut adj: Vec<Vec<(usize, Pose2)>> = vec![Vec::new(); n];
    for e in &fg.odometry {
        adj[e.i].push((e.j, e.measured));
        // inverse edge
        let m = e.measured;
        let inv = Pose2::new(0.0, 0.0, -m.theta_rad).compose(&Pose2::new(-m.x_m, -m.y_m, 0.0));
        adj[e.j].push((e.i, inv));
    }
    let mut queue = std::collections::VecDeque::from([0usize]);
    while let Some(a) = queue.pop_front() {
        let pa = out[a].ok_or_else(|| FgoError::Numeric("dead reckoning order".into()))?;
        for (b, m) in &adj[a] {
            if out[*b].is_none() {
                out[*b] = Some(pa.compose(m));
                queue.push_back(*b);
            }
        }
    }
    out.into_iter()
        .enumerate()
        .map(|(k, p)| p.ok_or_else(|| FgoError::Input(format!("pose {} is not connected by odometry", fg.poses[k].name))))
        .collect()
}

/// Absolute position error after the best rigid 2-D fit (rotation + translation, no scale) of
/// `est` onto `truth`: RMSE and max, m.
pub fn ape_rigid_2d(est: &[Vector2<f64>], truth: &[Vector2<f64>]) -> Result<(f64, f64), FgoError> {
    if est.len() != truth.len() || est.len() < 2 {
        return Err(FgoError::Input(format!("APE needs equal lengths >= 2 ({} vs {})", est.len(), truth.len())));
    }
    let n = est.len() as f64;
    let me = est.iter().sum::<Vector2<f64>>() / n;
    let mt = truth.iter().sum::<Vector2<f64>>() / n;
    let mut c = Matrix2::zeros();
    for (e, t) in est.iter().zip(truth) {
        c += (t - mt) * (e - me).transpose();
    }
    let svd = c.svd(true, true);
    let (u, vt) = (svd.u.ok_or_else(|| FgoError::Numeric("svd".into()))?, svd.v_t.ok_or_else(|| FgoError::Numeric("svd".into()))?);
    let mut d = Matrix2::identity();
    if (u * vt).determinant() < 0.0 {
        d[(1, 1)] = -1.0;
    }
    let r = u * d * vt;
    let t = mt - r * me;
    let errs: Vec<f64> = est.iter().zip(truth).map(|(e, tr)| (r * e + t - tr).norm()).collect();
    let rmse = (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    Ok((rmse, errs.iter().copied().fold(0.0, f64::max)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn between_jacobians_match_differences() {
        let (m, a, b) = (Pose2::new(1.0, 0.5, 0.3), Pose2::new(0.2, -0.1, 0.1), Pose2::new(1.5, 0.9, 0.9));
        for (m, a, b) in
            [(m, a, b), (a.between(&b), a, b), (Pose2::new(0.1, 0.0, 1e-6), Pose2::new(0.0, 0.0, 0.0), Pose2::new(0.1, 0.0, 0.0))]
        {
            let (e, ja, jb) = between_error(&m, &a, &b);
            assert!((e - m.between(&a.between(&b)).logmap()).amax() < 1e-12);
            const H: f64 = 1e-6;
            for k in 0..3 {
                let bump = |p: &Pose2, d: f64| {
                    let mut q = *p;
                    match k {
                        0 => q.x_m += d,
                        1 => q.y_m += d,
                        _ => q.theta_rad += d,
                    }
                    q
                };
                let na = (between_error(&m, &bump(&a, H), &b).0 - between_error(&m, &bump(&a, -H), &b).0) / (2.0 * H);
                let nb = (between_error(&m, &a, &bump(&b, H)).0 - between_error(&m, &a, &bump(&b, -H)).0) / (2.0 * H);
                assert!((na - ja.column(k)).amax() < 1e-7, "{k}: {na} vs {}", ja.column(k));
                assert!((nb - jb.column(k)).amax() < 1e-7, "{k}: {nb} vs {}", jb.column(k));
            }
        }
    }

    #[test]
    fn logmap_is_gtsams() {
        // values printed by gtsam 4.3 (BetweenFactorPose2.unwhitenedError) for these poses
        let (m, a, b) = (Pose2::new(1.0, 0.5, 0.3), Pose2::new(0.2, -0.1, 0.1), Pose2::new(1.5, 0.9, 0.9));
        let e = m.between(&a.between(&b)).logmap();
        assert!((e - Vector3::new(0.53174898, 0.10687626, 0.5)).amax() < 1e-8, "{e}");
    }

    /// A square survey with two beacons; exact ranges except ten consecutive ones to L0 off by
    /// `outlier_m` (multipath); biased odometry (1 % scale, 0.002 rad per step) so that dead
    /// reckoning drifts.
    fn square(outlier_m: f64) -> (PyFg, Vec<Pose2>) {
        let mut text = String::from("VERTEX_XY L0 20.0 10.0\nVERTEX_XY L1 -5.0 30.0\n");
        let mut truth = vec![Pose2::new(0.0, 0.0, 0.0)];
        for k in 1..80 {
            let turn = if k % 20 == 0 { std::f64::consts::FRAC_PI_2 } else { 0.0 };
            truth.push(truth[k - 1].compose(&Pose2::new(2.0, 0.0, turn)));
        }
        for (k, p) in truth.iter().enumerate() {
            text += &format!("VERTEX_SE2 {k} A{k} 0 0 0\n");
            if k > 0 {
                let m = truth[k - 1].between(p);
                // a small odometry bias, so that dead reckoning drifts
                text += &format!(
                    "EDGE_SE2 {k} A{} A{k} {} {} {} 0.0004 0 0 0.0004 0 0.000004\n",
                    k - 1,
                    m.x_m * 1.01,
                    m.y_m,
                    m.theta_rad + 0.002
                );
            }
            for (b, pos) in [(0, Vector2::new(20.0, 10.0)), (1, Vector2::new(-5.0, 30.0))] {
                let mut r = (p.t() - pos).norm();
                if (35..45).contains(&k) && b == 0 {
                    r += outlier_m;
                }
                text += &format!("EDGE_RANGE {k} A{k} L{b} {r} 0.5625\n");
            }
        }
        (PyFg::parse(&text, "square").unwrap(), truth)
    }

    #[test]
    fn known_and_unknown_beacons_recover_the_square_and_the_gate_catches_an_outlier() {
        for outlier in [0.0, 15.0] {
            let (fg, truth) = square(outlier);
            let tp: Vec<Vector2<f64>> = truth.iter().map(|p| p.t()).collect();
            let dr = dead_reckoning(&fg).unwrap();
            let (dr_ape, _) = ape_rigid_2d(&dr.iter().map(|p| p.t()).collect::<Vec<_>>(), &tp).unwrap();
            for mode in [Beacons::Known, Beacons::Unknown] {
                for gated in [true, false] {
                    let mut g = Graph2::from_pyfg(&fg, mode, Init::Odometry).unwrap();
                    let gate = RangeGate { enabled: gated, ..Default::default() };
                    let (_, s) = g.solve_gated(&gate, &LmOptions2::default()).unwrap();
                    let (ape, _) = ape_rigid_2d(&g.poses.iter().map(|p| p.t()).collect::<Vec<_>>(), &tp).unwrap();
                    if gated {
                        assert!(ape < 0.5 * dr_ape, "{mode:?} outlier {outlier}: APE {ape} (DR {dr_ape})");
                        assert_eq!(s.inflated, if outlier > 0.0 { 10 } else { 0 }, "{mode:?} outlier {outlier}: {s:?}");
                    } else if outlier > 0.0 {
                        // the outlier pulls the ungated solution
                        let mut gg = Graph2::from_pyfg(&fg, mode, Init::Odometry).unwrap();
                        gg.solve_gated(&RangeGate::default(), &LmOptions2::default()).unwrap();
                        let (ape_g, _) = ape_rigid_2d(&gg.poses.iter().map(|p| p.t()).collect::<Vec<_>>(), &tp).unwrap();
                        assert!(ape > ape_g, "{mode:?}: ungated {ape} vs gated {ape_g}");
                    }
                }
            }
        }
    }

    #[test]
    fn ape_removes_a_rigid_motion() {
        let truth: Vec<Vector2<f64>> = (0..10).map(|k| Vector2::new(k as f64, (k * k) as f64 * 0.1)).collect();
        let tf = Pose2::new(5.0, -3.0, 0.7);
        let est: Vec<Vector2<f64>> = truth.iter().map(|p| tf.compose(&Pose2::new(p.x, p.y, 0.0)).t()).collect();
        assert!(ape_rigid_2d(&est, &truth).unwrap().0 < 1e-9);
        let mut off = est.clone();
        off[3].x += 1.0;
        assert!(ape_rigid_2d(&off, &truth).unwrap().0 > 0.2);
    }
}
