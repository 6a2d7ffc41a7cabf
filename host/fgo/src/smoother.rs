//! Real-time fixed-lag smoother and the offline pipeline built on it.
//!
//! The smoother keeps the nodes of the last `lag_s` seconds. Each DVL observation (at its time
//! stamp) and each USBL fix (at its valid time = arrival - acoustic delay) is one update:
//! 1. get or create the node at the observation's time stamp: after the newest node, preintegrate
//!    the IMU up to it; between two window nodes (a late USBL fix), split that IMU interval and
//!    re-preintegrate both halves from the stored samples (time stamps, no interpolation);
//! 2. marginal covariance `P` of that node from the window's information (sparse Cholesky);
//! 3. gate the observation ([`super::gating`]), inflate its covariance if abnormal, add it
//!    (adaptive gate, USBL fixes: the IMU noise scale is first re-estimated from the fixes'
//!    innovations; the test is made at it, and without the neighbours rule the window's IMU
//!    factors take it);
//! 4. a few Levenberg-Marquardt iterations over the window; with the neighbours rule (the
//!    default), a USBL fix then decides on the fix before it ([`Smoother::delayed_decision`]);
//! 5. nodes older than the lag are marginalised (Schur complement) into a prior on the oldest
//!    kept node; their factors go to an archive with the final covariances.
//!
//! Offline (`run_batch`), the archived + window factors (initial prior, IMU, bias random walk,
//! gated DVL/USBL) over all nodes are solved by batch LM from the smoother's estimates.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Vector3};

use super::FgoError;
use super::factors::{BiasRandomWalkFactor, DvlFactor, Factor, ImuFactor, MarginalPrior, Noise, PriorFactor, RangeFactor, UsblFactor};
use super::gating::{self, GateLog, GatingConfig, Sensor};
use super::log::{ImuSample, LogConfig, SensorLog};
use super::preintegration::Preintegrated;
use super::solver::{self, LmOptions};
use super::state::{ImuBias, NavState, NodeState};
use subnav_base::chi2::chi2_quantile;
use subnav_base::so3;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SmootherConfig {
    pub lag_s: f64,
    pub gating: GatingConfig,
    /// LM iterations per update.
    pub iterations: usize,
}

impl Default for SmootherConfig {
    fn default() -> Self {
        Self { lag_s: 6.0, gating: GatingConfig::default(), iterations: 2 }
    }
}

/// The IMU pieces `[acc(3), gyro(3), dt]` covering `[t_a, t_b)`, each sample held on
/// `[t_k, t_k+1)` (the last one up to `t_b`): what the preintegration of that interval consumes.
pub fn imu_pieces(samples: &[ImuSample], t_a: f64, t_b: f64) -> Result<Vec<[f64; 7]>, FgoError> {
    if !(t_b > t_a) {
        return Err(FgoError::Input(format!("empty IMU interval [{t_a}, {t_b})")));
    }
    let start = match samples.binary_search_by(|s| s.t_s.total_cmp(&t_a)) {
        Ok(k) => k,
        Err(0) => return Err(FgoError::Input(format!("no IMU sample at or before t={t_a}"))),
        Err(k) => k - 1,
    };
    let mut out = Vec::new();
    let mut k = start;
    while k < samples.len() && samples[k].t_s < t_b {
        let s0 = samples[k].t_s.max(t_a);
        let s1 = samples.get(k + 1).map_or(t_b, |n| n.t_s.min(t_b));
        if s1 > s0 {
            let (a, w) = (samples[k].acc_mps2, samples[k].gyro_radps);
            out.push([a[0], a[1], a[2], w[0], w[1], w[2], s1 - s0]);
        }
        k += 1;
    }
    Ok(out)
}

/// Integrate the IMU stream over `[t_a, t_b)` (see [`imu_pieces`]).
pub fn preintegrate(samples: &[ImuSample], t_a: f64, t_b: f64, pim: &mut Preintegrated) -> Result<(), FgoError> {
    for p in imu_pieces(samples, t_a, t_b)? {
        pim.integrate(&Vector3::new(p[0], p[1], p[2]), &Vector3::new(p[3], p[4], p[5]), p[6])?;
    }
    Ok(())
}

/// CPU time consumed by the calling thread (POSIX `CLOCK_THREAD_CPUTIME_ID`), seconds.
pub fn thread_cpu_s() -> Option<f64> {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; the call only writes into it.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then(|| ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
}

/// Estimated node with its time and global id.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub id: usize,
    pub t_s: f64,
    pub state: NodeState,
}

pub struct Smoother {
    cfg: SmootherConfig,
    conf: LogConfig,
    imu: Vec<ImuSample>,
    // window (time-ordered), local indices in `factors`
    ids: Vec<usize>,
    times: Vec<f64>,
    nodes: Vec<NodeState>,
    factors: Vec<Factor>,
    // history (global ids)
    pub archive: Vec<Factor>,
    pub history: Vec<Estimate>,
    pub gate_log: GateLog,
    /// Latest-node estimate after each update: the real-time output.
    pub realtime: Vec<Estimate>,
    /// Wall time of each update, seconds.
    pub latency_s: Vec<f64>,
    /// CPU time of the updating thread for each update, seconds (one core; not inflated by other
    /// processes on a loaded machine). Empty where the thread CPU clock is unavailable.
    pub cpu_s: Vec<f64>,
    next_id: usize,
    /// IMU noise variance scale (adaptive gate; 1 = the IMU parameters as given), estimated from
    /// the innovations of the USBL fixes ([`gating::imu_noise_scale`]); new and window IMU
    /// factors carry it.
    pub imu_scale: f64,
    /// The last [`gating::ADAPT_WINDOW`] USBL innovations at arrival.
    usbl_innovations: Vec<gating::Innovation>,
    /// The neighbours rule's delayed decisions (time of the fix decided on, taken out), one per
    /// USBL fix that had a fix after it in the window ([`Smoother::delayed_decision`]).
    pub delayed: Vec<(f64, bool)>,
}

impl Smoother {
    pub fn new(conf: LogConfig, cfg: SmootherConfig) -> Result<Self, FgoError> {
        conf.imu.validate()?;
        if !(cfg.lag_s > 0.0) || !(cfg.gating.confidence > 0.0 && cfg.gating.confidence < 1.0) {
            return Err(FgoError::Input("smoother lag must be > 0 and gate confidence in (0, 1)".into()));
        }
        let p = conf.prior;
        let mean = NodeState::new(
            NavState::new(so3::exp(&Vector3::from(p.rotvec_enu_flu)), Vector3::from(p.pos_enu_m), Vector3::from(p.vel_enu_mps)),
            ImuBias::new(Vector3::from(p.bias_acc_mps2), Vector3::from(p.bias_gyro_radps)),
        );
        let prior = Factor::Prior(PriorFactor::new(0, mean, p.sigmas)?);
        let s = Self {
            cfg,
            conf,
            imu: Vec::new(),
            ids: vec![0],
            times: vec![p.t_s],
            nodes: vec![mean],
            factors: vec![prior],
            archive: Vec::new(),
            history: Vec::new(),
            gate_log: GateLog::default(),
            realtime: Vec::new(),
            latency_s: Vec::new(),
            cpu_s: Vec::new(),
            next_id: 1,
            imu_scale: 1.0,
            usbl_innovations: Vec::new(),
            delayed: Vec::new(),
        };
        Ok(s)
    }

    /// Feed one IMU sample (time-ordered).
    pub fn push_imu(&mut self, s: ImuSample) -> Result<(), FgoError> {
        if let Some(last) = self.imu.last() {
            if !(s.t_s > last.t_s) {
                return Err(FgoError::Input(format!("IMU time not increasing: {} after {}", s.t_s, last.t_s)));
            }
        }
        if !s.t_s.is_finite() || !s.acc_mps2.iter().chain(s.gyro_radps.iter()).all(|x| x.is_finite()) {
            return Err(FgoError::Input(format!("IMU sample at t={} has NaN/inf", s.t_s)));
        }
        self.imu.push(s);
        Ok(())
    }

    fn pim(&self, t_a: f64, t_b: f64, bias: ImuBias) -> Result<Preintegrated, FgoError> {
        let mut pim = Preintegrated::new(self.conf.imu, bias);
        preintegrate(&self.imu, t_a, t_b, &mut pim)?;
        Ok(pim)
    }

    fn imu_pair(&self, i: usize, j: usize, pim: Preintegrated) -> Result<[Factor; 2], FgoError> {
        let dt = pim.delta_t_s;
        let p = self.conf.imu;
        let mut pair =
            [Factor::Imu(ImuFactor::new(i, j, pim)?), Factor::BiasRw(BiasRandomWalkFactor::new(i, j, p.acc_bias_rw, p.gyro_bias_rw, dt)?)];
        pair.iter_mut().for_each(|f| f.set_imu_noise_scale(self.window_scale()));
        Ok(pair)
    }

    /// Local index of the node at `t`, creating it if needed; `None` if `t` is before the window.
    fn node_at(&mut self, t: f64) -> Result<Option<usize>, FgoError> {
        const EPS: f64 = 1e-9;
        let last = self.times.len() - 1;
        if let Some(k) = self.times.iter().position(|x| (x - t).abs() < EPS) {
            return Ok(Some(k));
        }
        if t < self.times[0] {
            return Ok(None);
        }
        if self.imu.last().is_none_or(|s| s.t_s + 1.0 < t) {
            return Err(FgoError::Input(format!("observation at t={t} is ahead of the IMU stream")));
        }
        let id = self.next_id;
        if t > self.times[last] {
            let pim = self.pim(self.times[last], t, self.nodes[last].bias)?;
            let pred = NodeState::new(pim.predict(&self.nodes[last].nav, &self.nodes[last].bias), self.nodes[last].bias);
            let pair = self.imu_pair(last, last + 1, pim)?;
            self.factors.extend(pair);
            self.ids.push(id);
            self.times.push(t);
            self.nodes.push(pred);
            self.next_id += 1;
            return Ok(Some(last + 1));
        }
        // split the interval (a, a+1) containing t
        let a = self.times.iter().rposition(|x| *x < t).unwrap_or(0);
        let b = a + 1;
        self.factors.retain(|f| !(matches!(f, Factor::Imu(_) | Factor::BiasRw(_)) && f.nodes() == vec![a, b]));
        for f in &mut self.factors {
            f.set_nodes(&|i| if i >= b { i + 1 } else { i });
        }
        let pim1 = self.pim(self.times[a], t, self.nodes[a].bias)?;
        let pred = NodeState::new(pim1.predict(&self.nodes[a].nav, &self.nodes[a].bias), self.nodes[a].bias);
        let pim2 = self.pim(t, self.times[a + 1], pred.bias)?;
        let p1 = self.imu_pair(a, b, pim1)?;
        let p2 = self.imu_pair(b, b + 1, pim2)?;
        self.factors.extend(p1);
        self.factors.extend(p2);
        self.ids.insert(b, id);
        self.times.insert(b, t);
        self.nodes.insert(b, pred);
        self.next_id += 1;
        Ok(Some(b))
    }

    fn gated_add(&mut self, t: f64, sensor: Sensor, mut f: Factor, k: usize) -> Result<(), FgoError> {
        let p = solver::marginal_covariance(&self.nodes, &self.factors, k)?;
        let e = f.evaluate(&[&self.nodes[k]]);
        let cov = match &f {
            Factor::Dvl(d) => d.noise.cov.clone(),
            Factor::Usbl(u) => u.noise.cov.clone(),
            Factor::Range(r) => r.noise.cov.clone(),
            _ => return Err(FgoError::Input("only DVL/USBL/range factors are gated".into())),
        };
        let h = &e.jacobians[0];
        let d = if self.cfg.gating.enabled && self.cfg.gating.adaptive && sensor == Sensor::Usbl {
            // the IMU noise scale from the fixes' innovations, this one included (accepted or
            // not), then the test at that scale
            let hph = h * DMatrix::from_iterator(15, 15, p.iter().copied()) * h.transpose();
            let inn = gating::Innovation { r: e.residual.clone(), hph, r_cov: cov.clone(), imu_scale: self.window_scale() };
            if self.usbl_innovations.len() == gating::ADAPT_WINDOW {
                self.usbl_innovations.remove(0);
            }
            self.usbl_innovations.push(inn.clone());
            if let Some(s) = gating::imu_noise_scale(&self.usbl_innovations)? {
                self.set_imu_scale(s);
            }
            let gamma = inn.gamma_at(self.imu_scale)?;
            let gammas = self.usbl_innovations.iter().map(|i| i.gamma_at(self.imu_scale)).collect::<Result<Vec<f64>, FgoError>>()?;
            let scale = gating::robust_scale(&gammas, e.residual.len())?;
            let mut d = gating::decide(t, sensor, gamma, e.residual.len(), &self.cfg.gating, scale)?;
            if self.neighbours_rule() && d.abnormal {
                // the seed's inflation was computed at the estimated scale; the window's IMU is
                // at the given noise: the same weight relative to the IMU
                d.kappa = (d.kappa / (self.imu_scale / self.window_scale())).max(1.0);
            }
            d
        } else {
            let scale = if self.cfg.gating.adaptive { self.gate_log.adaptive_scale(sensor, e.residual.len())? } else { 1.0 };
            gating::gate_scaled(t, sensor, &e.residual, h, &p, &cov, &self.cfg.gating, scale)?
        };
        if d.kappa != 1.0 {
            match &mut f {
                Factor::Dvl(x) => x.noise = x.noise.scaled(d.kappa),
                Factor::Usbl(x) => {
                    x.noise = x.noise.scaled(d.kappa);
                    x.kappa = d.kappa;
                }
                Factor::Range(x) => x.noise = x.noise.scaled(d.kappa),
                _ => {}
            }
        }
        self.gate_log.decisions.push(d);
        self.factors.push(f);
        Ok(())
    }

    /// The estimated IMU noise scale; the window's IMU factors take it unless the neighbours
    /// rule keeps them at the given noise ([`Smoother::window_scale`]).
    fn set_imu_scale(&mut self, s: f64) {
        self.imu_scale = s;
        let w = self.window_scale();
        self.factors.iter_mut().for_each(|f| f.set_imu_noise_scale(w));
    }

    /// The adaptive gate's neighbours rule is on ([`GatingConfig::neighbours`]).
    fn neighbours_rule(&self) -> bool {
        let g = self.cfg.gating;
        g.enabled && g.adaptive && g.neighbours
    }

    /// The IMU noise scale the window's IMU factors carry: the given noise (1) under the
    /// neighbours rule (the estimated scale is then used in the arrival test only), the
    /// estimated scale otherwise.
    fn window_scale(&self) -> f64 {
        if self.neighbours_rule() { 1.0 } else { self.imu_scale }
    }

    /// The neighbours rule's delayed decision, made when a fix arrives (after the window has been
    /// solved with it): the fix before it, `k`, is tested on its deletion innovation
    /// ([`gating::deletion`]: against what all the window's other observations, the new fix
    /// included, say), at the IMU noise as given. Fix `k` is taken out
    /// ([`gating::OUTLIER_KAPPA`]) if [`gating::neighbours_outlier`] says so against the
    /// deletion test values of the window's other kept fixes before it, computed with `k` out
    /// (one extra solve), unless the fix before `k` was taken out (an outlier is one fix; a run
    /// of them is the model erring). Then the window is solved again and the real-time output
    /// of this update is replaced. Nothing is decided on a fix without a kept fix before it in
    /// the window. The decision comes one fix late: a jumped fix pulls until the next fix
    /// arrives (on KITTI the decision at arrival cannot tell the jumps from the clean fixes,
    /// docs/PERFORMANCE.md).
    fn delayed_decision(&mut self) -> Result<(), FgoError> {
        if !self.neighbours_rule() {
            return Ok(());
        }
        // the window's fixes: (factor index, time, kappa), oldest first
        let mut fixes: Vec<(usize, f64, f64)> = self
            .factors
            .iter()
            .enumerate()
            .filter_map(|(i, f)| if let Factor::Usbl(u) = f { Some((i, self.times[u.node], u.kappa)) } else { None })
            .collect();
        fixes.sort_by(|a, b| a.1.total_cmp(&b.1));
        let n = fixes.len();
        if n < 2 {
            return Ok(());
        }
        let (fi, t_k, kappa_k) = fixes[n - 2];
        if kappa_k >= gating::OUTLIER_KAPPA {
            return Ok(());
        }
        // deletion innovations come in factor order; the fixes' positions in that order
        let pos = |i: usize| -> usize { fixes.iter().filter(|f| f.0 < i).count() };
        let thr = chi2_quantile(3, self.cfg.gating.confidence)?;
        let inn = gating::deletion_innovations(&self.nodes, &self.factors, 1.0)?;
        let g_k = inn[pos(fi)].gamma_at(1.0)?;
        let before: Vec<usize> = fixes[..n - 2].iter().filter(|f| f.2 < gating::OUTLIER_KAPPA).map(|f| pos(f.0)).collect();
        let prev_out = self.delayed.last().is_some_and(|d| d.1);
        if before.is_empty() || !(g_k > thr) || prev_out {
            self.delayed.push((t_k, false));
            return Ok(());
        }
        let saved = self.nodes.clone();
        Self::set_kappa(&mut self.factors[fi], gating::OUTLIER_KAPPA);
        let opts = LmOptions { max_iterations: self.cfg.iterations, ..Default::default() };
        solver::solve_lm(&mut self.nodes, &self.factors, &opts)?;
        let inn_out = gating::deletion_innovations(&self.nodes, &self.factors, 1.0)?;
        let g_nb = before.iter().map(|j| inn_out[*j].gamma_at(1.0)).collect::<Result<Vec<f64>, FgoError>>()?;
        let out = gating::neighbours_outlier(g_k, &g_nb, thr);
        if out {
            let last = self.nodes.len() - 1;
            if let Some(r) = self.realtime.last_mut() {
                r.state = self.nodes[last];
            }
        } else {
            Self::set_kappa(&mut self.factors[fi], kappa_k);
            self.nodes = saved;
        }
        self.delayed.push((t_k, out));
        Ok(())
    }

    /// A USBL factor's covariance at `kappa` times its nominal one.
    fn set_kappa(f: &mut Factor, kappa: f64) {
        if let Factor::Usbl(u) = f {
            u.noise = u.noise.scaled(kappa / u.kappa);
            u.kappa = kappa;
        }
    }

    fn optimize_and_marginalize(&mut self) -> Result<(), FgoError> {
        let opts = LmOptions { max_iterations: self.cfg.iterations, ..Default::default() };
        solver::solve_lm(&mut self.nodes, &self.factors, &opts)?;
        self.marginalize_and_output()
    }

    fn marginalize_and_output(&mut self) -> Result<(), FgoError> {
        let newest = *self.times.last().unwrap_or(&0.0);
        while self.times.len() > 2 && self.times[1] < newest - self.cfg.lag_s {
            self.marginalize_oldest()?;
        }
        let last = self.nodes.len() - 1;
        self.realtime.push(Estimate { id: self.ids[last], t_s: self.times[last], state: self.nodes[last] });
        Ok(())
    }

    /// Schur-complement node 0 onto node 1.
    fn marginalize_oldest(&mut self) -> Result<(), FgoError> {
        let (touch, keep): (Vec<Factor>, Vec<Factor>) = self.factors.drain(..).partition(|f| f.nodes().contains(&0));
        self.factors = keep;
        let mut h = DMatrix::<f64>::zeros(30, 30);
        let mut g = DVector::<f64>::zeros(30);
        for f in &touch {
            let keys = f.nodes();
            if keys.iter().any(|k| *k > 1) {
                return Err(FgoError::Numeric("factor spans more than the two oldest nodes".into()));
            }
            let states: Vec<&NodeState> = keys.iter().map(|k| &self.nodes[*k]).collect();
            let lin = f.linearize(&states);
            for (a, ja) in keys.iter().zip(&lin.jacobians) {
                let mut gs = g.rows_mut(15 * a, 15);
                gs += ja.transpose() * &lin.residual;
                for (b, jb) in keys.iter().zip(&lin.jacobians) {
                    let mut hs = h.view_mut((15 * a, 15 * b), (15, 15));
                    hs += ja.transpose() * jb;
                }
            }
        }
        let h00 = h.view((0, 0), (15, 15)).into_owned();
        let h01 = h.view((0, 15), (15, 15)).into_owned();
        let h11 = h.view((15, 15), (15, 15)).into_owned();
        let chol0 = h00.cholesky().ok_or_else(|| FgoError::Numeric("oldest node's information is not positive definite".into()))?;
        let hm = &h11 - h01.transpose() * chol0.solve(&h01);
        let gm = g.rows(15, 15) - h01.transpose() * chol0.solve(&g.rows(0, 15).into_owned());
        let hm = (&hm + hm.transpose()) * 0.5;
        // floor the eigenvalues so the prior stays positive definite
        let eig = hm.clone().symmetric_eigen();
        let floor = eig.eigenvalues.amax() * 1e-12 + 1e-12;
        let vals = eig.eigenvalues.map(|v| v.max(floor));
        let hm = &eig.eigenvectors * DMatrix::from_diagonal(&vals) * eig.eigenvectors.transpose();
        let chol = hm.cholesky().ok_or_else(|| FgoError::Numeric("marginal information not positive definite".into()))?;
        let l = chol.l();
        let s = l.transpose();
        let r0 = l.solve_lower_triangular(&gm).ok_or_else(|| FgoError::Numeric("singular marginal".into()))?;
        // archive the real factors with global ids
        let ids = self.ids.clone();
        for mut f in touch {
            if matches!(f, Factor::Marginal(_)) {
                continue;
            }
            f.set_nodes(&|i| ids[i]);
            self.archive.push(f);
        }
        self.history.push(Estimate { id: self.ids[0], t_s: self.times[0], state: self.nodes[0] });
        self.ids.remove(0);
        self.times.remove(0);
        self.nodes.remove(0);
        for f in &mut self.factors {
            f.set_nodes(&|i| i - 1);
        }
        self.factors.push(Factor::Marginal(MarginalPrior::new(0, self.nodes[0], s, r0)));
        Ok(())
    }

    fn gyro_at(&self, t: f64) -> Vector3<f64> {
        let k = match self.imu.binary_search_by(|s| s.t_s.total_cmp(&t)) {
            Ok(k) => k,
            Err(k) => k.saturating_sub(1),
        };
        self.imu.get(k).map_or(Vector3::zeros(), |s| Vector3::from(s.gyro_radps))
    }

    /// A node at `t` with no observation (IMU only), e.g. at the time of a held-out fix to be
    /// scored: no optimisation (the new node's IMU factor is at zero residual), then the
    /// window is marginalised as after an update and the node's prediction is the real-time
    /// output. `false` if `t` is older than the window (nothing done).
    pub fn add_node(&mut self, t: f64) -> Result<bool, FgoError> {
        let start = Instant::now();
        let cpu0 = thread_cpu_s();
        if self.node_at(t)?.is_none() {
            return Ok(false);
        }
        self.marginalize_and_output()?;
        self.latency_s.push(start.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu0, thread_cpu_s()) {
            self.cpu_s.push(b - a);
        }
        Ok(true)
    }

    /// One DVL update.
    pub fn add_dvl(&mut self, t: f64, vel_dvl_mps: Vector3<f64>, sigma_mps: f64) -> Result<(), FgoError> {
        let start = Instant::now();
        let cpu0 = thread_cpu_s();
        let Some(k) = self.node_at(t)? else {
            self.gate_log.dropped_too_old += 1;
            return Ok(());
        };
        let f = Factor::Dvl(DvlFactor {
            node: k,
            vel_dvl_mps,
            rot_body_dvl: so3::exp(&Vector3::from(self.conf.dvl_rotvec_body)),
            lever_body_m: Vector3::from(self.conf.dvl_lever_body_m),
            omega_body_radps: self.gyro_at(t) - self.nodes[k].bias.gyro_radps,
            noise: Noise::from_sigmas(&[sigma_mps; 3])?,
        });
        self.gated_add(t, Sensor::Dvl, f, k)?;
        self.optimize_and_marginalize()?;
        self.latency_s.push(start.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu0, thread_cpu_s()) {
            self.cpu_s.push(b - a);
        }
        Ok(())
    }

    /// One USBL update (fix valid at `t_valid`).
    pub fn add_usbl(&mut self, t_valid: f64, pos_enu_m: Vector3<f64>, sigma_h_m: f64, sigma_v_m: f64) -> Result<(), FgoError> {
        let start = Instant::now();
        let cpu0 = thread_cpu_s();
        let Some(k) = self.node_at(t_valid)? else {
            self.gate_log.dropped_too_old += 1;
            return Ok(());
        };
        let f = Factor::Usbl(UsblFactor {
            node: k,
            pos_enu_m,
            lever_body_m: Vector3::from(self.conf.usbl_lever_body_m),
            noise: Noise::from_sigmas(&[sigma_h_m, sigma_h_m, sigma_v_m])?,
            kappa: 1.0,
        });
        self.gated_add(t_valid, Sensor::Usbl, f, k)?;
        self.optimize_and_marginalize()?;
        self.delayed_decision()?;
        self.latency_s.push(start.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu0, thread_cpu_s()) {
            self.cpu_s.push(b - a);
        }
        Ok(())
    }

    /// One range update: the range (m) at `t` from the vehicle's transducer (lever arm `lever_body_m`)
    /// to a beacon at `beacon_enu_m` (known, surveyed), gated like a USBL fix.
    pub fn add_range(
        &mut self,
        t: f64,
        beacon_enu_m: Vector3<f64>,
        range_m: f64,
        sigma_m: f64,
        lever_body_m: Vector3<f64>,
    ) -> Result<(), FgoError> {
        if !(range_m.is_finite() && range_m >= 0.0) || !beacon_enu_m.iter().all(|x| x.is_finite()) {
            return Err(FgoError::Input(format!("range at t={t}: range {range_m} / beacon {beacon_enu_m:?} not finite or negative")));
        }
        let start = Instant::now();
        let cpu0 = thread_cpu_s();
        let Some(k) = self.node_at(t)? else {
            self.gate_log.dropped_too_old += 1;
            return Ok(());
        };
        let f = Factor::Range(RangeFactor { node: k, beacon_enu_m, range_m, lever_body_m, noise: Noise::from_sigmas(&[sigma_m])? });
        self.gated_add(t, Sensor::Range, f, k)?;
        self.optimize_and_marginalize()?;
        self.latency_s.push(start.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu0, thread_cpu_s()) {
            self.cpu_s.push(b - a);
        }
        Ok(())
    }

    /// Take a fix that is still in the window out after the fact (its covariance x
    /// [`gating::OUTLIER_KAPPA`]), solve the window again and output the newest node: what an
    /// outside judgement (an integrity monitor, or an evaluation that knows which fixes were
    /// corrupted, see `kitti_run::Oracle`) does with a fix once it is known to be wrong.
    /// `false` (nothing done) if no USBL fix at `t_valid` is in the window.
    pub fn exclude_fix(&mut self, t_valid: f64) -> Result<bool, FgoError> {
        let mut found = false;
        for f in self.factors.iter_mut() {
            if let Factor::Usbl(u) = f {
                if (self.times[u.node] - t_valid).abs() < 1e-9 && u.kappa < gating::OUTLIER_KAPPA {
                    u.noise = u.noise.scaled(gating::OUTLIER_KAPPA / u.kappa);
                    u.kappa = gating::OUTLIER_KAPPA;
                    found = true;
                }
            }
        }
        if found {
            self.optimize_and_marginalize()?;
        }
        Ok(found)
    }

    /// All node estimates (history + window), sorted by time, and all real factors re-indexed to
    /// that order: the batch problem.
    pub fn batch_problem(&self) -> (Vec<Estimate>, Vec<Factor>) {
        let mut est = self.history.clone();
        est.retain(|e| !self.ids.contains(&e.id));
        for (k, id) in self.ids.iter().enumerate() {
            est.push(Estimate { id: *id, t_s: self.times[k], state: self.nodes[k] });
        }
        est.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        let mut pos = vec![usize::MAX; self.next_id];
        for (i, e) in est.iter().enumerate() {
            pos[e.id] = i;
        }
        let mut factors: Vec<Factor> = self.archive.clone();
        let ids = self.ids.clone();
        for f in &self.factors {
            if matches!(f, Factor::Marginal(_)) {
                continue;
            }
            let mut f = f.clone();
            f.set_nodes(&|i| ids[i]);
            factors.push(f);
        }
        for f in &mut factors {
            f.set_nodes(&|id| pos[id]);
        }
        (est, factors)
    }
}

/// Result of processing a log.
pub struct RunResult {
    pub realtime: Vec<Estimate>,
    pub batch: Vec<Estimate>,
    pub gate_log: GateLog,
    pub latency_s: Vec<f64>,
    pub cpu_s: Vec<f64>,
    pub batch_report: Option<solver::LmReport>,
    pub batch_factors: Vec<Factor>,
    /// The IMU noise variance scale estimated at the end of the real-time run, and the batch's
    /// (adaptive gate; 1 otherwise). With the neighbours rule the IMU factors keep the given
    /// noise and these are the scales the tests used.
    pub realtime_imu_scale: f64,
    pub batch_imu_scale: f64,
}

/// Process a whole log in arrival order (real time), then optionally the batch LM.
pub fn run(log: &SensorLog, cfg: SmootherConfig, batch: bool, mut progress: impl FnMut(usize, usize)) -> Result<RunResult, FgoError> {
    log.validate()?;
    let mut sm = Smoother::new(log.config, cfg)?;
    // events in arrival order: DVL at its time, USBL at its arrival time
    enum Ev {
        Dvl(usize),
        Usbl(usize),
    }
    let mut evs: Vec<(f64, Ev)> = log.dvl.iter().enumerate().map(|(i, d)| (d.t_s, Ev::Dvl(i))).collect();
    evs.extend(log.usbl.iter().enumerate().map(|(i, u)| (u.t_arrival_s, Ev::Usbl(i))));
    evs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let t0 = log.config.prior.t_s;
    let mut next_imu = 0;
    let total = evs.len();
    for (n, (t_ev, ev)) in evs.into_iter().enumerate() {
        while next_imu < log.imu.len() && log.imu[next_imu].t_s <= t_ev {
            sm.push_imu(log.imu[next_imu])?;
            next_imu += 1;
        }
        match ev {
            Ev::Dvl(i) => {
                let d = &log.dvl[i];
                if d.t_s > t0 {
                    sm.add_dvl(d.t_s, Vector3::from(d.vel_dvl_mps), d.sigma_mps)?;
                }
            }
            Ev::Usbl(i) => {
                let u = &log.usbl[i];
                if u.t_valid_s > t0 {
                    sm.add_usbl(u.t_valid_s, Vector3::from(u.pos_enu_m), u.sigma_h_m, u.sigma_v_m)?;
                }
            }
        }
        progress(n + 1, total);
    }
    let (mut est, mut factors) = sm.batch_problem();
    let mut report = None;
    let realtime_imu_scale = sm.imu_scale;
    let mut batch_imu_scale = 1.0;
    if batch {
        let mut nodes: Vec<NodeState> = est.iter().map(|e| e.state).collect();
        report = Some(if cfg.gating.enabled && cfg.gating.adaptive {
            let (r, _, s) = gating::robust_batch(&mut nodes, &mut factors, &cfg.gating, &LmOptions::default())?;
            batch_imu_scale = s;
            r
        } else {
            solver::solve_lm(&mut nodes, &factors, &LmOptions::default())?
        });
        for (e, x) in est.iter_mut().zip(nodes) {
            e.state = x;
        }
    }
    Ok(RunResult {
        realtime: sm.realtime,
        batch: est,
        gate_log: sm.gate_log,
        latency_s: sm.latency_s,
        cpu_s: sm.cpu_s,
        batch_report: report,
        batch_factors: factors,
        realtime_imu_scale,
        batch_imu_scale,
    })
}

/// Position RMSE (m) of estimates against the simulator truth.
pub fn position_rmse(est: &[Estimate], truth: &super::sim::Truth) -> f64 {
    if est.is_empty() {
        return f64::NAN;
    }
    let se: f64 = est.iter().map(|e| (e.state.nav.pos_enu_m - truth.at(e.t_s).pos_enu_m).norm_squared()).sum();
    (se / est.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{SimConfig, simulate};

    #[test]
    fn short_mission_gated_beats_ungated_and_counts_decisions() {
        let sim = simulate(&SimConfig { duration_s: 20.0, seed: 7, abnormal_fraction: 0.3, ..Default::default() });
        let g = run(&sim.log, SmootherConfig::default(), true, |_, _| {}).unwrap();
        let off = SmootherConfig { gating: GatingConfig { enabled: false, ..Default::default() }, ..Default::default() };
        let u = run(&sim.log, off, true, |_, _| {}).unwrap();
        let (rg, ru) = (position_rmse(&g.batch, &sim.truth), position_rmse(&u.batch, &sim.truth));
        let (rtg, rtu) = (position_rmse(&g.realtime, &sim.truth), position_rmse(&u.realtime, &sim.truth));
        eprintln!("batch gated {rg:.3} ungated {ru:.3}; realtime gated {rtg:.3} ungated {rtu:.3}; {:?}", sim.stats);
        let n_dec = g.gate_log.decisions.len();
        assert_eq!(n_dec + g.gate_log.dropped_too_old, sim.stats.dvl_delivered + sim.stats.usbl_delivered);
        assert!(g.gate_log.count(Sensor::Usbl, true) + g.gate_log.count(Sensor::Dvl, true) > 0);
        assert_eq!(u.gate_log.count(Sensor::Usbl, true) + u.gate_log.count(Sensor::Dvl, true), 0);
        assert!(g.batch_report.unwrap().converged);
        assert!(rg < ru, "gated {rg} ungated {ru}");
        assert!(rg < 5.0);
    }

    /// A fix 30 m off, accepted (gate off), pulls the newest estimate; taken out after the fact
    /// it no longer does; a time with no fix in the window is refused.
    #[test]
    fn a_fix_taken_out_after_the_fact_stops_pulling() {
        let sim = simulate(&SimConfig { duration_s: 20.0, seed: 3, abnormal_fraction: 0.0, dvl_lock_losses: 0, ..Default::default() });
        let off = SmootherConfig { gating: GatingConfig { enabled: false, ..Default::default() }, ..Default::default() };
        let mut sm = Smoother::new(sim.log.config, off).unwrap();
        for s in &sim.log.imu {
            sm.push_imu(*s).unwrap();
        }
        let t0 = sim.log.config.prior.t_s;
        for d in sim.log.dvl.iter().filter(|d| d.t_s > t0 && d.t_s < t0 + 5.0) {
            sm.add_dvl(d.t_s, Vector3::from(d.vel_dvl_mps), d.sigma_mps).unwrap();
        }
        let t = *sm.times.last().unwrap();
        let truth = sim.truth.at(t).pos_enu_m;
        let err = |sm: &Smoother| (sm.realtime.last().unwrap().state.nav.pos_enu_m - truth).norm();
        let before = err(&sm);
        sm.add_usbl(t, truth + Vector3::new(30.0, 0.0, 0.0), 0.5, 0.5).unwrap();
        let pulled = err(&sm);
        assert!(sm.exclude_fix(t).unwrap());
        let after = err(&sm);
        eprintln!("error at the fix: {before:.3} m before, {pulled:.3} m with the 30-m fix, {after:.3} m once it is out");
        assert!(pulled > 10.0 && after < 0.2 * pulled, "{before} {pulled} {after}");
        assert!(!sm.exclude_fix(t).unwrap(), "already out");
        assert!(!sm.exclude_fix(t0 - 100.0).unwrap(), "no fix there");
    }

    /// The neighbours rule in real time, IMU and USBL fixes only (no DVL, as on KITTI), a 20-s
    /// window: one fix 25 m off is taken out when the next fix arrives, and no clean fix is
    /// taken out; without the rule (the fourth pass's adaptive gate) nothing is decided late.
    #[test]
    fn neighbours_rule_takes_a_jumped_fix_out_one_fix_late() {
        let sim = simulate(&SimConfig {
            duration_s: 120.0,
            seed: 11,
            abnormal_fraction: 0.0,
            usbl_packet_loss: 0.0,
            dvl_lock_losses: 0,
            ..Default::default()
        });
        let t0 = sim.log.config.prior.t_s;
        let mut fixes: Vec<_> = sim.log.usbl.iter().filter(|u| u.t_valid_s > t0).copied().collect();
        fixes.sort_by(|a, b| a.t_arrival_s.total_cmp(&b.t_arrival_s));
        let jumped = 12;
        fixes[jumped].pos_enu_m[0] += 25.0;
        let t_jump = fixes[jumped].t_valid_s;
        for neighbours in [true, false] {
            let cfg = SmootherConfig { lag_s: 20.0, gating: GatingConfig { neighbours, ..Default::default() }, ..Default::default() };
            let mut sm = Smoother::new(sim.log.config, cfg).unwrap();
            for s in &sim.log.imu {
                sm.push_imu(*s).unwrap();
            }
            for u in &fixes {
                sm.add_usbl(u.t_valid_s, Vector3::from(u.pos_enu_m), u.sigma_h_m, u.sigma_v_m).unwrap();
            }
            let out: Vec<f64> = sm.delayed.iter().filter(|d| d.1).map(|d| d.0).collect();
            eprintln!("neighbours {neighbours}: {} delayed decisions, out at {out:?} (jump at {t_jump})", sm.delayed.len());
            if neighbours {
                assert!(sm.delayed.len() >= fixes.len() - 3, "{} decisions for {} fixes", sm.delayed.len(), fixes.len());
                assert_eq!(out, vec![t_jump]);
            } else {
                assert!(sm.delayed.is_empty());
            }
        }
    }

    #[test]
    fn late_fix_older_than_window_is_dropped_and_counted() {
        let sim = simulate(&SimConfig { duration_s: 15.0, seed: 3, ..Default::default() });
        let mut sm = Smoother::new(sim.log.config, SmootherConfig { lag_s: 2.0, ..Default::default() }).unwrap();
        for s in &sim.log.imu {
            sm.push_imu(*s).unwrap();
        }
        for d in sim.log.dvl.iter().take(16) {
            sm.add_dvl(d.t_s, Vector3::from(d.vel_dvl_mps), d.sigma_mps).unwrap();
        }
        sm.add_usbl(1.0, Vector3::zeros(), 1.0, 1.0).unwrap();
        assert_eq!(sm.gate_log.dropped_too_old, 1);
        // a fix between window nodes splits the IMU interval
        let n_before = sm.times.len();
        let t_mid = 0.5 * (sm.times[n_before - 2] + sm.times[n_before - 1]);
        let x = sim.truth.at(t_mid);
        sm.add_usbl(t_mid, x.pos_enu_m, 1.0, 0.5).unwrap();
        assert_eq!(sm.times.len(), n_before + 1);
        assert!(sm.times.windows(2).all(|w| w[1] > w[0]));
        // bad input is an error, not a panic
        assert!(sm.push_imu(sim.log.imu[0]).is_err());
        assert!(sm.add_dvl(1e9, Vector3::zeros(), 0.01).is_err());
    }

    /// IMU + DVL with ranges to three known beacons (3-D range factors, every 5 s, one of them
    /// 30 m off): the ranges pull the dead-reckoned drift in, and the wrong one is gated.
    #[test]
    fn ranges_to_known_beacons_bound_the_drift_and_an_outlier_is_gated() {
        let sim = simulate(&SimConfig { duration_s: 120.0, seed: 5, abnormal_fraction: 0.0, dvl_lock_losses: 0, ..Default::default() });
        let beacons = [Vector3::new(150.0, 50.0, -80.0), Vector3::new(-60.0, 120.0, -80.0), Vector3::new(40.0, -140.0, -80.0)];
        let t0 = sim.log.config.prior.t_s;
        let mut err = Vec::new();
        for with_ranges in [false, true] {
            let mut sm = Smoother::new(sim.log.config, SmootherConfig::default()).unwrap();
            for s in &sim.log.imu {
                sm.push_imu(*s).unwrap();
            }
            let mut next_range = t0 + 5.0;
            let mut k = 0;
            let mut outlier_t = f64::NAN;
            for d in sim.log.dvl.iter().filter(|d| d.t_s > t0) {
                if with_ranges && d.t_s >= next_range {
                    let t = next_range;
                    let b = beacons[k % 3];
                    let mut r = (sim.truth.at(t).pos_enu_m - b).norm() + 0.2 * ((k as f64) * 1.7).sin();
                    if k == 12 {
                        r += 30.0;
                        outlier_t = t;
                    }
                    sm.add_range(t, b, r, 0.3, Vector3::zeros()).unwrap();
                    next_range += 5.0;
                    k += 1;
                }
                sm.add_dvl(d.t_s, Vector3::from(d.vel_dvl_mps), d.sigma_mps).unwrap();
            }
            let last = sm.realtime.last().unwrap();
            err.push((last.state.nav.pos_enu_m - sim.truth.at(last.t_s).pos_enu_m).norm());
            if with_ranges {
                let flagged: Vec<f64> =
                    sm.gate_log.decisions.iter().filter(|d| d.sensor == Sensor::Range && d.abnormal).map(|d| d.t_s).collect();
                assert!(flagged.iter().any(|t| (t - outlier_t).abs() < 1e-9), "outlier at {outlier_t} not flagged: {flagged:?}");
                assert!(flagged.len() <= 2, "clean ranges flagged: {flagged:?}");
                assert!(sm.add_range(1.0e9, beacons[0], f64::NAN, 0.3, Vector3::zeros()).is_err());
            }
        }
        eprintln!("final position error: IMU+DVL {:.3} m, + ranges {:.3} m", err[0], err[1]);
        assert!(err[1] < err[0] && err[1] < 1.0, "{err:?}");
    }
}
