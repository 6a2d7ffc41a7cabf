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
//!
//! The Cholesky factorization and the repair work in place ([`cholesky_into`],
//! [`repair_in_place`], [`finalize_in_place`]): nalgebra's `Cholesky::new` takes the matrix by
//! value and `unpack` returns a new one, and the repair's `V diag(d) V^T` made three more
//! `N x N` temporaries. On the sensor head (15 x 15 f32, 900 bytes each) those copies were
//! 9.4 KB of stack in `repair` and 5.4 KB in `finalize`, on the deepest call chain of the firmware
//! (docs/PERFORMANCE.md, "Firmware size and RAM").

use nalgebra::{RealField, SMatrix, SVector};

/// Eigenvalues and eigenvectors (columns) of a symmetric matrix by cyclic Jacobi rotations.
/// `None` if it does not converge in `max_sweeps` or the input is not finite.
pub fn jacobi_eigen<T: RealField + Copy, const N: usize>(
    a: &SMatrix<T, N, N>,
    max_sweeps: usize,
) -> Option<(SVector<T, N>, SMatrix<T, N, N>)> {
    let mut a = *a;
    let mut v = SMatrix::<T, N, N>::zeros();
    jacobi_eigen_in_place(&mut a, &mut v, max_sweeps).then(|| (a.diagonal(), v))
}

/// [`jacobi_eigen`] in place: `a` is rotated until diagonal (its diagonal then holds the
/// eigenvalues) and `v` receives the eigenvectors (columns). `false` if `a` is not finite or the
/// sweeps do not converge; `a` and `v` are then unspecified.
pub fn jacobi_eigen_in_place<T: RealField + Copy, const N: usize>(
    a: &mut SMatrix<T, N, N>,
    v: &mut SMatrix<T, N, N>,
    max_sweeps: usize,
) -> bool {
    if !all_finite(a) {
        return false;
    }
    v.fill_with_identity();
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
            return true;
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
    false
}

/// Lower Cholesky factor of the symmetric matrix `p` (only its lower triangle is read) into `l`
/// (upper triangle zeroed): `p = l l^T`. Right-looking, column by column on the column-major
/// storage (contiguous slices, so the inner loop has no index checks). `false` if a pivot is not
/// positive or not finite; `l` is then unspecified.
pub fn cholesky_into<T: RealField + Copy, const N: usize>(p: &SMatrix<T, N, N>, l: &mut SMatrix<T, N, N>) -> bool {
    for j in 0..N {
        for i in 0..N {
            l[(i, j)] = if i >= j { p[(i, j)] } else { T::zero() };
        }
    }
    let data = l.as_mut_slice();
    for j in 0..N {
        let (head, tail) = data.split_at_mut((j + 1) * N);
        let Some(col_j) = head.get_mut(j * N..) else { return false };
        let Some((pivot, below)) = col_j.get_mut(j..).and_then(|c| c.split_first_mut()) else { return false };
        if !(*pivot > T::zero()) || !pivot.is_finite() {
            return false;
        }
        *pivot = pivot.sqrt();
        let inv = T::one() / *pivot;
        for v in below.iter_mut() {
            *v *= inv;
        }
        // Trailing columns k > j, rows k..: col_k -= l[k, j] * col_j.
        for (kk, col_k) in tail.chunks_exact_mut(N).enumerate() {
            let Some((&l_kj, rest)) = below.get(kk..).and_then(|c| c.split_first()) else { break };
            if let Some(dst) = col_k.get_mut(j + 1 + kk..) {
                if let Some((d0, drest)) = dst.split_first_mut() {
                    *d0 -= l_kj * l_kj;
                    for (a, b) in drest.iter_mut().zip(rest.iter()) {
                        *a -= l_kj * *b;
                    }
                }
            }
        }
    }
    true
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

/// `m += w r r^T` on the lower triangle only (half the work of nalgebra's general `ger`, which
/// was the largest cost of the UKF predict on the target); call [`mirror_lower`] once after the
/// last term.
pub fn add_outer_lower<T: RealField + Copy, const N: usize>(m: &mut SMatrix<T, N, N>, w: T, r: &SVector<T, N>) {
    for j in 0..N {
        let wr = w * r[j];
        for i in j..N {
            m[(i, j)] += wr * r[i];
        }
    }
}

/// Copy the lower triangle onto the upper one.
pub fn mirror_lower<T: RealField + Copy, const N: usize>(m: &mut SMatrix<T, N, N>) {
    for j in 0..N {
        for i in (j + 1)..N {
            m[(j, i)] = m[(i, j)];
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
    let mut out = *p;
    repair_in_place(&mut out, abs_floor, rel_floor).then_some(out)
}

/// [`repair`] in place: the eigenvalues of `p` are floored at `max(abs_floor, rel_floor *
/// largest)` and `p = V diag(d) V^T` is rebuilt entry by entry (exactly symmetric). `false` when
/// the decomposition fails (non-finite input); `p` is then unspecified.
pub fn repair_in_place<T: RealField + Copy, const N: usize>(p: &mut SMatrix<T, N, N>, abs_floor: T, rel_floor: T) -> bool {
    let mut v = SMatrix::<T, N, N>::zeros();
    if !jacobi_eigen_in_place(p, &mut v, 50) {
        return false;
    }
    let mut d = p.diagonal();
    let largest = d.iter().fold(T::zero(), |a, &b| if b > a { b } else { a });
    let floor = if abs_floor > rel_floor * largest { abs_floor } else { rel_floor * largest };
    d.apply(|e| {
        if !(*e > floor) {
            *e = floor;
        }
    });
    for i in 0..N {
        for j in 0..=i {
            let mut s = T::zero();
            for k in 0..N {
                s += v[(i, k)] * d[k] * v[(j, k)];
            }
            p[(i, j)] = s;
            p[(j, i)] = s;
        }
    }
    true
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
    let mut l = SMatrix::<T, N, N>::zeros();
    let repaired = finalize_in_place(&mut p, &mut l, abs_floor, rel_floor)?;
    Some(Finalized { p, l, repaired })
}

/// [`finalize`] in place: `p` becomes the symmetrized (and if needed repaired) covariance and `l`
/// its lower Cholesky factor; returns whether a repair was needed. The factor must have every
/// pivot^2 above `abs_floor * 1e-3` (an f32 factorization can "succeed" on a matrix with a tiny
/// negative eigenvalue rounded away). `None` (with `p` and `l` unspecified) if even the repaired
/// matrix cannot be factored (non-finite input).
pub fn finalize_in_place<T: RealField + Copy, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    l: &mut SMatrix<T, N, N>,
    abs_floor: T,
    rel_floor: T,
) -> Option<bool> {
    symmetrize(p);
    if !all_finite(p) {
        return None;
    }
    let min_pivot2 = abs_floor * T::from_subset(&1e-3);
    let pivots_ok = |l: &SMatrix<T, N, N>| (0..N).all(|i| l[(i, i)] * l[(i, i)] > min_pivot2);
    if cholesky_into(p, l) && pivots_ok(l) {
        return Some(false);
    }
    if !repair_in_place(p, abs_floor, rel_floor) {
        return None;
    }
    // The repaired matrix has every eigenvalue >= abs_floor, so its pivots pass; the factor is
    // only required to exist (as before the in-place rewrite).
    cholesky_into(p, l).then_some(true)
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

    /// The in-place factor and repair against nalgebra (which we did not write): the Cholesky
    /// factor equals `nalgebra::linalg::Cholesky`'s, a non-PD matrix is refused, and the repaired
    /// matrix equals `V diag(max(e, floor)) V^T` built with nalgebra products.
    #[test]
    fn in_place_factor_and_repair_match_nalgebra() {
        use nalgebra::{SMatrix, linalg::Cholesky};
        // A 15 x 15 SPD matrix from a fixed pseudo-random A: A A^T + 0.1 I.
        let mut seed = 12345u64;
        let a = SMatrix::<f64, 15, 15>::from_fn(|_, _| {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        });
        let p = a * a.transpose() + SMatrix::<f64, 15, 15>::identity() * 0.1;
        let mut l = SMatrix::<f64, 15, 15>::zeros();
        assert!(cholesky_into(&p, &mut l));
        let l_ref = Cholesky::new(p).unwrap().unpack();
        assert!((l - l_ref).abs().max() < 1e-12, "{}", (l - l_ref).abs().max());
        // Indefinite: shift by the smallest eigenvalue + 1 so one eigenvalue is -1.
        let (vals, _) = jacobi_eigen(&p, 50).unwrap();
        let emin = vals.min();
        let q = p - SMatrix::<f64, 15, 15>::identity() * (emin + 1.0);
        assert!(!cholesky_into(&q, &mut l));
        assert!(Cholesky::new(q).is_none());
        let (vals_q, vq) = jacobi_eigen(&q, 50).unwrap();
        let floor = 1e-6f64.max(1e-9 * vals_q.max());
        let expected = vq * SMatrix::<f64, 15, 15>::from_diagonal(&vals_q.map(|e| e.max(floor))) * vq.transpose();
        let mut r = q;
        assert!(repair_in_place(&mut r, 1e-6, 1e-9));
        assert!((r - expected).abs().max() < 1e-9, "{}", (r - expected).abs().max());
        assert!(r == r.transpose());
        let f = finalize(q, 1e-6, 1e-9).unwrap();
        assert!(f.repaired && (f.p - expected).abs().max() < 1e-9);
        assert!((f.l * f.l.transpose() - f.p).abs().max() < 1e-9);
        // Non-finite input: refused by every entry point.
        let mut bad = p;
        bad[(3, 4)] = f64::NAN;
        bad[(4, 3)] = f64::NAN;
        assert!(!cholesky_into(&bad, &mut l));
        assert!(!repair_in_place(&mut bad.clone(), 1e-6, 1e-9));
        assert!(finalize(bad, 1e-6, 1e-9).is_none());
    }
}
