use super::*;
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::Distribution;
use std::path::PathBuf;
use std::time::Duration;
use subnav_core::head;
use subnav_wire::PolarizationCalibration;

/// A recording of `proc` from an IMU with `raw = N R x + b` (exact, plus white noise `sigma`).
fn synthetic_imu(proc: &Procedure, b: &crate::manufacturing::BuildErrors, sigma: f64) -> Recording {
    let traj = Trajectory::rig(&proc.motion);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = subnav_base::imu::normal(sigma);
    let mut rec = Recording { boot_seen: true, ..Recording::default() };
    let mut t_us = 0u64;
    while (t_us as f64) * 1e-6 < proc.duration_s() {
        let truth = traj.at(t_us as f64 * 1e-6);
        let (g, a) = b.sense(&truth.gyro_radps, &truth.specific_force_mps2);
        let f = |v: Vector3<f64>, rng: &mut ChaCha8Rng| [0, 1, 2].map(|k| (v[k] + n.sample(rng)) as f32);
        rec.imu.push(ImuSample { t_us, gyro_radps: f(g, &mut rng), accel_mps2: f(a, &mut rng), temp_c: 12.0 });
        t_us += 5_000;
    }
    rec
}

#[test]
fn imu_fit_recovers_the_injected_build() {
    let proc = Procedure::standard();
    for seed in [1, 2, 3] {
        let b = crate::manufacturing::BuildErrors::draw(seed);
        let cal = fit_imu(&synthetic_imu(&proc, &b, 0.0), &proc).unwrap();
        let e = recovery_errors(&[Record::Imu(cal)], seed);
        assert!(e.mounting_deg < 1e-3, "{e:?}");
        assert!(e.max_accel_scale_rel < 1e-5, "{e:?}");
        // The head's own correction maps the raw samples back to the body's.
        let k = subnav_firmware::calibration::ImuCorrection::new(&cal).unwrap();
        let (w, f) = (Vector3::new(0.3, -0.2, 0.5), Vector3::new(1.0, -2.0, -9.0));
        let (g, a) = b.sense(&w, &f);
        let raw = ImuSample {
            t_us: 0,
            gyro_radps: [g.x, g.y, g.z].map(|v| v as f32),
            accel_mps2: [a.x, a.y, a.z].map(|v| v as f32),
            temp_c: 0.0,
        };
        let out = k.apply(&raw);
        for i in 0..3 {
            assert!((f64::from(out.gyro_radps[i]) - w[i]).abs() < 1e-5, "gyro {out:?}");
            assert!((f64::from(out.accel_mps2[i]) - f[i]).abs() < 1e-4, "accel {out:?}");
        }
    }
    // With the head's noise (ICM-42688-P white noise per sample) the mounting is still within 0.01 deg.
    let b = crate::manufacturing::BuildErrors::draw(4);
    let cal = fit_imu(&synthetic_imu(&proc, &b, 0.01), &proc).unwrap();
    assert!(recovery_errors(&[Record::Imu(cal)], 4).mounting_deg < 0.01);
}

#[test]
fn polarization_fit_recovers_injected_channels_in_an_analytic_case() {
    // Counts from the channel model with known channels; chi sweeping, I and P varying.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let truth = crate::manufacturing::BuildErrors::draw(11).polarization[2];
    let samples: Vec<([f64; 4], f64)> = (0..600)
        .map(|i| {
            let chi = -1.0 + 2.2 * i as f64 / 600.0;
            let s0 = rng.random_range(8000.0..20000.0);
            let dolp = rng.random_range(0.2..0.4);
            (model_counts(&truth, [s0, s0 * dolp * (2.0 * chi).cos(), s0 * dolp * (2.0 * chi).sin()]), chi)
        })
        .collect();
    let cal = fit_unit(2, &samples).unwrap();
    let mean_true = truth.iter().map(|c| f64::from(c.gain)).sum::<f64>() / 4.0;
    for (k, t) in truth.iter().enumerate() {
        let g = f64::from(cal.gain[k]) / f64::from(head::POLARIZATION_GAIN_COUNTS);
        assert!((g - f64::from(t.gain) / mean_true).abs() < 1e-4, "channel {k} gain {g}: {cal:?}");
    }
    // The unobservable parts (module doc) aside, the calibrated unit gives the true angle of
    // polarization, and the nominal one does not.
    assert!(max_aop_error_deg(&cal, &truth) < 0.01, "{} deg: {cal:?}", max_aop_error_deg(&cal, &truth));
    let n = head::polarization_units()[2].unwrap().channels;
    let nominal = PolarizationCalibration {
        unit: 2,
        gain: n.map(|c| c.gain),
        offset_counts: n.map(|c| c.offset_counts),
        polarizer_rad: n.map(|c| c.polarizer_rad),
        extinction_ratio: n.map(|c| c.extinction_ratio),
    };
    assert!(max_aop_error_deg(&nominal, &truth) > 0.5, "{}", max_aop_error_deg(&nominal, &truth));
    // The head accepts it and its f32 compass agrees.
    let model = subnav_firmware::calibration::unit_model(&cal).unwrap();
    for chi in [-0.7f64, 0.1, 0.9] {
        let y = model_counts(&truth, [20000.0, 6000.0 * (2.0 * chi).cos(), 6000.0 * (2.0 * chi).sin()]);
        let o = model.observe(&y.map(|v| v.round() as i16), 1e-3, 0.02).unwrap();
        assert!((f64::from(o.aop_rad) - chi).abs() < 0.02f64.to_radians(), "chi {chi}: {}", o.aop_rad);
    }
}

#[test]
fn too_few_samples_and_no_head_are_named() {
    let err = fit_unit(1, &[([300.0; 4], 0.0); 10]).unwrap_err().to_string();
    assert!(err.contains("polarization unit 1") && err.contains("10 samples"), "{err}");
    let proc = Procedure::standard();
    let err = fit_all(&Recording::default(), &proc, &Site::of(&proc.scenario(None, 1))).unwrap_err().to_string();
    assert!(err.contains("no head answered"), "{err}");
    let missing = Target::Qemu { elf: PathBuf::from("/nonexistent/subnav-qemu.elf"), timeout: Duration::from_secs(5) };
    let sc = proc.scenario(None, 1);
    let err = run_session(&missing, &sc, SimHead::new(&sc)).unwrap_err().to_string();
    assert!(err.contains("/nonexistent/subnav-qemu.elf"), "{err}");
}
