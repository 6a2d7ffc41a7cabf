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
//! Real seas and skies ([`SeaField`]): the sunbeam refracts through the moving sea of
//! [`crate::sea`] at the point where it enters the water above each scattering point of a
//! unit's line of sight (8 points at equal-weight quantiles of the path integral), over the
//! unit's field of view (centre and both edges across it) and its exposure (start and end), so
//! the jitter is correlated in time and space as the waves make it. Skylight ([`Sky`]) is an
//! unpolarized, uniform sky refracted through the mean (flat) surface into the Snell cone, 24
//! beams; the sky kinds set the direct and diffuse shares (clear, partly cloudy with cloud
//! shadows drifting over the sun, overcast with no sun disc, twilight with the sun below the
//! horizon and little light). The real field's departure from this single-scattering model
//! (polarized multiple scattering, the sky's own polarization, particle polarization) is added
//! from a table of OSOAA radiative-transfer fields ([`crate::osoaa`], `Water::
//! polarization_table`): the polarization of a flat sea under a clear sky is then OSOAA's at the
//! table's cases, with this model's moving-sea fluctuation about it. Not modelled: wave focusing
//! of the beam's irradiance, waves shorter than the sea's cut (they average out over a
//! footprint).
//!
//! Not modelled in [`Field`] (the flat model): the departure table, skylight (units must look outside the Snell
//! window, i.e. more than ~42 deg below the zenith), the angular extent of the sun, sensor field
//! of view.

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
    /// Add the real field's departure from single scattering to [`SeaField`]'s polarization
    /// (the OSOAA table, [`crate::osoaa`]); off: the pure single-scattering model.
    pub polarization_table: bool,
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
            polarization_table: true,
        }
    }
}

impl Water {
    /// Clear oceanic water with the optics of the OSOAA reference's clear case (Chl 0.1
    /// mg/m^3: c = 0.109/m, b = 0.0818/m, single-scattering albedo 0.75; pure water scatters
    /// about 0.003/m of b at 500 nm, so particles are 0.96 of it), K_d 0.04/m (a + b_b for
    /// that water, our estimate). What `compass field --water oceanic` compares with OSOAA's
    /// clear cases; [`Water::clear`] is the simulator's default (more transparent) water.
    pub fn oceanic() -> Self {
        Water { c_per_m: 0.109, b_per_m: 0.75 * 0.109, particle_fraction: 0.96, kd_per_m: 0.04, ..Water::clear() }
    }

    /// Single-scattering albedo b / c.
    pub fn albedo(&self) -> f64 {
        if self.c_per_m > 0.0 { (self.b_per_m / self.c_per_m).clamp(0.0, 1.0) } else { 0.0 }
    }

    /// Turbid coastal water: the optics of the OSOAA reference's turbid case (Chl 3 mg/m^3
    /// plus 1 mg/L minerals: c = 1.056/m, b = 0.977/m (single-scattering albedo 0.925:
    /// particles 0.974/m, pure water about 0.003/m), with our
    /// guesses for what single scattering needs besides (K_d from a + b_b, the particles'
    /// Henyey-Greenstein asymmetry, the background's strength).
    pub fn turbid() -> Self {
        Water {
            n_water: subnav_core::compass::water::default_index() as f64,
            c_per_m: 1.056,
            b_per_m: 0.925 * 1.056,
            particle_fraction: 0.997,
            hg_g: 0.92,
            kd_per_m: 0.17,
            multiple_scattering: 0.6,
            slope_rms: 0.0,
            facets: 1,
            polarization_table: true,
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
        let mut total = Matrix3::zeros();
        let mut e_total = 0.0;
        for beam in &self.beams {
            total += single_scatter(&self.water, self.depth_m, beam, v);
            e_total += beam.c.trace();
        }
        total + background(&self.water, self.depth_m, e_total, v)
    }
}

/// Single scattering of a uniform beam along the line of sight `v` from depth `z0`: path
/// integral of `exp(-c z(l) / mu - c l)`, `z(l) = z0 + l v_z`, up to the surface, closed form.
fn single_scatter(w: &Water, z0: f64, beam: &Beam, v: Vector3<f64>) -> Matrix3<f64> {
    let mu = beam.k.z.max(1e-3);
    let k = w.c_per_m * (1.0 + v.z / mu);
    let l_max = if v.z < 0.0 { z0 / -v.z } else { f64::INFINITY };
    let g = (-w.c_per_m * z0 / mu).exp() * path_integral(k, l_max);
    scatter_matrix(w, beam, v) * g
}

/// `int_0^l_max exp(-k l) dl` (infinite when it diverges: 0, the light never arrives).
fn path_integral(k: f64, l_max: f64) -> f64 {
    if k.abs() < 1e-12 {
        l_max
    } else if l_max.is_finite() {
        (1.0 - (-k * l_max).exp()) / k
    } else if k > 0.0 {
        1.0 / k
    } else {
        0.0
    }
}

/// Coherency scattered per metre of path from `beam` toward the sensor looking along `v`:
/// Rayleigh (dipole) part and the unpolarized Henyey-Greenstein particle part.
fn scatter_matrix(w: &Water, beam: &Beam, v: Vector3<f64>) -> Matrix3<f64> {
    let out = -v; // propagation direction of the light reaching the sensor
    let p = Matrix3::identity() - out * out.transpose();
    let b_r = w.b_per_m * (1.0 - w.particle_fraction);
    let b_p = w.b_per_m * w.particle_fraction;
    let cos_g = beam.k.dot(&out);
    let rayleigh = p * beam.c * p * (3.0 / (8.0 * std::f64::consts::PI));
    let hg = (1.0 - w.hg_g * w.hg_g) / (4.0 * std::f64::consts::PI * (1.0 + w.hg_g * w.hg_g - 2.0 * w.hg_g * cos_g).powf(1.5));
    let particle = p * (0.5 * hg * beam.c.trace());
    rayleigh * b_r + particle * b_p
}

/// Unpolarized multiple-scattering background for a total refracted irradiance `e_total`: its
/// source strength at depth z falls as exp(-K_d z); it builds up along the same line of sight as
/// the single-scattered light (so both vanish near the surface alike).
fn background(w: &Water, z0: f64, e_total: f64, v: Vector3<f64>) -> Matrix3<f64> {
    let out = -v;
    let p = Matrix3::identity() - out * out.transpose();
    let l_max = if v.z < 0.0 { z0 / -v.z } else { f64::INFINITY };
    let path_d = path_integral(w.c_per_m + w.kd_per_m * v.z, l_max);
    let diffuse = w.multiple_scattering * e_total * w.b_per_m / (4.0 * std::f64::consts::PI) * (-w.kd_per_m * z0).exp() * path_d;
    p * (0.5 * diffuse)
}

/// What a light field gives a unit: the coherency of the radiance from a direction, and the
/// light level relative to a clear day (the exposure can stretch only so far).
pub trait LightField {
    fn radiance(&self, v: Vector3<f64>) -> Matrix3<f64>;
    /// Irradiance relative to a clear day with the sun high (1 for [`Field`]).
    fn light_level(&self) -> f64 {
        1.0
    }
}

impl LightField for Field {
    fn radiance(&self, v: Vector3<f64>) -> Matrix3<f64> {
        Field::radiance(self, v)
    }
}

/// How much longer than on a clear day a unit may expose (auto-exposure limit): below
/// 1 / this of a clear day's light the counts fall with the light.
pub const MAX_EXPOSURE_STRETCH: f64 = 50.0;
/// Half field of view of a polarization unit (rad) and its exposure (s): what a real sea
/// field is averaged over.
pub const UNIT_FOV_HALF_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;
pub const UNIT_EXPOSURE_S: f64 = 0.01;

/// The sky over the sea.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SkyKind {
    /// Sun disc and a clear sky (diffuse 12 % of the direct irradiance).
    #[default]
    Clear,
    /// Cumulus drifting over the sun: blocked about a third of the time (sharp-edged shadows,
    /// minutes apart), a brighter diffuse sky.
    PartlyCloudy,
    /// No sun disc: diffuse light only, 40 % of a clear day.
    Overcast,
    /// Sun at or below the horizon: diffuse light only, 0.3 % of a clear day.
    Twilight,
}

impl SkyKind {
    pub const ALL: [SkyKind; 4] = [SkyKind::Clear, SkyKind::PartlyCloudy, SkyKind::Overcast, SkyKind::Twilight];

    pub fn name(self) -> &'static str {
        match self {
            SkyKind::Clear => "clear",
            SkyKind::PartlyCloudy => "partly-cloudy",
            SkyKind::Overcast => "overcast",
            SkyKind::Twilight => "twilight",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }

    /// The light at time `t_s` (cloud shadows move with time; `seed` places them).
    pub fn light(self, t_s: f64, seed: u64) -> SkyLight {
        match self {
            SkyKind::Clear => SkyLight { direct: 1.0, diffuse: 0.12 },
            SkyKind::PartlyCloudy => {
                // Cloud optical depth along the sun's line: a few drifting scales, blocked when it
                // exceeds a threshold (sharp edges, ~35 % of the time).
                let ph = (seed % 1000) as f64 * 0.618;
                let c = (t_s / 47.0 + ph).sin() + 0.7 * (t_s / 113.0 + 2.0 * ph).sin() + 0.5 * (t_s / 19.0 + 3.0 * ph).sin();
                let blocked = ((c - 0.5) / 0.15).clamp(0.0, 1.0);
                SkyLight { direct: 1.0 - 0.97 * blocked, diffuse: 0.25 + 0.15 * blocked }
            }
            SkyKind::Overcast => SkyLight { direct: 0.0, diffuse: 0.4 },
            SkyKind::Twilight => SkyLight { direct: 0.0, diffuse: 0.003 },
        }
    }
}

impl std::fmt::Display for SkyKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Direct (sun) and diffuse (sky) irradiance, relative to a clear day's direct beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkyLight {
    pub direct: f64,
    pub diffuse: f64,
}

/// The light field at one depth and place under a moving sea and a sky (see the module doc).
pub struct SeaField<'a> {
    sea: &'a crate::sea::Sea,
    water: Water,
    depth_m: f64,
    pos_ne_m: (f64, f64),
    t_s: f64,
    /// Incident sunlight (propagation, downward) and its weight.
    k_sun: Vector3<f64>,
    direct: f64,
    /// The sunbeam through the mean surface (geometry of the footprints).
    mean_beam: Option<Beam>,
    /// Skylight beams through the mean surface.
    sky_beams: Vec<Beam>,
    level: f64,
    /// The real field's departure from single scattering (`Water::polarization_table`), and
    /// the clear sky's beams its reference (the simulator's mean field) is computed with.
    table: Option<&'a crate::osoaa::Table>,
    clear_sky_beams: Vec<Beam>,
}

/// Skylight of a uniform sky of `diffuse` (relative to a clear day's direct beam) through the
/// flat surface: 4 zenith rings at equal shares of the horizontal irradiance (sin^2 theta
/// quantiles) x 6 azimuths.
fn sky_beams(diffuse: f64, water: &Water) -> Vec<Beam> {
    let mut out = Vec::new();
    let share = diffuse.max(0.0) / 24.0;
    if share > 0.0 {
        for i in 0..4 {
            let th = ((i as f64 + 0.5) / 4.0).sqrt().asin();
            for j in 0..6 {
                let ph = std::f64::consts::TAU * (j as f64 + 0.25 * i as f64) / 6.0;
                let k_i = Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                if let Some(mut b) = refract(k_i, Vector3::z(), water.n_water) {
                    b.c *= share / th.cos().max(1e-3);
                    out.push(b);
                }
            }
        }
    }
    out
}

/// A look direction turned across a unit's field of view by `f` half-widths (-1, 0, 1).
fn fov_dir(v: Vector3<f64>, f: f64) -> Vector3<f64> {
    let lat = v.cross(&Vector3::z());
    let lat = if lat.norm() > 1e-9 { lat.normalize() } else { Vector3::x() };
    (v + lat * (f * UNIT_FOV_HALF_RAD.tan())).normalize()
}

/// The clear sky's beams (the departure table's reference).
fn sky_beams_clear(water: &Water) -> Vec<Beam> {
    sky_beams(SkyKind::Clear.light(0.0, 0).diffuse, water)
}

/// Line-of-sight quadrature points, field-of-view samples across the view, exposure samples.
const LOS_POINTS: usize = 8;
const FOV_SAMPLES: [f64; 3] = [-1.0, 0.0, 1.0];
const EXPOSURE_SAMPLES: usize = 2;

impl<'a> SeaField<'a> {
    /// `sun_ned`: toward the sun in air; the unit at `depth_m` below (north, east) `pos_ne_m` at
    /// time `t_s` (the sea's time).
    pub fn new(
        sun_ned: Vector3<f64>,
        sky: SkyLight,
        sea: &'a crate::sea::Sea,
        water: Water,
        depth_m: f64,
        pos_ne_m: (f64, f64),
        t_s: f64,
    ) -> Self {
        let k_sun = -sun_ned;
        let direct = sky.direct.max(0.0);
        let mean_beam = if direct > 0.0 {
            refract(k_sun, Vector3::z(), water.n_water).map(|mut b| {
                b.c *= direct;
                b
            })
        } else {
            None
        };
        let sky_beams = sky_beams(sky.diffuse, &water);
        let level = direct * (-sun_ned.z).max(0.0) + sky.diffuse.max(0.0);
        let table = if water.polarization_table { crate::osoaa::Table::osoaa() } else { None };
        let clear_sky_beams = if table.is_some() { sky_beams_clear(&water) } else { Vec::new() };
        SeaField { sea, water, depth_m, pos_ne_m, t_s, k_sun, direct, mean_beam, sky_beams, level, table, clear_sky_beams }
    }

    /// A flat sea under a clear sky (the default of the simulations): the sunbeam and the clear
    /// sky's skylight refracted through the flat surface, with the departure table when
    /// `water.polarization_table`.
    pub fn calm_clear(sun_ned: Vector3<f64>, water: Water, depth_m: f64) -> SeaField<'static> {
        static CALM: std::sync::OnceLock<crate::sea::Sea> = std::sync::OnceLock::new();
        let calm = CALM.get_or_init(|| crate::sea::Sea::new(crate::sea::SeaConfig::wind(0.0), 0));
        SeaField::new(sun_ned, SkyKind::Clear.light(0.0, 0), calm, water, depth_m, (0.0, 0.0), 0.0)
    }

    /// The same field with another departure table (None: pure single scattering), e.g. one
    /// with cases left out for a leave-one-out check.
    pub fn with_table(mut self, table: Option<&'a crate::osoaa::Table>) -> Self {
        if table.is_some() && self.clear_sky_beams.is_empty() {
            self.clear_sky_beams = sky_beams_clear(&self.water);
        }
        self.table = table;
        self
    }

    /// The simulator's mean field (flat sea, clear sky) for a sun and depth: what the
    /// departure table is taken against. Equal to this field's radiance when the sea is flat,
    /// the sky clear, and the sun and depth this field's.
    fn mean_radiance(&self, sun_ned: Vector3<f64>, depth_m: f64, v: Vector3<f64>) -> Matrix3<f64> {
        let clear = SkyKind::Clear.light(0.0, 0);
        let mut total = Matrix3::zeros();
        let mut e_total = 0.0;
        for b in &self.clear_sky_beams {
            total += single_scatter(&self.water, depth_m, b, v);
            e_total += b.c.trace();
        }
        if let Some(mut beam) = refract(-sun_ned, Vector3::z(), self.water.n_water) {
            beam.c *= clear.direct;
            e_total += beam.c.trace();
            for f in FOV_SAMPLES {
                total += single_scatter(&self.water, depth_m, &beam, fov_dir(v, f)) / FOV_SAMPLES.len() as f64;
            }
        }
        total + background(&self.water, depth_m, e_total, v)
    }

    /// The refracted sun direction through the mean surface (toward the sun, NED).
    pub fn refracted_sun_ned(&self) -> Option<Vector3<f64>> {
        self.mean_beam.map(|b| -b.k)
    }

    /// Direct sunlight scattered along the line of sight, each point lit by the beam refracted
    /// where it entered the sea above it.
    fn direct_los(&self, v: Vector3<f64>, mean: &Beam) -> Matrix3<f64> {
        let w = &self.water;
        let z0 = self.depth_m.max(0.0);
        let mu = mean.k.z.max(1e-3);
        let k = w.c_per_m * (1.0 + v.z / mu);
        let l_max = if v.z < 0.0 { z0 / -v.z } else { f64::INFINITY };
        let total = (-w.c_per_m * z0 / mu).exp() * path_integral(k, l_max);
        if !(total > 0.0) {
            return Matrix3::zeros();
        }
        // Equal-weight quantiles of exp(-k l) on [0, l_max].
        let span = if l_max.is_finite() { 1.0 - (-k * l_max).exp() } else { 1.0 };
        let mut acc = Matrix3::zeros();
        for j in 0..LOS_POINTS {
            let u = (j as f64 + 0.5) / LOS_POINTS as f64;
            let l = if k.abs() < 1e-12 { u * l_max } else { -(1.0 - u * span).ln() / k };
            let z = (z0 + l * v.z).max(0.0);
            // Back along the beam to the surface.
            let back = z / mu;
            let n_m = self.pos_ne_m.0 + l * v.x - back * mean.k.x;
            let e_m = self.pos_ne_m.1 + l * v.y - back * mean.k.y;
            for e in 0..EXPOSURE_SAMPLES {
                let t = self.t_s + UNIT_EXPOSURE_S * e as f64 / (EXPOSURE_SAMPLES - 1).max(1) as f64;
                let (sx, sy) = self.sea.slope(n_m, e_m, t);
                // Downward normal of the surface eta(n, e) in NED.
                let normal = Vector3::new(sx, sy, 1.0).normalize();
                if let Some(mut b) = refract(self.k_sun, normal, w.n_water) {
                    b.c *= self.direct;
                    acc += scatter_matrix(w, &b, v);
                }
            }
        }
        acc * (total / (LOS_POINTS * EXPOSURE_SAMPLES) as f64)
    }
}

impl LightField for SeaField<'_> {
    fn radiance(&self, v: Vector3<f64>) -> Matrix3<f64> {
        let mut total = Matrix3::zeros();
        let mut e_total = 0.0;
        for b in &self.sky_beams {
            total += single_scatter(&self.water, self.depth_m, b, v);
            e_total += b.c.trace();
        }
        if let Some(mean) = &self.mean_beam {
            e_total += mean.c.trace();
            // Across the field of view: the view turned across it by -half, 0, +half.
            for f in FOV_SAMPLES {
                total += self.direct_los(fov_dir(v, f), mean) / FOV_SAMPLES.len() as f64;
            }
        }
        let c = total + background(&self.water, self.depth_m, e_total, v);
        match self.table {
            Some(table) => crate::osoaa::Departure {
                table,
                sun_ned: -self.k_sun,
                albedo: self.water.albedo(),
                c_per_m: self.water.c_per_m,
                depth_m: self.depth_m,
                wind_mps: self.sea.config().wind_mps,
                direct: self.direct,
            }
            .apply(c, v, |sun, depth, v| self.mean_radiance(sun, depth, v)),
            None => c,
        }
    }

    fn light_level(&self) -> f64 {
        self.level
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
pub fn counts<R: Rng, F: LightField + ?Sized>(
    field: &F,
    r_nb: &Rotation3<f64>,
    units: &[UnitModel],
    true_cal: &[[ChannelCal; CHANNELS]],
    err: &SensorErrors,
    rng: &mut R,
) -> Vec<[i16; CHANNELS]> {
    counts_from_stokes(&unit_stokes(field, r_nb, units), field.light_level(), true_cal, err, rng)
}

/// Stokes (S0, S1, S2) each unit sees (its own frame) for a field and a body attitude.
pub fn unit_stokes<F: LightField + ?Sized>(field: &F, r_nb: &Rotation3<f64>, units: &[UnitModel]) -> Vec<[f64; 3]> {
    let v3 = |x: [f32; 3]| Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
    units
        .iter()
        .map(|u| {
            let d = r_nb * v3(u.view_body);
            let a = r_nb * v3(u.axis0_body);
            let b = d.cross(&a);
            stokes(&field.radiance(d), &a, &b)
        })
        .collect()
}

/// Raw counts from the units' Stokes: auto-exposure to the brightest unit (as far as the
/// exposure can stretch at `light_level`), the true channel calibrations, shot and read noise,
/// 16-bit quantization.
pub fn counts_from_stokes<R: Rng>(
    stokes_all: &[[f64; 3]],
    light_level: f64,
    true_cal: &[[ChannelCal; CHANNELS]],
    err: &SensorErrors,
    rng: &mut R,
) -> Vec<[i16; CHANNELS]> {
    let max_s0 = stokes_all.iter().map(|s| s[0]).fold(0.0, f64::max);
    // A clear day's light level is the 1 of `light_level`.
    let stretch = (light_level * MAX_EXPOSURE_STRETCH).min(1.0);
    let scale = if max_s0 > 0.0 { err.exposure_counts / max_s0 * stretch } else { 0.0 };
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
    use crate::wrap_pi;
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

    fn aop_dolp(c: &Matrix3<f64>, v: Vector3<f64>) -> (f64, f64, f64) {
        let a = v.cross(&Vector3::z()).normalize();
        let st = stokes(c, &a, &v.cross(&a));
        (0.5 * st[2].atan2(st[1]), (st[1].powi(2) + st[2].powi(2)).sqrt() / st[0], st[0])
    }

    /// Under a flat sea with no skylight the sea model (line-of-sight quadrature over the
    /// footprint, field of view) agrees with the closed-form flat field: AoP within 0.5 deg,
    /// DoLP within 0.01, S0 within 3 % (the field of view's average is what differs).
    #[test]
    fn sea_field_flat_matches_closed_form() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let calm = crate::sea::Sea::new(crate::sea::SeaConfig::wind(0.0), 1);
        let s = sun(35.0, 20.0);
        let water = Water { polarization_table: false, ..Water::clear() };
        for depth in [2.0, 10.0, 40.0] {
            let flat = Field::new(s, water, depth, &mut rng);
            let sea = SeaField::new(s, SkyLight { direct: 1.0, diffuse: 0.0 }, &calm, water, depth, (0.0, 0.0), 0.0);
            for az in [0.0f64, 70.0, 150.0, 260.0] {
                let v = Vector3::new(az.to_radians().cos(), az.to_radians().sin(), -0.26).normalize();
                let (a0, d0, s0) = aop_dolp(&Field::radiance(&flat, v), v);
                let (a1, d1, s1) = aop_dolp(&LightField::radiance(&sea, v), v);
                assert!(wrap_pi(2.0 * (a1 - a0)).abs() / 2.0 < 0.5f64.to_radians(), "depth {depth} az {az}: {a0} {a1}");
                assert!((d1 - d0).abs() < 0.01 && (s1 / s0 - 1.0).abs() < 0.03, "depth {depth} az {az}: {d0} {d1} {s0} {s1}");
            }
        }
    }

    /// Overcast: no sun disc, the pattern is symmetric about the vertical (every e-vector
    /// horizontal, perpendicular to the vertical plane of the view) and weakly polarized; waves
    /// move the e-vectors of a sunlit field, more with more wind.
    #[test]
    fn sky_kinds_and_waves() {
        let calm = crate::sea::Sea::new(crate::sea::SeaConfig::wind(0.0), 1);
        let s = sun(35.0, 20.0);
        let over = SeaField::new(s, SkyKind::Overcast.light(0.0, 1), &calm, Water::clear(), 10.0, (0.0, 0.0), 0.0);
        let clear = SeaField::new(s, SkyKind::Clear.light(0.0, 1), &calm, Water::clear(), 10.0, (0.0, 0.0), 0.0);
        let (mut d_over, mut d_clear) = (0.0f64, 0.0f64);
        for az in [0.0f64, 100.0, 200.0, 300.0] {
            let v = Vector3::new(az.to_radians().cos(), az.to_radians().sin(), -0.26).normalize();
            let (a, d, _) = aop_dolp(&LightField::radiance(&over, v), v);
            let (_, dc, _) = aop_dolp(&LightField::radiance(&clear, v), v);
            assert!(wrap_pi(2.0 * a).abs() / 2.0 < 1e-6, "overcast e-vector horizontal: {a}");
            (d_over, d_clear) = (d_over.max(d), d_clear.max(dc));
        }
        assert!(d_over < d_clear, "overcast DoLP {d_over} below clear {d_clear}");
        assert!(over.light_level() < clear.light_level());
        assert!(SkyKind::Twilight.light(0.0, 1).diffuse * MAX_EXPOSURE_STRETCH < 1.0, "twilight is exposure-limited");
        // Partly cloudy: the sun is blocked some of the time, not always.
        let blocked = (0..600).filter(|t| SkyKind::PartlyCloudy.light(*t as f64, 3).direct < 0.1).count();
        assert!((60..400).contains(&blocked), "{blocked}/600 s blocked");
        let spread = |u: f64| {
            let sea = crate::sea::Sea::new(crate::sea::SeaConfig::wind(u), 4);
            let v = Vector3::new(0.0, 1.0, -0.26).normalize();
            let aops: Vec<f64> = (0..30)
                .map(|i| {
                    let f = SeaField::new(s, SkyKind::Clear.light(0.0, 1), &sea, Water::clear(), 5.0, (0.0, 0.0), 0.5 * i as f64);
                    aop_dolp(&LightField::radiance(&f, v), v).0
                })
                .collect();
            let m = aops.iter().sum::<f64>() / 30.0;
            (aops.iter().map(|a| (a - m).powi(2)).sum::<f64>() / 30.0).sqrt()
        };
        let (s0, s5, s12) = (spread(0.0), spread(5.0), spread(12.0));
        assert!(s0 < 1e-9 && s5 > 1e-4 && s12 > s5, "AoP spread calm {s0} 5 m/s {s5} 12 m/s {s12}");
    }
}
