//! Monte Carlo of the compass heading error on the simulator: random instants 2020-2100 and
//! places (|lat| <= 60 deg) with the sun's apparent elevation in a band, random attitude, fresh
//! calibration residuals and noise each draw; the full `subnav_core::compass::solve` chain
//! (counts -> Stokes -> sun vector -> tilt -> ephemeris -> heading). The calm default is a flat
//! sea under a clear sky with the real field's departure from single scattering (OSOAA's table,
//! [`calm_field`]), which the head's solver models; without the table (`Water::
//! polarization_table` off) the closed-form single-scattering field and solver.
//!
//! Real seas ([`McConfig::sea`]): each session is one instant and place, a moving sea of its
//! own (`subnav_base::sea`, wind direction random) under a sky kind, a head at the depth
//! cruising at 1 m/s and turning at 1 deg/s with a random roll and pitch; the compass solves at
//! [`SeaRun::rate_hz`], the wave tracker (`subnav_core::compass::WaveSigma`, fed the turn as
//! the gyro would) runs from the start, and the last [`SeaRun::scored`] attempts after
//! [`SeaRun::warmup_s`] are scored (a draw is one scored attempt of the moving sea). The
//! reported sigma is the tracker's (solver and wave part); the solver's alone is scored too.

use std::collections::BTreeMap;

use nalgebra::{Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use subnav_core::compass::{self, CompassConfig, CompassInput};
use subnav_core::ephemeris::{self, Atmosphere, Observer};

use subnav_base::sea::{Sea, SeaConfig};
use subnav_base::sky::{self as sim, Field, SeaField, SensorErrors, SkyKind, Water};
use subnav_core::compass::WaveSigma;

/// 2020-01-01 and 2100-01-01, POSIX µs.
pub const T2020_US: i64 = 1_577_836_800_000_000;
pub const T2100_US: i64 = 4_102_444_800_000_000;

#[derive(Debug, Clone)]
pub struct McConfig {
    pub draws: usize,
    pub depth_m: f64,
    pub min_elevation_deg: f64,
    pub max_elevation_deg: f64,
    pub units: usize,
    pub water: Water,
    pub errors: SensorErrors,
    /// Tilt error of the gravity vector (1-sigma per axis, rad).
    pub tilt_sigma_rad: f64,
    /// Roll and pitch drawn uniformly within +-this (deg).
    pub max_tilt_deg: f64,
    pub seed: u64,
    /// A moving sea and a sky (None: the flat-surface draws of `water`).
    pub sea: Option<SeaRun>,
}

/// Real-sea sessions (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeaRun {
    pub wind_mps: f64,
    pub sky: SkyKind,
    pub rate_hz: f64,
    pub warmup_s: f64,
    pub scored: usize,
}

impl SeaRun {
    pub fn new(wind_mps: f64, sky: SkyKind) -> Self {
        SeaRun { wind_mps, sky, rate_hz: 4.0, warmup_s: 12.0, scored: 10 }
    }
}

impl Default for McConfig {
    fn default() -> Self {
        McConfig {
            draws: 1000,
            depth_m: 10.0,
            min_elevation_deg: 20.0,
            max_elevation_deg: 70.0,
            units: 8,
            water: Water::clear(),
            errors: SensorErrors::default(),
            tilt_sigma_rad: 0.01f64.to_radians(),
            max_tilt_deg: 10.0,
            seed: 1,
            sea: None,
        }
    }
}

/// Clear water with its attenuation and scattering times `turbidity` (as `subnav sim`'s).
pub fn turbid_water(turbidity: f64) -> Water {
    let w = Water::clear();
    Water { c_per_m: w.c_per_m * turbidity, b_per_m: w.b_per_m * turbidity, kd_per_m: w.kd_per_m * turbidity, ..w }
}

/// Compass configuration matching the simulated head (`subnav_core::head::compass_config`:
/// the model departure, the azimuth at the ephemeris's elevation, the OSOAA departure table).
pub fn compass_config(water: &Water, tilt_sigma_rad: f64) -> CompassConfig {
    compass_config_with(subnav_core::head::compass_config(), water, tilt_sigma_rad)
}

/// The compass for a field that is single scattering by construction (`Water::
/// polarization_table` off): the single-scattering solver
/// (`subnav_core::head::compass_config_single_scattering`).
pub fn compass_config_for(water: &Water, tilt_sigma_rad: f64) -> CompassConfig {
    if water.polarization_table {
        compass_config(water, tilt_sigma_rad)
    } else {
        compass_config_with(subnav_core::head::compass_config_single_scattering(), water, tilt_sigma_rad)
    }
}

fn compass_config_with(base: CompassConfig, water: &Water, tilt_sigma_rad: f64) -> CompassConfig {
    CompassConfig { min_s0: 50.0, n_water: water.n_water as f32, tilt_sigma_rad: tilt_sigma_rad as f32, ..base }
}

#[derive(Debug, Clone, Serialize)]
pub struct ElevationBin {
    pub elevation_deg: [f64; 2],
    pub fixes: usize,
    pub rmse_deg: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct McResult {
    pub draws: usize,
    pub fixes: usize,
    pub no_fix: BTreeMap<String, usize>,
    pub depth_m: f64,
    pub elevation_deg: [f64; 2],
    pub rmse_deg: f64,
    pub mean_error_deg: f64,
    pub p95_abs_error_deg: f64,
    pub max_abs_error_deg: f64,
    /// RMS of the reported 1-sigma, and the fraction of errors within 2 reported sigma.
    pub rms_reported_sigma_deg: f64,
    pub within_2_sigma: f64,
    pub mean_dolp: f64,
    pub bins: Vec<ElevationBin>,
    /// Real-sea runs: wind, sky, sessions, and the fraction within 2 of the solver's own sigma
    /// (without the wave part) and the RMS wave part.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sea: Option<SeaSummary>,
}

#[derive(Debug, Clone, Serialize)]
pub struct SeaSummary {
    pub wind_mps: f64,
    pub sky: String,
    pub sessions: usize,
    pub within_2_solver_sigma: f64,
    pub rms_wave_sigma_deg: f64,
}

/// Wrap an angle to (-pi, pi] (the one wrap, `subnav_core::ukf::wrap_pi`).
pub use subnav_base::wrap_pi;

/// A random instant and place with the sun's apparent elevation in [lo, hi] deg.
pub fn draw_sun<R: Rng>(rng: &mut R, lo_deg: f64, hi_deg: f64) -> (i64, Observer, ephemeris::SunPosition) {
    loop {
        let t = rng.random_range(T2020_US..T2100_US);
        let obs = Observer {
            lat_rad: rng.random_range(-60f32..60.0).to_radians(),
            lon_rad: rng.random_range(-180f32..180.0).to_radians(),
            height_m: 0.0,
        };
        let Ok(p) = ephemeris::sun_position(t, &obs, Some(&Atmosphere::default()), ephemeris::delta_t_estimate_s(t)) else {
            continue;
        };
        let el = (p.apparent_elevation_rad() as f64).to_degrees();
        if el >= lo_deg && el <= hi_deg {
            return (t, obs, p);
        }
    }
}

/// The field of a calm, clear day: a flat sea under a clear sky with the real field's departure
/// from single scattering (`SeaField::calm_clear`), or the closed-form single-scattering
/// `Field` when the water has no departure table.
pub fn calm_field<R: Rng>(sun_ned: Vector3<f64>, water: Water, depth_m: f64, rng: &mut R) -> Box<dyn sim::LightField> {
    if water.polarization_table {
        Box::new(SeaField::calm_clear(sun_ned, water, depth_m))
    } else {
        Box::new(Field::new(sun_ned, water, depth_m, rng))
    }
}

pub fn sun_ned(p: &ephemeris::SunPosition) -> Vector3<f64> {
    let (el, az) = (p.apparent_elevation_rad() as f64, p.azimuth_rad as f64);
    Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin())
}

pub fn run(cfg: &McConfig) -> McResult {
    if let Some(sea) = cfg.sea {
        return run_sea(cfg, &sea);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let units = sim::default_units(cfg.units);
    let ccfg = compass_config_for(&cfg.water, cfg.tilt_sigma_rad);
    let mut errs = Vec::new(); // (error rad, sigma rad, elevation deg)
    let mut no_fix = BTreeMap::new();
    let mut dolp_sum = 0.0;
    let mut dolp_n = 0usize;
    for _ in 0..cfg.draws {
        let (t, obs, p) = draw_sun(&mut rng, cfg.min_elevation_deg, cfg.max_elevation_deg);
        let field = calm_field(sun_ned(&p), cfg.water, cfg.depth_m, &mut rng);
        let mt = cfg.max_tilt_deg.to_radians();
        let (roll, pitch, yaw) = (rng.random_range(-mt..=mt), rng.random_range(-mt..=mt), rng.random_range(0.0..std::f64::consts::TAU));
        let r_nb = Rotation3::from_euler_angles(roll, pitch, yaw);
        let cal: Vec<_> = units.iter().map(|u| sim::true_channels(u, &cfg.errors, &mut rng)).collect();
        let counts = sim::counts(field.as_ref(), &r_nb, &units, &cal, &cfg.errors, &mut rng);
        let accel = sim::accel(&r_nb, cfg.tilt_sigma_rad, &mut rng);
        let input = CompassInput {
            counts: &counts,
            accel_body_mps2: accel,
            unix_us: Some(t),
            observer: Some(obs),
            delta_t_s: ephemeris::delta_t_estimate_s(t),
        };
        if let Ok(good) = compass::observe_units(&units, &counts, &ccfg) {
            for o in &good {
                dolp_sum += o.dolp as f64;
                dolp_n += 1;
            }
        }
        match compass::solve(&units, &input, &ccfg) {
            Ok(fix) => {
                let e = wrap_pi(fix.heading_rad as f64 - yaw);
                errs.push((e, fix.sigma_heading_rad as f64, (p.apparent_elevation_rad() as f64).to_degrees()));
            }
            Err((r, _)) => *no_fix.entry(format!("{r:?}")).or_insert(0) += 1,
        }
    }
    summarize(cfg, errs, no_fix, if dolp_n > 0 { dolp_sum / dolp_n as f64 } else { 0.0 })
}

/// Sun elevation band of a sky kind: twilight puts the sun within 6 deg below to 2 deg above
/// the horizon, the others use the configured band.
pub fn elevation_band_deg(cfg: &McConfig, sky: SkyKind) -> (f64, f64) {
    if sky == SkyKind::Twilight { (-6.0, 2.0) } else { (cfg.min_elevation_deg, cfg.max_elevation_deg) }
}

fn run_sea(cfg: &McConfig, sr: &SeaRun) -> McResult {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let units = sim::default_units(cfg.units);
    let ccfg = compass_config_for(&cfg.water, cfg.tilt_sigma_rad);
    let per = sr.scored.max(1);
    let sessions = cfg.draws.div_ceil(per);
    let dt = 1.0 / sr.rate_hz.max(0.1);
    let steps = (sr.warmup_s / dt).ceil() as usize + per;
    let (lo, hi) = elevation_band_deg(cfg, sr.sky);
    let mut errs = Vec::new();
    let (mut solver_in, mut wave_sq) = (0usize, 0.0);
    let mut no_fix = BTreeMap::new();
    let (mut dolp_sum, mut dolp_n) = (0.0, 0usize);
    let yaw_rate = 1f64.to_radians();
    for sess in 0..sessions {
        let (t0, obs, _) = draw_sun(&mut rng, lo, hi);
        let sea = Sea::new(
            SeaConfig { wind_toward_rad: rng.random_range(0.0..std::f64::consts::TAU), ..SeaConfig::wind(sr.wind_mps) },
            rng.random(),
        );
        let mt = cfg.max_tilt_deg.to_radians();
        let (roll, pitch, yaw0) = (rng.random_range(-mt..=mt), rng.random_range(-mt..=mt), rng.random_range(0.0..std::f64::consts::TAU));
        let cal: Vec<_> = units.iter().map(|u| sim::true_channels(u, &cfg.errors, &mut rng)).collect();
        let cloud_seed: u64 = rng.random();
        let mut tracker = WaveSigma::default();
        let scored_here = per.min(cfg.draws - sess * per);
        for k in 0..steps {
            let t_s = k as f64 * dt;
            let t_us = t0 + (t_s * 1e6) as i64;
            let yaw = yaw0 + yaw_rate * t_s;
            if k > 0 {
                tracker.rotate((yaw_rate * dt) as f32);
            }
            let r_nb = Rotation3::from_euler_angles(roll, pitch, yaw);
            let pos = (t_s * yaw.cos(), t_s * yaw.sin());
            let Ok(p) = ephemeris::sun_position(t_us, &obs, Some(&Atmosphere::default()), ephemeris::delta_t_estimate_s(t_us)) else {
                continue;
            };
            let light = sr.sky.light(t_s + (cloud_seed % 3600) as f64, cloud_seed);
            let field = SeaField::new(sun_ned(&p), light, &sea, cfg.water, cfg.depth_m, pos, t_s);
            let counts = sim::counts(&field, &r_nb, &units, &cal, &cfg.errors, &mut rng);
            let accel = sim::accel(&r_nb, cfg.tilt_sigma_rad, &mut rng);
            let input = CompassInput {
                counts: &counts,
                accel_body_mps2: accel,
                unix_us: Some(t_us),
                observer: Some(obs),
                delta_t_s: ephemeris::delta_t_estimate_s(t_us),
            };
            let scored = k + scored_here >= steps;
            let result = compass::solve(&units, &input, &ccfg);
            let sigma = match &result {
                Ok(fix) => tracker.update(t_us as u64, fix.heading_rad, fix.sigma_heading_rad),
                Err(_) => f32::NAN,
            };
            if !scored {
                continue;
            }
            if let Ok(good) = compass::observe_units(&units, &counts, &ccfg) {
                for o in &good {
                    dolp_sum += o.dolp as f64;
                    dolp_n += 1;
                }
            }
            match result {
                Ok(fix) => {
                    let e = wrap_pi(fix.heading_rad as f64 - wrap_pi(yaw));
                    if e.abs() <= 2.0 * fix.sigma_heading_rad as f64 {
                        solver_in += 1;
                    }
                    wave_sq += tracker.wave_var_rad2() as f64;
                    errs.push((e, sigma as f64, (p.apparent_elevation_rad() as f64).to_degrees()));
                }
                Err((r, _)) => *no_fix.entry(format!("{r:?}")).or_insert(0) += 1,
            }
        }
    }
    let n = errs.len().max(1) as f64;
    let summary = SeaSummary {
        wind_mps: sr.wind_mps,
        sky: sr.sky.name().to_string(),
        sessions,
        within_2_solver_sigma: solver_in as f64 / n,
        rms_wave_sigma_deg: (wave_sq / n).sqrt().to_degrees(),
    };
    let band = McConfig { min_elevation_deg: lo, max_elevation_deg: hi, ..cfg.clone() };
    let mut r = summarize(&band, errs, no_fix, if dolp_n > 0 { dolp_sum / dolp_n as f64 } else { 0.0 });
    r.sea = Some(summary);
    r
}

fn rms(x: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = x.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    if n == 0 { f64::NAN } else { (s / n as f64).sqrt() }
}

fn summarize(cfg: &McConfig, errs: Vec<(f64, f64, f64)>, no_fix: BTreeMap<String, usize>, mean_dolp: f64) -> McResult {
    let d = |x: f64| x.to_degrees();
    let mut abs: Vec<f64> = errs.iter().map(|e| e.0.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let p95 = abs.get(((abs.len() as f64 * 0.95) as usize).min(abs.len().saturating_sub(1))).copied().unwrap_or(f64::NAN);
    let n = errs.len().max(1) as f64;
    let width = (cfg.max_elevation_deg - cfg.min_elevation_deg) / 5.0;
    let bins = (0..5)
        .map(|i| {
            let lo = cfg.min_elevation_deg + width * i as f64;
            let hi = lo + width;
            let sel: Vec<f64> = errs.iter().filter(|e| e.2 >= lo && (e.2 < hi || (i == 4 && e.2 <= hi))).map(|e| e.0).collect();
            ElevationBin { elevation_deg: [lo, hi], fixes: sel.len(), rmse_deg: d(rms(sel.into_iter())) }
        })
        .collect();
    McResult {
        draws: cfg.draws,
        fixes: errs.len(),
        no_fix,
        depth_m: cfg.depth_m,
        elevation_deg: [cfg.min_elevation_deg, cfg.max_elevation_deg],
        rmse_deg: d(rms(errs.iter().map(|e| e.0))),
        mean_error_deg: d(errs.iter().map(|e| e.0).sum::<f64>() / n),
        p95_abs_error_deg: d(p95),
        max_abs_error_deg: d(abs.last().copied().unwrap_or(f64::NAN)),
        rms_reported_sigma_deg: d(rms(errs.iter().map(|e| e.1))),
        within_2_sigma: errs.iter().filter(|e| e.0.abs() <= 2.0 * e.1).count() as f64 / n,
        mean_dolp,
        bins,
        sea: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Smaller version of the documented 1,000-draw run (docs/PERFORMANCE.md): 10 m, clear water,
    /// sun 20-70 deg, realistic noise, in the field with the real (OSOAA) field's polarization.
    /// The heading RMSE meets issue 35's clear-water 0.5 deg and >= 90 % of the errors are inside
    /// the reported 2 sigma; a low sun whose skylight pulls the measured elevation too far is
    /// refused as `Inconsistent` (the only no-fix reason allowed here), never a confident guess.
    #[test]
    fn heading_rmse_small_monte_carlo() {
        let r = run(&McConfig { draws: 150, seed: 7, ..McConfig::default() });
        assert!(r.fixes >= 120, "{r:?}");
        assert!(r.no_fix.keys().all(|k| k == "Inconsistent"), "{r:?}");
        assert!(r.rmse_deg <= 0.5, "heading RMSE {} deg: {r:?}", r.rmse_deg);
        assert!(r.within_2_sigma >= 0.9, "{r:?}");
    }

    /// Turbid, deep water: DoLP collapses and the compass says so instead of guessing.
    #[test]
    fn deep_turbid_water_gives_no_fix() {
        let water = Water { c_per_m: 0.8, b_per_m: 0.6, kd_per_m: 0.15, multiple_scattering: 3.0, ..Water::clear() };
        let r = run(&McConfig { draws: 20, depth_m: 60.0, water, seed: 3, ..McConfig::default() });
        assert_eq!(r.fixes, 0, "{r:?}");
        assert!(r.no_fix.contains_key("LowDolp"), "{r:?}");
    }

    /// A short version of the documented 1,000-draw moving-sea run (docs/PERFORMANCE.md): 10 m,
    /// clear water and sky, 5 m/s wind, the field with the real field's departure and issue 35's
    /// solver. The waves cost accuracy, but the reported sigma (with the tracker's wave part)
    /// stays honest. Sun 35-70 deg up
    /// (below ~33 deg the skylight's elevation bias gives `Inconsistent`, see the docs).
    #[test]
    fn moving_sea_sigma_is_honest() {
        let sea = SeaRun { scored: 5, ..SeaRun::new(5.0, SkyKind::Clear) };
        let r = run(&McConfig { draws: 60, seed: 11, sea: Some(sea), min_elevation_deg: 35.0, ..McConfig::default() });
        let s = r.sea.clone().unwrap();
        assert!(r.fixes >= 55, "{r:?}");
        assert!(r.within_2_sigma >= 0.85, "{r:?}");
        assert!(s.within_2_solver_sigma <= r.within_2_sigma, "{r:?}");
        // The field carries the real field's departure (`Water::polarization_table`) and the
        // solver is issue 35's, whose model term already covers the waves' scatter at 5 m/s
        // (the tracker's wave part is the excess over it; its own tests are in
        // `subnav_core::compass::wave`): either the tracker adds a wave part or the solver's
        // sigma alone covers the errors.
        assert!(s.rms_wave_sigma_deg > 0.05 || s.within_2_solver_sigma >= 0.85, "the waves are covered: {r:?}");
        assert!(r.rmse_deg < 3.0, "{r:?}");
    }

    /// Overcast, twilight: no heading, and the reason says why; a calm clear sea gives fixes.
    #[test]
    fn skies_without_a_sun_disc_give_no_fix() {
        for sky in [SkyKind::Overcast, SkyKind::Twilight] {
            let sea = SeaRun { scored: 4, warmup_s: 1.0, ..SeaRun::new(3.0, sky) };
            let r = run(&McConfig { draws: 12, seed: 5, sea: Some(sea), ..McConfig::default() });
            assert_eq!(r.fixes, 0, "{sky}: {r:?}");
            let reasons: Vec<&String> = r.no_fix.keys().collect();
            assert!(
                r.no_fix.keys().all(
                    |k| ["NoSunDisc", "LowDolp", "SunBelowHorizon", "Dark", "OutsideSnellWindow", "Inconsistent"].contains(&k.as_str())
                ),
                "{sky}: {reasons:?}"
            );
        }
        let sea = SeaRun { scored: 4, warmup_s: 1.0, ..SeaRun::new(0.0, SkyKind::Clear) };
        let r = run(&McConfig { draws: 12, seed: 5, sea: Some(sea), min_elevation_deg: 40.0, ..McConfig::default() });
        assert_eq!(r.fixes, 12, "{r:?}");
    }

    /// A cloud over the sun (the partly cloudy sky's blocked state: 3 % of the direct beam, a
    /// bright diffuse sky) under a 5 m/s sea: no heading, with the reason, at every attempt.
    #[test]
    fn blocked_sun_gives_no_fix() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let units = sim::default_units(8);
        let ccfg = compass_config(&Water::clear(), 0.0);
        let sea = Sea::new(SeaConfig::wind(5.0), 3);
        let blocked = SkyKind::PartlyCloudy.light(0.0, 0);
        let blocked = subnav_base::sky::SkyLight { direct: 0.03, ..blocked };
        for k in 0..20 {
            let (t, obs, p) = draw_sun(&mut rng, 20.0, 60.0);
            let r_nb = Rotation3::from_euler_angles(0.05, -0.03, 0.3 * k as f64);
            let field = SeaField::new(sun_ned(&p), blocked, &sea, Water::clear(), 10.0, (0.0, 0.0), k as f64);
            let cal: Vec<_> = units.iter().map(|u| u.channels).collect();
            let counts = sim::counts(&field, &r_nb, &units, &cal, &SensorErrors::default(), &mut rng);
            let accel = sim::accel(&r_nb, 0.0, &mut rng);
            let input = CompassInput { counts: &counts, accel_body_mps2: accel, unix_us: Some(t), observer: Some(obs), delta_t_s: 69.0 };
            match compass::solve(&units, &input, &ccfg) {
                Ok(f) => panic!("a heading under a cloud: {f:?}"),
                Err((r, _)) => {
                    assert!(matches!(r, compass::NoFix::NoSunDisc | compass::NoFix::LowDolp | compass::NoFix::Inconsistent), "{r:?}")
                }
            }
        }
    }
}
