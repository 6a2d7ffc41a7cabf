//! The whole chain: soundings -> points -> submaps -> loop closures (matching, vote, robust
//! global solve) -> per-ping offsets (uniform and spring) -> corrected trajectory and grid;
//! plus the evaluation against a simulator's truth (sounding position errors, crossline depth
//! differences, closure errors).

use super::association::{self, AssocConfig};
use super::correction::{self, Closure, Distribution, DriftConfig, DriftIndex, VoteConfig};
use super::grid::Grid;
use super::matching::{self, MatchConfig, MatchResult, Rejection};
use super::points;
use super::sim::SimOutput;
use super::submap::{self, SubmapConfig};
use super::{NavSample, Point, Survey, V2};
use anyhow::{Result, bail};
use std::time::Instant;

#[derive(Debug, Clone, serde::Serialize)]
pub struct PipelineConfig {
    pub submap: SubmapConfig,
    pub matching: MatchConfig,
    pub drift: DriftConfig,
    pub vote: VoteConfig,
    pub assoc: AssocConfig,
    pub min_search_m: f64,
    pub max_search_m: f64,
    /// Robust-solve gate on a closure's normalized squared residual.
    pub robust_chi2: f64,
    pub grid_cell_m: f64,
}

impl PipelineConfig {
    pub fn for_altitude(alt_m: f64) -> Self {
        let submap = SubmapConfig::for_altitude(alt_m);
        let cell = submap.cell_m;
        Self {
            matching: MatchConfig { min_overlap_cells: ((30.0 * alt_m * alt_m) / (cell * cell)) as usize / 10, ..MatchConfig::default() },
            submap,
            drift: DriftConfig::default(),
            vote: VoteConfig::default(),
            assoc: AssocConfig::default(),
            min_search_m: 0.75 * alt_m,
            max_search_m: 4.0 * alt_m,
            robust_chi2: 25.0,
            grid_cell_m: cell,
        }
    }
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct Attempt {
    pub a: usize,
    pub b: usize,
    pub key_a: usize,
    pub key_b: usize,
    pub radius_m: f64,
    pub result: Result<MatchResult, Rejection>,
    pub votes: usize,
    pub voted: bool,
    pub kept: bool,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Timing {
    pub points_submaps_s: f64,
    pub association_s: f64,
    pub matching_s: f64,
    pub solve_s: f64,
    pub total_s: f64,
}

#[derive(Debug, Clone)]
pub struct PipelineOutput {
    pub submaps: Vec<submap::Submap>,
    pub attempts: Vec<Attempt>,
    /// Keyframe pings: [0 (anchor), key of submap 0, key of submap 1, ...].
    pub keys: Vec<usize>,
    pub key_offsets: Vec<V2>,
    pub offsets_uniform: Vec<V2>,
    pub offsets_spring: Vec<V2>,
    /// Spring with the dead-reckoning drift model only (no weak association), for comparison.
    pub offsets_spring_dr_only: Vec<V2>,
    pub timing: Timing,
}

/// Reject surveys the chain cannot process, with a clear message.
pub fn validate(s: &Survey) -> Result<()> {
    if s.pings.is_empty() {
        bail!("survey has no pings");
    }
    if s.nav.len() != s.pings.len() {
        bail!("survey has {} navigation samples for {} pings", s.nav.len(), s.pings.len());
    }
    for (i, n) in s.nav.iter().enumerate() {
        if ![n.t_s, n.north_m, n.east_m, n.depth_m, n.heading_rad].iter().all(|v| v.is_finite()) {
            bail!("navigation sample {i} (t = {}) has a non-finite value", n.t_s);
        }
    }
    for (i, p) in s.pings.iter().enumerate() {
        if let Some(b) = p.beams.iter().find(|b| !(b.angle_rad.is_finite() && b.range_m.is_finite() && b.range_m >= 0.0)) {
            bail!("ping {i} (t = {}) has an invalid beam {b:?}", p.t_s);
        }
    }
    Ok(())
}

pub fn run(survey: &Survey, cfg: &PipelineConfig) -> Result<PipelineOutput> {
    validate(survey)?;
    // The grids cover the navigation plus the swath: bound their size before building any.
    let (mut n_lo, mut n_hi, mut e_lo, mut e_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for n in &survey.nav {
        (n_lo, n_hi, e_lo, e_hi) = (n_lo.min(n.north_m), n_hi.max(n.north_m), e_lo.min(n.east_m), e_hi.max(n.east_m));
    }
    let swath_m = survey.pings.iter().flat_map(|p| p.beams.iter().map(|b| b.range_m)).fold(0.0, f64::max);
    subnav_base::limits::check_grid("the survey", n_hi - n_lo + 2.0 * swath_m, e_hi - e_lo + 2.0 * swath_m, cfg.grid_cell_m)
        .map_err(anyhow::Error::msg)?;
    let t0 = Instant::now();
    let nav = &survey.nav;
    let pts = points::survey_points(survey, None);
    let pos: Vec<V2> = nav.iter().map(|n| V2::new(n.north_m, n.east_m)).collect();
    let heading: Vec<f64> = nav.iter().map(|n| n.heading_rad).collect();
    let submaps = submap::build(&pts, &pos, &heading, &cfg.submap);
    let t1 = Instant::now();
    let assoc = association::associate(&pts, nav, &cfg.assoc);
    let extra: Vec<f64> =
        assoc.iter().map(|a| a.map_or(0.0, |a| cfg.drift.assoc_weight * a.info.symmetric_eigenvalues().min().max(0.0))).collect();
    let t2 = Instant::now();
    let step_var = correction::step_variances(nav, cfg.drift.q_dist_m2_per_m);
    let spring_var = correction::step_variances(nav, cfg.drift.q_dist_spring_m2_per_m);
    let drift = DriftIndex::new(&step_var);
    // Degraded steps (velocity sigma above twice the survey's median: DVL water track) count as
    // a velocity bias for the search window; the rest is in the random-walk drift.
    let mut sig: Vec<f64> = nav.iter().map(|n| n.vel_sigma_mps).filter(|v| v.is_finite()).collect();
    sig.sort_by(f64::total_cmp);
    let med = sig.get(sig.len() / 2).copied().unwrap_or(0.0);
    let mut vel_cum = vec![0.0; nav.len()];
    for i in 1..nav.len() {
        let s = if nav[i].vel_sigma_mps.is_finite() && nav[i].vel_sigma_mps > 2.0 * med { nav[i].vel_sigma_mps } else { 0.0 };
        vel_cum[i] = vel_cum[i - 1] + s * (nav[i].t_s - nav[i - 1].t_s).abs();
    }
    // Incremental: submaps are matched in time order against all earlier non-adjacent ones,
    // searching around the shift predicted by the current solution (as it would run on board),
    // with a window from the drift accumulated since the last accepted closure.
    let keys: Vec<usize> = std::iter::once(0).chain(submaps.iter().map(|s| s.key_ping)).collect();
    let mut key_e = vec![V2::zeros(); keys.len()];
    let mut attempts: Vec<Attempt> = vec![];
    let mut last_fix_ping = 0usize;
    let mut kept_all = vec![];
    let mut votes_ok: (Vec<usize>, Vec<bool>) = (vec![], vec![]);
    let mut cand: Vec<(usize, Closure)> = vec![];
    for b in 0..submaps.len() {
        key_e[b + 1] = key_e[b];
        let kb = submaps[b].key_ping;
        let mut new_match = false;
        for a in 0..b.saturating_sub(1) {
            let (ga, gb) = (&submaps[a].grid, &submaps[b].grid);
            let ka = submaps[a].key_ping;
            let prior = key_e[b + 1] - key_e[a + 1];
            // Velocity errors (water track: unknown current) act as biases, so they add up
            // linearly in the window; the per-metre drift as a random walk.
            let sys = (vel_cum[kb] - vel_cum[last_fix_ping]).max(0.0);
            let radius = (2.0 * sys + 3.0 * drift.between(last_fix_ping, kb).sqrt() + 10.0).clamp(cfg.min_search_m, cfg.max_search_m);
            if bbox_overlap_area(ga, gb, prior, radius) < cfg.matching.min_overlap_cells as f64 * ga.cell_m * ga.cell_m {
                continue;
            }
            let result = matching::match_grids(ga, gb, prior, radius, &cfg.matching);
            if matches!(result, Err(Rejection::NoOverlap { .. })) {
                continue;
            }
            if let Ok(m) = &result {
                cand.push((attempts.len(), Closure { a: a + 1, b: b + 1, key_a: ka, key_b: kb, shift: m.shift(), cov: m.cov2() }));
                new_match = true;
            }
            attempts.push(Attempt { a, b, key_a: ka, key_b: kb, radius_m: radius, result, votes: 0, voted: false, kept: false });
        }
        if new_match || b + 1 == submaps.len() {
            let closures: Vec<Closure> = cand.iter().map(|c| c.1.clone()).collect();
            votes_ok = correction::vote(&closures, &drift, &cfg.vote);
            let voted: Vec<Closure> = closures.iter().zip(&votes_ok.1).filter(|(_, k)| **k).map(|(c, _)| c.clone()).collect();
            let Some((e, kept)) = correction::solve_robust(&keys, &voted, &drift, cfg.robust_chi2) else {
                bail!("global least squares failed (singular system)");
            };
            if voted.iter().zip(&kept).any(|(c, k)| *k && c.b == b + 1) {
                last_fix_ping = kb;
            }
            key_e = e;
            kept_all = kept;
        }
    }
    let t3 = Instant::now();
    let (votes, ok) = votes_ok;
    let key_offsets = key_e;
    let mut kept_it = kept_all.iter();
    for ((i, _), (v, o)) in cand.iter().zip(votes.iter().zip(&ok)) {
        attempts[*i].votes = *v;
        attempts[*i].voted = *o;
        if *o {
            attempts[*i].kept = kept_it.next().copied().unwrap_or(false);
        }
    }
    let n = nav.len();
    let offsets_uniform = correction::distribute(n, &keys, &key_offsets, &step_var, None, Distribution::Uniform);
    let offsets_spring = correction::distribute(n, &keys, &key_offsets, &spring_var, Some(&extra), Distribution::Spring);
    let offsets_spring_dr_only = correction::distribute(n, &keys, &key_offsets, &spring_var, None, Distribution::Spring);
    let t4 = Instant::now();
    let timing = Timing {
        points_submaps_s: (t1 - t0).as_secs_f64(),
        association_s: (t2 - t1).as_secs_f64(),
        matching_s: (t3 - t2).as_secs_f64(),
        solve_s: (t4 - t3).as_secs_f64(),
        total_s: (t4 - t0).as_secs_f64(),
    };
    Ok(PipelineOutput { submaps, attempts, keys, key_offsets, offsets_uniform, offsets_spring, offsets_spring_dr_only, timing })
}

/// Area of a's bounding box moved by `shift` that falls in b's box grown by `grow`.
fn bbox_overlap_area(a: &Grid, b: &Grid, shift: V2, grow: f64) -> f64 {
    let (an0, an1) = (a.north0_m + shift.x, a.north0_m + shift.x + a.rows as f64 * a.cell_m);
    let (ae0, ae1) = (a.east0_m + shift.y, a.east0_m + shift.y + a.cols as f64 * a.cell_m);
    let (bn0, bn1) = (b.north0_m - grow, b.north0_m + b.rows as f64 * b.cell_m + grow);
    let (be0, be1) = (b.east0_m - grow, b.east0_m + b.cols as f64 * b.cell_m + grow);
    (an1.min(bn1) - an0.max(bn0)).max(0.0) * (ae1.min(be1) - ae0.max(be0)).max(0.0)
}

/// Navigation corrected with per-ping offsets.
pub fn corrected_nav(nav: &[NavSample], offsets: &[V2]) -> Vec<NavSample> {
    nav.iter().zip(offsets).map(|(n, o)| NavSample { north_m: n.north_m - o.x, east_m: n.east_m - o.y, ..*n }).collect()
}

/// Grid of all soundings placed with the given offsets.
pub fn bathymetry(survey: &Survey, offsets: Option<&[V2]>, cell_m: f64) -> Option<Grid> {
    let pts: Vec<Point> = points::survey_points(survey, offsets).into_iter().flatten().collect();
    Grid::from_points(&pts, cell_m, 1)
}

// ----------------------------------------------------------------------------- evaluation

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ErrorStats {
    pub mean_m: f64,
    pub median_m: f64,
    pub p95_m: f64,
    pub count: usize,
}

impl ErrorStats {
    pub fn of(mut v: Vec<f64>) -> Self {
        v.retain(|x| x.is_finite());
        if v.is_empty() {
            return Self::default();
        }
        let n = v.len();
        let mean = v.iter().sum::<f64>() / n as f64;
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((n - 1) as f64 * p).round() as usize];
        Self { mean_m: mean, median_m: q(0.5), p95_m: q(0.95), count: n }
    }
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct CrosslineStats {
    pub mean_abs_m: f64,
    pub rms_m: f64,
    pub cells: usize,
    pub line_pairs: usize,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct MethodEval {
    pub sounding_error: ErrorStats,
    pub nav_error: ErrorStats,
    pub crossline: CrosslineStats,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ClosureEval {
    pub submaps: usize,
    pub attempted: usize,
    pub matched: usize,
    pub voted: usize,
    pub kept: usize,
    pub rejected_no_relief_or_info: usize,
    pub rejected_ambiguous: usize,
    pub rejected_other: usize,
    /// Error of kept closures against the true offset difference at the keyframes.
    pub kept_error: ErrorStats,
    /// Kept closures more than 5 m from the truth (false closures that got through).
    pub kept_false: usize,
    /// Matched (pre-vote) closures more than 5 m from the truth.
    pub matched_false: usize,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Evaluation {
    pub pings: usize,
    pub soundings: usize,
    pub duration_s: f64,
    pub path_m: f64,
    pub dead_reckoning: MethodEval,
    pub uniform: MethodEval,
    pub spring: MethodEval,
    pub spring_dr_only: MethodEval,
    pub closures: ClosureEval,
    pub timing: Timing,
}

/// Straight line segments of the track (for crossline statistics): runs of pings whose heading
/// stays within 20 deg of the run's median start heading and at least `min_len_m` long.
pub fn line_segments(nav: &[NavSample], min_len_m: f64) -> Vec<(usize, usize, f64)> {
    let mut out = vec![];
    let mut s = 0;
    let diff = |a: f64, b: f64| {
        let d = (a - b).rem_euclid(std::f64::consts::TAU);
        d.min(std::f64::consts::TAU - d)
    };
    let flush = |s: usize, e: usize, out: &mut Vec<(usize, usize, f64)>| {
        if e <= s + 1 {
            return;
        }
        let len: f64 =
            (s + 1..=e).map(|i| ((nav[i].north_m - nav[i - 1].north_m).powi(2) + (nav[i].east_m - nav[i - 1].east_m).powi(2)).sqrt()).sum();
        if len >= min_len_m {
            out.push((s, e, nav[(s + e) / 2].heading_rad));
        }
    };
    for i in 1..nav.len() {
        if diff(nav[i].heading_rad, nav[s].heading_rad) > 20f64.to_radians() {
            flush(s, i - 1, &mut out);
            s = i;
        }
    }
    flush(s, nav.len().saturating_sub(1), &mut out);
    out
}

/// Depth differences between crossing lines (heading difference 45..135 deg), per common cell.
pub fn crossline_stats(survey: &Survey, offsets: Option<&[V2]>, cell_m: f64, min_len_m: f64) -> CrosslineStats {
    let pts = points::survey_points(survey, offsets);
    let segs = line_segments(&survey.nav, min_len_m);
    let grids: Vec<Option<Grid>> = segs
        .iter()
        .map(|&(s, e, _)| {
            let p: Vec<Point> = pts[s..=e].iter().flatten().copied().collect();
            Grid::from_points(&p, cell_m, 0)
        })
        .collect();
    let (mut sa, mut s2, mut n, mut pairs) = (0.0, 0.0, 0usize, 0usize);
    for i in 0..segs.len() {
        for j in i + 1..segs.len() {
            let d = (segs[i].2 - segs[j].2).rem_euclid(std::f64::consts::PI);
            if !(45f64.to_radians()..=135f64.to_radians()).contains(&d) {
                continue;
            }
            let (Some(a), Some(b)) = (&grids[i], &grids[j]) else { continue };
            let mut any = false;
            for r in 0..a.rows {
                for c in 0..a.cols {
                    let va = a.get(r, c);
                    if !va.is_finite() {
                        continue;
                    }
                    let (pn, pe) = a.centre(r, c);
                    if let Some(k) = b.index_of(pn, pe) {
                        let vb = b.data[k];
                        if vb.is_finite() {
                            let d = vb - va;
                            sa += d.abs();
                            s2 += d * d;
                            n += 1;
                            any = true;
                        }
                    }
                }
            }
            pairs += any as usize;
        }
    }
    if n == 0 {
        return CrosslineStats::default();
    }
    CrosslineStats { mean_abs_m: sa / n as f64, rms_m: (s2 / n as f64).sqrt(), cells: n, line_pairs: pairs }
}

/// Horizontal error of every sounding placed with `offsets` against the simulator's truth.
pub fn sounding_errors(sim: &SimOutput, offsets: Option<&[V2]>) -> Vec<f64> {
    let est = points::survey_points(&sim.survey, offsets);
    est.iter()
        .zip(&sim.truth_points)
        .flat_map(|(e, t)| e.iter().zip(t).map(|(a, b)| ((a.north_m - b.north_m).powi(2) + (a.east_m - b.east_m).powi(2)).sqrt()))
        .collect()
}

fn nav_errors(sim: &SimOutput, offsets: Option<&[V2]>) -> Vec<f64> {
    sim.survey
        .nav
        .iter()
        .zip(&sim.truth_nav)
        .enumerate()
        .map(|(i, (n, t))| {
            let o = offsets.and_then(|o| o.get(i)).copied().unwrap_or_else(V2::zeros);
            ((n.north_m - o.x - t.north_m).powi(2) + (n.east_m - o.y - t.east_m).powi(2)).sqrt()
        })
        .collect()
}

pub fn evaluate(sim: &SimOutput, out: &PipelineOutput, cfg: &PipelineConfig) -> Evaluation {
    let cross_len = cfg.submap.max_len_m;
    let m = |o: Option<&[V2]>| MethodEval {
        sounding_error: ErrorStats::of(sounding_errors(sim, o)),
        nav_error: ErrorStats::of(nav_errors(sim, o)),
        crossline: crossline_stats(&sim.survey, o, cfg.grid_cell_m, cross_len),
    };
    let true_e = |k: usize| {
        let (n, t) = (&sim.survey.nav[k], &sim.truth_nav[k]);
        V2::new(n.north_m - t.north_m, n.east_m - t.east_m)
    };
    let mut ce = ClosureEval { submaps: out.submaps.len(), attempted: out.attempts.len(), ..Default::default() };
    let mut kept_err = vec![];
    for at in &out.attempts {
        match &at.result {
            Ok(r) => {
                ce.matched += 1;
                let err = (r.shift() - (true_e(at.key_b) - true_e(at.key_a))).norm();
                if err > 5.0 {
                    ce.matched_false += 1;
                }
                if at.voted {
                    ce.voted += 1;
                }
                if at.kept {
                    ce.kept += 1;
                    kept_err.push(err);
                    if err > 5.0 {
                        ce.kept_false += 1;
                    }
                }
            }
            Err(Rejection::LowRelief { .. } | Rejection::LowInformation { .. }) => ce.rejected_no_relief_or_info += 1,
            Err(Rejection::Ambiguous { .. }) => ce.rejected_ambiguous += 1,
            Err(_) => ce.rejected_other += 1,
        }
    }
    ce.kept_error = ErrorStats::of(kept_err);
    let path_m =
        sim.truth_nav.windows(2).map(|w| ((w[1].north_m - w[0].north_m).powi(2) + (w[1].east_m - w[0].east_m).powi(2)).sqrt()).sum();
    Evaluation {
        pings: sim.survey.pings.len(),
        soundings: sim.survey.pings.iter().map(|p| p.beams.len()).sum(),
        duration_s: sim.survey.nav.last().map_or(0.0, |n| n.t_s) - sim.survey.nav.first().map_or(0.0, |n| n.t_s),
        path_m,
        dead_reckoning: m(None),
        uniform: m(Some(&out.offsets_uniform)),
        spring: m(Some(&out.offsets_spring)),
        spring_dr_only: m(Some(&out.offsets_spring_dr_only)),
        closures: ce,
        timing: out.timing.clone(),
    }
}
