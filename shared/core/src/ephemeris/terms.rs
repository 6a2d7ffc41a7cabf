//! Truncated periodic-term tables of NREL's Solar Position Algorithm (Reda & Andreas 2004,
//! NREL/TP-560-34302, tables A4.2 and A4.3; the Earth series are VSOP87, Bretagnon & Francou 1988).
//!
//! Only the terms that matter at the 0.001 deg level for 1950-2150 are kept (amplitude times
//! tau^k >= 50e-8 rad for L and B at |tau| <= 0.1 millennia, >= 1e-4 au for R, which only feeds the
//! aberration and parallax; nutation terms with |a| or |c| >= 0.03 arcsec). Secular parts
//! (B = C = 0) are split out as polynomials. The accuracy of the truncation is measured against
//! the full algorithm (pvlib) in `tests/tests/peer_pvlib.rs`.

use super::phase::{Rate, turns_q64};

const TAU64: f64 = core::f64::consts::TAU;
/// Days per Julian millennium / century.
const DAYS_PER_MILLENNIUM: f64 = 365_250.0;
const DAYS_PER_CENTURY: f64 = 36_525.0;

/// `amp * tau^k * cos(b + rate * t)`.
#[derive(Clone, Copy, Debug)]
pub(super) struct VsopTerm {
    pub k: u8,
    /// Amplitude in 1e-8 rad (or au), as f32.
    pub amp: f32,
    pub b: u64,
    pub rate: Rate,
}

pub(super) const fn vsop(k: u8, a: f64, b_rad: f64, c_rad_per_millennium: f64) -> VsopTerm {
    VsopTerm {
        k,
        amp: a as f32,
        b: turns_q64(b_rad / TAU64),
        rate: Rate::from_turns_per_day(c_rad_per_millennium / TAU64 / DAYS_PER_MILLENNIUM),
    }
}

/// Delaunay-type arguments of the nutation series (SPA eqs. 15-19), linear parts, degrees and
/// degrees per Julian century. The quadratic and cubic parts (< 0.01 deg over 1950-2150) are
/// dropped: they change the nutation by < 0.001 arcsec.
const NUT_ARGS: [(f64, f64); 5] = [
    (297.850_36, 445_267.111_480),
    (357.527_72, 35_999.050_340),
    (134.962_98, 477_198.867_398),
    (93.271_91, 483_202.017_538),
    (125.044_52, -1_934.136_261),
];

/// `(a + b T) sin(arg)` for Delta psi, `(c + d T) cos(arg)` for Delta epsilon, 1e-4 arcsec.
#[derive(Clone, Copy, Debug)]
pub(super) struct NutationTerm {
    pub a: f32,
    pub b: f32,
    pub c: f32,
    pub d: f32,
    pub arg0: u64,
    pub rate: Rate,
}

pub(super) const fn nutation(y: [i32; 5], a: f64, b: f64, c: f64, d: f64) -> NutationTerm {
    let mut x0 = 0.0;
    let mut r = 0.0;
    let mut j = 0;
    while j < 5 {
        x0 += y[j] as f64 * NUT_ARGS[j].0;
        r += y[j] as f64 * NUT_ARGS[j].1;
        j += 1;
    }
    NutationTerm {
        a: a as f32,
        b: b as f32,
        c: c as f32,
        d: d as f32,
        arg0: turns_q64(x0 / 360.0),
        rate: Rate::from_turns_per_day(r / 360.0 / DAYS_PER_CENTURY),
    }
}

/// L: secular polynomial coefficients in tau^k (1e-8 rad), k = 0..5.
pub(super) const L_POLY: [f64; 6] = [175347046.0, 628331966747.0, 52919.0, 35.0, 0.0, 0.0];
/// L: periodic terms (k, A [1e-8 rad], B [rad], C [rad/millennium]): A tau^k cos(B + C tau).
pub(super) const L_TERMS: [VsopTerm; 54] = [
    vsop(0, 3341656.0, 4.6692568, 6283.07585),
    vsop(0, 34894.0, 4.6261, 12566.1517),
    vsop(0, 3497.0, 2.7441, 5753.3849),
    vsop(0, 3418.0, 2.8289, 3.5231),
    vsop(0, 3136.0, 3.6277, 77713.7715),
    vsop(0, 2676.0, 4.4181, 7860.4194),
    vsop(0, 2343.0, 6.1352, 3930.2097),
    vsop(0, 1324.0, 0.7425, 11506.7698),
    vsop(0, 1273.0, 2.0371, 529.691),
    vsop(0, 1199.0, 1.1096, 1577.3435),
    vsop(0, 990.0, 5.233, 5884.927),
    vsop(0, 902.0, 2.045, 26.298),
    vsop(0, 857.0, 3.508, 398.149),
    vsop(0, 780.0, 1.179, 5223.694),
    vsop(0, 753.0, 2.533, 5507.553),
    vsop(0, 505.0, 4.583, 18849.228),
    vsop(0, 492.0, 4.205, 775.523),
    vsop(0, 357.0, 2.92, 0.067),
    vsop(0, 317.0, 5.849, 11790.629),
    vsop(0, 284.0, 1.899, 796.298),
    vsop(0, 271.0, 0.315, 10977.079),
    vsop(0, 243.0, 0.345, 5486.778),
    vsop(0, 206.0, 4.806, 2544.314),
    vsop(0, 205.0, 1.869, 5573.143),
    vsop(0, 202.0, 2.458, 6069.777),
    vsop(0, 156.0, 0.833, 213.299),
    vsop(0, 132.0, 3.411, 2942.463),
    vsop(0, 126.0, 1.083, 20.775),
    vsop(0, 115.0, 0.645, 0.98),
    vsop(0, 103.0, 0.636, 4694.003),
    vsop(0, 102.0, 0.976, 15720.839),
    vsop(0, 102.0, 4.267, 7.114),
    vsop(0, 99.0, 6.21, 2146.17),
    vsop(0, 98.0, 0.68, 155.42),
    vsop(0, 86.0, 5.98, 161000.69),
    vsop(0, 85.0, 1.3, 6275.96),
    vsop(0, 85.0, 3.67, 71430.7),
    vsop(0, 80.0, 1.81, 17260.15),
    vsop(0, 79.0, 3.04, 12036.46),
    vsop(0, 75.0, 1.76, 5088.63),
    vsop(0, 74.0, 3.5, 3154.69),
    vsop(0, 74.0, 4.68, 801.82),
    vsop(0, 70.0, 0.83, 9437.76),
    vsop(0, 62.0, 3.98, 8827.39),
    vsop(0, 61.0, 1.82, 7084.9),
    vsop(0, 57.0, 2.78, 6286.6),
    vsop(0, 56.0, 4.39, 14143.5),
    vsop(0, 56.0, 3.47, 6279.55),
    vsop(0, 52.0, 0.19, 12139.55),
    vsop(0, 52.0, 1.33, 1748.02),
    vsop(0, 51.0, 0.28, 5856.48),
    vsop(1, 206059.0, 2.678235, 6283.07585),
    vsop(1, 4303.0, 2.6351, 12566.1517),
    vsop(2, 8720.0, 1.0721, 6283.0758),
];
/// B: secular polynomial coefficients in tau^k (1e-8 rad), k = 0..1.
pub(super) const B_POLY: [f64; 2] = [0.0, 0.0];
/// B: periodic terms (k, A [1e-8 rad], B [rad], C [rad/millennium]): A tau^k cos(B + C tau).
pub(super) const B_TERMS: [VsopTerm; 3] = [vsop(0, 280.0, 3.199, 84334.662), vsop(0, 102.0, 5.422, 5507.553), vsop(0, 80.0, 3.88, 5223.69)];
/// R: secular polynomial coefficients in tau^k (1e-8 au), k = 0..4.
pub(super) const R_POLY: [f64; 5] = [100013989.0, 0.0, 0.0, 0.0, 0.0];
/// R: periodic terms (k, A [1e-8 au], B [rad], C [rad/millennium]): A tau^k cos(B + C tau).
pub(super) const R_TERMS: [VsopTerm; 3] =
    [vsop(0, 1670700.0, 3.0984635, 6283.07585), vsop(0, 13956.0, 3.05525, 12566.1517), vsop(1, 103019.0, 1.10749, 6283.07585)];
/// Nutation terms (Y0..Y4 multipliers of D, M, M', F, Omega; a, b [1e-4 arcsec]; c, d [1e-4 arcsec]).
pub(super) const NUTATION_TERMS: [NutationTerm; 9] = [
    nutation([0, 0, 0, 0, 1], -171996.0, -174.2, 92025.0, 8.9),
    nutation([-2, 0, 0, 2, 2], -13187.0, -1.6, 5736.0, -3.1),
    nutation([0, 0, 0, 2, 2], -2274.0, -0.2, 977.0, -0.5),
    nutation([0, 0, 0, 0, 2], 2062.0, 0.2, -895.0, 0.5),
    nutation([0, 1, 0, 0, 0], 1426.0, -3.4, 54.0, -0.1),
    nutation([0, 0, 1, 0, 0], 712.0, 0.1, -7.0, 0.0),
    nutation([-2, 1, 0, 2, 2], -517.0, 1.2, 224.0, -0.6),
    nutation([0, 0, 0, 2, 1], -386.0, -0.4, 200.0, 0.0),
    nutation([0, 0, 1, 2, 2], -301.0, 0.0, 129.0, -0.1),
];
