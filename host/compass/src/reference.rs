//! The compass against a light field from outside: a downwelling Stokes field (I, Q, U) on a
//! view-zenith x relative-azimuth grid, as written by a vector radiative-transfer model (OSOAA;
//! the CSV format and frame convention of `../shared/reference/osoaa/README.md`) or measured.
//!
//! Why: our simulator (`subnav_base::sky`) and the compass's solver share one single-scattering
//! physics, so the compass agreeing with the simulator proves little. Here the head's units
//! (their geometry and field of view, calibration residuals, shot and read noise) look into the
//! external field at many body headings and tilts, and the real solver (`subnav_core::compass`,
//! the firmware's code) gives the heading; we score its error and its reported sigma.
//!
//! CSV: a header beginning `view_zenith_deg,rel_azimuth_deg,I,Q,U` (more columns allowed and
//! ignored), then one row per grid point. The reader is strict: a missing or non-numeric value,
//! NaN or infinity, a negative I, a polarized part larger than I, an angle out of range, a
//! duplicated point, a point missing from the grid or a grid that differs between azimuths is
//! refused with the line named. Frame (README): z up, x toward the sun's azimuth,
//! `rel_azimuth = A_sun - A_look`, Stokes in the meridian frame (l in the vertical plane of the
//! line of sight, r horizontal), `aop = 0.5 atan2(U, Q)`.

use std::collections::BTreeMap;
use std::fmt;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use subnav_base::sky::{self as sim, LightField, SensorErrors, UNIT_FOV_HALF_RAD};
use subnav_base::wrap_pi;
use subnav_core::compass::{self, CompassConfig, CompassInput};
use subnav_core::ephemeris;

use crate::montecarlo::{compass_config, draw_sun};

/// A bad reference file: the 1-based line and what is wrong with it.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldError {
    pub line: usize,
    pub message: String,
}

impl fmt::Display for FieldError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}: {}", self.line, self.message)
    }
}

impl std::error::Error for FieldError {}

/// The columns a reference file begins with.
pub const HEADER: [&str; 5] = ["view_zenith_deg", "rel_azimuth_deg", "I", "Q", "U"];

/// A downwelling Stokes field on a regular (not necessarily uniform) grid.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceField {
    /// View zeniths (rad, ascending) and relative azimuths (rad, ascending in [0, 2 pi)).
    pub zenith_rad: Vec<f64>,
    pub azimuth_rad: Vec<f64>,
    /// `stokes[ia * zenith.len() + iz] = [I, Q, U]`.
    pub stokes: Vec<[f64; 3]>,
}

fn err(line: usize, message: impl Into<String>) -> FieldError {
    FieldError { line, message: message.into() }
}

/// Angles are compared on a 1e-6 deg lattice.
fn key(deg: f64) -> i64 {
    (deg * 1e6).round() as i64
}

impl ReferenceField {
    /// Reads the CSV text (see the module doc). Errors name the 1-based line.
    pub fn parse(text: &str) -> Result<Self, FieldError> {
        let mut lines = text.lines().enumerate();
        let (_, header) = lines.next().ok_or_else(|| err(1, "empty file: expected the header view_zenith_deg,rel_azimuth_deg,I,Q,U"))?;
        let cols: Vec<&str> = header.trim_start_matches('\u{feff}').split(',').map(str::trim).collect();
        if cols.len() < HEADER.len() || cols.iter().zip(HEADER).any(|(c, h)| *c != h) {
            return Err(err(1, format!("header must begin with {}, found {:?}", HEADER.join(","), header.trim())));
        }
        // (zenith key, azimuth key) -> (line, stokes)
        let mut points: BTreeMap<(i64, i64), (usize, [f64; 3])> = BTreeMap::new();
        let mut first_line_of_az: BTreeMap<i64, usize> = BTreeMap::new();
        let mut last_line = 1;
        for (i, raw) in lines {
            let line = i + 1;
            if raw.trim().is_empty() {
                continue;
            }
            last_line = line;
            let f: Vec<&str> = raw.split(',').map(str::trim).collect();
            let mut v = [0.0f64; 5];
            for (k, name) in HEADER.iter().enumerate() {
                let s = f.get(k).copied().unwrap_or("");
                if s.is_empty() {
                    return Err(err(line, format!("missing {name}")));
                }
                let x: f64 = s.parse().map_err(|_| err(line, format!("{name} is not a number: {s:?}")))?;
                if !x.is_finite() {
                    return Err(err(line, format!("{name} is not finite: {s:?}")));
                }
                v[k] = x;
            }
            if f.len() > cols.len() {
                return Err(err(line, format!("{} fields, the header has {}", f.len(), cols.len())));
            }
            let [vz, az, i_, q, u] = v;
            if !(0.0..=90.0).contains(&vz) {
                return Err(err(line, format!("view_zenith_deg must be in 0..=90 (downwelling), got {vz}")));
            }
            if !(0.0..360.0).contains(&az) {
                return Err(err(line, format!("rel_azimuth_deg must be in 0..360, got {az}")));
            }
            if i_ < 0.0 {
                return Err(err(line, format!("negative I: {i_}")));
            }
            if (q * q + u * u).sqrt() > i_ * (1.0 + 1e-6) + 1e-30 {
                return Err(err(line, format!("polarized part sqrt(Q^2+U^2) = {:e} exceeds I = {i_:e}", (q * q + u * u).sqrt())));
            }
            let k = (key(vz), key(az));
            if let Some((prev, _)) = points.get(&k) {
                return Err(err(line, format!("duplicate point view_zenith_deg {vz}, rel_azimuth_deg {az} (first on line {prev})")));
            }
            points.insert(k, (line, [i_, q, u]));
            first_line_of_az.entry(k.1).or_insert(line);
        }
        if points.is_empty() {
            return Err(err(last_line + 1, "no data rows"));
        }
        // The grid: the zenith set shared by most azimuths; every azimuth must have exactly it.
        let mut per_az: BTreeMap<i64, Vec<i64>> = BTreeMap::new();
        for &(z, a) in points.keys() {
            per_az.entry(a).or_default().push(z);
        }
        let mut votes: BTreeMap<&Vec<i64>, usize> = BTreeMap::new();
        for zs in per_az.values() {
            *votes.entry(zs).or_insert(0) += 1;
        }
        let grid_z: Vec<i64> = votes.iter().max_by_key(|(_, n)| **n).map(|(z, _)| (*z).clone()).unwrap_or_default();
        let list = |zs: &[i64]| zs.iter().map(|z| format!("{}", *z as f64 * 1e-6)).collect::<Vec<_>>().join(", ");
        for (&a, zs) in &per_az {
            if zs == &grid_z {
                continue;
            }
            let az_deg = a as f64 * 1e-6;
            if let Some(extra) = zs.iter().find(|z| !grid_z.contains(z)) {
                let line = points.get(&(*extra, a)).map_or(0, |p| p.0);
                return Err(err(
                    line,
                    format!(
                        "inconsistent grid: view_zenith_deg {} at rel_azimuth_deg {az_deg} is not on the zenith grid of the other azimuths ({})",
                        *extra as f64 * 1e-6,
                        list(&grid_z)
                    ),
                ));
            }
            let missing = grid_z.iter().find(|z| !zs.contains(z)).copied().unwrap_or(0);
            // Name the line where the missing row would be: after the row of the next lower
            // zenith of this azimuth (or the azimuth's first line).
            let line = zs
                .iter()
                .filter(|z| **z < missing)
                .max()
                .and_then(|z| points.get(&(*z, a)))
                .map_or_else(|| first_line_of_az.get(&a).copied().unwrap_or(0), |p| p.0 + 1);
            return Err(err(
                line,
                format!(
                    "missing angles: no row for view_zenith_deg {} at rel_azimuth_deg {az_deg} (the zenith grid of the other azimuths is {})",
                    missing as f64 * 1e-6,
                    list(&grid_z)
                ),
            ));
        }
        let azs: Vec<i64> = per_az.keys().copied().collect();
        if grid_z.len() < 2 || azs.len() < 4 {
            return Err(err(last_line, format!("grid too small: {} zeniths x {} azimuths (need >= 2 x 4)", grid_z.len(), azs.len())));
        }
        // Azimuth gaps: at most 90 deg around the circle, so the interpolation never bridges a
        // missing half of the field.
        let mut gaps = azs.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>();
        gaps.push(azs[0] + key(360.0) - azs[azs.len() - 1]);
        if let Some(g) = gaps.iter().find(|g| **g > key(90.0)) {
            return Err(err(last_line, format!("the azimuths leave a gap of {} deg (at most 90 allowed)", *g as f64 * 1e-6)));
        }
        let mut stokes = Vec::with_capacity(azs.len() * grid_z.len());
        for &a in &azs {
            for &z in &grid_z {
                stokes.push(points.get(&(z, a)).map_or([0.0; 3], |p| p.1));
            }
        }
        Ok(ReferenceField {
            zenith_rad: grid_z.iter().map(|z| (*z as f64 * 1e-6).to_radians()).collect(),
            azimuth_rad: azs.iter().map(|a| (*a as f64 * 1e-6).to_radians()).collect(),
            stokes,
        })
    }

    /// Largest view zenith of the grid (rad).
    pub fn max_zenith_rad(&self) -> f64 {
        self.zenith_rad.last().copied().unwrap_or(0.0)
    }

    /// Stokes (I, Q, U) at a view zenith and relative azimuth (rad), bilinear in both (cyclic in
    /// azimuth); `None` outside the zenith range.
    pub fn stokes_at(&self, zenith_rad: f64, rel_azimuth_rad: f64) -> Option<[f64; 3]> {
        let zs = &self.zenith_rad;
        let (z0, z1) = (*zs.first()?, *zs.last()?);
        if !(zenith_rad >= z0 - 1e-9 && zenith_rad <= z1 + 1e-9) {
            return None;
        }
        let iz = zs.partition_point(|z| *z <= zenith_rad).clamp(1, zs.len() - 1);
        let tz = ((zenith_rad - zs[iz - 1]) / (zs[iz] - zs[iz - 1])).clamp(0.0, 1.0);
        let azs = &self.azimuth_rad;
        let tau = std::f64::consts::TAU;
        let phi = rel_azimuth_rad.rem_euclid(tau);
        // Bracketing azimuths, cyclic.
        let ia = azs.partition_point(|a| *a <= phi);
        let (a_lo, a_hi, i_lo, i_hi) = if ia == 0 {
            (azs[azs.len() - 1] - tau, azs[0], azs.len() - 1, 0)
        } else if ia == azs.len() {
            (azs[ia - 1], azs[0] + tau, ia - 1, 0)
        } else {
            (azs[ia - 1], azs[ia], ia - 1, ia)
        };
        let ta = ((phi - a_lo) / (a_hi - a_lo)).clamp(0.0, 1.0);
        let nz = zs.len();
        let at = |ia: usize, iz: usize| self.stokes[ia * nz + iz];
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let lo = at(i_lo, iz - 1)[k] * (1.0 - tz) + at(i_lo, iz)[k] * tz;
            let hi = at(i_hi, iz - 1)[k] * (1.0 - tz) + at(i_hi, iz)[k] * tz;
            *o = lo * (1.0 - ta) + hi * ta;
        }
        Some(out)
    }
}

/// Meridian frame and coherency: `subnav_base::osoaa`'s (the simulator's departure table uses
/// the same convention).
pub use subnav_base::osoaa::{coherency, meridian_frame};

/// The reference field around a sun at a NED azimuth, seen by a unit with the head's field of
/// view (averaged, as `subnav_base::sky::SeaField` does, over the view turned about the vertical
/// by -half, 0 and +half of the field of view). Directions outside the grid are dark.
pub struct PlacedField<'a> {
    pub field: &'a ReferenceField,
    pub sun_az_rad: f64,
}

impl PlacedField<'_> {
    fn point(&self, v: Vector3<f64>) -> Matrix3<f64> {
        let (theta, phi, l, r) = meridian_frame(v, self.sun_az_rad);
        self.field.stokes_at(theta, phi).map_or_else(Matrix3::zeros, |s| coherency(s, &l, &r))
    }

    /// Whether every field-of-view sample of a look direction is on the grid.
    pub fn covers(&self, v: Vector3<f64>) -> bool {
        let theta = (-v.normalize().z).clamp(-1.0, 1.0).acos();
        theta <= self.field.max_zenith_rad() + 1e-9 && theta >= self.field.zenith_rad.first().copied().unwrap_or(0.0) - 1e-9
    }
}

impl LightField for PlacedField<'_> {
    fn radiance(&self, v: Vector3<f64>) -> Matrix3<f64> {
        // Turning about the vertical keeps the view zenith (the grid's edge stays the edge);
        // the turn is scaled so the view moves by the half field of view.
        let v = v.normalize();
        let horiz = (v.x * v.x + v.y * v.y).sqrt().max(0.1);
        let mut acc = Matrix3::zeros();
        for f in [-1.0, 0.0, 1.0] {
            let vf = Rotation3::from_axis_angle(&Vector3::z_axis(), f * UNIT_FOV_HALF_RAD / horiz) * v;
            acc += self.point(vf);
        }
        acc / 3.0
    }
}

impl ReferenceField {
    /// The CSV of this field (the reference format: `view_zenith_deg,rel_azimuth_deg,I,Q,U`,
    /// then `dolp,aop_deg` for reading), azimuth-major as the OSOAA files.
    pub fn to_csv(&self) -> String {
        let mut out = String::from("view_zenith_deg,rel_azimuth_deg,I,Q,U,dolp,aop_deg\n");
        let nz = self.zenith_rad.len();
        for (ia, a) in self.azimuth_rad.iter().enumerate() {
            for (iz, z) in self.zenith_rad.iter().enumerate() {
                let [i, q, u] = self.stokes[ia * nz + iz];
                let dolp = if i > 0.0 { (q * q + u * u).sqrt() / i } else { 0.0 };
                out += &format!(
                    "{:.2},{:.0},{:.6e},{:.6e},{:.6e},{:.5},{:.2}\n",
                    z.to_degrees(),
                    a.to_degrees(),
                    i,
                    q,
                    u,
                    dolp,
                    (0.5 * u.atan2(q)).to_degrees()
                );
            }
        }
        out
    }

    /// The simulator's own downwelling field (`subnav_base::sky::SeaField`: the sun at
    /// `sun_zenith_deg` under a clear sky, the water, with its departure table) on the reference
    /// grid: view zenith 0-80 deg by 5, relative azimuth 0-345 by 15. Under wind the mean of
    /// the Stokes over [`SEA_INSTANTS`] instants 0.7 s apart of a moving sea (the reference is a
    /// mean over the sea's slopes). I is in the simulator's own unit (irradiance-normalised);
    /// compare DoLP and AoP.
    pub fn simulated(sun_zenith_deg: f64, depth_m: f64, wind_mps: f64, water: sim::Water, seed: u64) -> Self {
        let table = if water.polarization_table { subnav_base::osoaa::Table::osoaa() } else { None };
        Self::simulated_with(sun_zenith_deg, depth_m, wind_mps, water, seed, table)
    }

    /// [`ReferenceField::simulated`] with a given departure table (None: pure single scattering).
    pub fn simulated_with(
        sun_zenith_deg: f64,
        depth_m: f64,
        wind_mps: f64,
        water: sim::Water,
        seed: u64,
        table: Option<&subnav_base::osoaa::Table>,
    ) -> Self {
        let sea = subnav_base::sea::Sea::new(subnav_base::sea::SeaConfig::wind(wind_mps), seed);
        let z = sun_zenith_deg.to_radians();
        let sun_ned = Vector3::new(z.sin(), 0.0, -z.cos()); // sun azimuth 0 (north)
        let instants = if sea.is_flat() { 1 } else { SEA_INSTANTS };
        let fields: Vec<_> = (0..instants)
            .map(|k| {
                sim::SeaField::new(sun_ned, sim::SkyKind::Clear.light(0.0, seed), &sea, water, depth_m, (0.0, 0.0), 0.7 * k as f64)
                    .with_table(table)
            })
            .collect();
        let zenith_rad: Vec<f64> = (0..=16).map(|i| (5.0 * i as f64).to_radians()).collect();
        let azimuth_rad: Vec<f64> = (0..24).map(|i| (15.0 * i as f64).to_radians()).collect();
        let mut stokes = Vec::with_capacity(zenith_rad.len() * azimuth_rad.len());
        for &phi in &azimuth_rad {
            for &theta in &zenith_rad {
                // A_look = A_sun - phi with A_sun = 0.
                let a_look = -phi;
                let v = Vector3::new(theta.sin() * a_look.cos(), theta.sin() * a_look.sin(), -theta.cos());
                // The frame from the grid's own azimuth (at the zenith, v alone does not fix it).
                let (st, ct) = theta.sin_cos();
                let (sp, cp) = phi.sin_cos();
                let (x, y, up) = (Vector3::x(), -Vector3::y(), -Vector3::z());
                let l = x * (-ct * cp) + y * (-ct * sp) + up * st;
                let r = x * (-sp) + y * cp;
                let mut acc = [0.0; 3];
                for f in &fields {
                    let s = sim::stokes(&LightField::radiance(f, v), &l, &r);
                    for k in 0..3 {
                        acc[k] += s[k] / instants as f64;
                    }
                }
                stokes.push(acc);
            }
        }
        ReferenceField { zenith_rad, azimuth_rad, stokes }
    }
}

/// Instants of a moving sea averaged by [`ReferenceField::simulated`].
pub const SEA_INSTANTS: usize = 16;

/// How two fields on the same grid differ: AoP (where both DoLPs exceed a threshold) and DoLP.
#[derive(Debug, Clone, Serialize)]
pub struct FieldComparison {
    /// Grid points compared for AoP (DoLP above the threshold in the reference) and in all.
    pub aop_points: usize,
    pub points: usize,
    pub aop_rms_deg: f64,
    pub aop_max_abs_deg: f64,
    pub dolp_rms: f64,
    pub dolp_max_abs: f64,
}

/// Compares `sim` with `reference` at the reference's grid points up to `max_zenith_deg`:
/// DoLP everywhere, AoP where the reference's DoLP exceeds `min_dolp`. `None` when the grids
/// differ.
pub fn compare(sim: &ReferenceField, reference: &ReferenceField, min_dolp: f64, max_zenith_deg: f64) -> Option<FieldComparison> {
    if sim.zenith_rad.len() != reference.zenith_rad.len() || sim.azimuth_rad.len() != reference.azimuth_rad.len() {
        return None;
    }
    let same = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    if !same(&sim.zenith_rad, &reference.zenith_rad) || !same(&sim.azimuth_rad, &reference.azimuth_rad) {
        return None;
    }
    let nz = reference.zenith_rad.len();
    let (mut n, mut na, mut a2, mut amax, mut d2, mut dmax) = (0usize, 0usize, 0.0, 0.0f64, 0.0, 0.0f64);
    for (ia, _) in reference.azimuth_rad.iter().enumerate() {
        for (iz, z) in reference.zenith_rad.iter().enumerate() {
            if z.to_degrees() > max_zenith_deg + 1e-9 {
                continue;
            }
            let (r, s) = (reference.stokes[ia * nz + iz], sim.stokes[ia * nz + iz]);
            let dolp = |x: [f64; 3]| if x[0] > 0.0 { (x[1] * x[1] + x[2] * x[2]).sqrt() / x[0] } else { 0.0 };
            let dd = dolp(s) - dolp(r);
            n += 1;
            d2 += dd * dd;
            dmax = dmax.max(dd.abs());
            if dolp(r) > min_dolp {
                let da = wrap_pi(s[2].atan2(s[1]) - r[2].atan2(r[1])) / 2.0;
                na += 1;
                a2 += da * da;
                amax = amax.max(da.abs());
            }
        }
    }
    Some(FieldComparison {
        aop_points: na,
        points: n,
        aop_rms_deg: (a2 / na.max(1) as f64).sqrt().to_degrees(),
        aop_max_abs_deg: amax.to_degrees(),
        dolp_rms: (d2 / n.max(1) as f64).sqrt(),
        dolp_max_abs: dmax,
    })
}

/// One run of the compass in a reference field.
#[derive(Debug, Clone)]
pub struct ReferenceConfig {
    /// Sun zenith (in air, deg) and sensor depth (m) the file was made for.
    pub sun_zenith_deg: f64,
    pub depth_m: f64,
    pub draws: usize,
    pub units: usize,
    /// Body tilt drawn uniformly within a cone of this half angle (deg), heading uniform.
    pub max_tilt_deg: f64,
    pub tilt_sigma_rad: f64,
    pub errors: SensorErrors,
    pub seed: u64,
    /// Run the single-scattering solver (`head::compass_config_single_scattering`, the head's
    /// before issue 35) instead of the head's (`head::compass_config`).
    pub single_scattering_solver: bool,
    /// The AoP departure table issue 35's solver subtracts (`subnav_core::compass::departure`).
    pub departure: DepartureTable,
}

/// Which AoP departure table the solver uses in [`run`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DepartureTable {
    /// None (the model-departure sigma and the azimuth fit alone).
    Off,
    /// The head's (`OSOAA_CLEAR`: every depth and wind of OSOAA's clear water, so on these
    /// fields partly the table agreeing with itself).
    Head,
    /// Built from the other depths than the run's (`--depth-m`): the leave-one-out check.
    #[default]
    LeaveDepthOut,
}

impl Default for ReferenceConfig {
    fn default() -> Self {
        ReferenceConfig {
            sun_zenith_deg: 30.0,
            depth_m: 10.0,
            draws: 2000,
            units: subnav_core::head::POLARIZATION_UNITS,
            max_tilt_deg: 5.0,
            tilt_sigma_rad: 0.01f64.to_radians(),
            errors: SensorErrors::default(),
            seed: 1,
            single_scattering_solver: false,
            departure: DepartureTable::default(),
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct ReferenceResult {
    pub sun_zenith_deg: f64,
    pub depth_m: f64,
    pub units: usize,
    pub draws: usize,
    pub fixes: usize,
    pub no_fix_fraction: f64,
    pub no_fix: BTreeMap<String, usize>,
    /// Error statistics over the fixes (NaN, `null` in JSON, without fixes).
    pub rmse_deg: f64,
    pub max_abs_err_deg: f64,
    pub bias_deg: f64,
    /// Fraction of fixes within 2 and 3 reported sigma, and the RMS reported sigma.
    pub within_2_sigma: f64,
    pub within_3_sigma: f64,
    pub rms_reported_sigma_deg: f64,
    /// Mean DoLP of the units the solver kept.
    pub mean_dolp: f64,
}

/// The largest body tilt (deg) that keeps every unit of the head on the grid.
pub fn max_tilt_on_grid_deg(field: &ReferenceField) -> f64 {
    let el = subnav_core::head::POLARIZATION_UNIT_ELEVATION_RAD as f64;
    (field.max_zenith_rad() - (std::f64::consts::FRAC_PI_2 - el)).to_degrees()
}

/// Runs the head's units and the real solver in the field (module doc).
pub fn run(field: &ReferenceField, cfg: &ReferenceConfig) -> ReferenceResult {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let units = sim::default_units(cfg.units);
    // The head's settings (the firmware's) or the single-scattering solver's.
    let base = if cfg.single_scattering_solver {
        subnav_core::head::compass_config_single_scattering()
    } else {
        subnav_core::head::compass_config()
    };
    let host = compass_config(&sim::Water::clear(), cfg.tilt_sigma_rad);
    // n = 1.34: OSOAA's index (README).
    let aop_departure: Option<&'static compass::departure::AopDeparture> = match cfg.departure {
        _ if cfg.single_scattering_solver => None,
        DepartureTable::Off => None,
        DepartureTable::Head => Some(&compass::departure::OSOAA_CLEAR),
        DepartureTable::LeaveDepthOut => {
            subnav_base::osoaa::Table::osoaa().map(|t| &*Box::leak(Box::new(crate::departure::aop_departure(t, 1.34, Some(cfg.depth_m)))))
        }
    };
    let ccfg = CompassConfig { min_s0: host.min_s0, tilt_sigma_rad: host.tilt_sigma_rad, n_water: 1.34, aop_departure, ..base };
    let el_deg = 90.0 - cfg.sun_zenith_deg;
    let v3 = |x: [f32; 3]| Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
    let (mut errs, mut no_fix) = (Vec::new(), BTreeMap::new());
    let (mut dolp_sum, mut dolp_n) = (0.0, 0usize);
    let mut sun = draw_sun(&mut rng, el_deg - 0.25, el_deg + 0.25);
    let mut attempts = 0usize;
    while errs.len() + no_fix.values().sum::<usize>() < cfg.draws {
        attempts += 1;
        if attempts % 50 == 0 {
            sun = draw_sun(&mut rng, el_deg - 0.25, el_deg + 0.25);
        }
        let (t, obs, p) = sun;
        let placed = PlacedField { field, sun_az_rad: p.azimuth_rad as f64 };
        let yaw = rng.random_range(0.0..std::f64::consts::TAU);
        let tilt = cfg.max_tilt_deg.to_radians() * rng.random_range(0.0f64..1.0).sqrt();
        let dir = rng.random_range(0.0..std::f64::consts::TAU);
        let r_nb = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
            * Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(Vector3::new(dir.cos(), dir.sin(), 0.0)), tilt);
        if !units.iter().all(|u| placed.covers(r_nb * v3(u.view_body))) {
            // Only when the caller asked for more tilt than the grid covers.
            *no_fix.entry("OutsideReferenceGrid".to_string()).or_insert(0) += 1;
            continue;
        }
        let cal: Vec<_> = units.iter().map(|u| sim::true_channels(u, &cfg.errors, &mut rng)).collect();
        let counts = sim::counts(&placed, &r_nb, &units, &cal, &cfg.errors, &mut rng);
        let accel = sim::accel(&r_nb, cfg.tilt_sigma_rad, &mut rng);
        if let Ok(good) = compass::observe_units(&units, &counts, &ccfg) {
            for o in &good {
                dolp_sum += o.dolp as f64;
                dolp_n += 1;
            }
        }
        // The true heading of the body x axis projected on the horizontal.
        let x = r_nb * Vector3::x();
        let true_h = x.y.atan2(x.x);
        let input = CompassInput {
            counts: &counts,
            accel_body_mps2: accel,
            unix_us: Some(t),
            observer: Some(obs),
            delta_t_s: ephemeris::delta_t_estimate_s(t),
        };
        match compass::solve(&units, &input, &ccfg) {
            Ok(fix) => errs.push((wrap_pi(fix.heading_rad as f64 - true_h), fix.sigma_heading_rad as f64)),
            Err((r, _)) => *no_fix.entry(format!("{r:?}")).or_insert(0) += 1,
        }
    }
    let n = errs.len();
    // No fixes: the error statistics are undefined (NaN, `null` in JSON), not 0.
    let nf = if n > 0 { n as f64 } else { f64::NAN };
    let deg = |x: f64| x.to_degrees();
    ReferenceResult {
        sun_zenith_deg: cfg.sun_zenith_deg,
        depth_m: cfg.depth_m,
        units: cfg.units,
        draws: cfg.draws,
        fixes: n,
        no_fix_fraction: 1.0 - n as f64 / cfg.draws.max(1) as f64,
        no_fix,
        rmse_deg: deg((errs.iter().map(|e| e.0 * e.0).sum::<f64>() / nf).sqrt()),
        max_abs_err_deg: if n > 0 { deg(errs.iter().map(|e| e.0.abs()).fold(0.0, f64::max)) } else { f64::NAN },
        bias_deg: deg(errs.iter().map(|e| e.0).sum::<f64>() / nf),
        within_2_sigma: errs.iter().filter(|e| e.0.abs() <= 2.0 * e.1).count() as f64 / nf,
        within_3_sigma: errs.iter().filter(|e| e.0.abs() <= 3.0 * e.1).count() as f64 / nf,
        rms_reported_sigma_deg: deg((errs.iter().map(|e| e.1 * e.1).sum::<f64>() / nf).sqrt()),
        mean_dolp: if dolp_n > 0 { dolp_sum / dolp_n as f64 } else { 0.0 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_text() -> String {
        let mut s = String::from("view_zenith_deg,rel_azimuth_deg,I,Q,U,dolp\n");
        for a in (0..360).step_by(90) {
            for z in [0, 40, 80] {
                s += &format!("{z},{a},1.0,0.1,0.05,0.1\n");
            }
        }
        s
    }

    #[test]
    fn parses_a_good_grid() {
        let f = ReferenceField::parse(&grid_text()).unwrap();
        assert_eq!((f.zenith_rad.len(), f.azimuth_rad.len()), (3, 4));
        let s = f.stokes_at(0.5, 1.0).unwrap();
        assert!((s[0] - 1.0).abs() < 1e-12 && (s[1] - 0.1).abs() < 1e-12);
        assert!(f.stokes_at(81f64.to_radians(), 0.0).is_none());
    }

    fn refused(text: &str) -> FieldError {
        ReferenceField::parse(text).expect_err("must be refused")
    }

    #[test]
    fn refuses_bad_input_naming_the_line() {
        let good = grid_text();
        let lines: Vec<&str> = good.lines().collect();
        let with = |i: usize, row: &str| {
            let mut l = lines.clone();
            l[i] = row;
            l.join("\n")
        };
        let e = refused(&with(0, "zenith,azimuth,I,Q,U"));
        assert!(e.line == 1 && e.message.contains("header"), "{e}");
        let e = refused(&with(3, "80,0,1.0,NaN,0.0"));
        assert!(e.line == 4 && e.message.contains("not finite"), "{e}");
        let e = refused(&with(5, "40,90,-1.0,0.0,0.0"));
        assert!(e.line == 6 && e.message.contains("negative I"), "{e}");
        let e = refused(&with(5, ",90,1.0,0.0,0.0"));
        assert!(e.line == 6 && e.message.contains("missing view_zenith_deg"), "{e}");
        let e = refused(&with(5, "40,90,1.0,0.0"));
        assert!(e.line == 6 && e.message.contains("missing U"), "{e}");
        let e = refused(&with(5, "40,90,1.0,2.0,0.0"));
        assert!(e.line == 6 && e.message.contains("exceeds I"), "{e}");
        // A row moved off the grid: an inconsistent grid, named at that row.
        let e = refused(&with(5, "45,90,1.0,0.0,0.0"));
        assert!(e.line == 6 && e.message.contains("inconsistent grid"), "{e}");
        // A row left out: missing angles, named where it would be.
        let mut l = lines.clone();
        l.remove(5);
        let e = refused(&l.join("\n"));
        assert!(e.line == 6 && e.message.contains("missing angles") && e.message.contains("view_zenith_deg 40"), "{e}");
        // A duplicate.
        let e = refused(&with(5, "0,90,1.0,0.0,0.0"));
        assert!(e.line == 6 && e.message.contains("duplicate"), "{e}");
        assert_eq!(refused("").line, 1);
        assert!(refused("view_zenith_deg,rel_azimuth_deg,I,Q,U\n").message.contains("no data"));
    }

    /// The frame recipe of the README: an e-vector perpendicular to the scattering plane of a
    /// sun straight ahead gives aop = +-90 (horizontal) when looking toward the sun, and the
    /// coherency round-trips through `subnav_base::sky::stokes`.
    #[test]
    fn frame_and_coherency_round_trip() {
        let sun_az = 0.7f64;
        for (az, el) in [(0.3f64, 0.26f64), (2.0, 0.5), (4.0, 0.1)] {
            let v = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
            let (theta, phi, l, r) = meridian_frame(v, sun_az);
            assert!((theta - (std::f64::consts::FRAC_PI_2 - el)).abs() < 1e-12);
            assert!((phi - (sun_az - az).rem_euclid(std::f64::consts::TAU)).abs() < 1e-12);
            // (l, r, k) right-handed with k = -v.
            assert!((l.cross(&r) + v).norm() < 1e-12 && l.z < 0.0);
            let s = [2.0, 0.3, -0.4];
            let c = coherency(s, &l, &r);
            let back = sim::stokes(&c, &l, &r);
            for k in 0..3 {
                assert!((back[k] - s[k]).abs() < 1e-12);
            }
        }
    }

    /// A field that is exactly single-scattering (e-vector perpendicular to the plane of the
    /// refracted sun and the view) gives the solver its own physics: the heading is right.
    #[test]
    fn single_scattering_grid_gives_the_heading() {
        let sza = 30f64.to_radians();
        let sun_w = (sza.sin() / 1.34).asin();
        let s_ref = Vector3::new(sun_w.sin(), 0.0, sun_w.cos()); // toward the refracted sun, z up
        let mut text = String::from("view_zenith_deg,rel_azimuth_deg,I,Q,U\n");
        for a in (0..360).step_by(15) {
            for z in (0..=80).step_by(5) {
                let (t, p) = ((z as f64).to_radians(), (a as f64).to_radians());
                let d = Vector3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
                let l = Vector3::new(-t.cos() * p.cos(), -t.cos() * p.sin(), t.sin());
                let r = Vector3::new(-p.sin(), p.cos(), 0.0);
                let e = d.cross(&s_ref);
                let (q, u) = if e.norm() > 1e-9 {
                    let chi = e.dot(&r).atan2(e.dot(&l));
                    (0.4 * (2.0 * chi).cos(), 0.4 * (2.0 * chi).sin())
                } else {
                    (0.0, 0.0)
                };
                text += &format!("{z},{a},1.0,{q},{u}\n");
            }
        }
        let f = ReferenceField::parse(&text).unwrap();
        let r = run(&f, &ReferenceConfig { draws: 200, ..ReferenceConfig::default() });
        assert!(r.fixes >= 190, "{r:?}");
        assert!(r.rmse_deg < 1.0 && r.bias_deg.abs() < 0.2, "{r:?}");
    }
}
