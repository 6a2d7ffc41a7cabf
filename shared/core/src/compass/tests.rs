//! Compass tests on synthetic single-scattering (Rayleigh) data generated here from first
//! principles: e-vector perpendicular to the plane of sun and view, DoLP = sin^2 g / (1 + cos^2 g).
//! The physically based field with Fresnel transmission and noise lives in the host simulator.

use super::*;
use nalgebra::Rotation3;

const N_UNITS: usize = 8;

/// The synthetic data here is pure Rayleigh (no Fresnel polarization of the sunbeam).
fn cfg() -> CompassConfig {
    CompassConfig { fresnel_correction: false, ..CompassConfig::default() }
}

fn units() -> [UnitModel; N_UNITS] {
    core::array::from_fn(|i| {
        let (v, a) = unit::ring_geometry(i, N_UNITS, 15.0 * DEG);
        UnitModel::nominal(v, a, 20_000.0, 300.0, 500.0, NoiseModel::default()).unwrap()
    })
}

/// Counts for refracted sun `s_body` (toward the sun), with DoLP scaled by `dolp_scale` and
/// intensity `s0`. Unit `bad` (if any) gets its AoP turned by 50 deg.
fn counts(units: &[UnitModel], s_body: Vector3<f32>, s0: f32, dolp_scale: f32, bad: Option<usize>) -> [[i16; 4]; N_UNITS] {
    core::array::from_fn(|i| {
        let u = &units[i];
        let d = Vector3::from(u.view_body);
        let a = Vector3::from(u.axis0_body);
        let b = d.cross(&a);
        let e = d.cross(&s_body);
        let cos_g = d.dot(&s_body);
        let dolp = dolp_scale * (1.0 - cos_g * cos_g) / (1.0 + cos_g * cos_g);
        let mut chi = libm::atan2f(e.dot(&b), e.dot(&a));
        if bad == Some(i) {
            chi += 50.0 * DEG;
        }
        let (s1, s2) = (s0 * dolp * libm::cosf(2.0 * chi), s0 * dolp * libm::sinf(2.0 * chi));
        core::array::from_fn(|k| {
            let c = &u.channels[k];
            let eta = (c.extinction_ratio - 1.0) / (c.extinction_ratio + 1.0);
            let th = 2.0 * c.polarizer_rad;
            let i = 0.5 * (s0 + eta * (s1 * libm::cosf(th) + s2 * libm::sinf(th)));
            (c.offset_counts + c.gain * i).round().clamp(-32768.0, 32767.0) as i16
        })
    })
}

/// 2030-06-01 14:00 UTC, 43.3 N 5.4 E (Marseille): sun well up.
const T_US: i64 = 1_906_552_800_000_000;
fn place() -> Observer {
    Observer { lat_rad: 43.3 * DEG, lon_rad: 5.4 * DEG, height_m: 0.0 }
}

struct Scene {
    counts: [[i16; 4]; N_UNITS],
    accel: [f32; 3],
}

/// Scene for a vehicle attitude (roll, pitch, yaw) with the sun from the ephemeris.
fn scene(units: &[UnitModel], roll: f32, pitch: f32, yaw: f32, s0: f32, dolp_scale: f32, bad: Option<usize>) -> Scene {
    let cfg = cfg();
    let eph = ephemeris::sun_position(T_US, &place(), Some(&Atmosphere::default()), 70.0).unwrap();
    let zw = water::water_zenith_rad(eph.apparent_zenith_rad, cfg.n_water);
    let (sz, cz) = (libm::sinf(zw), libm::cosf(zw));
    let s_ned = Vector3::new(sz * libm::cosf(eph.azimuth_rad), sz * libm::sinf(eph.azimuth_rad), -cz);
    scene_for(units, s_ned, roll, pitch, yaw, s0, dolp_scale, bad)
}

#[allow(clippy::too_many_arguments)]
fn scene_for(
    units: &[UnitModel],
    s_ned: Vector3<f32>,
    roll: f32,
    pitch: f32,
    yaw: f32,
    s0: f32,
    dolp_scale: f32,
    bad: Option<usize>,
) -> Scene {
    let r_nb = Rotation3::from_euler_angles(roll, pitch, yaw);
    let s_body = r_nb.inverse() * s_ned;
    let f = r_nb.inverse() * Vector3::new(0.0, 0.0, -G0_MPS2);
    Scene { counts: counts(units, s_body, s0, dolp_scale, bad), accel: [f.x, f.y, f.z] }
}

fn run(units: &[UnitModel], sc: &Scene) -> Result<HeadingFix, (NoFix, Option<SunMeasurement>)> {
    let input =
        CompassInput { counts: &sc.counts, accel_body_mps2: sc.accel, unix_us: Some(T_US), observer: Some(place()), delta_t_s: 70.0 };
    solve(units, &input, &cfg())
}

fn ang_diff(a: f32, b: f32) -> f32 {
    let mut d = (a - b) % core::f32::consts::TAU;
    if d > core::f32::consts::PI {
        d -= core::f32::consts::TAU;
    }
    if d < -core::f32::consts::PI {
        d += core::f32::consts::TAU;
    }
    d.abs()
}

#[test]
fn heading_with_tilt_is_recovered() {
    let u = units();
    for &(roll, pitch, yaw) in &[(0.0f32, 0.0f32, 0.3f32), (5.0, -3.0, 123.0), (-10.0, 8.0, 250.0), (2.0, 12.0, 359.0)] {
        let sc = scene(&u, roll * DEG, pitch * DEG, yaw * DEG, 1.0, 1.0, None);
        let fix = run(&u, &sc).unwrap();
        let err = ang_diff(fix.heading_rad, yaw * DEG) / DEG;
        assert!(err < 0.05, "attitude ({roll}, {pitch}, {yaw}): heading error {err} deg");
        assert!(fix.sigma_heading_rad > 0.0 && fix.sigma_heading_rad < 0.5 * DEG);
        // In-air elevation from inverse Snell matches the ephemeris.
        assert!((fix.sun.air_elevation_rad - fix.ephemeris_elevation_rad).abs() < 0.1 * DEG);
        assert_eq!(fix.sun.sun.units_used, N_UNITS as u8);
    }
}

/// The pairs form (what the firmware calls, with the units that were read) is the same solve:
/// the same fix to the bit on a subset of units, and more than `MAX_UNITS` pairs refused.
#[test]
fn solving_by_pairs_is_the_same_solve() {
    let u = units();
    let sc = scene(&u, 4.0 * DEG, -6.0 * DEG, 77.0 * DEG, 1.0, 1.0, Some(5));
    let read = [0usize, 2, 3, 5, 6, 7];
    let sub_units: heapless::Vec<UnitModel, N_UNITS> = read.iter().map(|&i| u[i]).collect();
    let sub_counts: heapless::Vec<[i16; 4], N_UNITS> = read.iter().map(|&i| sc.counts[i]).collect();
    let input =
        CompassInput { counts: &sub_counts, accel_body_mps2: sc.accel, unix_us: Some(T_US), observer: Some(place()), delta_t_s: 70.0 };
    let by_slices = solve(&sub_units, &input, &cfg()).unwrap();
    let by_pairs = solve_pairs(read.iter().map(|&i| (&u[i], &sc.counts[i])), &CompassInput { counts: &[], ..input }, &cfg()).unwrap();
    assert_eq!(by_slices.heading_rad.to_bits(), by_pairs.heading_rad.to_bits());
    assert_eq!(by_slices.sigma_heading_rad.to_bits(), by_pairs.sigma_heading_rad.to_bits());
    assert_eq!(by_pairs.sun.sun.outliers, 1);
    let too_many = (0..MAX_UNITS + 1).map(|i| (&u[i % N_UNITS], &sc.counts[i % N_UNITS]));
    assert_eq!(no_fix(solve_pairs(too_many, &input, &cfg())), NoFix::BadInput);
}

#[test]
fn outlier_unit_is_rejected() {
    let u = units();
    let sc = scene(&u, 3.0 * DEG, -2.0 * DEG, 200.0 * DEG, 1.0, 1.0, Some(2));
    let fix = run(&u, &sc).unwrap();
    assert_eq!(fix.sun.sun.outliers, 1);
    let err = ang_diff(fix.heading_rad, 200.0 * DEG) / DEG;
    assert!(err < 0.1, "heading error with an outlier unit: {err} deg");
}

fn no_fix(r: Result<HeadingFix, (NoFix, Option<SunMeasurement>)>) -> NoFix {
    match r {
        Ok(f) => panic!("expected no fix, got heading {}", f.heading_rad),
        Err((e, _)) => e,
    }
}

#[test]
fn no_fix_dark_saturated_low_dolp() {
    let u = units();
    // Night / too deep: counts at the dark offset.
    let dark = scene(&u, 0.0, 0.0, 1.0, 0.0, 1.0, None);
    assert_eq!(no_fix(run(&u, &dark)), NoFix::Dark);
    // Overexposed.
    let sat = scene(&u, 0.0, 0.0, 1.0, 3.5, 1.0, None);
    assert_eq!(no_fix(run(&u, &sat)), NoFix::Saturated);
    // Depolarized light field.
    let flat = scene(&u, 0.0, 0.0, 1.0, 1.0, 0.005, None);
    assert_eq!(no_fix(run(&u, &flat)), NoFix::LowDolp);
}

#[test]
fn no_fix_too_few_units_and_bad_input() {
    let u = units();
    let sc = scene(&u, 0.0, 0.0, 1.0, 1.0, 1.0, None);
    let input =
        CompassInput { counts: &sc.counts[..2], accel_body_mps2: sc.accel, unix_us: Some(T_US), observer: Some(place()), delta_t_s: 70.0 };
    assert_eq!(no_fix(solve(&u[..2], &input, &cfg())), NoFix::TooFewUnits);
    assert_eq!(no_fix(solve(&u[..3], &input, &cfg())), NoFix::BadInput);
    assert_eq!(sun_vector::solve(&[], &Vector3::z(), None, &SolverConfig::default()), Err(NoFix::TooFewUnits));
}

#[test]
fn no_fix_degenerate_geometry() {
    // All units look the same way: every e-vector is the same, the sun is undetermined.
    let (v, a) = unit::ring_geometry(0, 8, 15.0 * DEG);
    let same = [UnitModel::nominal(v, a, 20_000.0, 300.0, 500.0, NoiseModel::default()).unwrap(); N_UNITS];
    let sc = scene(&same, 0.0, 0.0, 1.0, 1.0, 1.0, None);
    assert_eq!(no_fix(run(&same, &sc)), NoFix::Degenerate);
}

#[test]
fn no_fix_sun_near_zenith_and_outside_window() {
    let u = units();
    let zen = scene_for(&u, Vector3::new(0.01, 0.0, -1.0).normalize(), 0.0, 0.0, 0.5, 1.0, 1.0, None);
    // Without the time the zenith pattern is only a sun near the zenith; with the ephemeris sun
    // well below the zenith it is a sky without a sun disc (overcast, a cloud over the sun).
    let no_time = CompassInput { counts: &zen.counts, accel_body_mps2: zen.accel, unix_us: None, observer: None, delta_t_s: 70.0 };
    assert_eq!(no_fix(solve(&u, &no_time, &cfg())), NoFix::SunNearZenith);
    assert_eq!(no_fix(run(&u, &zen)), NoFix::NoSunDisc);
    // A "sun" 10 deg above the horizon in water cannot be refracted sunlight.
    let low = scene_for(&u, Vector3::new(0.985, 0.0, -0.174), 0.0, 0.0, 0.5, 1.0, 1.0, None);
    assert_eq!(no_fix(run(&u, &low)), NoFix::OutsideSnellWindow);
}

#[test]
fn no_fix_time_night_tilt() {
    let u = units();
    let sc = scene(&u, 0.0, 0.0, 1.0, 1.0, 1.0, None);
    // No time: the sun is still measured.
    let input = CompassInput { counts: &sc.counts, accel_body_mps2: sc.accel, unix_us: None, observer: None, delta_t_s: 70.0 };
    match solve(&u, &input, &cfg()) {
        Err((NoFix::NoTime, Some(m))) => assert!(m.sun.units_used as usize == N_UNITS),
        other => panic!("{other:?}"),
    }
    // Ephemeris says night (same place, 02:00 UTC).
    let night = CompassInput { unix_us: Some(T_US - 12 * 3_600_000_000), observer: Some(place()), ..input };
    let r = solve(&u, &night, &cfg());
    assert_eq!(no_fix(r), NoFix::SunBelowHorizon);
    // Free fall / bad accelerometer, NaN.
    let tilt = CompassInput { accel_body_mps2: [0.0, 0.0, -2.0], ..night };
    assert_eq!(no_fix(solve(&u, &tilt, &cfg())), NoFix::TiltInvalid);
    let nan = CompassInput { accel_body_mps2: [f32::NAN, 0.0, -9.8], ..input };
    assert_eq!(no_fix(solve(&u, &nan, &cfg())), NoFix::NonFinite);
    // Body x axis vertical.
    let vertical = CompassInput { accel_body_mps2: [-9.8, 0.0, 0.0], ..input };
    assert_eq!(no_fix(solve(&u, &vertical, &cfg())), NoFix::TiltInvalid);
    // Wrong place: measured elevation disagrees with the ephemeris.
    let wrong =
        CompassInput { observer: Some(Observer { lat_rad: -30.0 * DEG, ..place() }), unix_us: Some(T_US - 5 * 3_600_000_000), ..input };
    let r = solve(&u, &wrong, &cfg());
    assert!(matches!(no_fix(r), NoFix::Inconsistent | NoFix::SunBelowHorizon));
}

#[test]
fn codes_round_trip_and_report() {
    for c in 1..=16u8 {
        let r = NoFix::from_code(c).unwrap();
        assert_eq!(r.code(), c);
        assert!(!r.describe().is_empty());
    }
    assert_eq!(NoFix::from_code(0), None);
    assert_eq!(NoFix::from_code(17), None);
    let u = units();
    let sc = scene(&u, 0.0, 0.0, 1.0, 1.0, 1.0, None);
    let fix = run(&u, &sc);
    let rep = report(7, &fix);
    assert_eq!(rep.no_fix_reason, 0);
    assert!(rep.heading_rad.is_some());
    let dark = scene(&u, 0.0, 0.0, 1.0, 0.0, 1.0, None);
    let rep = report(8, &run(&u, &dark));
    assert_eq!(rep.no_fix_reason, NoFix::Dark.code());
    assert_eq!(rep.heading_rad, None);
}

#[test]
fn sigma_follows_noise() {
    // The reported 1-sigma grows when the polarization signal shrinks.
    let u = units();
    let strong = run(&u, &scene(&u, 0.0, 0.0, 1.0, 1.0, 1.0, None)).unwrap();
    let weak = run(&u, &scene(&u, 0.0, 0.0, 1.0, 1.0, 0.1, None)).unwrap();
    assert!(weak.sigma_heading_rad > 3.0 * strong.sigma_heading_rad, "{} vs {}", weak.sigma_heading_rad, strong.sigma_heading_rad);
}
