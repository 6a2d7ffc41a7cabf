//! One polarization unit: four photodiodes behind linear polarizers, read by an ADC, looking along
//! a known body-frame direction. Calibration (per channel gain, offset, polarizer angle, extinction
//! ratio) turns raw counts into Stokes S0, S1, S2 with a propagated covariance, then AoP, DoLP and
//! the e-vector in the body frame.
//!
//! Channel model: `counts_k = offset_k + gain_k * 0.5 * (S0 + eta_k (S1 cos 2 th_k + S2 sin 2 th_k))`
//! with `eta_k = (ER_k - 1) / (ER_k + 1)` (ER = extinction ratio T_max / T_min) and `th_k` the
//! polarizer angle measured from the unit's reference axis `a` toward `b = d x a` (`d` = viewing
//! direction). AoP uses the same convention, so the e-vector is `cos(AoP) a + sin(AoP) b`.
//! Noise model: per channel variance `read_sigma_counts^2 + signal_counts / electrons_per_count`
//! (read + ADC quantization, photon shot noise).

use nalgebra::{Matrix3, SMatrix, Vector3};

/// Channels per unit (0/45/90/135 deg nominal), as in [`subnav_wire::messages::PolarizationSample`].
pub const CHANNELS: usize = 4;

/// Calibration of one photodiode channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelCal {
    /// Counts per unit of intensity.
    pub gain: f32,
    /// Dark offset (counts).
    pub offset_counts: f32,
    /// Polarizer transmission axis angle (rad) from the unit's reference axis (nominal + error).
    pub polarizer_rad: f32,
    /// Extinction ratio T_max / T_min (> 1).
    pub extinction_ratio: f32,
}

/// Noise of the readout, for the quality measure and the weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Read + quantization noise per channel (counts, 1-sigma).
    pub read_sigma_counts: f32,
    /// Photo-electrons per count (shot noise); `f32::INFINITY` to ignore shot noise.
    pub electrons_per_count: f32,
    /// Counts at or above this are saturated.
    pub saturation_counts: i16,
}

impl Default for NoiseModel {
    fn default() -> Self {
        NoiseModel { read_sigma_counts: 3.0, electrons_per_count: 100.0, saturation_counts: 32_000 }
    }
}

/// Geometry, calibration and noise of one unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitModel {
    /// Viewing direction (unit vector, body FRD): the unit sees light coming from this direction.
    pub view_body: [f32; 3],
    /// Reference axis `a` of the polarizer angles (unit vector, body FRD, perpendicular to view).
    pub axis0_body: [f32; 3],
    pub channels: [ChannelCal; CHANNELS],
    pub noise: NoiseModel,
    /// Least-squares inverse of the channel model (3x4), precomputed by [`UnitModel::new`].
    pinv: SMatrix<f32, 3, CHANNELS>,
}

/// S0 below this many of its own 1-sigma (the readout noise through the channel model) is dark.
/// Noise alone passes it with probability ~3e-7 per unit.
pub const DARK_SIGMAS: f32 = 5.0;
/// Linear polarization `P = |(S1, S2)|` below this many of its per-component 1-sigma is not
/// measured (the DoLP test's noise floor): noise alone gives `P^2 / sigma^2` chi-square with 2
/// degrees of freedom, above `4^2` with probability `exp(-8)` = 3.4e-4 per unit. With the head's
/// exposure (S0 near 20,000 counts) it binds below a DoLP of 0.004, under `min_dolp`.
pub const POLARIZED_SIGMAS: f32 = 4.0;

/// Why a unit was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UnitReject {
    Saturated,
    Dark,
    LowDolp,
    NonFinite,
}

impl core::fmt::Display for UnitReject {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            UnitReject::Saturated => "polarization unit rejected: a channel is saturated",
            UnitReject::Dark => "polarization unit rejected: total intensity S0 below the minimum or within the readout noise (too dark)",
            UnitReject::LowDolp => {
                "polarization unit rejected: degree of linear polarization below the minimum or within the readout noise"
            }
            UnitReject::NonFinite => "polarization unit rejected: NaN or infinite Stokes value",
        })
    }
}

impl core::error::Error for UnitReject {}

/// One unit's measurement after calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnitObservation {
    pub s0: f32,
    pub s1: f32,
    pub s2: f32,
    pub aop_rad: f32,
    pub dolp: f32,
    /// e-vector (unit, body frame).
    pub e_body: Vector3<f32>,
    /// Viewing direction (unit, body frame).
    pub view_body: Vector3<f32>,
    /// 1-sigma of the AoP from the noise model (rad): the quality measure (smaller is better).
    pub sigma_aop_rad: f32,
}

/// Model construction errors (configuration, not data path).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelError {
    /// View or axis not unit length / not perpendicular / non-finite.
    BadGeometry,
    /// Channel angles or extinction ratios do not determine S1, S2 (e.g. all polarizers parallel).
    Singular,
    /// Gain <= 0, extinction ratio <= 1 or non-finite values.
    BadCalibration,
}

impl core::fmt::Display for ModelError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ModelError::BadGeometry => "unit geometry: view or axis not unit length, not perpendicular, or not finite",
            ModelError::Singular => "unit channels: polarizer angles or extinction ratios do not determine S1, S2",
            ModelError::BadCalibration => "unit calibration: gain <= 0, extinction ratio <= 1, or not finite",
        })
    }
}

impl core::error::Error for ModelError {}

fn unit3(v: [f32; 3]) -> Vector3<f32> {
    Vector3::new(v[0], v[1], v[2])
}

impl UnitModel {
    /// Builds a unit model, checking the geometry and precomputing the Stokes inverse.
    pub fn new(view_body: [f32; 3], axis0_body: [f32; 3], channels: [ChannelCal; CHANNELS], noise: NoiseModel) -> Result<Self, ModelError> {
        let d = unit3(view_body);
        let a = unit3(axis0_body);
        let ok = |x: f32| x.is_finite();
        if !(view_body.iter().all(|&x| ok(x)) && axis0_body.iter().all(|&x| ok(x)))
            || (d.norm() - 1.0).abs() > 1e-3
            || (a.norm() - 1.0).abs() > 1e-3
            || d.dot(&a).abs() > 1e-3
        {
            return Err(ModelError::BadGeometry);
        }
        let mut m = SMatrix::<f32, CHANNELS, 3>::zeros();
        for (k, c) in channels.iter().enumerate() {
            if !(c.gain.is_finite() && c.gain > 0.0 && c.offset_counts.is_finite() && c.polarizer_rad.is_finite())
                || !(c.extinction_ratio.is_finite() && c.extinction_ratio > 1.0)
            {
                return Err(ModelError::BadCalibration);
            }
            let eta = (c.extinction_ratio - 1.0) / (c.extinction_ratio + 1.0);
            let (s2, c2) = crate::ephemeris::phase::sincos_rad(2.0 * c.polarizer_rad);
            m[(k, 0)] = 0.5;
            m[(k, 1)] = 0.5 * eta * c2;
            m[(k, 2)] = 0.5 * eta * s2;
        }
        let mtm: Matrix3<f32> = m.transpose() * m;
        let inv = mtm.try_inverse().ok_or(ModelError::Singular)?;
        // Condition check: the S1/S2 rows must be well determined.
        if !(inv[(1, 1)].is_finite() && inv[(1, 1)] < 1e4 && inv[(2, 2)] < 1e4) {
            return Err(ModelError::Singular);
        }
        Ok(UnitModel { view_body, axis0_body, channels, noise, pinv: inv * m.transpose() })
    }

    /// A unit with nominal 0/45/90/135 deg polarizers and identical channels.
    pub fn nominal(
        view_body: [f32; 3],
        axis0_body: [f32; 3],
        gain: f32,
        offset_counts: f32,
        extinction_ratio: f32,
        noise: NoiseModel,
    ) -> Result<Self, ModelError> {
        let q = core::f32::consts::FRAC_PI_4;
        let ch = |k: usize| ChannelCal { gain, offset_counts, polarizer_rad: q * k as f32, extinction_ratio };
        Self::new(view_body, axis0_body, [ch(0), ch(1), ch(2), ch(3)], noise)
    }

    /// Calibrated Stokes, AoP, DoLP and e-vector from raw counts.
    pub fn observe(&self, counts: &[i16; CHANNELS], min_s0: f32, min_dolp: f32) -> Result<UnitObservation, UnitReject> {
        let mut y = SMatrix::<f32, CHANNELS, 1>::zeros();
        let mut var_y = [0.0f32; CHANNELS];
        for (k, (&c, cal)) in counts.iter().zip(&self.channels).enumerate() {
            if c >= self.noise.saturation_counts {
                return Err(UnitReject::Saturated);
            }
            let signal = c as f32 - cal.offset_counts;
            y[k] = signal / cal.gain;
            let var_counts = self.noise.read_sigma_counts * self.noise.read_sigma_counts
                + if signal > 0.0 { signal / self.noise.electrons_per_count } else { 0.0 };
            if let Some(v) = var_y.get_mut(k) {
                *v = var_counts / (cal.gain * cal.gain);
            }
        }
        let s = self.pinv * y;
        let (s0, s1, s2) = (s[0], s[1], s[2]);
        if !(s0.is_finite() && s1.is_finite() && s2.is_finite()) {
            return Err(UnitReject::NonFinite);
        }
        // Covariance of S0, S1, S2: pinv diag(var_y) pinv^T (diagonal, and S1-S2).
        let (mut v00, mut v11, mut v22, mut v12) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for (k, &v) in var_y.iter().enumerate() {
            let (r0, r1, r2) = (self.pinv[(0, k)], self.pinv[(1, k)], self.pinv[(2, k)]);
            v00 += r0 * r0 * v;
            v11 += r1 * r1 * v;
            v22 += r2 * r2 * v;
            v12 += r1 * r2 * v;
        }
        // Light is what stands out of the readout's own noise: in the dark (night, deep water,
        // a head at the surface whose units see nothing) S0 and P are noise, the DoLP of noise
        // over a near-zero S0 is anything, and three such units once gave a 40-deg-sigma fix
        // 150 deg off (`a_dark_unit_is_dark_whatever_its_noise_says`).
        if s0 < min_s0 || s0 * s0 < DARK_SIGMAS * DARK_SIGMAS * v00 {
            return Err(UnitReject::Dark);
        }
        let p2 = s1 * s1 + s2 * s2;
        let p = libm::sqrtf(p2);
        let dolp = p / s0;
        if !(dolp >= min_dolp) || p2 <= 0.0 || p2 < POLARIZED_SIGMAS * POLARIZED_SIGMAS * 0.5 * (v11 + v22) {
            return Err(UnitReject::LowDolp);
        }
        // AoP = 0.5 atan2(S2, S1): gradient (-S2, S1) / (2 P^2).
        let var_aop = (s2 * s2 * v11 + s1 * s1 * v22 - 2.0 * s1 * s2 * v12) / (4.0 * p2 * p2);
        let aop = 0.5 * libm::atan2f(s2, s1);
        let (sa, ca) = crate::ephemeris::phase::sincos_rad(aop);
        let d = unit3(self.view_body);
        let a = unit3(self.axis0_body);
        let b = d.cross(&a);
        let e = a * ca + b * sa;
        let sigma = libm::sqrtf(var_aop.max(0.0));
        if !(sigma.is_finite() && e.iter().all(|x| x.is_finite())) {
            return Err(UnitReject::NonFinite);
        }
        Ok(UnitObservation { s0, s1, s2, aop_rad: aop, dolp, e_body: e, view_body: d, sigma_aop_rad: sigma })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit() -> UnitModel {
        UnitModel::nominal([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], 10_000.0, 200.0, 1000.0, NoiseModel::default()).unwrap()
    }

    /// Counts for a known Stokes vector through the unit's own channel model.
    fn counts_for(u: &UnitModel, s: [f32; 3]) -> [i16; 4] {
        let mut out = [0i16; 4];
        for (o, c) in out.iter_mut().zip(&u.channels) {
            let eta = (c.extinction_ratio - 1.0) / (c.extinction_ratio + 1.0);
            let i = 0.5 * (s[0] + eta * (s[1] * libm::cosf(2.0 * c.polarizer_rad) + s[2] * libm::sinf(2.0 * c.polarizer_rad)));
            *o = (c.offset_counts + c.gain * i).round() as i16;
        }
        out
    }

    #[test]
    fn recovers_aop_and_dolp() {
        let u = unit();
        let aop = 0.7f32;
        let dolp = 0.3f32;
        let s = [2.0, 2.0 * dolp * libm::cosf(2.0 * aop), 2.0 * dolp * libm::sinf(2.0 * aop)];
        let o = u.observe(&counts_for(&u, s), 0.01, 0.01).unwrap();
        assert!((o.aop_rad - aop).abs() < 2e-3, "{}", o.aop_rad);
        assert!((o.dolp - dolp).abs() < 2e-3, "{}", o.dolp);
        // e-vector: cos(aop) a + sin(aop) b with a = y, b = x cross y = z.
        assert!((o.e_body - Vector3::new(0.0, libm::cosf(aop), libm::sinf(aop))).norm() < 3e-3);
        assert!(o.sigma_aop_rad > 0.0 && o.sigma_aop_rad < 0.01);
    }

    /// The head's units in the dark (their offset, read noise and quantisation; counts as the
    /// simulator's head at the surface gave them): no draw of the noise is light. A fixed `min_s0`
    /// alone passed about half of them (S0 of noise is as often above zero as below), with any
    /// DoLP; three such units made a fix 150 deg off with a 40-deg sigma.
    #[test]
    fn a_dark_unit_is_dark_whatever_its_noise_says() {
        let units = crate::head::polarization_units();
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut gauss = move || libm::sqrt(-2.0 * libm::log(uniform())) * libm::cos(core::f64::consts::TAU * uniform());
        let (mut above_min_s0, mut draws) = (0, 0);
        for u in units.iter().flatten() {
            for _ in 0..20_000 {
                let counts = [0; 4].map(|_: i16| (crate::head::POLARIZATION_OFFSET_COUNTS as f64 + 3.0 * gauss()).round() as i16);
                let s0: f32 = (u.pinv * SMatrix::<f32, 4, 1>::from_iterator(counts.iter().map(|&c| c as f32 - 300.0)))[0];
                above_min_s0 += usize::from(s0 >= 1e-3);
                draws += 1;
                let r = u.observe(&counts, 1e-3, 0.02);
                assert!(matches!(r, Err(UnitReject::Dark | UnitReject::LowDolp)), "noise {counts:?} taken as light: {r:?}");
            }
        }
        assert!(above_min_s0 > draws / 3, "the draws test what min_s0 alone let through ({above_min_s0} of {draws})");
        // Faint but real light is still light: 200 counts a channel above the offset (S0 = 400,
        // 2 % of the exposure target), DoLP 0.3 (P 14 of its sigmas).
        let u = units[0].expect("unit 0");
        let aop = 0.4f32;
        let o = u.observe(&counts_for(&u, [400.0, 120.0 * libm::cosf(2.0 * aop), 120.0 * libm::sinf(2.0 * aop)]), 1e-3, 0.02).unwrap();
        assert!((o.aop_rad - aop).abs() < 0.05, "{}", o.aop_rad);
    }

    #[test]
    fn rejects() {
        let u = unit();
        assert_eq!(u.observe(&[32_500, 100, 100, 100], 0.01, 0.01), Err(UnitReject::Saturated));
        assert_eq!(u.observe(&[200, 200, 200, 200], 0.01, 0.01), Err(UnitReject::Dark));
        assert_eq!(u.observe(&counts_for(&u, [1.0, 0.001, 0.0]), 0.01, 0.01), Err(UnitReject::LowDolp));
        let bad = UnitModel::nominal([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1.0, 0.0, 100.0, NoiseModel::default());
        assert_eq!(bad, Err(ModelError::BadGeometry));
        let flat = ChannelCal { gain: 1.0, offset_counts: 0.0, polarizer_rad: 0.0, extinction_ratio: 100.0 };
        let singular = UnitModel::new([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [flat; 4], NoiseModel::default());
        assert_eq!(singular, Err(ModelError::Singular));
    }
}

/// Geometry of unit `i` of a ring of `n` units: azimuths `360 i / n` deg around the body z axis,
/// looking `elevation_rad` above the body's horizontal plane; reference axis horizontal.
/// Returns (view, axis0) in body FRD.
pub fn ring_geometry(i: usize, n: usize, elevation_rad: f32) -> ([f32; 3], [f32; 3]) {
    let az = core::f32::consts::TAU * i as f32 / n.max(1) as f32;
    let (sa, ca) = crate::ephemeris::phase::sincos_rad(az);
    let (se, ce) = crate::ephemeris::phase::sincos_rad(elevation_rad);
    ([ce * ca, ce * sa, -se], [-sa, ca, 0.0])
}
