//! Solar ephemeris for the sensor head: apparent solar zenith and azimuth from UTC, latitude,
//! longitude and height, on a single-precision FPU.
//!
//! Method: NREL's Solar Position Algorithm (SPA, Reda & Andreas 2004) with its periodic series
//! truncated to the terms that matter over 1950-2150 ([`terms`]), evaluated in f32 except for the
//! angles that grow linearly with time (mean longitude, the arguments of every periodic term,
//! sidereal time), which are exact 64-bit fixed-point phases ([`phase`]). This is the "split
//! epoch" the issue asks for, done in integer arithmetic: no f64 operation runs on the target
//! (all f64 in this module is `const` evaluation at compile time).
//!
//! Why our own code: the maintained crates (`spa`, `sun`) compute in f64 (software emulation on
//! the Cortex-M4F) and use the full tables; we need an f32/integer formulation.
//!
//! Accuracy (measured, see `docs/PERFORMANCE.md`): against pvlib 0.16.1 `spa_python` (the full
//! SPA in f64) on 10,000 random instants 2020-2100 at latitudes within +-70 deg, in
//! `tests/tests/peer_pvlib.rs`.
//!
//! Conventions: azimuth from true north, clockwise (eastward), in [0, 2 pi); zenith from the local
//! vertical. Time is UTC as POSIX microseconds (no leap seconds, as `t_us + utc_offset_us` in
//! [`subnav_wire::messages`]). `delta_t_s` = TT - UT1 in seconds (the sun's position is nearly
//! insensitive to it: 1 s moves the sun by 0.04 arcsec); [`delta_t_estimate_s`] gives a default.

pub mod phase;
mod terms;

use phase::{Rate, SplitTime, from_rad, phase, sincos, sincos_rad, turns_q64};

/// POSIX microseconds of J2000.0 (JD 2451545.0 = 2000-01-01T12:00:00).
pub const J2000_UNIX_US: i64 = 946_728_000_000_000;
/// Supported range: +-150 years around J2000 (the truncation was chosen for +-100 years).
const MAX_ABS_DAYS: i64 = 55_000;

const DEG: f32 = core::f32::consts::PI / 180.0;
const ARCSEC: f32 = DEG / 3600.0;

/// Observer position (WGS84-ish geodetic; SPA uses a spherical-Earth parallax model).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observer {
    pub lat_rad: f32,
    /// East positive.
    pub lon_rad: f32,
    /// Height above sea level (m); only affects the parallax (< 0.0025 deg).
    pub height_m: f32,
}

/// Atmosphere for the refraction correction (SPA's Bennett-type formula).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Atmosphere {
    pub pressure_hpa: f32,
    pub temp_c: f32,
}

impl Default for Atmosphere {
    fn default() -> Self {
        Atmosphere { pressure_hpa: 1013.25, temp_c: 12.0 }
    }
}

/// Topocentric sun position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunPosition {
    /// Geometric (no refraction) topocentric zenith angle.
    pub zenith_rad: f32,
    /// Zenith angle after the refraction correction (equal to `zenith_rad` without atmosphere).
    pub apparent_zenith_rad: f32,
    /// Azimuth from north, clockwise, [0, 2 pi).
    pub azimuth_rad: f32,
    /// Geocentric declination and right ascension.
    pub declination_rad: f32,
    pub right_ascension_rad: f32,
    /// Earth-sun distance (au).
    pub distance_au: f32,
}

impl SunPosition {
    /// Apparent elevation (rad).
    pub fn apparent_elevation_rad(&self) -> f32 {
        core::f32::consts::FRAC_PI_2 - self.apparent_zenith_rad
    }
    /// Unit vector toward the sun in NED (apparent, i.e. refracted).
    pub fn ned_unit(&self) -> [f32; 3] {
        let (se, ce) = sincos_rad(self.apparent_elevation_rad());
        let (sa, ca) = sincos_rad(self.azimuth_rad);
        [ce * ca, ce * sa, -se]
    }
}

/// Why the ephemeris refused an input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EphemerisError {
    /// A NaN or infinite input.
    NonFinite,
    /// Latitude outside [-90, 90] deg.
    LatitudeOutOfRange,
    /// Time more than 150 years from J2000.
    TimeOutOfRange,
}

impl core::fmt::Display for EphemerisError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            EphemerisError::NonFinite => "ephemeris input (position, height, delta T or atmosphere) is NaN or infinite",
            EphemerisError::LatitudeOutOfRange => "latitude outside [-90, 90] deg",
            EphemerisError::TimeOutOfRange => "time more than 150 years from J2000 (or |delta T| above 10,000 s)",
        })
    }
}

impl core::error::Error for EphemerisError {}

/// TT - UT1 estimate (s) for a POSIX time, from the Espenak & Meeus (NASA) polynomials for
/// 2005-2050 and 2050-2150 (also used, clamped, outside). A few seconds of error are harmless.
pub fn delta_t_estimate_s(unix_us: i64) -> f32 {
    // Years since 2000.0 (f32 is ample here).
    let y = 2000.0 + (unix_us - 946_684_800_000_000) as f32 / (365.2425 * 86_400.0e6);
    if y < 2050.0 {
        let t = y - 2000.0;
        62.92 + 0.32217 * t + 0.005589 * t * t
    } else {
        let u = (y - 1820.0) / 100.0;
        -20.0 + 32.0 * u * u - 0.5628 * (2150.0 - y)
    }
}

const L_MEAN_B: u64 = turns_q64(terms::L_POLY[0] * 1e-8 / core::f64::consts::TAU);
const L_MEAN_RATE: Rate = Rate::from_turns_per_day(terms::L_POLY[1] * 1e-8 / core::f64::consts::TAU / 365_250.0);
/// Greenwich mean sidereal time at J2000 and its rate (SPA eq. 28).
const GMST_B: u64 = turns_q64(280.460_618_37 / 360.0);
const GMST_RATE: Rate = Rate::from_turns_per_day(360.985_647_366_29 / 360.0);
const HALF_TURN: u64 = 1 << 63;
/// Secular polynomials as f32 (compile time); L's orders 0 and 1 are the mean-longitude phase.
const L_POLY_REST: [f32; 6] =
    [0.0, 0.0, terms::L_POLY[2] as f32, terms::L_POLY[3] as f32, terms::L_POLY[4] as f32, terms::L_POLY[5] as f32];
const B_POLY_F32: [f32; 2] = [terms::B_POLY[0] as f32, terms::B_POLY[1] as f32];
const R_POLY_F32: [f32; 5] =
    [terms::R_POLY[0] as f32, terms::R_POLY[1] as f32, terms::R_POLY[2] as f32, terms::R_POLY[3] as f32, terms::R_POLY[4] as f32];

/// Sums `amp * cos(phase)` per power of tau, then combines with the powers of tau.
fn vsop_sum<const N: usize>(terms: &[terms::VsopTerm; N], poly: &[f32], t: SplitTime, tau: f32) -> f32 {
    let mut by_k = [0.0f32; 6];
    for term in terms {
        let (_, c) = sincos(phase(term.b, term.rate, t));
        if let Some(s) = by_k.get_mut(term.k as usize) {
            *s += term.amp * c;
        }
    }
    // Secular polynomial terms of order >= 2 (order 0/1 of L are handled as a phase).
    for (k, &p) in poly.iter().enumerate() {
        if let Some(s) = by_k.get_mut(k) {
            *s += p;
        }
    }
    let mut acc = 0.0;
    for s in by_k.iter().rev() {
        acc = acc * tau + s;
    }
    acc
}

/// Sun position for a POSIX time (µs), an observer, an optional atmosphere (refraction) and
/// TT - UT1 (s).
pub fn sun_position(unix_us: i64, obs: &Observer, atmosphere: Option<&Atmosphere>, delta_t_s: f32) -> Result<SunPosition, EphemerisError> {
    if !(obs.lat_rad.is_finite() && obs.lon_rad.is_finite() && obs.height_m.is_finite() && delta_t_s.is_finite()) {
        return Err(EphemerisError::NonFinite);
    }
    if let Some(a) = atmosphere {
        if !(a.pressure_hpa.is_finite() && a.temp_c.is_finite()) {
            return Err(EphemerisError::NonFinite);
        }
    }
    if obs.lat_rad.abs() > core::f32::consts::FRAC_PI_2 {
        return Err(EphemerisError::LatitudeOutOfRange);
    }
    if delta_t_s.abs() > 10_000.0 {
        return Err(EphemerisError::TimeOutOfRange);
    }
    let ut_us = unix_us.checked_sub(J2000_UNIX_US).ok_or(EphemerisError::TimeOutOfRange)?;
    let ut = SplitTime::from_us(ut_us);
    if ut.days.abs() > MAX_ABS_DAYS {
        return Err(EphemerisError::TimeOutOfRange);
    }
    // |delta_t| <= 1e4 s, so this cannot overflow after the range check above.
    let tt = SplitTime::from_us(ut_us + (delta_t_s * 1.0e6) as i64);
    let tt_days = tt.days_f32();
    let tau = tt_days / 365_250.0; // Julian ephemeris millennia
    let jce = tt_days / 36_525.0; // Julian ephemeris centuries
    let jc = ut.days_f32() / 36_525.0;

    // Heliocentric longitude (phase + small f32 part), latitude and radius (SPA 3.2).
    let l_mean = phase(L_MEAN_B, L_MEAN_RATE, tt);
    let l_small_rad = vsop_sum(&terms::L_TERMS, &L_POLY_REST, tt, tau) * 1e-8;
    let b_rad = vsop_sum(&terms::B_TERMS, &B_POLY_F32, tt, tau) * 1e-8;
    let r_au = vsop_sum(&terms::R_TERMS, &R_POLY_F32, tt, tau) * 1e-8;

    // Nutation (SPA 3.4).
    let mut dpsi = 0.0f32;
    let mut deps = 0.0f32;
    for n in &terms::NUTATION_TERMS {
        let (s, c) = sincos(phase(n.arg0, n.rate, tt));
        dpsi += (n.a + n.b * jce) * s;
        deps += (n.c + n.d * jce) * c;
    }
    let dpsi_rad = dpsi * (1e-4 * ARCSEC);
    let deps_rad = deps * (1e-4 * ARCSEC);

    // True obliquity (SPA 3.5), U = JME / 10; terms beyond U^3 are < 1e-6 arcsec here.
    let u = tau / 10.0;
    let eps0_arcsec = 84_381.448 + u * (-4_680.93 + u * (-1.55 + u * 1_999.25));
    let eps_rad = eps0_arcsec * ARCSEC + deps_rad;

    // Apparent geocentric longitude: theta = L + 180 deg, plus nutation and aberration.
    let aberration_rad = -20.4898 * ARCSEC / r_au;
    let lambda = from_rad(l_small_rad + dpsi_rad + aberration_rad).wrapping_add(l_mean).wrapping_add(HALF_TURN);
    let beta_rad = -b_rad;

    // Geocentric right ascension and declination via the equatorial unit vector.
    let (sl, cl) = sincos(lambda);
    let (sb, cb) = sincos_rad(beta_rad);
    let (se, ce) = sincos_rad(eps_rad);
    let x = cb * cl;
    let y = cb * sl * ce - sb * se;
    let z = cb * sl * se + sb * ce;
    let rho = libm::sqrtf(x * x + y * y);
    let ra_rad = libm::atan2f(y, x);
    let norm = libm::sqrtf(rho * rho + z * z);
    let (sin_dec, cos_dec) = (z / norm, rho / norm);

    // Apparent sidereal time and local hour angle (SPA 3.8, 3.9).
    let nu = phase(GMST_B, GMST_RATE, ut).wrapping_add(from_rad(0.000_387_933 * DEG * jc * jc + dpsi_rad * ce));
    let h = nu.wrapping_add(from_rad(obs.lon_rad)).wrapping_sub(from_rad(ra_rad));

    // Topocentric parallax (SPA 3.10-3.12).
    let xi_rad = 8.794 * ARCSEC / r_au;
    let (sphi, cphi) = sincos_rad(obs.lat_rad);
    let u_geo = libm::atan2f(0.996_647_19 * sphi, cphi);
    let (su, cu) = sincos_rad(u_geo);
    let hr = obs.height_m / 6_378_140.0;
    let xt = cu + hr * cphi;
    let yt = 0.996_647_19 * su + hr * sphi;
    let (sh, ch) = sincos(h);
    let sxi = xi_rad; // sin(xi) = xi to 1e-13 relative
    let den = cos_dec - xt * sxi * ch;
    let dalpha_rad = libm::atan2f(-xt * sxi * sh, den);
    let cda = 1.0 - 0.5 * dalpha_rad * dalpha_rad;
    let num = (sin_dec - yt * sxi) * cda;
    let hyp = libm::sqrtf(num * num + den * den);
    let (sin_dec_t, cos_dec_t) = (num / hyp, den / hyp);
    let h_t = h.wrapping_sub(from_rad(dalpha_rad));
    let (sht, cht) = sincos(h_t);

    // Local horizontal components: up, north, east.
    let up = sphi * sin_dec_t + cphi * cos_dec_t * cht;
    let north = cphi * sin_dec_t - sphi * cos_dec_t * cht;
    let east = -cos_dec_t * sht;
    let horiz = libm::sqrtf(north * north + east * east);
    let e0_rad = libm::atan2f(up, horiz);
    let mut az = libm::atan2f(east, north);
    if az < 0.0 {
        az += core::f32::consts::TAU;
    }
    if az >= core::f32::consts::TAU {
        az -= core::f32::consts::TAU;
    }

    // Refraction (SPA 3.14), applied when the sun's upper limb may be visible.
    let mut de_rad = 0.0;
    if let Some(a) = atmosphere {
        let e0_deg = e0_rad / DEG;
        if e0_deg >= -(0.26667 + 0.5667) {
            let (s, c) = sincos_rad((e0_deg + 10.3 / (e0_deg + 5.11)) * DEG);
            let tan = s / c;
            de_rad = (a.pressure_hpa / 1010.0) * (283.0 / (273.0 + a.temp_c)) * 1.02 / (60.0 * tan) * DEG;
        }
    }
    let zenith_rad = core::f32::consts::FRAC_PI_2 - e0_rad;
    let apparent_zenith_rad = zenith_rad - de_rad;
    let result = SunPosition {
        zenith_rad,
        apparent_zenith_rad,
        azimuth_rad: az,
        declination_rad: libm::atan2f(z, rho),
        right_ascension_rad: if ra_rad < 0.0 { ra_rad + core::f32::consts::TAU } else { ra_rad },
        distance_au: r_au,
    };
    if result.apparent_zenith_rad.is_finite() && result.azimuth_rad.is_finite() { Ok(result) } else { Err(EphemerisError::NonFinite) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// POSIX µs for a UTC calendar date (days-from-civil, proleptic Gregorian).
    fn unix_us(y: i64, m: i64, d: i64, hh: i64, mm: i64, ss: i64) -> i64 {
        let y2 = if m <= 2 { y - 1 } else { y };
        let era = y2.div_euclid(400);
        let yoe = y2 - era * 400;
        let mp = (m + 9) % 12;
        let doy = (153 * mp + 2) / 5 + d - 1;
        let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
        let days = era * 146_097 + doe - 719_468;
        (days * 86_400 + hh * 3600 + mm * 60 + ss) * 1_000_000
    }

    /// The SPA paper's example (Reda & Andreas 2004, table A5.1): 2003-10-17 12:30:30 local time at
    /// UTC-7, lat 39.742476, lon -105.1786, 1830.14 m, 820 mbar, 11 C, delta T 67 s ->
    /// topocentric zenith 50.11162 deg, azimuth 194.34024 deg.
    #[test]
    fn spa_paper_test_vector() {
        let t = unix_us(2003, 10, 17, 19, 30, 30);
        let obs = Observer { lat_rad: 39.742476 * DEG, lon_rad: -105.1786 * DEG, height_m: 1830.14 };
        let atm = Atmosphere { pressure_hpa: 820.0, temp_c: 11.0 };
        let p = sun_position(t, &obs, Some(&atm), 67.0).unwrap();
        let zen = p.apparent_zenith_rad / DEG;
        let az = p.azimuth_rad / DEG;
        assert!((zen - 50.11162).abs() < 0.0005, "zenith {zen}");
        assert!((az - 194.34024).abs() < 0.0005, "azimuth {az}");
    }

    #[test]
    fn bad_inputs_are_errors() {
        let t = unix_us(2030, 1, 1, 0, 0, 0);
        let ok = Observer { lat_rad: 0.5, lon_rad: 0.1, height_m: 0.0 };
        assert!(sun_position(t, &ok, None, 70.0).is_ok());
        let nan = Observer { lat_rad: f32::NAN, ..ok };
        assert_eq!(sun_position(t, &nan, None, 70.0), Err(EphemerisError::NonFinite));
        let far = Observer { lat_rad: 1.6, ..ok };
        assert_eq!(sun_position(t, &far, None, 70.0), Err(EphemerisError::LatitudeOutOfRange));
        assert_eq!(sun_position(i64::MIN, &ok, None, 70.0), Err(EphemerisError::TimeOutOfRange));
        assert_eq!(sun_position(unix_us(2300, 1, 1, 0, 0, 0), &ok, None, 70.0), Err(EphemerisError::TimeOutOfRange));
        assert_eq!(sun_position(t, &ok, None, f32::INFINITY), Err(EphemerisError::NonFinite));
    }

    #[test]
    fn delta_t_is_plausible() {
        let d2025 = delta_t_estimate_s(unix_us(2025, 1, 1, 0, 0, 0));
        let d2100 = delta_t_estimate_s(unix_us(2100, 1, 1, 0, 0, 0));
        assert!((60.0..90.0).contains(&d2025), "{d2025}");
        assert!((150.0..250.0).contains(&d2100), "{d2100}");
    }

    /// Equinox/solstice sanity: declination near +23.44 deg at the June 2024 solstice.
    #[test]
    fn solstice_declination() {
        let t = unix_us(2024, 6, 20, 20, 51, 0);
        let obs = Observer { lat_rad: 0.0, lon_rad: 0.0, height_m: 0.0 };
        let p = sun_position(t, &obs, None, 69.0).unwrap();
        assert!((p.declination_rad / DEG - 23.4367).abs() < 0.002, "{}", p.declination_rad / DEG);
    }
}
