//! Polarization compass: photodiode counts -> Stokes -> robust sun vector -> heading.
//!
//! Pipeline (spec A2), each step its own module:
//! 1. [`unit`]: per-unit calibration, counts -> S0, S1, S2 -> AoP, DoLP, body-frame e-vector and
//!    its 1-sigma (the quality measure); saturated, dark or weakly polarized units are dropped.
//! 2. [`sun_vector`]: smallest-eigenvector weighted least squares with Huber-IRLS, DoLP weights,
//!    sign from the sun being above; tangent-plane covariance.
//! 3. [`measure_sun`]: tilt from the accelerometer's gravity vector -> sun azimuth relative to the
//!    body x axis and refracted elevation; [`water`]: inverse Snell -> in-air elevation.
//! 4. [`heading`]: heading = ephemeris sun azimuth - relative azimuth, with a propagated 1-sigma.
//!
//! Anything that would give a wrong heading instead gives a [`NoFix`] reason, whose
//! [`NoFix::code`] goes into [`subnav_wire::messages::CompassReport::no_fix_reason`] (0 = fix).
//! Frames: body FRD, navigation NED (see [`subnav_wire::messages`]); heading and azimuths are
//! from north, clockwise.

pub mod departure;
mod departure_table;
pub mod sun_vector;
pub mod unit;
pub mod water;
pub mod wave;

use nalgebra::Vector3;

use crate::ephemeris::{self, Atmosphere, Observer};
pub use sun_vector::{SolverConfig, SunVector};
pub use unit::{CHANNELS, ChannelCal, NoiseModel, UnitModel, UnitObservation, UnitReject};
pub use wave::{WaveSigma, WaveSigmaConfig};

/// Most units one solve accepts (fixed-size buffers).
pub const MAX_UNITS: usize = 16;
/// Standard gravity (m/s^2).
pub const G0_MPS2: f32 = 9.806_65;

/// Why there is no heading. `code()` is the telemetry value (0 is reserved for "fix").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum NoFix {
    /// Inputs inconsistent with the configuration (unit count mismatch, more than [`MAX_UNITS`]).
    BadInput = 1,
    /// Non-finite measurement.
    NonFinite = 2,
    /// Too little light in most units (night, too deep, blocked).
    Dark = 3,
    /// Saturated channels in most units.
    Saturated = 4,
    /// Degree of linear polarization too low in most units (turbid or deep water, overcast).
    LowDolp = 5,
    /// Fewer good units than required (mixed reasons, or outliers removed).
    TooFewUnits = 6,
    /// The e-vectors do not determine the sun direction (e.g. all nearly parallel).
    Degenerate = 7,
    /// The eigen solver did not converge.
    NoConvergence = 8,
    /// Residuals far beyond the noise model, or measured and ephemeris elevations disagree.
    Inconsistent = 9,
    /// The measured refracted sun lies outside the Snell window.
    OutsideSnellWindow = 10,
    /// No usable gravity vector (not about 1 g, or the body x axis is vertical).
    TiltInvalid = 11,
    /// Sun too close to the zenith: its azimuth is undefined.
    SunNearZenith = 12,
    /// The ephemeris puts the sun below the minimum elevation (night, twilight).
    SunBelowHorizon = 13,
    /// UTC or position unknown: the sun vector is measured but no heading can be formed.
    NoTime = 14,
    /// The ephemeris refused the time or position.
    Ephemeris = 15,
    /// The pattern is symmetric about the vertical while the ephemeris sun is well below the
    /// zenith: no sun disc (overcast, a cloud over the sun).
    NoSunDisc = 16,
}

impl core::fmt::Display for NoFix {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "no heading: {}", self.describe())
    }
}

impl core::error::Error for NoFix {}

impl NoFix {
    pub fn code(self) -> u8 {
        self as u8
    }
    pub fn from_code(c: u8) -> Option<Self> {
        use NoFix::*;
        Some(match c {
            1 => BadInput,
            2 => NonFinite,
            3 => Dark,
            4 => Saturated,
            5 => LowDolp,
            6 => TooFewUnits,
            7 => Degenerate,
            8 => NoConvergence,
            9 => Inconsistent,
            10 => OutsideSnellWindow,
            11 => TiltInvalid,
            12 => SunNearZenith,
            13 => SunBelowHorizon,
            14 => NoTime,
            15 => Ephemeris,
            16 => NoSunDisc,
            _ => return None,
        })
    }
    pub fn describe(self) -> &'static str {
        use NoFix::*;
        match self {
            BadInput => "inputs do not match the configuration (unit count)",
            NonFinite => "NaN or infinite measurement",
            Dark => "too little light in most units",
            Saturated => "saturated channels in most units",
            LowDolp => "degree of linear polarization too low in most units",
            TooFewUnits => "fewer good polarization units than required",
            Degenerate => "the e-vectors do not determine the sun direction",
            NoConvergence => "the eigen solver did not converge",
            Inconsistent => "residuals or sun elevation inconsistent with the noise model and ephemeris",
            OutsideSnellWindow => "the measured refracted sun lies outside the Snell window",
            TiltInvalid => "no usable gravity vector (not about 1 g, or body x axis vertical)",
            SunNearZenith => "sun too close to the zenith: its azimuth is undefined",
            SunBelowHorizon => "sun below the minimum elevation",
            NoTime => "UTC time or position unknown (sun vector measured)",
            Ephemeris => "the ephemeris refused the time or position",
            NoSunDisc => "no sun disc: the pattern is symmetric about the vertical (overcast or a cloud over the sun)",
        }
    }
}

/// Compass settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompassConfig {
    pub solver: SolverConfig,
    /// Minimum S0 (intensity units after gain) for a unit to be used.
    pub min_s0: f32,
    /// Minimum DoLP for a unit to be used.
    pub min_dolp: f32,
    /// Refractive index of the water ([`water::seawater_index`]).
    pub n_water: f32,
    /// Correct the e-vectors for the Fresnel polarization of the refracted sunbeam.
    pub fresnel_correction: bool,
    /// Tolerance beyond the Snell window's edge (rad).
    pub snell_tolerance_rad: f32,
    /// Refracted sun elevation above which the azimuth is not trusted (rad).
    pub max_water_elevation_rad: f32,
    /// Ephemeris (apparent, in air) sun elevation limits for a heading (rad).
    pub min_sun_elevation_rad: f32,
    pub max_sun_elevation_rad: f32,
    /// Largest allowed |measured in-air elevation - ephemeris elevation| (rad). Skylight pulls
    /// the measured sun toward the zenith (it adds e-vectors perpendicular to the vertical
    /// planes): by 3 deg with the sun at 50 deg and 10 deg at 25 deg under a clear sky in the
    /// simulator's sea model, so a low sun under a clear sky gives `Inconsistent`. A 14 deg
    /// bound was tried: the 4-unit head's dive compass RMSE went from about 0.3 to 3-5 deg
    /// (wrong fixes the check had been refusing), so it stays at 6 deg.
    pub max_elevation_mismatch_rad: f32,
    /// The elevation check's bound is at least this many of the measured in-air elevation's
    /// reported 1-sigma (0: the fixed bound alone).
    pub elevation_mismatch_sigmas: f32,
    /// Accepted |accel| / g0 range.
    pub gravity_tolerance: f32,
    /// 1-sigma tilt (roll/pitch) error of the gravity vector (rad).
    pub tilt_sigma_rad: f32,
    /// With time and position known, re-fit the sun's azimuth alone on the cone of the
    /// ephemeris's refracted elevation ([`sun_vector::solve_azimuth`]): the real field pulls
    /// the measured elevation, and the free elevation leaks that pull into the azimuth.
    pub azimuth_at_known_elevation: bool,
    /// Largest reported heading 1-sigma for a fix (rad); beyond it the field cannot give a
    /// heading (low DoLP, turbid water with a low sun) and the reason is `LowDolp`.
    pub max_sigma_heading_rad: f32,
    /// With `azimuth_at_known_elevation`: the real field's expected AoP departure from single
    /// scattering, subtracted from each unit before the azimuth fit ([`departure`]).
    pub aop_departure: Option<&'static departure::AopDeparture>,
}

impl Default for CompassConfig {
    fn default() -> Self {
        CompassConfig {
            solver: SolverConfig::default(),
            min_s0: 1e-3,
            min_dolp: 0.02,
            n_water: water::default_index(),
            fresnel_correction: true,
            snell_tolerance_rad: 0.035,
            max_water_elevation_rad: 85.0 * DEG,
            min_sun_elevation_rad: 3.0 * DEG,
            max_sun_elevation_rad: 87.0 * DEG,
            max_elevation_mismatch_rad: 6.0 * DEG,
            elevation_mismatch_sigmas: 0.0,
            gravity_tolerance: 0.2,
            tilt_sigma_rad: 0.0,
            azimuth_at_known_elevation: false,
            max_sigma_heading_rad: f32::INFINITY,
            aop_departure: None,
        }
    }
}

const DEG: f32 = core::f32::consts::PI / 180.0;

/// The sun as measured by the compass (no time or position needed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunMeasurement {
    pub sun: SunVector,
    /// Sun azimuth relative to the body x axis projected on the horizontal plane, clockwise (rad).
    pub rel_azimuth_rad: f32,
    pub sigma_rel_azimuth_rad: f32,
    /// Refracted (in-water) elevation and the in-air elevation from inverse Snell (rad).
    pub water_elevation_rad: f32,
    pub air_elevation_rad: f32,
    /// 1-sigma of the in-water and in-air elevations (rad).
    pub sigma_water_elevation_rad: f32,
    pub sigma_air_elevation_rad: f32,
}

/// A heading fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingFix {
    /// Heading of the body x axis, from north, clockwise, [0, 2 pi).
    pub heading_rad: f32,
    pub sigma_heading_rad: f32,
    pub sun: SunMeasurement,
    /// Ephemeris sun azimuth and apparent elevation (rad).
    pub ephemeris_azimuth_rad: f32,
    pub ephemeris_elevation_rad: f32,
}

/// Unit vector toward the sky from the accelerometer's specific force (body FRD; at rest the
/// accelerometer reads -g, i.e. it points up).
pub fn up_from_accel(accel_body_mps2: [f32; 3], cfg: &CompassConfig) -> Result<Vector3<f32>, NoFix> {
    let f = Vector3::new(accel_body_mps2[0], accel_body_mps2[1], accel_body_mps2[2]);
    if !f.iter().all(|x| x.is_finite()) {
        return Err(NoFix::NonFinite);
    }
    let n = f.norm();
    if !((n / G0_MPS2 - 1.0).abs() <= cfg.gravity_tolerance) {
        return Err(NoFix::TiltInvalid);
    }
    Ok(f / n)
}

/// Calibrates all units and keeps the good ones.
pub fn observe_units(
    units: &[UnitModel],
    counts: &[[i16; CHANNELS]],
    cfg: &CompassConfig,
) -> Result<heapless::Vec<UnitObservation, MAX_UNITS>, NoFix> {
    if units.len() != counts.len() || units.len() > MAX_UNITS {
        return Err(NoFix::BadInput);
    }
    observe_pairs(units.iter().zip(counts), cfg)
}

/// As [`observe_units`], the units given as (model, counts) pairs; more than [`MAX_UNITS`] is
/// `BadInput`.
pub fn observe_pairs<'a, U: core::borrow::Borrow<UnitModel>>(
    pairs: impl IntoIterator<Item = (U, &'a [i16; CHANNELS])>,
    cfg: &CompassConfig,
) -> Result<heapless::Vec<UnitObservation, MAX_UNITS>, NoFix> {
    let mut good = heapless::Vec::new();
    let mut rejects = [0u8; 4]; // dark, saturated, low dolp, non-finite
    for (i, (u, c)) in pairs.into_iter().enumerate() {
        if i >= MAX_UNITS {
            return Err(NoFix::BadInput);
        }
        match u.borrow().observe(c, cfg.min_s0, cfg.min_dolp) {
            Ok(o) => {
                // Capacity equals MAX_UNITS and at most MAX_UNITS pairs reach here.
                let _ = good.push(o);
            }
            Err(r) => {
                let i = match r {
                    UnitReject::Dark => 0,
                    UnitReject::Saturated => 1,
                    UnitReject::LowDolp => 2,
                    UnitReject::NonFinite => 3,
                };
                if let Some(x) = rejects.get_mut(i) {
                    *x += 1;
                }
            }
        }
    }
    if good.len() < cfg.solver.min_units.max(2) as usize {
        // Report the most frequent reason (ties: dark, saturated, low DoLP, non-finite).
        let mut best = 0;
        for (i, &r) in rejects.iter().enumerate() {
            if r > rejects.get(best).copied().unwrap_or(0) {
                best = i;
            }
        }
        return Err(match (best, rejects.get(best).copied().unwrap_or(0)) {
            (_, 0) => NoFix::TooFewUnits,
            (0, _) => NoFix::Dark,
            (1, _) => NoFix::Saturated,
            (2, _) => NoFix::LowDolp,
            _ => NoFix::NonFinite,
        });
    }
    Ok(good)
}

/// Measures the sun relative to the body: units -> sun vector -> relative azimuth and elevations.
pub fn measure_sun(
    units: &[UnitModel],
    counts: &[[i16; CHANNELS]],
    accel_body_mps2: [f32; 3],
    cfg: &CompassConfig,
) -> Result<SunMeasurement, NoFix> {
    let up = up_from_accel(accel_body_mps2, cfg)?;
    let obs = observe_units(units, counts, cfg)?;
    measure_sun_from(&obs, &up, cfg, None)
}

/// [`measure_sun`] from the kept units and the vertical.
fn measure_sun_from(
    obs: &[UnitObservation],
    up: &Vector3<f32>,
    cfg: &CompassConfig,
    sun_zenith_air_rad: Option<f32>,
) -> Result<SunMeasurement, NoFix> {
    let up = *up;
    let departure = cfg.aop_departure.zip(sun_zenith_air_rad);
    let sun = sun_vector::solve_with_departure(obs, &up, cfg.fresnel_correction.then_some(cfg.n_water), &cfg.solver, departure)?;
    // Level (heading) frame: x = body x projected on the horizontal, z = down.
    let down = -up;
    let xb = Vector3::new(1.0, 0.0, 0.0);
    let fwd = xb - down * xb.dot(&down);
    let fn_ = fwd.norm();
    if !(fn_ > 0.05) {
        return Err(NoFix::TiltInvalid);
    }
    let fwd = fwd / fn_;
    let right = down.cross(&fwd);
    let s = sun.s_body;
    let (sx, sy, sz) = (s.dot(&fwd), s.dot(&right), s.dot(&down));
    let horiz = libm::sqrtf(sx * sx + sy * sy);
    let water_el = libm::atan2f(-sz, horiz);
    if water_el > cfg.max_water_elevation_rad {
        return Err(NoFix::SunNearZenith);
    }
    let rel_az = libm::atan2f(sy, sx);
    let water_zenith = core::f32::consts::FRAC_PI_2 - water_el;
    let air_zenith = water::air_zenith_rad(water_zenith, cfg.n_water, cfg.snell_tolerance_rad).ok_or(NoFix::OutsideSnellWindow)?;
    let cos_el = crate::ephemeris::phase::sincos_rad(water_el).1.max(1e-3);
    let tan_el = libm::sqrtf((1.0 - cos_el * cos_el).max(0.0)) / cos_el;
    let sigma_az_sensor = libm::sqrtf(sun.cov_tangent[(0, 0)]) / cos_el;
    let sigma_tilt = cfg.tilt_sigma_rad * tan_el;
    let sigma_rel_az = libm::sqrtf(sigma_az_sensor * sigma_az_sensor + sigma_tilt * sigma_tilt);
    let sigma_water_el = libm::sqrtf(sun.cov_tangent[(1, 1)] + cfg.tilt_sigma_rad * cfg.tilt_sigma_rad);
    // d(air zenith)/d(water zenith) = n cos(z_w) / cos(z_a).
    let cos_za = crate::ephemeris::phase::sincos_rad(air_zenith).1.max(1e-2);
    let gain = cfg.n_water * crate::ephemeris::phase::sincos_rad(water_zenith).1 / cos_za;
    Ok(SunMeasurement {
        sun,
        rel_azimuth_rad: rel_az,
        sigma_rel_azimuth_rad: sigma_rel_az,
        water_elevation_rad: water_el,
        air_elevation_rad: core::f32::consts::FRAC_PI_2 - air_zenith,
        sigma_water_elevation_rad: sigma_water_el,
        sigma_air_elevation_rad: sigma_water_el * gain,
    })
}

/// Heading from a sun measurement, UTC (POSIX µs), position and TT - UT1.
pub fn heading(m: &SunMeasurement, unix_us: i64, obs: &Observer, delta_t_s: f32, cfg: &CompassConfig) -> Result<HeadingFix, NoFix> {
    let eph = ephemeris::sun_position(unix_us, obs, Some(&Atmosphere::default()), delta_t_s).map_err(|_| NoFix::Ephemeris)?;
    let el = eph.apparent_elevation_rad();
    if el < cfg.min_sun_elevation_rad {
        return Err(NoFix::SunBelowHorizon);
    }
    if el > cfg.max_sun_elevation_rad {
        return Err(NoFix::SunNearZenith);
    }
    // The bound grows with the measured elevation's own 1-sigma: where the solver reports
    // that the field does not fix the elevation (low DoLP, the model departure), a pulled
    // elevation is what it said, not a sign of a wrong sun.
    let bound = cfg.max_elevation_mismatch_rad.max(cfg.elevation_mismatch_sigmas * m.sigma_air_elevation_rad);
    if !((m.air_elevation_rad - el).abs() <= bound) {
        return Err(NoFix::Inconsistent);
    }
    let mut h = eph.azimuth_rad - m.rel_azimuth_rad;
    while h < 0.0 {
        h += core::f32::consts::TAU;
    }
    while h >= core::f32::consts::TAU {
        h -= core::f32::consts::TAU;
    }
    // The ephemeris error (< 0.003 deg, measured) is negligible next to the sensor's.
    Ok(HeadingFix {
        heading_rad: h,
        sigma_heading_rad: m.sigma_rel_azimuth_rad,
        sun: *m,
        ephemeris_azimuth_rad: eph.azimuth_rad,
        ephemeris_elevation_rad: el,
    })
}

/// Inputs of one compass solve.
#[derive(Debug, Clone, Copy)]
pub struct CompassInput<'a> {
    pub counts: &'a [[i16; CHANNELS]],
    /// Accelerometer specific force (body FRD, m/s^2), averaged.
    pub accel_body_mps2: [f32; 3],
    /// UTC (POSIX µs) and position, when known.
    pub unix_us: Option<i64>,
    pub observer: Option<Observer>,
    pub delta_t_s: f32,
}

/// The whole solve. On `Err`, the sun measurement is returned when it was made (e.g. `NoTime`).
pub fn solve(units: &[UnitModel], input: &CompassInput<'_>, cfg: &CompassConfig) -> Result<HeadingFix, (NoFix, Option<SunMeasurement>)> {
    solve_observed(|| observe_units(units, input.counts, cfg), input, cfg)
}

/// As [`solve`], the units given as (model, counts) pairs and `input.counts` unused: the
/// firmware passes the units that were read, each model built as it is observed (no array of
/// models, about 150 B each, on its stack).
pub fn solve_pairs<'a, U: core::borrow::Borrow<UnitModel>>(
    pairs: impl IntoIterator<Item = (U, &'a [i16; CHANNELS])>,
    input: &CompassInput<'_>,
    cfg: &CompassConfig,
) -> Result<HeadingFix, (NoFix, Option<SunMeasurement>)> {
    solve_observed(|| observe_pairs(pairs, cfg), input, cfg)
}

fn solve_observed(
    observe: impl FnOnce() -> Result<heapless::Vec<UnitObservation, MAX_UNITS>, NoFix>,
    input: &CompassInput<'_>,
    cfg: &CompassConfig,
) -> Result<HeadingFix, (NoFix, Option<SunMeasurement>)> {
    let up = up_from_accel(input.accel_body_mps2, cfg).map_err(|e| (e, None))?;
    let obs = observe().map_err(|e| (e, None))?;
    // With a departure table and the time and place, the sun's zenith from the ephemeris (the
    // table is indexed by it); without them the departure is left out of the sun vector.
    let sun_zenith_air = match (cfg.aop_departure, input.unix_us, input.observer) {
        (Some(_), Some(t), Some(o)) => ephemeris::sun_position(t, &o, Some(&Atmosphere::default()), input.delta_t_s)
            .ok()
            .map(|p| (core::f32::consts::FRAC_PI_2 - p.apparent_elevation_rad()).max(0.0)),
        _ => None,
    };
    let m = measure_sun_from(&obs, &up, cfg, sun_zenith_air).map_err(|e| match (e, input.unix_us, input.observer) {
        (NoFix::SunNearZenith, Some(t), Some(o)) if sun_disc_missing(t, &o, input.delta_t_s, cfg) => (NoFix::NoSunDisc, None),
        _ => (e, None),
    })?;
    let (Some(t), Some(o)) = (input.unix_us, input.observer) else {
        return Err((NoFix::NoTime, Some(m)));
    };
    let mut fix = heading(&m, t, &o, input.delta_t_s, cfg).map_err(|e| (e, Some(m)))?;
    if cfg.azimuth_at_known_elevation {
        let air_zenith = core::f32::consts::FRAC_PI_2 - fix.ephemeris_elevation_rad;
        let water_el = core::f32::consts::FRAC_PI_2 - water::water_zenith_rad(air_zenith.max(0.0), cfg.n_water);
        let departure = cfg.aop_departure.map(|t| (t, air_zenith.max(0.0)));
        let fit = sun_vector::solve_azimuth(
            &obs,
            &up,
            cfg.fresnel_correction.then_some(cfg.n_water),
            &cfg.solver,
            water_el,
            &m.sun.s_body,
            departure,
        )
        .map_err(|e| (e, Some(m)))?;
        let (se, ce) = crate::ephemeris::phase::sincos_rad(water_el);
        let sigma_tilt = cfg.tilt_sigma_rad * se / ce.max(1e-3);
        let sigma = libm::sqrtf(fit.sigma_rel_azimuth_rad * fit.sigma_rel_azimuth_rad + sigma_tilt * sigma_tilt);
        let mut h = fix.ephemeris_azimuth_rad - fit.rel_azimuth_rad;
        while h < 0.0 {
            h += core::f32::consts::TAU;
        }
        while h >= core::f32::consts::TAU {
            h -= core::f32::consts::TAU;
        }
        fix.heading_rad = h;
        fix.sigma_heading_rad = sigma;
        fix.sun.rel_azimuth_rad = fit.rel_azimuth_rad;
        fix.sun.sigma_rel_azimuth_rad = sigma;
    }
    if !(fix.sigma_heading_rad <= cfg.max_sigma_heading_rad) {
        return Err((NoFix::LowDolp, Some(fix.sun)));
    }
    Ok(fix)
}

/// A measured sun at the zenith while the ephemeris puts the refracted sun at least 10 deg
/// below the compass's zenith limit: the light comes from the whole sky, not from a sun disc.
fn sun_disc_missing(unix_us: i64, obs: &Observer, delta_t_s: f32, cfg: &CompassConfig) -> bool {
    let Ok(eph) = ephemeris::sun_position(unix_us, obs, Some(&Atmosphere::default()), delta_t_s) else { return false };
    let air_zenith = core::f32::consts::FRAC_PI_2 - eph.apparent_elevation_rad();
    let water_el = core::f32::consts::FRAC_PI_2 - water::water_zenith_rad(air_zenith.max(0.0), cfg.n_water);
    water_el < cfg.max_water_elevation_rad - 10.0 * DEG
}

/// The telemetry message for a solve result.
pub fn report(t_us: u64, result: &Result<HeadingFix, (NoFix, Option<SunMeasurement>)>) -> subnav_wire::messages::CompassReport {
    use subnav_wire::messages::CompassReport;
    match result {
        Ok(f) => CompassReport {
            t_us,
            heading_rad: Some(f.heading_rad),
            sigma_heading_rad: f.sigma_heading_rad,
            sun_rel_azimuth_rad: f.sun.rel_azimuth_rad,
            sun_elevation_rad: f.sun.water_elevation_rad,
            no_fix_reason: 0,
            units_used: f.sun.sun.units_used,
        },
        Err((r, m)) => CompassReport {
            t_us,
            heading_rad: None,
            sigma_heading_rad: f32::INFINITY,
            sun_rel_azimuth_rad: m.map_or(f32::NAN, |m| m.rel_azimuth_rad),
            sun_elevation_rad: m.map_or(f32::NAN, |m| m.water_elevation_rad),
            no_fix_reason: r.code(),
            units_used: m.map_or(0, |m| m.sun.units_used),
        },
    }
}

#[cfg(test)]
mod tests;
