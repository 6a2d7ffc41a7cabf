//! `subnav lmnn`: LMNN metric learning (spec A3) on labelled samples in CSV.
//!
//! - `fit --train CSV [--k 3] --out model.json`: standardise (fitted on the training set), learn
//!   `L`, save the model (scaler, `L`, mapped training samples).
//! - `eval --model model.json --test CSV`: kNN accuracy in the learned metric (and, for
//!   reference, Euclidean kNN on the standardised features).
//!
//! CSV: comma-separated features, then an integer label in the last column; an optional header.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde_json::json;

use super::Format;
use subnav_topo::lmnn::model::read_csv;
use subnav_topo::lmnn::{LmnnConfig, LmnnModel, accuracy};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Sub,
}

#[derive(Debug, clap::Subcommand)]
pub enum Sub {
    /// Learn the metric on a labelled CSV and save the model.
    Fit {
        /// Training samples (CSV: features..., integer label).
        #[arg(long)]
        train: PathBuf,
        /// Target neighbours per sample (and the k of kNN), 1..=1000.
        #[arg(long, allow_hyphen_values = true, default_value_t = 3, value_parser = super::args::int_in(1usize..=1000))]
        k: usize,
        /// Maximum gradient iterations (2..=1000000).
        #[arg(long, allow_hyphen_values = true, default_value_t = 1000, value_parser = super::args::int_in(2usize..=1_000_000))]
        max_iter: usize,
        /// Pull-term weight (push gets 1 - this), 0..=1.
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.5, value_parser = super::args::f64_in(0.0..=1.0))]
        regularization: f64,
        /// Output model (JSON).
        #[arg(long)]
        out: PathBuf,
    },
    /// kNN accuracy of a saved model on a labelled CSV.
    Eval {
        /// Model (JSON, from `lmnn fit`).
        #[arg(long)]
        model: PathBuf,
        /// Test samples (CSV: features..., integer label).
        #[arg(long)]
        test: PathBuf,
    },
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    match args.command {
        Sub::Fit { train, k, max_iter, regularization, out } => {
            subnav_link::output::refuse_input_as_output("--out", &out, &[&train])?;
            let (x, y) = read_csv(&train)?;
            if k == 0 {
                bail!("--k must be at least 1");
            }
            let cfg = LmnnConfig { k, max_iter, regularization, ..LmnnConfig::default() };
            let t0 = Instant::now();
            let model = LmnnModel::fit(&x, &y, &cfg).with_context(|| format!("fitting {}", train.display()))?;
            let secs = t0.elapsed().as_secs_f64();
            model.save(&out)?;
            let train_acc = accuracy(&model.predict(&x), &y);
            let rep = model.report.clone();
            match format {
                Format::Json => println!(
                    "{}",
                    json!({"samples": x.nrows(), "features": x.ncols(), "k": k, "fit_s": secs, "train_accuracy": train_acc, "report": rep, "model": out})
                ),
                Format::Text => {
                    println!("fitted LMNN on {} samples x {} features (k = {k}) in {secs:.3} s", x.nrows(), x.ncols());
                    if let Some(r) = rep {
                        println!(
                            "  {} iterations ({}), objective {:.4}, {} active triplets",
                            r.iterations,
                            if r.converged { "converged" } else { "iteration limit" },
                            r.objective,
                            r.active_triplets
                        );
                    }
                    println!("  training accuracy ({k}-NN, learned metric): {:.2} %", train_acc * 100.0);
                    println!("  model written to {}", out.display());
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Sub::Eval { model, test } => {
            let m = LmnnModel::load(&model)?;
            let (x, y) = read_csv(&test)?;
            if x.ncols() != m.dim() {
                bail!("{} has {} features, the model expects {}", test.display(), x.ncols(), m.dim());
            }
            let acc = accuracy(&m.predict(&x), &y);
            // Euclidean kNN on the same standardised features, for reference.
            let euclid = accuracy(&m.predict_euclidean(&x), &y);
            match format {
                Format::Json => println!("{}", json!({"samples": x.nrows(), "k": m.k, "accuracy": acc, "euclidean_accuracy": euclid})),
                Format::Text => {
                    println!("{}-NN accuracy on {} samples: {:.2} % (learned metric)", m.k, x.nrows(), acc * 100.0);
                    println!("                               {:.2} % (Euclidean, standardised)", euclid * 100.0);
                }
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
