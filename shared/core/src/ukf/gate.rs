//! Chi-square innovation gating with a floor.
//!
//! The NIS `e^T S^-1 e` with `S = P_zz + R` tends to zero when the state covariance grows (long
//! outage, bad tuning): an ungated filter, or a gate on that NIS alone, then accepts anything.
//! The gate here uses `S_gate = R + c * P_zz` with `c = min(1, gate_state_max / max_i(P_zz,ii /
//! R_ii))`: on every axis the state part of the gating covariance is capped at `gate_state_max`
//! times the measurement noise, so a
//! measurement far from the prediction (in units of the sensor's own noise) is still rejected
//! however large `P` is. To re-acquire after a real jump, the cap is lifted once a configured
//! number of consecutive measurements has been rejected.

use nalgebra::linalg::Cholesky;
use nalgebra::{RealField, SMatrix, SVector};

/// Chi-square quantiles at p = 0.999 for 1..=18 degrees of freedom (scipy.stats.chi2.ppf).
const CHI2_999: [f64; 18] = [
    10.828, 13.816, 16.266, 18.467, 20.515, 22.458, 24.322, 26.124, 27.877, 29.588, 31.264, 32.909, 34.528, 36.123, 37.697, 39.252, 40.790,
    42.312,
];

/// Chi-square quantile at p = 0.999 for `dof` degrees of freedom (clamped to 1..=18).
pub fn chi2_999<T: RealField + Copy>(dof: usize) -> T {
    let i = dof.clamp(1, CHI2_999.len()) - 1;
    T::from_subset(CHI2_999.get(i).unwrap_or(&CHI2_999[0]))
}

/// `e^T S^-1 e`, or `None` if `S` is not PD.
pub fn nis<T: RealField + Copy, const M: usize>(e: &SVector<T, M>, s: &SMatrix<T, M, M>) -> Option<T> {
    let c = Cholesky::new(*s)?;
    let y = c.solve(e);
    let v = e.dot(&y);
    if v.is_finite() { Some(v) } else { None }
}

/// The gating covariance `R + c P_zz` (see module doc).
pub fn gating_cov<T: RealField + Copy, const M: usize>(pzz: &SMatrix<T, M, M>, r: &SMatrix<T, M, M>, state_max: T) -> SMatrix<T, M, M> {
    let mut worst = T::zero();
    for i in 0..M {
        let ratio = pzz[(i, i)] / r[(i, i)];
        if ratio > worst {
            worst = ratio;
        }
    }
    let c = if worst > state_max { state_max / worst } else { T::one() };
    r + pzz * c
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Vector1};

    #[test]
    fn gate_floor_keeps_rejecting_when_p_is_huge() {
        let r = Matrix1::new(1.0f64);
        let pzz = Matrix1::new(1e12);
        let e = Vector1::new(20.0);
        // Without the floor: NIS ~ 4e-10, accepted.
        assert!(nis(&e, &(pzz + r)).unwrap() < 1e-6);
        // With it: NIS = 400 / (1 + 16) > 10.8, rejected.
        let g = nis(&e, &gating_cov(&pzz, &r, 16.0)).unwrap();
        assert!(g > chi2_999::<f64>(1), "{g}");
    }
}
