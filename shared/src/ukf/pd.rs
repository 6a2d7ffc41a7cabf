//! Keeping covariances symmetric positive definite.
//!
//! Every covariance the filter writes goes through [`finalize`]: symmetrize, then a Cholesky
//! factorization (which the next sigma-point draw reuses, so the check is free). Only when that
//! fails does [`repair`] run: a symmetric eigendecomposition with the eigenvalues floored at
//! `max(abs_floor, rel_floor * largest)`. Each repair is counted by the caller.
//!
//! The eigendecomposition is a small cyclic Jacobi sweep written here: nalgebra's
//! `SymmetricEigen` needs typenum bounds (`Const<N>: DimSub<U1>`) that would spread to every
//! generic signature of the filter, and repairs are rare, so speed does not matter.

use nalgebra::linalg::Cholesky;
use nalgebra::{RealField, SMatrix, SVector};

/// Eigenvalues and eigenvectors (columns) of a symmetric matrix by cyclic Jacobi rotations.
/// `None` if it does not converge in `max_sweeps` or the input is not finite.
pub fn jacobi_eigen<T: RealField + Copy, const N: usize>(
    a: &SMatrix<T, N, N>,
    max_sweeps: usize,
) -> Option<(SVector<T, N>, SMatrix<T, N, N>)> {
    if !all_finite(a) {
        return None;
    }
    let mut a = *a;
    let mut v = SMatrix::<T, N, N>::identity();
    let eps = T::default_epsilon();
    for _ in 0..max_sweeps {
        let mut off = T::zero();
        let mut diag = T::zero();
        for i in 0..N {
            diag += a[(i, i)] * a[(i, i)];
            for j in (i + 1)..N {
                off += a[(i, j)] * a[(i, j)];
            }
        }
        if off <= eps * eps * diag || off == T::zero() {
            return Some((a.diagonal(), v));
        }
        for p in 0..N {
            for q in (p + 1)..N {
                let apq = a[(p, q)];
                if apq == T::zero() {
                    continue;
                }
                let theta = (a[(q, q)] - a[(p, p)]) / (apq + apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + T::one()).sqrt());
                let t = if theta == T::zero() { T::one() } else { t };
                let c = T::one() / (t * t + T::one()).sqrt();
                let s = t * c;
                for k in 0..N {
                    let akp = a[(k, p)];
                    let akq = a[(k, q)];
                    a[(k, p)] = c * akp - s * akq;
                    a[(k, q)] = s * akp + c * akq;
                }
                for k in 0..N {
                    let apk = a[(p, k)];
                    let aqk = a[(q, k)];
                    a[(p, k)] = c * apk - s * aqk;
                    a[(q, k)] = s * apk + c * aqk;
                }
                for k in 0..N {
                    let vkp = v[(k, p)];
                    let vkq = v[(k, q)];
                    v[(k, p)] = c * vkp - s * vkq;
                    v[(k, q)] = s * vkp + c * vkq;
                }
            }
        }
    }
    None
}

/// Make `p` exactly symmetric: `(P + P^T) / 2`.
pub fn symmetrize<T: RealField + Copy, const N: usize>(p: &mut SMatrix<T, N, N>) {
    let half = T::from_subset(&0.5);
    for i in 0..N {
        for j in (i + 1)..N {
            let v = (p[(i, j)] + p[(j, i)]) * half;
            p[(i, j)] = v;
            p[(j, i)] = v;
        }
    }
}

/// Whether every entry is finite.
pub fn all_finite<T: RealField + Copy, const R: usize, const C: usize>(m: &SMatrix<T, R, C>) -> bool {
    m.iter().all(|v| v.is_finite())
}

/// Floor the eigenvalues of a symmetric matrix. Returns `None` when the decomposition fails
/// (non-finite input).
pub fn repair<T: RealField + Copy, const N: usize>(p: &SMatrix<T, N, N>, abs_floor: T, rel_floor: T) -> Option<SMatrix<T, N, N>> {
    if !all_finite(p) {
        return None;
    }
    let (vals, v) = jacobi_eigen(p, 50)?;
    let largest = vals.iter().fold(T::zero(), |a, &b| if b > a { b } else { a });
    let floor = if abs_floor > rel_floor * largest { abs_floor } else { rel_floor * largest };
    let d = vals.map(|e| if e > floor { e } else { floor });
    let mut out = v * SMatrix::<T, N, N>::from_diagonal(&d) * v.transpose();
    symmetrize(&mut out);
    Some(out)
}

/// Result of [`finalize`].
pub struct Finalized<T: RealField + Copy, const N: usize> {
    pub p: SMatrix<T, N, N>,
    /// Lower Cholesky factor of `p`.
    pub l: SMatrix<T, N, N>,
    /// Whether an eigenvalue repair was needed.
    pub repaired: bool,
}

/// Symmetrize `p`, factor it, and repair it if the factorization fails. `None` if even the
/// repaired matrix cannot be factored (non-finite input).
pub fn finalize<T: RealField + Copy, const N: usize>(mut p: SMatrix<T, N, N>, abs_floor: T, rel_floor: T) -> Option<Finalized<T, N>> {
    symmetrize(&mut p);
    if all_finite(&p) {
        if let Some(c) = Cholesky::new(p) {
            // Also require a positive diagonal of the factor, well above zero (f32 Cholesky can
            // "succeed" on a matrix with a tiny negative eigenvalue rounded away).
            let l = c.unpack();
            let min_pivot2 = (0..N).fold(T::max_value().unwrap_or(T::one()), |a, i| {
                let v = l[(i, i)] * l[(i, i)];
                if v < a { v } else { a }
            });
            if min_pivot2 > abs_floor * T::from_subset(&1e-3) {
                return Some(Finalized { p, l, repaired: false });
            }
        }
    }
    let p2 = repair(&p, abs_floor, rel_floor)?;
    let l = Cholesky::new(p2)?.unpack();
    Some(Finalized { p: p2, l, repaired: true })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    #[test]
    fn repairs_an_indefinite_matrix() {
        let p = Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0f64); // eig -1, 1, 3
        let f = finalize(p, 1e-9, 1e-12).unwrap();
        assert!(f.repaired);
        let e = jacobi_eigen(&f.p, 50).unwrap().0;
        assert!(e.iter().all(|&v| v >= 1e-9 * 0.999), "{e}");
        let ok = finalize(Matrix3::<f64>::identity(), 1e-9, 1e-12).unwrap();
        assert!(!ok.repaired);
        let (vals, _) = jacobi_eigen(&Matrix3::new(2.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 5.0f64), 50).unwrap();
        let mut v: [f64; 3] = [vals[0], vals[1], vals[2]];
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert!((v[0] - 1.0).abs() < 1e-12 && (v[1] - 3.0).abs() < 1e-12 && (v[2] - 5.0).abs() < 1e-12);
        assert!(finalize(Matrix3::new(f64::NAN, 0., 0., 0., 1., 0., 0., 0., 1.), 1e-9, 1e-12).is_none());
    }
}
