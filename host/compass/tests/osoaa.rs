//! The compass and the simulator against an independent light field: four OSOAA vector
//! radiative-transfer fields copied into `test-data/osoaa/` (PROVENANCE.md there). Cheap: a few
//! hundred solves and four simulated fields, about a second in release.
//!
//! What the issue asks (issue 35, "Done when") and what these assert:
//! - the compass (the head's 4 units, the firmware's solver): clear water with the sun at 30 deg
//!   RMSE <= 0.5 deg; every case >= 90 % of fixes within 2 reported sigma and <= 5 % outside 3;
//!   turbid water RMSE <= 1.5 deg or no fix. Not met and asserted as measured instead: clear
//!   water with the sun at 60 deg (RMSE about 0.9 deg with 4 units, under 1.2 asserted).
//! - the simulator's field: the goal (AoP within 2 deg where DoLP > 0.1, DoLP within 0.05) is
//!   NOT met; the bounds below are the measured disagreement plus a margin, so that a change
//!   that makes the simulator worse fails here (docs/PERFORMANCE.md has the full table).

use subnav_base::sky::Water;
use subnav_compass::reference::{ReferenceConfig, ReferenceField, compare, run};

fn load(name: &str) -> ReferenceField {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("test-data/osoaa").join(name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    ReferenceField::parse(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

struct Case {
    file: &'static str,
    sza: f64,
    depth: f64,
    wind: f64,
    turbid: bool,
}

const CASES: [Case; 4] = [
    Case { file: "sza30_wind0_clear_z10.csv", sza: 30.0, depth: 10.0, wind: 0.0, turbid: false },
    Case { file: "sza60_wind0_clear_z10.csv", sza: 60.0, depth: 10.0, wind: 0.0, turbid: false },
    Case { file: "sza30_wind0_turbid_z10.csv", sza: 30.0, depth: 10.0, wind: 0.0, turbid: true },
    Case { file: "sza60_wind5_turbid_z20.csv", sza: 60.0, depth: 20.0, wind: 5.0, turbid: true },
];

#[test]
fn compass_in_osoaa_fields() {
    for c in &CASES {
        let f = load(c.file);
        let r = run(&f, &ReferenceConfig { sun_zenith_deg: c.sza, depth_m: c.depth, draws: 300, seed: 3, ..ReferenceConfig::default() });
        assert_eq!(r.units, subnav_core::head::POLARIZATION_UNITS);
        if r.fixes > 0 {
            assert!(r.within_2_sigma >= 0.9, "{}: {r:?}", c.file);
            assert!(r.within_3_sigma >= 0.95, "{}: {r:?}", c.file);
        }
        if c.turbid {
            assert!(r.rmse_deg <= 1.5 || r.fixes == 0, "{}: {r:?}", c.file);
            // Wherever there is no fix, there is a reason.
            assert_eq!(r.no_fix.values().sum::<usize>(), r.draws - r.fixes, "{}: {r:?}", c.file);
        } else {
            assert!(r.no_fix_fraction <= 0.05, "{}: {r:?}", c.file);
            let bound = if c.sza < 45.0 { 0.5 } else { 1.2 };
            assert!(r.rmse_deg <= bound, "{}: {r:?}", c.file);
        }
    }
}

/// The solver as it was (pure single scattering) gives confident wrong headings in the low-sun
/// clear field: fewer than 80 % within 2 sigma or most solves refused; the one above does not.
#[test]
fn the_single_scattering_solver_was_overconfident() {
    let f = load("sza60_wind0_clear_z10.csv");
    let cfg = ReferenceConfig {
        sun_zenith_deg: 60.0,
        depth_m: 10.0,
        draws: 300,
        seed: 3,
        single_scattering_solver: true,
        ..ReferenceConfig::default()
    };
    let old = run(&f, &cfg);
    let new = run(&f, &ReferenceConfig { single_scattering_solver: false, ..cfg });
    assert!(old.no_fix_fraction > 0.3 || old.within_2_sigma < 0.9, "{old:?}");
    assert!(new.no_fix_fraction < old.no_fix_fraction && new.rmse_deg < old.rmse_deg, "{old:?}\n{new:?}");
}

#[test]
fn simulator_field_vs_osoaa() {
    // Measured disagreement (AoP RMS deg, DoLP max) and the bounds asserted (a margin above).
    // Measured (seed 1): AoP RMS 3.39, 9.41, 2.00, 18.25 deg; DoLP max 0.347, 0.433, 0.250, 0.199.
    for ((c, aop_rms_bound), dolp_max_bound) in CASES.iter().zip([4.0, 11.0, 2.5, 20.0]).zip([0.40, 0.50, 0.30, 0.25]) {
        let reference = load(c.file);
        let water = if c.turbid { Water::turbid() } else { Water::clear() };
        let sim = ReferenceField::simulated(c.sza, c.depth, c.wind, water, 1);
        let cmp = compare(&sim, &reference, 0.1, 80.0).expect("same grid");
        assert!(cmp.aop_points > 50, "{}: {cmp:?}", c.file);
        assert!(cmp.aop_rms_deg <= aop_rms_bound, "{}: {cmp:?}", c.file);
        assert!(cmp.dolp_max_abs <= dolp_max_bound, "{}: {cmp:?}", c.file);
        // The CSV the CLI writes reads back as the same field.
        let back = ReferenceField::parse(&sim.to_csv()).expect("own CSV");
        let same = compare(&back, &sim, 0.1, 80.0).expect("same grid");
        assert!(same.aop_rms_deg < 0.01 && same.dolp_max_abs < 1e-4, "{}: {same:?}", c.file);
    }
}
