//! Survey simulator: a vehicle following a lawnmower plan with crossing lines and a revisit
//! over a synthetic seafloor ([`super::terrain`]), a multibeam echosounder (swath ~10x altitude,
//! range noise, sound-speed error) and a dead reckoning that drifts (DVL noise and scale error,
//! DVL bottom-lock dropouts with water-track fallback, gyro-compass bias and random walk).
//! The truth (poses and true sounding footprints) is kept for evaluation.

use super::grid::Grid;
use super::terrain::{self, TerrainConfig};
use super::{Beam, NavSample, Ping, Point, Survey};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

#[derive(Debug, Clone, serde::Serialize)]
pub struct SimConfig {
    pub terrain: TerrainConfig,
    /// Waypoints (north, east) in order; the vehicle starts at the first one heading to the second.
    pub waypoints: Vec<(f64, f64)>,
    pub altitude_m: f64,
    pub beams: usize,
    /// Outermost beam angle; tan(78.7 deg) = 5 gives a swath of 10x altitude.
    pub max_beam_angle_rad: f64,
    pub ping_dt_s: f64,
    pub speed_range_mps: (f64, f64),
    pub max_turn_rate_rad_s: f64,
    pub range_noise_m: f64,
    pub range_noise_rel: f64,
    pub angle_noise_rad: f64,
    /// 1-sigma relative error of the sonar's assumed sound speed.
    pub sound_speed_rel_sigma: f64,
    pub dvl_noise_mps: f64,
    pub dvl_scale_sigma: f64,
    pub heading_bias_sigma_rad: f64,
    pub heading_rw_rad_per_sqrt_s: f64,
    pub heading_noise_rad: f64,
    /// Expected DVL bottom-lock dropouts per second and their duration range.
    pub dropout_rate_hz: f64,
    pub dropout_s: (f64, f64),
    /// Water current magnitude range (unknown to the DR while in water-track mode).
    pub current_mps: (f64, f64),
    pub water_track_noise_mps: f64,
    /// The DR's own 1-sigma velocity error figures (reported with each nav sample).
    pub reported_sigma_bottom_mps: f64,
    pub reported_sigma_water_mps: f64,
    pub max_pings: usize,
}

impl SimConfig {
    /// About one hour of survey at ~2 m/s: six 700 m main lines 140 m apart (swath ~200 m), two
    /// cross lines and a diagonal transit back to the start (revisit), over 0..700 m x 0..700 m.
    pub fn one_hour(seed: u64) -> Self {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xF1A7);
        let (len, sp, nl) = (700.0, 140.0, 6);
        let mut wps = vec![];
        for l in 0..nl {
            let e = l as f64 * sp;
            if l % 2 == 0 {
                wps.push((0.0, e));
                wps.push((len, e));
            } else {
                wps.push((len, e));
                wps.push((0.0, e));
            }
        }
        let emax = (nl - 1) as f64 * sp;
        wps.push((0.3 * len, emax));
        wps.push((0.3 * len, 0.0));
        wps.push((0.75 * len, 0.0));
        wps.push((0.75 * len, emax));
        wps.push((0.0, 0.0));
        let mut terrain = TerrainConfig::area((-160.0, len + 160.0), (-160.0, emax + 160.0));
        // One patch of flat sand somewhere inside the block: closures there must be rejected.
        terrain.flat_patches =
            vec![(rng.random_range(0.2 * len..0.8 * len), rng.random_range(0.2 * emax..0.8 * emax), rng.random_range(60.0..110.0))];
        Self::with(terrain, wps)
    }

    /// A small survey (some minutes) for tests: `lines` lines of `len` m, `sp` m apart, at 20 m
    /// altitude, plus one cross line.
    pub fn small(lines: usize, len: f64, sp: f64) -> Self {
        let mut wps = vec![];
        for l in 0..lines {
            let e = l as f64 * sp;
            if l % 2 == 0 {
                wps.push((0.0, e));
                wps.push((len, e));
            } else {
                wps.push((len, e));
                wps.push((0.0, e));
            }
        }
        let emax = (lines.max(1) - 1) as f64 * sp;
        let last = wps.last().copied().unwrap_or((0.0, 0.0));
        wps.push((0.5 * len, last.1));
        wps.push((0.5 * len, if last.1 > 0.5 * emax { -20.0 } else { emax + 20.0 }));
        // Same seafloor statistics and altitude as the one-hour survey, fewer/shorter lines.
        let t = TerrainConfig::area((-130.0, len + 130.0), (-130.0, emax + 130.0));
        Self::with(t, wps)
    }

    fn with(terrain: TerrainConfig, waypoints: Vec<(f64, f64)>) -> Self {
        Self {
            terrain,
            waypoints,
            altitude_m: 20.0,
            beams: 101,
            max_beam_angle_rad: 5f64.atan(),
            ping_dt_s: 1.0,
            speed_range_mps: (1.5, 2.6),
            max_turn_rate_rad_s: 4f64.to_radians(),
            range_noise_m: 0.05,
            range_noise_rel: 0.002,
            angle_noise_rad: 0.05f64.to_radians(),
            sound_speed_rel_sigma: 0.002,
            dvl_noise_mps: 0.01,
            dvl_scale_sigma: 0.002,
            heading_bias_sigma_rad: 0.3f64.to_radians(),
            heading_rw_rad_per_sqrt_s: 0.05f64.to_radians() / 60f64.sqrt(),
            heading_noise_rad: 0.02f64.to_radians(),
            dropout_rate_hz: 1.0 / 600.0,
            dropout_s: (20.0, 90.0),
            current_mps: (0.05, 0.25),
            water_track_noise_mps: 0.03,
            reported_sigma_bottom_mps: 0.01,
            reported_sigma_water_mps: 0.2,
            max_pings: 20_000,
        }
    }
}

#[derive(Debug, Clone)]
pub struct SimOutput {
    /// What the processing sees: dead-reckoned navigation and the pings.
    pub survey: Survey,
    /// True pose at each ping.
    pub truth_nav: Vec<NavSample>,
    /// True footprint of each beam (same indexing as `survey.pings[i].beams`).
    pub truth_points: Vec<Vec<Point>>,
    pub terrain: Grid,
}

fn gauss(rng: &mut impl Rng) -> f64 {
    rng.sample(StandardNormal)
}

use subnav_base::wrap_pi as wrap;

/// Cast a beam from the vehicle into the terrain; returns (true range, hit point).
fn ray_cast(terrain: &Grid, n: f64, e: f64, depth: f64, heading: f64, beta: f64, max_range: f64) -> Option<(f64, Point)> {
    let (sn, cs) = (beta.sin(), beta.cos());
    let (sdn, sde) = (-heading.sin() * sn, heading.cos() * sn);
    let at = |s: f64| -> Option<f64> {
        let d = terrain.sample(n + sdn * s, e + sde * s)?;
        Some(d - (depth + cs * s)) // > 0: still above the seafloor
    };
    let mut s = 0.0;
    let mut gap = at(s)?;
    if gap <= 0.0 {
        return None;
    }
    let mut prev = s;
    while gap > 0.0 {
        prev = s;
        // Safe step for slopes up to 1:1.
        s += (gap / (cs + sn.abs())).max(0.05);
        if s > max_range {
            return None;
        }
        gap = at(s)?;
    }
    let (mut lo, mut hi) = (prev, s);
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if at(mid)? > 0.0 {
            lo = mid
        } else {
            hi = mid
        }
        if hi - lo < 1e-4 {
            break;
        }
    }
    let r = 0.5 * (lo + hi);
    Some((r, Point { north_m: n + sdn * r, east_m: e + sde * r, depth_m: depth + cs * r }))
}

pub fn simulate(cfg: &SimConfig, seed: u64) -> SimOutput {
    let terrain = terrain::generate(&cfg.terrain, seed);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5EED);
    let dt = cfg.ping_dt_s;
    let heading_bias = cfg.heading_bias_sigma_rad * gauss(&mut rng);
    let dvl_scale = 1.0 + cfg.dvl_scale_sigma * gauss(&mut rng);
    let sound_speed_ratio = 1.0 + cfg.sound_speed_rel_sigma * gauss(&mut rng); // true / assumed
    let cur_mag = rng.random_range(cfg.current_mps.0..=cfg.current_mps.1);
    let cur_dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let current = (cur_mag * cur_dir.cos(), cur_mag * cur_dir.sin());

    let wps = &cfg.waypoints;
    let (mut n, mut e) = wps.first().copied().unwrap_or((0.0, 0.0));
    let mut psi = match wps.get(1) {
        Some(&(n1, e1)) => (e1 - e).atan2(n1 - n),
        None => 0.0,
    };
    let mut depth = terrain.sample(n, e).map_or(10.0, |d| (d - cfg.altitude_m).max(2.0));
    let (mut dr_n, mut dr_e) = (n, e);
    let mut heading_rw = 0.0;
    let mut seg = 1usize;
    let mut seg_speed = rng.random_range(cfg.speed_range_mps.0..=cfg.speed_range_mps.1);
    let mut speed = seg_speed;
    let mut dropout_left = 0.0;

    let mut out =
        SimOutput { survey: Survey::default(), truth_nav: vec![], truth_points: vec![], terrain: Grid::new_empty(0.0, 0.0, 1.0, 0, 0) };
    let mut t = 0.0;
    let max_range = cfg.altitude_m * 10.0;
    while seg < wps.len() && out.survey.pings.len() < cfg.max_pings {
        // ---- ping at the current pose
        let truth = NavSample { t_s: t, north_m: n, east_m: e, depth_m: depth, heading_rad: psi, vel_sigma_mps: 0.0 };
        let water = dropout_left > 0.0;
        let vel_sigma = if water { cfg.reported_sigma_water_mps } else { cfg.reported_sigma_bottom_mps };
        let meas_heading = wrap(psi + heading_bias + heading_rw + cfg.heading_noise_rad * gauss(&mut rng));
        let dr = NavSample {
            t_s: t,
            north_m: dr_n,
            east_m: dr_e,
            depth_m: depth + 0.05 * gauss(&mut rng),
            heading_rad: meas_heading,
            vel_sigma_mps: vel_sigma,
        };
        let mut beams = Vec::with_capacity(cfg.beams);
        let mut hits = Vec::with_capacity(cfg.beams);
        for k in 0..cfg.beams {
            // Equidistant mode: beams spaced evenly across track on a flat seafloor.
            let beta = if cfg.beams > 1 {
                let u = -1.0 + 2.0 * k as f64 / (cfg.beams - 1) as f64;
                (u * cfg.max_beam_angle_rad.tan()).atan()
            } else {
                0.0
            };
            if let Some((r, p)) = ray_cast(&terrain, n, e, depth, psi, beta, max_range) {
                let r_meas = r / sound_speed_ratio + (cfg.range_noise_m + cfg.range_noise_rel * r) * gauss(&mut rng);
                let a_meas = beta + cfg.angle_noise_rad * gauss(&mut rng);
                beams.push(Beam { angle_rad: a_meas, range_m: r_meas });
                hits.push(p);
            }
        }
        out.survey.nav.push(dr);
        out.survey.pings.push(Ping { t_s: t, beams });
        out.truth_nav.push(truth);
        out.truth_points.push(hits);

        // ---- guidance: line-of-sight to a point 25 m ahead on the current leg
        let mut want = None;
        while seg < wps.len() {
            let (an, ae) = wps[seg - 1];
            let (bn, be) = wps[seg];
            let (ln, le) = (bn - an, be - ae);
            let len = (ln * ln + le * le).sqrt().max(1e-9);
            let (un, ue) = (ln / len, le / len);
            let along = (n - an) * un + (e - ae) * ue;
            if along >= len - 5.0 {
                seg += 1;
                seg_speed = rng.random_range(cfg.speed_range_mps.0..=cfg.speed_range_mps.1);
                continue;
            }
            let la = (along + 25.0).min(len);
            want = Some((ae + ue * la - e).atan2(an + un * la - n));
            break;
        }
        let Some(want) = want else { break };
        advance(
            cfg,
            &mut rng,
            &terrain,
            dt,
            current,
            dvl_scale,
            heading_bias,
            &mut heading_rw,
            water,
            &mut dropout_left,
            &mut n,
            &mut e,
            &mut depth,
            &mut psi,
            &mut speed,
            seg_speed,
            &mut dr_n,
            &mut dr_e,
            Some(want),
        );
        t += dt;
    }
    out.terrain = terrain;
    out
}

/// One time step of vehicle motion and dead reckoning.
#[allow(clippy::too_many_arguments)]
fn advance(
    cfg: &SimConfig,
    rng: &mut rand_chacha::ChaCha8Rng,
    terrain: &Grid,
    dt: f64,
    current: (f64, f64),
    dvl_scale: f64,
    heading_bias: f64,
    heading_rw: &mut f64,
    water: bool,
    dropout_left: &mut f64,
    n: &mut f64,
    e: &mut f64,
    depth: &mut f64,
    psi: &mut f64,
    speed: &mut f64,
    seg_speed: f64,
    dr_n: &mut f64,
    dr_e: &mut f64,
    want_heading: Option<f64>,
) {
    // Heading and speed control.
    let dpsi = match want_heading {
        Some(w) => wrap(w - *psi).clamp(-cfg.max_turn_rate_rad_s * dt, cfg.max_turn_rate_rad_s * dt),
        None => 0.0,
    };
    let target_speed = if dpsi.abs() > 0.5 * cfg.max_turn_rate_rad_s * dt { seg_speed.min(1.3) } else { seg_speed };
    *speed += (target_speed - *speed).clamp(-0.05 * dt, 0.05 * dt);
    // True velocity over ground: heading * speed through water + current.
    let (ch, sh) = (psi.cos(), psi.sin());
    let vg_n = *speed * ch + current.0;
    let vg_e = *speed * sh + current.1;
    // Body-frame (forward, starboard) velocity over ground and through water.
    let fwd_g = vg_n * ch + vg_e * sh;
    let stb_g = -vg_n * sh + vg_e * ch;
    let (fwd_m, stb_m) = if water {
        let fwd_w = fwd_g - (current.0 * ch + current.1 * sh);
        let stb_w = stb_g - (-current.0 * sh + current.1 * ch);
        (fwd_w + cfg.water_track_noise_mps * gauss(rng), stb_w + cfg.water_track_noise_mps * gauss(rng))
    } else {
        (dvl_scale * fwd_g + cfg.dvl_noise_mps * gauss(rng), dvl_scale * stb_g + cfg.dvl_noise_mps * gauss(rng))
    };
    let hm = *psi + heading_bias + *heading_rw + cfg.heading_noise_rad * gauss(rng);
    *dr_n += (fwd_m * hm.cos() - stb_m * hm.sin()) * dt;
    *dr_e += (fwd_m * hm.sin() + stb_m * hm.cos()) * dt;
    *heading_rw += cfg.heading_rw_rad_per_sqrt_s * dt.sqrt() * gauss(rng);
    *n += vg_n * dt;
    *e += vg_e * dt;
    *psi = wrap(*psi + dpsi);
    // Depth: keep the altitude with a first-order lag.
    if let Some(d) = terrain.sample(*n, *e) {
        let cmd = (d - cfg.altitude_m).max(2.0);
        *depth += (cmd - *depth) * (dt / 15.0).min(1.0);
    }
    // DVL dropouts.
    if *dropout_left > 0.0 {
        *dropout_left -= dt;
    } else if rng.random::<f64>() < cfg.dropout_rate_hz * dt {
        *dropout_left = rng.random_range(cfg.dropout_s.0..=cfg.dropout_s.1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points;

    #[test]
    fn ray_cast_on_flat_seafloor_is_analytic() {
        let mut tc = TerrainConfig::area((-100.0, 100.0), (-100.0, 100.0));
        tc.all_flat = true;
        tc.base_depth_m = 30.0;
        tc.cell_m = 2.0;
        let g = terrain::generate(&tc, 0);
        for beta_deg in [-70.0f64, -30.0, 0.0, 45.0, 75.0] {
            let b = beta_deg.to_radians();
            let (r, p) = ray_cast(&g, 0.0, 0.0, 10.0, 0.3, b, 500.0).unwrap();
            assert!((r - 20.0 / b.cos()).abs() < 1e-3, "beta {beta_deg}: {r}");
            assert!((p.depth_m - 30.0).abs() < 1e-3);
        }
    }

    #[test]
    fn noiseless_soundings_with_true_nav_land_on_the_true_footprints() {
        let mut cfg = SimConfig::small(2, 80.0, 20.0);
        cfg.range_noise_m = 0.0;
        cfg.range_noise_rel = 0.0;
        cfg.angle_noise_rad = 0.0;
        cfg.sound_speed_rel_sigma = 0.0;
        cfg.max_pings = 40;
        let out = simulate(&cfg, 5);
        assert_eq!(out.survey.pings.len(), 40);
        let mut n = 0;
        for (i, ping) in out.survey.pings.iter().enumerate() {
            for (b, truth) in ping.beams.iter().zip(&out.truth_points[i]) {
                let p = points::sounding(&out.truth_nav[i], b);
                assert!((p.north_m - truth.north_m).abs() < 1e-3 && (p.east_m - truth.east_m).abs() < 1e-3);
                assert!((p.depth_m - truth.depth_m).abs() < 1e-3);
                n += 1;
            }
        }
        assert!(n > 40 * 50, "too few returns: {n}");
        // The dead reckoning drifts away from the truth.
        let last = out.survey.nav.len() - 1;
        let d = ((out.survey.nav[last].north_m - out.truth_nav[last].north_m).powi(2)
            + (out.survey.nav[last].east_m - out.truth_nav[last].east_m).powi(2))
        .sqrt();
        assert!(d > 0.0);
    }
}
