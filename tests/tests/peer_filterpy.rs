//! Peer check: `subnav_core::ukf::Ukf` with adaptation off against FilterPy 2.0.0's
//! `UnscentedKalmanFilter` + `MerweScaledSigmaPoints` (tests/peers/filterpy_ukf.py), same
//! alpha/beta/kappa, on a nonlinear problem: a coordinated-turn target (heading wraps through
//! +-pi) tracked by range and bearing to a beacon (bearing wraps), 300 steps, plus a range-only
//! update of a different size every third step.
//!
//! Tolerance (relative): for every step and component, `|x - x_py| <= 1e-6 * max(|x_py|,
//! sqrt(P_py_ii))` (heading compared modulo 2 pi) and `|P_ij - P_py_ij| <= 1e-6 *
//! sqrt(P_py_ii P_py_jj)`.

use std::process::Command;

use subnav_core::ukf::nalgebra::{SMatrix, SVector, Vector1};
use subnav_core::ukf::{Euclidean, MeasNoise, Space, Ukf, UkfConfig, wrap_pi};

const STEPS: usize = 300;
const DT: f64 = 0.5;
const BEACON: [f64; 2] = [20.0, 60.0];

struct CtState;
impl Space<f64, 5> for CtState {
    fn add(x: &SVector<f64, 5>, dx: &SVector<f64, 5>) -> SVector<f64, 5> {
        let mut y = x + dx;
        y[3] = wrap_pi(y[3]);
        y
    }
    fn residual(a: &SVector<f64, 5>, b: &SVector<f64, 5>) -> SVector<f64, 5> {
        let mut y = a - b;
        y[3] = wrap_pi(y[3]);
        y
    }
    fn mean<const S: usize>(p: &[SVector<f64, 5>; S], wm: &[f64; S]) -> SVector<f64, 5> {
        let mut m = SVector::<f64, 5>::zeros();
        let (mut s, mut c) = (0.0, 0.0);
        for (x, w) in p.iter().zip(wm) {
            m += x * *w;
            s += x[3].sin() * w;
            c += x[3].cos() * w;
        }
        m[3] = s.atan2(c);
        m
    }
}

struct RangeBearing;
impl Space<f64, 2> for RangeBearing {
    fn residual(a: &SVector<f64, 2>, b: &SVector<f64, 2>) -> SVector<f64, 2> {
        let mut y = a - b;
        y[1] = wrap_pi(y[1]);
        y
    }
    fn mean<const S: usize>(p: &[SVector<f64, 2>; S], wm: &[f64; S]) -> SVector<f64, 2> {
        let mut m = SVector::<f64, 2>::zeros();
        let (mut s, mut c) = (0.0, 0.0);
        for (z, w) in p.iter().zip(wm) {
            m += z * *w;
            s += z[1].sin() * w;
            c += z[1].cos() * w;
        }
        m[1] = s.atan2(c);
        m
    }
}

fn fx(x: &SVector<f64, 5>) -> SVector<f64, 5> {
    SVector::<f64, 5>::new(x[0] + x[2] * x[3].cos() * DT, x[1] + x[2] * x[3].sin() * DT, x[2], wrap_pi(x[3] + x[4] * DT), x[4])
}
fn hx2(x: &SVector<f64, 5>) -> SVector<f64, 2> {
    let (dx, dy) = (x[0] - BEACON[0], x[1] - BEACON[1]);
    SVector::<f64, 2>::new(dx.hypot(dy), dy.atan2(dx))
}
fn hx1(x: &SVector<f64, 5>) -> SVector<f64, 1> {
    Vector1::new((x[0] - BEACON[0]).hypot(x[1] - BEACON[1]))
}

/// xorshift64* + Box-Muller: deterministic noise without a dependency.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

fn diag<const D: usize>(v: [f64; D]) -> SMatrix<f64, D, D> {
    SMatrix::<f64, D, D>::from_diagonal(&SVector::<f64, D>::from(v))
}

#[test]
fn ukf_matches_filterpy_unscented_kalman_filter() {
    // Truth and measurements.
    let mut rng = Rng(0x5eed_1234_abcd_0001);
    let mut truth = SVector::<f64, 5>::new(0.0, 0.0, 5.0, 2.9, 0.05);
    let (sr, sb) = (0.5, 0.02);
    let mut steps = Vec::new();
    for k in 0..STEPS {
        truth = fx(&truth);
        truth[2] += 0.05 * rng.normal();
        truth[4] += 0.002 * rng.normal();
        let z = hx2(&truth);
        let z2 = [z[0] + sr * rng.normal(), wrap_pi(z[1] + sb * rng.normal())];
        let z1 = (k % 3 == 0).then(|| z[0] + sr * rng.normal());
        steps.push((z2, z1));
    }
    let x0 = [2.0, -3.0, 4.0, 2.7, 0.0];
    let p0 = diag([25.0, 25.0, 1.0, 0.1, 0.01]);
    let q = diag([0.01, 0.01, 0.01, 1e-4, 1e-5]);
    let r2 = diag([sr * sr, sb * sb]);
    let r1 = diag([sr * sr]);
    let configs = [(0.5, 2.0, -2.0), (0.1, 2.0, 0.0), (1.0, 0.0, 1.0)];

    let to_rows =
        |m: &dyn Fn(usize, usize) -> f64, n: usize| -> Vec<Vec<f64>> { (0..n).map(|i| (0..n).map(|j| m(i, j)).collect()).collect() };
    let problem = serde_json::json!({
        "dt": DT,
        "beacon": BEACON,
        "x0": x0,
        "p0": to_rows(&|i, j| p0[(i, j)], 5),
        "q": to_rows(&|i, j| q[(i, j)], 5),
        "r2": to_rows(&|i, j| r2[(i, j)], 2),
        "r1": to_rows(&|i, j| r1[(i, j)], 1),
        "configs": configs.iter().map(|(a, b, k)| serde_json::json!({"alpha": a, "beta": b, "kappa": k})).collect::<Vec<_>>(),
        "steps": steps.iter().map(|(z2, z1)| serde_json::json!({"z2": z2, "z1": z1})).collect::<Vec<_>>(),
    });
    let dir = std::env::temp_dir().join(format!("subnav-peer-filterpy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let inp = dir.join("problem.json");
    let outp = dir.join("filterpy.json");
    std::fs::write(&inp, serde_json::to_vec(&problem).unwrap()).unwrap();
    let script = subnav_tests::peers_dir().join("filterpy_ukf.py");
    let run = Command::new(subnav_tests::peer_python()).arg(&script).arg(&inp).arg(&outp).output().unwrap();
    assert!(run.status.success(), "peer script failed: {}", String::from_utf8_lossy(&run.stderr));
    let peer: serde_json::Value = serde_json::from_slice(&std::fs::read(&outp).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);

    for (ci, &(alpha, beta, kappa)) in configs.iter().enumerate() {
        let cfg = UkfConfig::plain(alpha, beta, kappa);
        let mut ukf: Ukf<f64, 5, 11, CtState> = Ukf::new(cfg, SVector::from(x0), p0, q).unwrap();
        let mut n2 = MeasNoise::new(r2);
        let mut n1 = MeasNoise::new(r1);
        let px = &peer[ci]["x"];
        let pp = &peer[ci]["p"];
        let (mut worst_x, mut worst_p) = (0.0f64, 0.0f64);
        for (k, (z2, z1)) in steps.iter().enumerate() {
            ukf.predict(1.0, fx).unwrap();
            let rep = ukf.update::<2, RangeBearing, _>(&SVector::from(*z2), &mut n2, hx2).unwrap();
            assert!(rep.accepted);
            if let Some(r) = z1 {
                ukf.update::<1, Euclidean, _>(&Vector1::new(*r), &mut n1, hx1).unwrap();
            }
            let x = ukf.x();
            let p = ukf.p();
            for i in 0..5 {
                let xp = px[k][i].as_f64().unwrap();
                let pii = pp[k][i][i].as_f64().unwrap();
                let mut d = x[i] - xp;
                if i == 3 {
                    d = wrap_pi(d);
                }
                let rel = d.abs() / xp.abs().max(pii.sqrt());
                worst_x = worst_x.max(rel);
                assert!(rel <= 1e-6, "config {ci} step {k} x[{i}]: ours {} filterpy {xp} (rel {rel:e})", x[i]);
                for j in 0..5 {
                    let pj = pp[k][j][j].as_f64().unwrap();
                    let v = pp[k][i][j].as_f64().unwrap();
                    let rel = (p[(i, j)] - v).abs() / (pii * pj).sqrt();
                    worst_p = worst_p.max(rel);
                    assert!(rel <= 1e-6, "config {ci} step {k} P[{i},{j}]: ours {} filterpy {v} (rel {rel:e})", p[(i, j)]);
                }
            }
        }
        println!(
            "config alpha={alpha} beta={beta} kappa={kappa}: {STEPS} steps, worst relative difference x {worst_x:.2e}, P {worst_p:.2e}"
        );
    }
}
