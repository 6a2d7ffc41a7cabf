//! Physically based underwater polarization field and polarization-unit sensor simulator (f64).
//!
//! Light path (spec A2, S_d = M_{S->D} M_S M_{R->S} M_R S_i), written with 3x3 coherency
//! matrices of the electric field instead of Stokes vectors and rotation matrices (equivalent for
//! linear polarization, and the frame rotations come for free):
//! 1. Sunlight is unpolarized: `C_i = (I - k_i k_i^T) / 2`.
//! 2. Fresnel transmission at the surface facet (flat, or a set of Gaussian-slope facets for a
//!    wavy surface): `C_t = (T_s s s^T + T_p p p^T) / 2`, refracted by Snell's law.
//! 3. Single scattering toward the sensor: Rayleigh (dipole) scattering projects the field on
//!    the plane transverse to the scattered direction `w`: `C_s = (3 / 8 pi) P C_t P`,
//!    `P = I - w w^T`; an optional particle part scatters with a Henyey-Greenstein phase function
//!    and no polarization.
//! 4. Depth: the refracted beam is attenuated by `exp(-c z / mu_t)` and the scattered light by
//!    `exp(-c l)` along the line of sight (integrated in closed form from the sensor to the
//!    surface or to infinity). Multiple scattering is an unpolarized background attenuated with
//!    the (smaller) diffuse coefficient `K_d`; it is what lowers DoLP with depth.
//! 5. Sensor: each channel sees `0.5 (S0 + eta (S1 cos 2 th + S2 sin 2 th))` through its true
//!    (not the calibrated) gain, offset, polarizer angle and extinction ratio; photon shot noise,
//!    read noise, 16-bit ADC quantization and clipping.
//!
//! Not modelled: skylight inside the Snell window (units must look outside it, i.e. more than
//! ~42 deg below the zenith), the angular extent of the sun, sensor field of view.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use subnav_core::compass::{CHANNELS, ChannelCal, UnitModel, unit::ring_geometry};
use subnav_core::head;

/// Optical properties of the water column and the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Water {
    pub n_water: f64,
    /// Beam attenuation coefficient c (1/m).
    pub c_per_m: f64,
    /// Scattering coefficient b (1/m) and the particle part of it.
    pub b_per_m: f64,
    pub particle_fraction: f64,
    /// Henyey-Greenstein asymmetry of particle scattering.
    pub hg_g: f64,
    /// Diffuse attenuation coefficient K_d (1/m).
    pub kd_per_m: f64,
    /// Strength of the unpolarized multiple-scattering source relative to single scattering
    /// (dimensionless: source `multiple_scattering * E_t b / (4 pi) exp(-K_d z)` per metre of path).
    pub multiple_scattering: f64,
    /// RMS surface slope (0 = flat) and the number of facets sampled for a wavy surface.
    pub slope_rms: f64,
    pub facets: usize,
}

impl Water {
    /// Clear oceanic water (Jerlov type I-like, blue-green): c = 0.06/m, b = 0.02/m, K_d = 0.035/m.
    pub fn clear() -> Self {
        Water {
            n_water: subnav_core::compass::water::default_index() as f64,
            c_per_m: 0.06,
            b_per_m: 0.02,
            particle_fraction: 0.2,
            hg_g: 0.9,
            kd_per_m: 0.035,
            multiple_scattering: 0.6,
            slope_rms: 0.0,
            facets: 1,
        }
    }
}

/// Sensor noise and calibration residuals (what the calibration does not know).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorErrors {
    pub electrons_per_count: f64,
    pub read_sigma_counts: f64,
    /// Calibration residuals (1-sigma): relative gain, offset (counts), polarizer angle (rad),
    /// relative extinction ratio.
    pub gain_rel: f64,
    pub offset_counts: f64,
    pub angle_rad: f64,
    pub extinction_rel: f64,
    /// Counts of the brightest unit's S0 (auto-exposure target).
    pub exposure_counts: f64,
}

impl Default for SensorErrors {
    /// The sensor head's photodiode front end and exposure (`subnav_core::head`), and our
    /// calibration residuals.
    fn default() -> Self {
        SensorErrors {
            electrons_per_count: head::PHOTODIODE_NOISE.electrons_per_count as f64,
            read_sigma_counts: head::PHOTODIODE_NOISE.read_sigma_counts as f64,
            gain_rel: 1e-3,
            offset_counts: 1.0,
            angle_rad: 0.05f64.to_radians(),
            extinction_rel: 0.05,
            exposure_counts: head::POLARIZATION_EXPOSURE_COUNTS as f64,
        }
    }
}

/// Nominal calibration of the simulated units: the sensor head's (`subnav_core::head`).
pub const NOMINAL_GAIN: f32 = head::POLARIZATION_GAIN_COUNTS;
pub const NOMINAL_OFFSET: f32 = head::POLARIZATION_OFFSET_COUNTS;
pub const NOMINAL_ER: f32 = head::POLARIZER_EXTINCTION_RATIO;

/// A sensor head with `n` units: the head's ring geometry (`subnav_core::head`: looking
/// [`head::POLARIZATION_UNIT_ELEVATION_RAD`] above the body horizontal, outside the Snell window),
/// nominal 0/45/90/135 deg polarizers, the head's calibration and photodiode noise. Intensities
/// are in counts (gain 1 count per count of the exposure-normalized field). `n =
/// head::POLARIZATION_UNITS` gives `head::polarization_units()`.
pub fn default_units(n: usize) -> Vec<UnitModel> {
    (0..n)
        .filter_map(|i| {
            let (v, a) = ring_geometry(i, n, head::POLARIZATION_UNIT_ELEVATION_RAD);
            UnitModel::nominal(v, a, NOMINAL_GAIN, NOMINAL_OFFSET, NOMINAL_ER, head::PHOTODIODE_NOISE).ok()
        })
        .collect()
}

/// One refracted beam in the water: propagation direction and coherency (per unit irradiance).
#[derive(Debug, Clone, Copy)]
struct Beam {
    k: Vector3<f64>,
    c: Matrix3<f64>,
}

/// Fresnel transmission of unpolarized sunlight through a facet with normal `n` (pointing down,
/// into the water). `k_i`: incident propagation (downward).
fn refract(k_i: Vector3<f64>, n: Vector3<f64>, n_w: f64) -> Option<Beam> {
    let cos_i = k_i.dot(&n);
    if cos_i <= 1e-6 {
        return None;
    }
    let sin_i2 = (1.0 - cos_i * cos_i).max(0.0);
    let sin_t2 = sin_i2 / (n_w * n_w);
    let cos_t = (1.0 - sin_t2).sqrt();
    // Snell in vector form.
    let k_t = (k_i / n_w + n * (cos_t - cos_i / n_w)).normalize();
    let rs = ((cos_i - n_w * cos_t) / (cos_i + n_w * cos_t)).powi(2);
    let rp = ((n_w * cos_i - cos_t) / (n_w * cos_i + cos_t)).powi(2);
    let (ts, tp) = (1.0 - rs, 1.0 - rp);
    let sv = k_i.cross(&n);
    let s_hat = if sv.norm() > 1e-9 { sv.normalize() } else { k_i.cross(&Vector3::x()).normalize() };
    let p_t = s_hat.cross(&k_t).normalize();
    // Irradiance on the facet scales with cos_i (for a horizontal surface this is the usual
    // cos(zenith) factor).
    let c = (s_hat * s_hat.transpose() * ts + p_t * p_t.transpose() * tp) * (0.5 * cos_i);
    Some(Beam { k: k_t, c })
}

/// The light field at one depth for one sun direction.
pub struct Field {
    beams: Vec<Beam>,
    water: Water,
    depth_m: f64,
}

impl Field {
    /// `sun_ned`: unit vector toward the sun in air (NED, z down, so sun above has z < 0).
    pub fn new<R: Rng>(sun_ned: Vector3<f64>, water: Water, depth_m: f64, rng: &mut R) -> Self {
        let k_i = -sun_ned;
        let mut beams = Vec::new();
        if water.slope_rms <= 0.0 || water.facets <= 1 {
            beams.extend(refract(k_i, Vector3::z(), water.n_water));
        } else {
            let slope = Normal::new(0.0, water.slope_rms).unwrap_or(Normal::new(0.0, 0.0).expect("zero sigma"));
            for _ in 0..water.facets {
                let (sx, sy): (f64, f64) = (slope.sample(rng), slope.sample(rng));
                let n = Vector3::new(-sx, -sy, 1.0).normalize();
                beams.extend(refract(k_i, n, water.n_water));
            }
            let m = water.facets as f64;
            for b in &mut beams {
                b.c /= m;
            }
        }
        Field { beams, water, depth_m }
    }

    /// Refracted sun direction (toward the sun, NED) of the mean beam.
    pub fn refracted_sun_ned(&self) -> Option<Vector3<f64>> {
        let k: Vector3<f64> = self.beams.iter().map(|b| b.k).sum();
        (k.norm() > 0.0).then(|| -k.normalize())
    }

    /// Coherency matrix of the radiance arriving from direction `v` (unit, NED, pointing away from
    /// the sensor toward where the light comes from).
    pub fn radiance(&self, v: Vector3<f64>) -> Matrix3<f64> {
        let w = &self.water;
        let z0 = self.depth_m;
        let out = -v; // propagation direction of the light reaching the sensor
        let p = Matrix3::identity() - out * out.transpose();
        let b_r = w.b_per_m * (1.0 - w.particle_fraction);
        let b_p = w.b_per_m * w.particle_fraction;
        let mut total = Matrix3::zeros();
        let mut e_total = 0.0;
        for beam in &self.beams {
            let mu = beam.k.z.max(1e-3);
            // Path integral of exp(-c z(l) / mu - c l), z(l) = z0 + l v_z, up to the surface.
            let k = w.c_per_m * (1.0 + v.z / mu);
            let l_max = if v.z < 0.0 { z0 / -v.z } else { f64::INFINITY };
            let path = if k.abs() < 1e-12 {
                l_max
            } else if l_max.is_finite() {
                (1.0 - (-k * l_max).exp()) / k
            } else if k > 0.0 {
                1.0 / k
            } else {
                0.0
            };
            let g = (-w.c_per_m * z0 / mu).exp() * path;
            let cos_g = beam.k.dot(&out);
            let rayleigh = p * beam.c * p * (3.0 / (8.0 * std::f64::consts::PI));
            let hg = (1.0 - w.hg_g * w.hg_g) / (4.0 * std::f64::consts::PI * (1.0 + w.hg_g * w.hg_g - 2.0 * w.hg_g * cos_g).powf(1.5));
            let particle = p * (0.5 * hg * beam.c.trace());
            total += (rayleigh * b_r + particle * b_p) * g;
            e_total += beam.c.trace();
        }
        // Unpolarized multiple-scattering background.
        // Its source strength at depth z falls as exp(-K_d z); it builds up along the same line of
        // sight as the single-scattered light (so both vanish near the surface alike).
        let kd_path = w.c_per_m + w.kd_per_m * v.z;
        let l_max = if v.z < 0.0 { z0 / -v.z } else { f64::INFINITY };
        let path_d = if kd_path.abs() < 1e-12 {
            l_max
        } else if l_max.is_finite() {
            (1.0 - (-kd_path * l_max).exp()) / kd_path
        } else if kd_path > 0.0 {
            1.0 / kd_path
        } else {
            0.0
        };
        let diffuse = w.multiple_scattering * e_total * w.b_per_m / (4.0 * std::f64::consts::PI) * (-w.kd_per_m * z0).exp() * path_d;
        total + p * (0.5 * diffuse)
    }
}

/// Stokes (S0, S1, S2) of a coherency matrix in a unit's frame (a, b = d x a).
pub fn stokes(c: &Matrix3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> [f64; 3] {
    let caa = a.dot(&(c * a));
    let cbb = b.dot(&(c * b));
    let cab = a.dot(&(c * b));
    [caa + cbb, caa - cbb, 2.0 * cab]
}

/// True channel calibration of a unit: the nominal one plus calibration residuals.
pub fn true_channels<R: Rng>(u: &UnitModel, err: &SensorErrors, rng: &mut R) -> [ChannelCal; CHANNELS] {
    let n = |rng: &mut R, s: f64| -> f64 { Normal::new(0.0, s.max(0.0)).map_or(0.0, |d| d.sample(rng)) };
    let mut out = u.channels;
    for c in &mut out {
        c.gain *= (1.0 + n(rng, err.gain_rel)) as f32;
        c.offset_counts += n(rng, err.offset_counts) as f32;
        c.polarizer_rad += n(rng, err.angle_rad) as f32;
        c.extinction_ratio = (c.extinction_ratio as f64 * (1.0 + n(rng, err.extinction_rel))).max(2.0) as f32;
    }
    out
}

/// Raw counts of all units for a field, a body attitude and the true calibrations.
pub fn counts<R: Rng>(
    field: &Field,
    r_nb: &Rotation3<f64>,
    units: &[UnitModel],
    true_cal: &[[ChannelCal; CHANNELS]],
    err: &SensorErrors,
    rng: &mut R,
) -> Vec<[i16; CHANNELS]> {
    let v3 = |x: [f32; 3]| Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
    let stokes_all: Vec<[f64; 3]> = units
        .iter()
        .map(|u| {
            let d = r_nb * v3(u.view_body);
            let a = r_nb * v3(u.axis0_body);
            let b = d.cross(&a);
            stokes(&field.radiance(d), &a, &b)
        })
        .collect();
    let max_s0 = stokes_all.iter().map(|s| s[0]).fold(0.0, f64::max);
    let scale = if max_s0 > 0.0 { err.exposure_counts / max_s0 } else { 0.0 };
    let read = Normal::new(0.0, err.read_sigma_counts.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("zero sigma"));
    stokes_all
        .iter()
        .zip(true_cal)
        .map(|(s, cal)| {
            let mut out = [0i16; CHANNELS];
            for (o, c) in out.iter_mut().zip(cal) {
                let eta = (c.extinction_ratio as f64 - 1.0) / (c.extinction_ratio as f64 + 1.0);
                let th = 2.0 * c.polarizer_rad as f64;
                let i = 0.5 * (s[0] + eta * (s[1] * th.cos() + s[2] * th.sin())) * scale * c.gain as f64;
                let shot =
                    if i > 0.0 { (i / err.electrons_per_count).sqrt() * Normal::new(0.0, 1.0).map_or(0.0, |d| d.sample(rng)) } else { 0.0 };
                let x = c.offset_counts as f64 + i + shot + read.sample(rng);
                *o = x.round().clamp(i16::MIN as f64, i16::MAX as f64) as i16;
            }
            out
        })
        .collect()
}

/// Accelerometer specific force at rest for an attitude, with a tilt error of `tilt_sigma_rad`
/// (1-sigma per axis) and white noise.
pub fn accel<R: Rng>(r_nb: &Rotation3<f64>, tilt_sigma_rad: f64, rng: &mut R) -> [f32; 3] {
    let n = Normal::new(0.0, tilt_sigma_rad.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("zero sigma"));
    let err = Rotation3::from_euler_angles(n.sample(rng), n.sample(rng), 0.0);
    let f = (r_nb * err).inverse() * Vector3::new(0.0, 0.0, -subnav_core::compass::G0_MPS2 as f64);
    [f.x as f32, f.y as f32, f.z as f32]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn sun(el_deg: f64, az_deg: f64) -> Vector3<f64> {
        let (e, a) = (el_deg.to_radians(), az_deg.to_radians());
        Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), -e.sin())
    }

    /// Fresnel: normal incidence T = 1 - ((n-1)/(n+1))^2 for both polarizations; Snell holds.
    #[test]
    fn fresnel_and_snell_analytic() {
        let n = 1.34;
        let b = refract(Vector3::z(), Vector3::z(), n).unwrap();
        let t = 1.0 - ((n - 1.0) / (n + 1.0)).powi(2);
        assert!((b.c.trace() - t).abs() < 1e-12);
        let s = sun(30.0, 0.0);
        let b = refract(-s, Vector3::z(), n).unwrap();
        let sin_t = (b.k.x.powi(2) + b.k.y.powi(2)).sqrt();
        assert!((sin_t - 60f64.to_radians().sin() / n).abs() < 1e-12);
        // Transmitted light is slightly p-polarized (T_p > T_s).
        // s direction for a sun in the north is y.
        assert!(b.c[(1, 1)] < b.c.trace() / 2.0);
    }

    /// Single Rayleigh scattering at 90 deg of an unpolarized beam is fully polarized,
    /// perpendicular to the scattering plane; with the background DoLP falls with depth.
    #[test]
    fn rayleigh_polarization_and_depth() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let pure = Water { particle_fraction: 0.0, multiple_scattering: 0.0, ..Water::clear() };
        let s = sun(90.0, 0.0); // overhead: refracted beam straight down
        let f = Field::new(s, pure, 5.0, &mut rng);
        let v = Vector3::new(1.0, 0.0, 0.0); // look north, horizontal: 90 deg scattering
        let c = f.radiance(v);
        let st = stokes(&c, &Vector3::y(), &v.cross(&Vector3::y()));
        let dolp = (st[1].powi(2) + st[2].powi(2)).sqrt() / st[0];
        assert!((dolp - 1.0).abs() < 1e-9, "{dolp}");
        // E-vector along y (perpendicular to the vertical scattering plane): S1 > 0 in frame a = y.
        assert!(st[1] > 0.0);
        let mut dolp_at = |z: f64| {
            let f = Field::new(sun(50.0, 0.0), Water::clear(), z, &mut rng);
            let v = Vector3::new(0.0, 1.0, -0.26).normalize();
            let st = stokes(&f.radiance(v), &Vector3::x(), &v.cross(&Vector3::x()));
            (st[1].powi(2) + st[2].powi(2)).sqrt() / st[0]
        };
        let (d1, d10, d40) = (dolp_at(1.0), dolp_at(10.0), dolp_at(40.0));
        assert!(d1 > d10 && d10 > d40, "{d1} {d10} {d40}");
        assert!(d10 > 0.1 && d10 < 0.8, "{d10}");
    }
}
