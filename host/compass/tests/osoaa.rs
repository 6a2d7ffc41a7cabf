//! The compass and the simulator against an independent light field: four OSOAA vector
//! radiative-transfer fields copied into `test-data/osoaa/` (PROVENANCE.md there). Cheap: a few
//! hundred solves and a few simulated fields, a few seconds in release.
//!
//! What the issue asks (issue 35, "Done when") and what these assert:
//! - the compass (the head's 4 units, issue 35's solver with an AoP departure table that has
//!   not seen the case's depth): clear water RMSE <= 0.5 deg; every case >= 90 % of fixes
//!   within 2 reported sigma and >= 95 % within 3; turbid water RMSE <= 1.5 deg or no fix with
//!   a reason. (Not every one of the 24 cases meets it with 4 units: docs/PERFORMANCE.md.)
//! - the simulator's field (with the OSOAA departure table): the goal (AoP within 2 deg where
//!   DoLP > 0.1, DoLP within 0.05), trivially, since the table comes from these fields; and its
//!   leave-one-out figure (the depth from the other depths) within the measured bounds.

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

/// Issue 35's solver with the AoP departure table built from the other depths than the
/// case's (`DepartureTable::LeaveDepthOut`, the default): never a table that has seen the case.
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
            assert!(r.rmse_deg <= 0.5, "{}: {r:?}", c.file);
        }
    }
}

/// The head as it was (4 units, the pure single-scattering solver) gives confident wrong
/// headings in the low-sun clear field: fewer than 90 % within 2 sigma or most solves refused;
/// the head's (8 units, issue 35's solver) refuses fewer and is closer.
#[test]
fn the_single_scattering_solver_was_overconfident() {
    let f = load("sza60_wind0_clear_z10.csv");
    let cfg = ReferenceConfig {
        sun_zenith_deg: 60.0,
        depth_m: 10.0,
        draws: 300,
        seed: 3,
        units: 4,
        single_scattering_solver: true,
        ..ReferenceConfig::default()
    };
    let old = run(&f, &cfg);
    let new = run(&f, &ReferenceConfig { single_scattering_solver: false, units: subnav_core::head::POLARIZATION_UNITS, ..cfg });
    assert!(old.no_fix_fraction > 0.3 || old.within_2_sigma < 0.9, "{old:?}");
    assert!(new.no_fix_fraction < old.no_fix_fraction && new.rmse_deg < old.rmse_deg, "{old:?}\n{new:?}");
}

/// The simulator's field (`SeaField` with the OSOAA departure table, the reference case's
/// water) against the original OSOAA files: the goal (AoP within 2 deg where DoLP > 0.1,
/// DoLP within 0.05, at every grid point). The table was derived from these fields, so this
/// checks the derivation and the code that uses it, not the physics; the leave-one-out below
/// is the check of how the simulator generalises.
#[test]
fn simulator_field_vs_osoaa() {
    let table = subnav_base::osoaa::Table::osoaa().expect("the embedded table");
    for c in &CASES {
        let reference = load(c.file);
        let water = if c.turbid { Water::turbid() } else { Water::oceanic() };
        let sim = ReferenceField::simulated(c.sza, c.depth, c.wind, water, 1);
        let cmp = compare(&sim, &reference, 0.1, 80.0).expect("same grid");
        assert!(cmp.aop_points > 50, "{}: {cmp:?}", c.file);
        assert!(cmp.aop_max_abs_deg <= 2.0 && cmp.dolp_max_abs <= 0.05, "{}: {cmp:?}", c.file);
        // The pure single-scattering simulator is far off (what the table corrects).
        let pure = ReferenceField::simulated_with(c.sza, c.depth, c.wind, Water { polarization_table: false, ..water }, 1, None);
        let cmp_pure = compare(&pure, &reference, 0.1, 80.0).expect("same grid");
        assert!(cmp_pure.aop_rms_deg > 3.0 && cmp_pure.dolp_max_abs > 0.15, "{}: {cmp_pure:?}", c.file);
        // The CSV the CLI writes reads back as the same field.
        let back = ReferenceField::parse(&sim.to_csv()).expect("own CSV");
        let same = compare(&back, &sim, 0.1, 80.0).expect("same grid");
        assert!(same.aop_rms_deg < 0.01 && same.dolp_max_abs < 1e-4, "{}: {same:?}", c.file);
        // Leave-one-out: the case's depth from the table's other depths (interpolated for 10 m,
        // held from 10 m for 20 m). Bounds: the measured figures (docs/PERFORMANCE.md) plus a
        // margin: AoP RMS 0.34, 0.89, 0.68, 6.45 deg; DoLP max 0.038, 0.034, 0.043, 0.111.
        let loo = table.without(c.sza, c.wind, c.turbid, c.depth, subnav_base::osoaa::LeaveOut::Depth);
        let sim = ReferenceField::simulated_with(c.sza, c.depth, c.wind, water, 1, Some(&loo));
        let cmp = compare(&sim, &reference, 0.1, 80.0).expect("same grid");
        let (aop_rms, dolp_max) = match (c.sza < 45.0, c.turbid) {
            (true, false) => (0.5, 0.05),
            (false, false) => (1.2, 0.05),
            (true, true) => (1.0, 0.06),
            (false, true) => (7.5, 0.13),
        };
        assert!(cmp.aop_rms_deg <= aop_rms && cmp.dolp_max_abs <= dolp_max, "{} leave-depth-out: {cmp:?}", c.file);
    }
}
