//! k-nearest-neighbour classification (uniform vote, ties to the smallest label, like
//! scikit-learn's `KNeighborsClassifier`) of samples already mapped by `L`.

use nalgebra::DMatrix;

/// The `k` nearest rows of `train` to `q` (squared distances ascending), `(index, d2)`.
pub fn nearest(train: &DMatrix<f64>, q: &[f64], k: usize) -> Vec<(usize, f64)> {
    let mut best: Vec<(usize, f64)> = Vec::with_capacity(k + 1);
    for i in 0..train.nrows() {
        let d2: f64 = train.row(i).iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
        if best.len() < k || d2 < best[best.len() - 1].1 {
            let pos = best.partition_point(|e| e.1 <= d2);
            best.insert(pos, (i, d2));
            best.truncate(k);
        }
    }
    best
}

/// Predicted labels of the rows of `test` by a `k`-NN vote among the rows of `train`.
pub fn predict(train: &DMatrix<f64>, y_train: &[i64], test: &DMatrix<f64>, k: usize) -> Vec<i64> {
    let mut out = Vec::with_capacity(test.nrows());
    let mut q = vec![0.0; test.ncols()];
    for r in 0..test.nrows() {
        for (c, v) in q.iter_mut().enumerate() {
            *v = test[(r, c)];
        }
        let nn = nearest(train, &q, k);
        let mut votes: Vec<(i64, usize)> = Vec::new();
        for (i, _) in nn {
            let lab = y_train[i];
            match votes.iter_mut().find(|v| v.0 == lab) {
                Some(v) => v.1 += 1,
                None => votes.push((lab, 1)),
            }
        }
        votes.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        out.push(votes.first().map_or(0, |v| v.0));
    }
    out
}

/// Fraction of equal labels.
pub fn accuracy(pred: &[i64], truth: &[i64]) -> f64 {
    if truth.is_empty() {
        return 0.0;
    }
    pred.iter().zip(truth).filter(|(a, b)| a == b).count() as f64 / truth.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vote_and_tie_break() {
        let train = DMatrix::from_row_slice(4, 1, &[0.0, 0.1, 1.0, 5.0]);
        let y = [2, 1, 1, 0];
        let test = DMatrix::from_row_slice(2, 1, &[0.05, 4.9]);
        assert_eq!(predict(&train, &y, &test, 3), vec![1, 1]);
        // three different labels: tie goes to the smallest
        assert_eq!(predict(&train, &[3, 2, 1, 0], &DMatrix::from_row_slice(1, 1, &[0.0]), 3), vec![1]);
        assert_eq!(accuracy(&[1, 2, 3], &[1, 2, 0]), 2.0 / 3.0);
    }
}
