//! The polarization of the real underwater light field from a radiative-transfer table: the
//! departure of the downwelling DoLP and AoP from what [`crate::sky`]'s single-scattering model
//! predicts, taken from 24 fields computed by OSOAA V2.0 (vector successive orders of the
//! coupled atmosphere-ocean: polarized multiple scattering, a polarized sky, Mie hydrosols).
//!
//! Why a table: the simulator draws its field from single scattering of the refracted sun
//! (multiple scattering an unpolarized background, particles that do not polarize); the real
//! field's AoP departs from that by degrees and its DoLP is 0.1-0.25 higher (issue 35). Writing a
//! vector radiative-transfer solver is out of reach here; the issue allows a precomputed table
//! from one if its origin and licence are stated and the code that uses it is ours.
//!
//! Data: `host/base/data/osoaa_polarization.csv` (origin, licence and how it was made:
//! `host/base/data/OSOAA_PROVENANCE.md`): per case (sun zenith 30 and 60 deg in air, wind 0 and
//! 5 m/s, OSOAA's clear and turbid water, depth 5, 10 and 20 m) the normalized Stokes `q = Q/I`,
//! `u = U/I` in the meridian frame on view zenith 0-80 deg by 5 x relative azimuth 0-180 by 15
//! (the other half by the fields' mirror symmetry).
//!
//! How a field uses it ([`Departure::apply`]): at a look direction the table's (q, u) at the
//! bracketing cases, minus the simulator's own mean (flat-sea, clear-sky) field at the same
//! cases' geometry, is added to the simulator's (q, u); I stays the simulator's. At a table case
//! under a flat sea the result is the table's field exactly; a moving sea adds its own
//! fluctuation about it. Between and outside the cases:
//! - water: by its single-scattering albedo `b / c` between OSOAA's clear (0.75) and turbid
//!   (0.925), linear, held at the nearer one outside;
//! - depth: by optical depth `c z`, linear between a water's cases (5, 10, 20 m of its `c`),
//!   held at the nearest case shallower than 5 m and deeper up to twice the deepest case's
//!   optical depth; beyond that the departure fades as the simulator's own DoLP falls from there;
//! - wind: linear between 0 and 5 m/s, held at 5 m/s above;
//! - sun zenith: linear between 30 and 60 deg, held at the nearer outside (the departure, not
//!   the field: the single-scattering pattern still follows the real sun);
//! - view zenith beyond 80 deg: held at 80; looking down (upwelling light): no departure;
//! - the departure is scaled by the direct sun's share (the table's fields are clear-sky): none
//!   under an overcast sky or at twilight, where the simulator's field stays symmetric.

use std::sync::OnceLock;

use nalgebra::{Matrix3, Vector3};

/// The embedded table (module doc).
pub const TABLE_CSV: &str = include_str!("../data/osoaa_polarization.csv");

/// OSOAA's waters (`../shared/reference/osoaa/README.md`): beam attenuation (1/m) and
/// single-scattering albedo.
pub const CLEAR_C_PER_M: f64 = 0.109;
pub const CLEAR_ALBEDO: f64 = 0.75;
pub const TURBID_C_PER_M: f64 = 1.056;
pub const TURBID_ALBEDO: f64 = 0.925;

/// The grid of every case: view zenith 0-80 by 5, relative azimuth 0-180 by 15 (deg).
pub const ZENITHS: usize = 17;
pub const AZIMUTHS: usize = 13;
const ZENITH_STEP_DEG: f64 = 5.0;
const AZIMUTH_STEP_DEG: f64 = 15.0;

/// One OSOAA case: its conditions and (q, u) on the grid (`[iz * AZIMUTHS + ia]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    pub sun_zenith_deg: f64,
    pub wind_mps: f64,
    pub turbid: bool,
    pub depth_m: f64,
    pub qu: Vec<[f64; 2]>,
}

impl Case {
    /// Beam attenuation of the case's water (1/m).
    pub fn c_per_m(&self) -> f64 {
        if self.turbid { TURBID_C_PER_M } else { CLEAR_C_PER_M }
    }

    /// (q, u) in the meridian frame at a view zenith and relative azimuth (rad), bilinear; the
    /// azimuth mirrored into 0-180 deg (u changes sign), the zenith held at the grid's edge.
    pub fn qu_at(&self, zenith_rad: f64, rel_azimuth_rad: f64) -> [f64; 2] {
        let mut phi = rel_azimuth_rad.to_degrees().rem_euclid(360.0);
        let sign = if phi > 180.0 {
            phi = 360.0 - phi;
            -1.0
        } else {
            1.0
        };
        let z = (zenith_rad.to_degrees() / ZENITH_STEP_DEG).clamp(0.0, (ZENITHS - 1) as f64);
        let a = (phi / AZIMUTH_STEP_DEG).clamp(0.0, (AZIMUTHS - 1) as f64);
        let (iz, ia) = ((z.floor() as usize).min(ZENITHS - 2), (a.floor() as usize).min(AZIMUTHS - 2));
        let (tz, ta) = (z - iz as f64, a - ia as f64);
        let at = |iz: usize, ia: usize| self.qu[iz * AZIMUTHS + ia];
        let mut out = [0.0; 2];
        for (k, o) in out.iter_mut().enumerate() {
            let lo = at(iz, ia)[k] * (1.0 - ta) + at(iz, ia + 1)[k] * ta;
            let hi = at(iz + 1, ia)[k] * (1.0 - ta) + at(iz + 1, ia + 1)[k] * ta;
            *o = lo * (1.0 - tz) + hi * tz;
        }
        [out[0], sign * out[1]]
    }
}

/// Which cases a leave-one-out check removes (see [`Table::without`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LeaveOut {
    /// The case itself: its depth comes from the other depths of its sun, wind and water.
    Depth,
    /// Its wind for its water (every sun and depth): the other wind's departure.
    Wind,
    /// Its sun zenith for its water and wind: the other sun's departure.
    Sun,
    /// Its water: the other water's departure.
    Water,
}

/// The OSOAA cases (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub cases: Vec<Case>,
}

/// A table case used at a look direction with its weight, and the depth (m) in the simulated
/// water with the case's optical depth.
#[derive(Debug, Clone, Copy)]
pub struct Node<'a> {
    pub case: &'a Case,
    pub weight: f64,
    pub depth_m: f64,
    /// The water's deepest case, held for a greater optical depth.
    pub beyond_deepest: bool,
}

/// Linear weights of `x` between the bracketing values of `xs` (sorted, distinct), held at the
/// ends: (index, weight) pairs.
fn weights(xs: &[f64], x: f64) -> Vec<(usize, f64)> {
    match xs.len() {
        0 => vec![],
        1 => vec![(0, 1.0)],
        n => {
            if x <= xs[0] {
                vec![(0, 1.0)]
            } else if x >= xs[n - 1] {
                vec![(n - 1, 1.0)]
            } else {
                let i = xs.partition_point(|v| *v <= x).clamp(1, n - 1);
                let t = (x - xs[i - 1]) / (xs[i] - xs[i - 1]);
                // On a case to rounding: that case alone.
                if t < 1e-9 {
                    vec![(i - 1, 1.0)]
                } else if t > 1.0 - 1e-9 {
                    vec![(i, 1.0)]
                } else {
                    vec![(i - 1, 1.0 - t), (i, t)]
                }
            }
        }
    }
}

fn distinct(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

impl Table {
    /// Parses the table's CSV (`sun_zenith_deg,wind_mps,water,depth_m,view_zenith_deg,
    /// rel_azimuth_deg,q,u`); every case must fill the grid exactly once.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text.lines().enumerate();
        let header = lines.next().map(|(_, h)| h.trim()).unwrap_or("");
        if header != "sun_zenith_deg,wind_mps,water,depth_m,view_zenith_deg,rel_azimuth_deg,q,u" {
            return Err(format!("line 1: unexpected header {header:?}"));
        }
        let mut cases: Vec<(Case, Vec<bool>)> = Vec::new();
        for (i, raw) in lines {
            let line = i + 1;
            if raw.trim().is_empty() {
                continue;
            }
            let f: Vec<&str> = raw.split(',').map(str::trim).collect();
            if f.len() != 8 {
                return Err(format!("line {line}: {} fields, expected 8", f.len()));
            }
            let num = |k: usize| -> Result<f64, String> {
                f[k].parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("line {line}: field {} is not a number: {:?}", k + 1, f[k]))
            };
            let turbid = match f[2] {
                "clear" => false,
                "turbid" => true,
                w => return Err(format!("line {line}: water must be clear or turbid, got {w:?}")),
            };
            let (sz, wind, depth, vz, az, q, u) = (num(0)?, num(1)?, num(3)?, num(4)?, num(5)?, num(6)?, num(7)?);
            let (iz, ia) = ((vz / ZENITH_STEP_DEG).round(), (az / AZIMUTH_STEP_DEG).round());
            if (iz * ZENITH_STEP_DEG - vz).abs() > 1e-6 || !(0.0..ZENITHS as f64).contains(&iz) {
                return Err(format!("line {line}: view_zenith_deg {vz} is not on the 0-80 by 5 grid"));
            }
            if (ia * AZIMUTH_STEP_DEG - az).abs() > 1e-6 || !(0.0..AZIMUTHS as f64).contains(&ia) {
                return Err(format!("line {line}: rel_azimuth_deg {az} is not on the 0-180 by 15 grid"));
            }
            if q.hypot(u) > 1.0 + 1e-4 {
                return Err(format!("line {line}: sqrt(q^2 + u^2) = {} exceeds 1", q.hypot(u)));
            }
            let k = iz as usize * AZIMUTHS + ia as usize;
            let idx = match cases
                .iter()
                .position(|(c, _)| c.sun_zenith_deg == sz && c.wind_mps == wind && c.turbid == turbid && c.depth_m == depth)
            {
                Some(p) => p,
                None => {
                    let case = Case { sun_zenith_deg: sz, wind_mps: wind, turbid, depth_m: depth, qu: vec![[0.0; 2]; ZENITHS * AZIMUTHS] };
                    cases.push((case, vec![false; ZENITHS * AZIMUTHS]));
                    cases.len() - 1
                }
            };
            let (case, seen) = &mut cases[idx];
            if seen[k] {
                return Err(format!("line {line}: duplicate point"));
            }
            seen[k] = true;
            case.qu[k] = [q, u];
        }
        if cases.is_empty() {
            return Err("no data rows".into());
        }
        let mut out = Vec::new();
        for (c, seen) in cases {
            if seen.iter().any(|s| !s) {
                return Err(format!(
                    "case sun {} wind {} {} {} m: missing grid points",
                    c.sun_zenith_deg,
                    c.wind_mps,
                    if c.turbid { "turbid" } else { "clear" },
                    c.depth_m
                ));
            }
            out.push(c);
        }
        Ok(Table { cases: out })
    }

    /// The embedded OSOAA table (parsed once; a unit test checks that it parses).
    pub fn osoaa() -> Option<&'static Table> {
        static TABLE: OnceLock<Option<Table>> = OnceLock::new();
        TABLE.get_or_init(|| Table::parse(TABLE_CSV).ok()).as_ref()
    }

    /// The table without what a leave-one-out check of the case (sun, wind, water, depth)
    /// removes ([`LeaveOut`]).
    pub fn without(&self, sun_zenith_deg: f64, wind_mps: f64, turbid: bool, depth_m: f64, what: LeaveOut) -> Table {
        let drop = |c: &Case| match what {
            LeaveOut::Depth => c.turbid == turbid && c.wind_mps == wind_mps && c.sun_zenith_deg == sun_zenith_deg && c.depth_m == depth_m,
            LeaveOut::Wind => c.turbid == turbid && c.wind_mps == wind_mps,
            LeaveOut::Sun => c.turbid == turbid && c.wind_mps == wind_mps && c.sun_zenith_deg == sun_zenith_deg,
            LeaveOut::Water => c.turbid == turbid,
        };
        Table { cases: self.cases.iter().filter(|c| !drop(c)).cloned().collect() }
    }

    /// The cases (with weights summing to 1) for a water of single-scattering albedo `albedo`
    /// and attenuation `c_per_m` at `depth_m`, wind and sun zenith (module doc).
    pub fn nodes(&self, albedo: f64, c_per_m: f64, depth_m: f64, wind_mps: f64, sun_zenith_deg: f64) -> Vec<Node<'_>> {
        let mut out = Vec::new();
        let t = ((albedo - CLEAR_ALBEDO) / (TURBID_ALBEDO - CLEAR_ALBEDO)).clamp(0.0, 1.0);
        let t = if t < 1e-9 {
            0.0
        } else if t > 1.0 - 1e-9 {
            1.0
        } else {
            t
        };
        let waters: Vec<(bool, f64)> = {
            let have = |turbid: bool| self.cases.iter().any(|c| c.turbid == turbid);
            match (have(false), have(true)) {
                (true, true) => vec![(false, 1.0 - t), (true, t)],
                (true, false) => vec![(false, 1.0)],
                (false, true) => vec![(true, 1.0)],
                (false, false) => vec![],
            }
        };
        let tau = c_per_m.max(1e-9) * depth_m.max(0.0);
        for (turbid, ww) in waters.into_iter().filter(|w| w.1 > 0.0) {
            let winds = distinct(self.cases.iter().filter(|c| c.turbid == turbid).map(|c| c.wind_mps).collect());
            for (iw, wwi) in weights(&winds, wind_mps) {
                let wind = winds[iw];
                let suns =
                    distinct(self.cases.iter().filter(|c| c.turbid == turbid && c.wind_mps == wind).map(|c| c.sun_zenith_deg).collect());
                for (is, ws) in weights(&suns, sun_zenith_deg) {
                    let sun = suns[is];
                    let depths: Vec<&Case> = {
                        let mut v: Vec<&Case> =
                            self.cases.iter().filter(|c| c.turbid == turbid && c.wind_mps == wind && c.sun_zenith_deg == sun).collect();
                        v.sort_by(|a, b| a.depth_m.total_cmp(&b.depth_m));
                        v
                    };
                    let taus: Vec<f64> = depths.iter().map(|c| c.c_per_m() * c.depth_m).collect();
                    for (id, wd) in weights(&taus, tau) {
                        let weight = ww * wwi * ws * wd;
                        if weight > 0.0 {
                            let beyond_deepest = id + 1 == taus.len() && tau > taus[id] * (1.0 + 1e-9);
                            out.push(Node { case: depths[id], weight, depth_m: taus[id] / c_per_m.max(1e-9), beyond_deepest });
                        }
                    }
                }
            }
        }
        out
    }
}

/// Meridian frame of a look direction `v` (NED, toward where the light comes from) for a sun at
/// NED azimuth `sun_az_rad`: (view zenith, relative azimuth `A_sun - A_look` in [0, 2 pi), l, r)
/// with l in the vertical plane of the line of sight and r horizontal (OSOAA's convention).
pub fn meridian_frame(v: Vector3<f64>, sun_az_rad: f64) -> (f64, f64, Vector3<f64>, Vector3<f64>) {
    let v = v.normalize();
    let theta = (-v.z).clamp(-1.0, 1.0).acos();
    let a_look = v.y.atan2(v.x);
    let phi = (sun_az_rad - a_look).rem_euclid(std::f64::consts::TAU);
    // Reference axes in NED: x toward the sun's azimuth, z up, y = z x x.
    let (sa, ca) = sun_az_rad.sin_cos();
    let (x, y, z) = (Vector3::new(ca, sa, 0.0), Vector3::new(sa, -ca, 0.0), Vector3::new(0.0, 0.0, -1.0));
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    let l = x * (-ct * cp) + y * (-ct * sp) + z * st;
    let r = x * (-sp) + y * cp;
    (theta, phi, l, r)
}

/// Coherency matrix of Stokes (I, Q, U) in the frame (l, r): `S0 = C_ll + C_rr`, `S1 = C_ll -
/// C_rr`, `S2 = 2 C_lr` (the inverse of [`crate::sky::stokes`]).
pub fn coherency(s: [f64; 3], l: &Vector3<f64>, r: &Vector3<f64>) -> Matrix3<f64> {
    let ll = l * l.transpose();
    let rr = r * r.transpose();
    let lr = l * r.transpose() + r * l.transpose();
    (ll + rr) * (0.5 * s[0]) + (ll - rr) * (0.5 * s[1]) + lr * (0.5 * s[2])
}

/// The departure of one field (module doc): the sun, the water's optics, depth, wind and the
/// direct share, and the table.
#[derive(Debug, Clone, Copy)]
pub struct Departure<'a> {
    pub table: &'a Table,
    /// Toward the sun in air (NED).
    pub sun_ned: Vector3<f64>,
    pub albedo: f64,
    pub c_per_m: f64,
    pub depth_m: f64,
    pub wind_mps: f64,
    /// The direct sun's share of a clear day's (0-1): the departure's scale.
    pub direct: f64,
}

impl Departure<'_> {
    /// The simulator's coherency `c_sim` at look direction `v` with the departure added.
    /// `mean(sun_ned, depth_m, v)`: the simulator's own mean field (flat sea, clear sky) for a
    /// sun and depth, the reference the table's departure is taken against.
    pub fn apply(
        &self,
        c_sim: Matrix3<f64>,
        v: Vector3<f64>,
        mean: impl Fn(Vector3<f64>, f64, Vector3<f64>) -> Matrix3<f64>,
    ) -> Matrix3<f64> {
        let scale = self.direct.clamp(0.0, 1.0);
        if scale <= 0.0 || v.z >= 0.0 || self.sun_ned.z >= 0.0 {
            return c_sim;
        }
        let sun_az = self.sun_ned.y.atan2(self.sun_ned.x);
        let sun_zenith_deg = (-self.sun_ned.z / self.sun_ned.norm()).clamp(-1.0, 1.0).acos().to_degrees();
        let (theta, phi, l, r) = meridian_frame(v, sun_az);
        let [i, q, u] = crate::sky::stokes(&c_sim, &l, &r);
        if !(i > 0.0) {
            return c_sim;
        }
        let (mut dq, mut du) = (0.0, 0.0);
        let nodes = self.table.nodes(self.albedo, self.c_per_m, self.depth_m, self.wind_mps, sun_zenith_deg);
        // The simulator's mean at each distinct (sun, depth) of the nodes.
        let mut means: Vec<(f64, f64, [f64; 2])> = Vec::new();
        for n in &nodes {
            let key = (n.case.sun_zenith_deg, n.depth_m);
            let m = match means.iter().find(|m| (m.0, m.1) == key) {
                Some(m) => m.2,
                None => {
                    let z = n.case.sun_zenith_deg.to_radians();
                    let (sa, ca) = sun_az.sin_cos();
                    let sun = Vector3::new(z.sin() * ca, z.sin() * sa, -z.cos());
                    let s = crate::sky::stokes(&mean(sun, n.depth_m, v), &l, &r);
                    let m = if s[0] > 0.0 { [s[1] / s[0], s[2] / s[0]] } else { [0.0, 0.0] };
                    means.push((key.0, key.1, m));
                    m
                }
            };
            // Deeper than twice the water's deepest case (in optical depth): the departure fades
            // as the simulator's own polarization does from there (held without end, it would
            // outlive the field's polarization and lock a sun pattern onto a diffuse deep field;
            // up to twice it is held, the extrapolation the leave-depth-out check measured).
            let fade = if n.beyond_deepest && self.depth_m > 2.0 * n.depth_m {
                let z = n.case.sun_zenith_deg.to_radians();
                let (sa, ca) = sun_az.sin_cos();
                let sun = Vector3::new(z.sin() * ca, z.sin() * sa, -z.cos());
                let dolp = |depth_m: f64| {
                    let s = crate::sky::stokes(&mean(sun, depth_m, v), &l, &r);
                    if s[0] > 0.0 { s[1].hypot(s[2]) / s[0] } else { 0.0 }
                };
                let p_from = dolp(2.0 * n.depth_m);
                if p_from > 0.0 { (dolp(self.depth_m) / p_from).clamp(0.0, 1.0) } else { 0.0 }
            } else {
                1.0
            };
            let t = n.case.qu_at(theta, phi);
            dq += n.weight * fade * (t[0] - m[0]);
            du += n.weight * fade * (t[1] - m[1]);
        }
        let (mut q2, mut u2) = (q + scale * i * dq, u + scale * i * du);
        let p = q2.hypot(u2);
        if p > 0.999 * i {
            (q2, u2) = (q2 * 0.999 * i / p, u2 * 0.999 * i / p);
        }
        coherency([i, q2, u2], &l, &r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_table_parses_and_is_complete() {
        let t = Table::osoaa().expect("the embedded table parses");
        assert_eq!(t.cases.len(), 24);
        // Spot values copied from the source CSVs (sza30_wind0_clear_z5.csv line 2: Q/I at
        // VZA 0, az 0; sza60_wind5_clear_z5.csv VZA 80, az 0: Q/I = -1.076009e-02 / 6.424488e-02).
        let c = t.cases.iter().find(|c| c.sun_zenith_deg == 30.0 && c.wind_mps == 0.0 && !c.turbid && c.depth_m == 5.0).unwrap();
        assert!((c.qu[0][0] - (-0.04427)).abs() < 1e-9);
        let c = t.cases.iter().find(|c| c.sun_zenith_deg == 60.0 && c.wind_mps == 5.0 && !c.turbid && c.depth_m == 5.0).unwrap();
        assert!((c.qu[16 * AZIMUTHS][0] - (-1.076009e-02 / 6.424488e-02)).abs() < 1e-5);
        // Mirror: u changes sign across the solar plane.
        let a = c.qu_at(1.0, 1.0);
        let b = c.qu_at(1.0, std::f64::consts::TAU - 1.0);
        assert!((a[0] - b[0]).abs() < 1e-12 && (a[1] + b[1]).abs() < 1e-12);
    }

    #[test]
    fn bad_tables_are_refused_with_the_line() {
        let head = "sun_zenith_deg,wind_mps,water,depth_m,view_zenith_deg,rel_azimuth_deg,q,u\n";
        assert!(Table::parse("x\n").unwrap_err().contains("line 1"));
        assert!(Table::parse(&format!("{head}30,0,muddy,5,0,0,0,0\n")).unwrap_err().contains("line 2"));
        assert!(Table::parse(&format!("{head}30,0,clear,5,3,0,0,0\n")).unwrap_err().contains("line 2"));
        assert!(Table::parse(&format!("{head}30,0,clear,5,0,0,NaN,0\n")).unwrap_err().contains("line 2"));
        assert!(Table::parse(&format!("{head}30,0,clear,5,0,0,0,0\n")).unwrap_err().contains("missing grid points"));
    }

    #[test]
    fn node_weights() {
        let t = Table::osoaa().unwrap();
        let sum = |n: &[Node]| n.iter().map(|n| n.weight).sum::<f64>();
        // A table case exactly: one node, weight 1.
        let n = t.nodes(CLEAR_ALBEDO, CLEAR_C_PER_M, 10.0, 0.0, 30.0);
        assert_eq!(n.len(), 1);
        assert!((n[0].depth_m - 10.0).abs() < 1e-9 && n[0].case.depth_m == 10.0);
        // Between depths, winds and suns: 8 nodes summing to 1; between the waters (whose
        // optical depths do not overlap: each held at its nearest depth) 4 + 4.
        let n = t.nodes(CLEAR_ALBEDO, CLEAR_C_PER_M, 7.5, 2.0, 45.0);
        assert_eq!(n.len(), 8);
        assert!((sum(&n) - 1.0).abs() < 1e-12);
        let n = t.nodes(0.8, 0.5, 7.5, 2.0, 45.0);
        assert_eq!(n.len(), 8);
        assert!(n.iter().any(|n| n.case.turbid) && n.iter().any(|n| !n.case.turbid));
        assert!((sum(&n) - 1.0).abs() < 1e-12);
        let n = t.nodes(0.3, 0.06, 200.0, 12.0, 80.0);
        assert_eq!(n.len(), 1);
        assert!(n[0].case.depth_m == 20.0 && n[0].case.wind_mps == 5.0 && n[0].case.sun_zenith_deg == 60.0 && !n[0].case.turbid);
        // Leave-one-out removes what it says.
        let w = t.without(30.0, 0.0, false, 10.0, LeaveOut::Depth);
        assert_eq!(w.cases.len(), 23);
        let n = w.nodes(CLEAR_ALBEDO, CLEAR_C_PER_M, 10.0, 0.0, 30.0);
        assert_eq!(n.len(), 2);
        assert_eq!(t.without(30.0, 0.0, false, 10.0, LeaveOut::Wind).cases.len(), 18);
        assert_eq!(t.without(30.0, 0.0, false, 10.0, LeaveOut::Sun).cases.len(), 21);
        assert_eq!(t.without(30.0, 0.0, false, 10.0, LeaveOut::Water).cases.len(), 12);
    }
}
