//! `subnav calibrate` end to end on the native head: a mis-built head is calibrated from its
//! own raw samples, the records go over the downlink into its flash, the next boot uses them,
//! and its compass comes near the ideal head's (the full table is `subnav calibrate compare`,
//! docs/PERFORMANCE.md).

use subnav_sil::Scenario;
use subnav_sil::calibrate::{self, Procedure, Target};
use subnav_sil::chips::w25q::SharedFlash;
use subnav_wire::{Record, Uplink};

#[test]
fn calibrated_heads_come_near_the_ideal_head() {
    let dive = Scenario { duration_s: 90.0, ..Scenario::default() };
    for seed in [3, 8] {
        let c = calibrate::compare(seed, &dive).unwrap();
        eprintln!("{c:?}");
        let r = c.recovery;
        assert!(r.max_aop_deg < 0.05 && r.max_gain_rel < 0.005 && r.mounting_deg < 0.05, "seed {seed}: {r:?}");
        let (u, k, i) = (c.uncalibrated, c.calibrated, c.ideal);
        assert!(k.compass_fixes > 500, "seed {seed}: {c:?}");
        // Uncalibrated: no fix at all, or fixes far off.
        assert!(u.compass_fixes == 0 || k.compass_median_abs_deg < 0.5 * u.compass_median_abs_deg, "seed {seed}: {c:?}");
        assert!(k.compass_rmse_inliers_deg < 1.5 * i.compass_rmse_inliers_deg, "seed {seed}: {c:?}");
    }
}

#[test]
fn the_next_boot_uses_the_written_calibration_and_bad_records_are_refused_by_name() {
    let flash = SharedFlash::default();
    let cal = calibrate::calibrate(&Target::Native, Some(5), 77, &flash).unwrap();
    assert_eq!(cal.records.len(), subnav_core::head::POLARIZATION_UNITS + 1);
    eprintln!("{:?}", calibrate::recovery_errors(&cal.records, 5));
    let sc = Scenario { duration_s: 1.0, build_seed: Some(5), ..Scenario::default() };
    let run = subnav_sil::run::HeadRun::native(&sc)
        .on_head(subnav_sil::SimHead::new(&sc).with_flash_chip(flash.clone()))
        .keep_all()
        .run()
        .unwrap();
    let boot = run.messages.iter().find_map(|m| if let Uplink::Boot(b) = m { Some(b.calibration) } else { None }).unwrap();
    assert_eq!(boot.polarization_units_stored, u8::MAX >> (8 - subnav_core::head::POLARIZATION_UNITS), "{boot:?}");
    assert!(boot.imu_stored, "{boot:?}");

    // A gain the head's range check refuses: the error names the record and the reason.
    let Some(Record::Polarization(mut p)) = cal.records.first().copied() else { panic!("first record is unit 0") };
    p.gain[2] = 5.0;
    let proc = Procedure::standard();
    let still = proc.scenario(Some(5), 78);
    let err = calibrate::write_and_verify(&Target::Native, &still, &flash, &[Record::Polarization(p)]).unwrap_err().to_string();
    assert!(err.contains("refused the polarization unit 0 calibration"), "{err}");
}
