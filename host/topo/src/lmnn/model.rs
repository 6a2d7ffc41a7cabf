//! A fitted LMNN classifier as saved by `subnav lmnn fit` (JSON): the standardiser fitted on the
//! training set, `L`, and the training samples with their labels (kNN needs them); and the CSV
//! format of labelled samples (features, then an integer label in the last column; an optional
//! header line).

use std::path::Path;

use anyhow::{Context, Result, bail};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::knn;
use super::solver::{FitReport, LmnnConfig, fit};

/// Per-feature standardisation `(x - mean) / scale`, scale = population standard deviation, or
/// 1 for a constant feature (as scikit-learn's `StandardScaler`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scaler {
    pub mean: Vec<f64>,
    pub scale: Vec<f64>,
}

impl Scaler {
    pub fn fit(x: &DMatrix<f64>) -> Self {
        let n = x.nrows().max(1) as f64;
        let mean: Vec<f64> = x.column_iter().map(|c| c.sum() / n).collect();
        let scale = x
            .column_iter()
            .zip(&mean)
            .map(|(c, m)| {
                let var = c.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / n;
                let s = var.sqrt();
                if s < 10.0 * f64::EPSILON * m.abs().max(1.0) { 1.0 } else { s }
            })
            .collect();
        Scaler { mean, scale }
    }

    pub fn transform(&self, x: &DMatrix<f64>) -> DMatrix<f64> {
        DMatrix::from_fn(x.nrows(), x.ncols(), |r, c| (x[(r, c)] - self.mean[c]) / self.scale[c])
    }
}

/// A fitted classifier.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LmnnModel {
    pub k: usize,
    pub scaler: Scaler,
    /// `L`, row-major d x d.
    pub l: Vec<Vec<f64>>,
    /// Standardised training samples (row per sample) and their labels.
    pub train_std: Vec<Vec<f64>>,
    pub train_labels: Vec<i64>,
    pub report: Option<FitReport>,
}

/// Most training samples [`LmnnModel::fit`] accepts: the solver holds n x n pairwise
/// distances (a Gram matrix, 10,000 samples: 800 MB, plus 400 MB of f32 input distances, plus the
/// active set's rows, 20 bytes per kept pair; 100,000 asked for 80 GB and aborted).
pub const MAX_FIT_SAMPLES: usize = 10_000;

impl LmnnModel {
    /// Standardise `x`, fit LMNN, keep what kNN needs.
    pub fn fit(x: &DMatrix<f64>, y: &[i64], cfg: &LmnnConfig) -> Result<Self> {
        subnav_base::limits::check_rows("the training set", x.nrows(), MAX_FIT_SAMPLES).map_err(anyhow::Error::msg)?;
        let scaler = Scaler::fit(x);
        if let Some(c) = scaler.mean.iter().zip(&scaler.scale).position(|(m, s)| !m.is_finite() || !s.is_finite()) {
            bail!("feature {} is too large to standardise (its mean or standard deviation overflows f64); rescale the features", c + 1);
        }
        let xs = scaler.transform(x);
        let (l, report) = fit(&xs, y, cfg)?;
        Ok(LmnnModel {
            k: cfg.k,
            scaler,
            l: l.row_iter().map(|r| r.iter().cloned().collect()).collect(),
            train_std: xs.row_iter().map(|r| r.iter().cloned().collect()).collect(),
            train_labels: y.to_vec(),
            report: Some(report),
        })
    }

    pub fn dim(&self) -> usize {
        self.scaler.mean.len()
    }

    pub fn l_matrix(&self) -> DMatrix<f64> {
        let d = self.l.len();
        DMatrix::from_fn(d, d, |r, c| self.l.get(r).and_then(|row| row.get(c)).copied().unwrap_or(0.0))
    }

    /// Map raw samples (rows) into the learned space.
    pub fn map(&self, x: &DMatrix<f64>) -> DMatrix<f64> {
        self.scaler.transform(x) * self.l_matrix().transpose()
    }

    /// Check that a loaded model is self-consistent.
    pub fn validate(&self) -> Result<()> {
        let d = self.dim();
        if d == 0 || self.scaler.scale.len() != d || self.l.len() != d || self.l.iter().any(|r| r.len() != d) {
            bail!("model: L and the scaler must be {d} x {d} and {d} long");
        }
        if self.train_std.len() != self.train_labels.len() || self.train_std.iter().any(|r| r.len() != d) {
            bail!("model: training samples and labels do not match");
        }
        if self.k == 0 || self.k > self.train_labels.len() {
            bail!("model: k = {} with {} training samples", self.k, self.train_labels.len());
        }
        let finite = self.l.iter().flatten().chain(self.scaler.mean.iter()).chain(self.scaler.scale.iter()).all(|v| v.is_finite());
        if !finite || self.scaler.scale.contains(&0.0) {
            bail!("model: non-finite or zero values in L or the scaler");
        }
        Ok(())
    }

    /// The standardised training samples as a matrix.
    pub fn train_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_fn(self.train_std.len(), self.dim(), |r, c| self.train_std[r][c])
    }

    /// kNN labels of raw samples in the learned metric.
    pub fn predict(&self, x: &DMatrix<f64>) -> Vec<i64> {
        let lt = self.l_matrix().transpose();
        knn::predict(&(self.train_matrix() * &lt), &self.train_labels, &self.map(x), self.k)
    }

    /// kNN labels of raw samples in the Euclidean metric of the standardised features.
    pub fn predict_euclidean(&self, x: &DMatrix<f64>) -> Vec<i64> {
        knn::predict(&self.train_matrix(), &self.train_labels, &self.scaler.transform(x), self.k)
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        let s = serde_json::to_string(self)?;
        std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
    }

    pub fn load(path: &Path) -> Result<Self> {
        let s = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let m: LmnnModel = serde_json::from_str(&s).with_context(|| format!("{} is not an LMNN model", path.display()))?;
        m.validate().with_context(|| format!("{}", path.display()))?;
        Ok(m)
    }
}

/// Read labelled samples: comma-separated, features then an integer label; a first line that
/// with no number in any cell is a header (one with a typo in a single cell is an error). Every
/// row must have the same number of columns.
pub fn read_csv(path: &Path) -> Result<(DMatrix<f64>, Vec<i64>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    parse_csv(&text).with_context(|| format!("{}", path.display()))
}

pub fn parse_csv(text: &str) -> Result<(DMatrix<f64>, Vec<i64>)> {
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut labels = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Option<Vec<f64>> = cells.iter().map(|c| c.parse::<f64>().ok()).collect();
        let Some(vals) = parsed else {
            // A header has no number at all; a first row with one typo (`1,2.O,0`) is an error.
            if rows.is_empty() && labels.is_empty() && ln == 0 && cells.iter().all(|c| c.parse::<f64>().is_err()) {
                continue; // header
            }
            bail!("line {}: not a number in {line:?}", ln + 1);
        };
        if vals.len() < 2 {
            bail!("line {}: need at least one feature and a label", ln + 1);
        }
        let (feat, lab) = vals.split_at(vals.len() - 1);
        let lab = lab[0];
        if lab.fract() != 0.0 || !lab.is_finite() || lab.abs() > 1e15 {
            bail!("line {}: the label (last column) must be an integer, got {lab}", ln + 1);
        }
        if let Some(first) = rows.first() {
            if first.len() != feat.len() {
                bail!("line {}: {} features, the first row has {}", ln + 1, feat.len(), first.len());
            }
        }
        if feat.iter().any(|v| !v.is_finite()) {
            bail!("line {}: a feature is not finite", ln + 1);
        }
        rows.push(feat.to_vec());
        labels.push(lab as i64);
    }
    if rows.is_empty() {
        bail!("no samples");
    }
    let d = rows[0].len();
    Ok((DMatrix::from_fn(rows.len(), d, |r, c| rows[r][c]), labels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_errors_are_clear() {
        assert!(parse_csv("a,b,label\n1,2,0\n3,4,1\n").is_ok());
        let e = parse_csv("1,2,0\n3,x,1\n").unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
        assert!(parse_csv("1,2,0.5\n").unwrap_err().to_string().contains("integer"));
        assert!(parse_csv("1,2,0\n1,0\n").unwrap_err().to_string().contains("features"));
        assert!(parse_csv("").is_err());
    }

    #[test]
    fn scaler_matches_population_std() {
        let x = DMatrix::from_row_slice(4, 2, &[1.0, 5.0, 2.0, 5.0, 3.0, 5.0, 4.0, 5.0]);
        let s = Scaler::fit(&x);
        assert!((s.mean[0] - 2.5).abs() < 1e-12 && (s.scale[0] - 1.25f64.sqrt()).abs() < 1e-12);
        assert_eq!(s.scale[1], 1.0, "constant feature keeps scale 1");
    }
}
