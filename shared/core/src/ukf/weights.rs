//! Scaled unscented transform weights (van der Merwe): `2N+1` sigma points.
//!
//! `lambda = alpha^2 (N + kappa) - N`, `gamma = sqrt(N + lambda)`,
//! `Wm_0 = lambda / (N + lambda)`, `Wc_0 = Wm_0 + 1 - alpha^2 + beta`,
//! `Wm_i = Wc_i = 1 / (2 (N + lambda))`. The same definitions as FilterPy's
//! `MerweScaledSigmaPoints`, which the peer test checks against.

use nalgebra::RealField;

/// Weights and spread of the `S = 2N+1` sigma points of an `N`-dimensional state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SigmaWeights<T, const S: usize> {
    pub wm: [T; S],
    pub wc: [T; S],
    /// `sqrt(N + lambda)`: sigma points are `x +- gamma * column_i(chol(P))`.
    pub gamma: T,
}

/// Why a weight set could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WeightError {
    /// `S != 2N + 1`.
    WrongPointCount,
    /// `N + lambda <= 0` or a parameter is not finite.
    BadParameters,
}

impl core::fmt::Display for WeightError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            WeightError::WrongPointCount => "sigma-point count S is not 2N + 1 (or N is 0)",
            WeightError::BadParameters => "sigma-point parameters give N + lambda <= 0 or are not finite",
        })
    }
}

impl core::error::Error for WeightError {}

impl<T: RealField + Copy, const S: usize> SigmaWeights<T, S> {
    /// Weights for an `n`-dimensional state.
    pub fn merwe(n: usize, alpha: T, beta: T, kappa: T) -> Result<Self, WeightError> {
        if S != 2 * n + 1 || n == 0 {
            return Err(WeightError::WrongPointCount);
        }
        let nt = T::from_subset(&(n as f64));
        let lambda = alpha * alpha * (nt + kappa) - nt;
        let c = nt + lambda;
        if !(c > T::zero()) || !alpha.is_finite() || !beta.is_finite() || !kappa.is_finite() {
            return Err(WeightError::BadParameters);
        }
        let wi = T::one() / (T::from_subset(&2.0) * c);
        let mut wm = [wi; S];
        let mut wc = [wi; S];
        let w0 = lambda / c;
        wm[0] = w0; // S >= 3 checked above
        wc[0] = w0 + T::one() - alpha * alpha + beta;
        Ok(Self { wm, wc, gamma: c.sqrt() })
    }
}

/// The same weights in 16 bytes: `2N` of the `2N + 1` are equal (RAM on the M4F, where the
/// filter is held twice at boot: 236 B each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompactWeights<T> {
    pub wm0: T,
    pub wc0: T,
    /// `Wm_i = Wc_i`, i >= 1.
    pub wi: T,
    pub gamma: T,
}

impl<T: RealField + Copy> CompactWeights<T> {
    pub fn of<const S: usize>(w: &SigmaWeights<T, S>) -> Self {
        let wi = w.wm.get(1).copied().unwrap_or_else(T::zero);
        let (wm0, wc0) = (w.wm.first().copied().unwrap_or(wi), w.wc.first().copied().unwrap_or(wi));
        Self { wm0, wc0, wi, gamma: w.gamma }
    }

    /// The full arrays.
    pub fn expand<const S: usize>(&self) -> SigmaWeights<T, S> {
        let mut wm = [self.wi; S];
        let mut wc = [self.wi; S];
        if let (Some(m), Some(c)) = (wm.first_mut(), wc.first_mut()) {
            *m = self.wm0;
            *c = self.wc0;
        }
        SigmaWeights { wm, wc, gamma: self.gamma }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_weights_sum_to_one() {
        let w = SigmaWeights::<f64, 31>::merwe(15, 1e-3, 2.0, 0.0).unwrap();
        let s: f64 = w.wm.iter().sum();
        assert!((s - 1.0).abs() < 1e-9);
        assert!(SigmaWeights::<f64, 30>::merwe(15, 1e-3, 2.0, 0.0).is_err());
        assert!(SigmaWeights::<f64, 31>::merwe(15, 1.0, 2.0, -15.0).is_err());
    }
}
