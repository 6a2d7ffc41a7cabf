//! `Scenario::validate`: the one check of every number a scenario file can set. Each bad value
//! below was accepted before (issue 23): some hung `subnav run` (a survey that never advances),
//! some asked for gigabytes (a fix every 1e-20 s), the others gave silently wrong figures.

use subnav_sil::Scenario;

fn with(edit: impl FnOnce(&mut serde_json::Value)) -> Result<Scenario, String> {
    let mut v = serde_json::to_value(Scenario::default()).map_err(|e| e.to_string())?;
    edit(&mut v);
    let sc: Scenario = serde_json::from_value(v).map_err(|e| e.to_string())?;
    sc.validate().map_err(|e| e.to_string())?;
    Ok(sc)
}

#[test]
fn the_default_scenario_is_valid() {
    Scenario::default().validate().unwrap();
}

#[test]
fn every_bad_field_is_refused_with_its_name() {
    use serde_json::json;
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit)> = vec![
        ("duration_s", Box::new(|v| v["duration_s"] = json!(1e9))),
        ("lat_deg", Box::new(|v| v["lat_deg"] = json!(95.0))),
        ("lon_deg", Box::new(|v| v["lon_deg"] = json!(500.0))),
        ("start_utc_unix_us", Box::new(|v| v["start_utc_unix_us"] = json!(-5_364_662_400_000_000_i64))), // 1800
        ("start_utc_unix_us", Box::new(|v| v["start_utc_unix_us"] = json!(32_503_680_000_000_000_i64))), // 3000
        ("survey.speed_mps", Box::new(|v| v["survey"]["speed_mps"] = json!(-1.0))),
        ("survey.speed_mps", Box::new(|v| v["survey"]["speed_mps"] = json!(1e300))),
        ("survey.depth_m", Box::new(|v| v["survey"]["depth_m"] = json!(-5.0))),
        ("survey.descent_mps", Box::new(|v| v["survey"]["descent_mps"] = json!(-0.2))),
        ("turbidity", Box::new(|v| v["turbidity"] = json!(-1.0))),
        ("imu_noise_scale", Box::new(|v| v["imu_noise_scale"] = json!(-1.0))),
        ("position_fixes.period_s", Box::new(|v| v["position_fixes"]["period_s"] = json!(1e-20))),
        ("position_fixes.sigma_m", Box::new(|v| v["position_fixes"]["sigma_m"] = json!(-2.0))),
        ("faults.imu_nack_s", Box::new(|v| v["faults"]["imu_nack_s"] = json!([101.0, 100.0]))),
        ("faults.imu_stuck_axis", Box::new(|v| v["faults"]["imu_stuck_axis"] = json!([10.0, 9]))),
        ("faults.occluded_unit", Box::new(|v| v["faults"]["occluded_unit"] = json!([30.0, 40.0, subnav_core::head::POLARIZATION_UNITS]))),
        ("faults.occluded_unit", Box::new(|v| v["faults"]["occluded_unit"] = json!([40.0, 30.0, 1]))),
        ("dvl.seafloor_depth_m", Box::new(|v| v["dvl"]["seafloor_depth_m"] = json!(5.0))),
        ("dvl.dropout_probability", Box::new(|v| v["dvl"]["dropout_probability"] = json!(1.5))),
    ];
    for (field, edit) in cases {
        let e = with(|v| edit(v)).expect_err(field);
        assert!(e.contains(field), "{field}: {e}");
    }
}

#[test]
fn the_main_job_is_valid_and_bad_camera_fields_are_refused() {
    let mut sc = Scenario::map_survey(1);
    sc.validate().unwrap();
    for (name, edit) in [
        ("camera.latency_s", Box::new(|c: &mut subnav_sil::CameraPlan| c.latency_s = -1.0) as Box<dyn Fn(&mut subnav_sil::CameraPlan)>),
        ("camera.blackout_s", Box::new(|c| c.blackout_s = Some((10.0, 5.0)))),
        ("camera.drop_probability", Box::new(|c| c.drop_probability = f64::NAN)),
        ("camera.far_image_probability", Box::new(|c| c.far_image_probability = 2.0)),
    ] {
        let mut bad = sc.clone();
        if let Some(c) = bad.camera.as_mut() {
            edit(c);
        }
        let e = bad.validate().expect_err(name).to_string();
        assert!(e.contains(name), "{name}: {e}");
    }
    sc.survey.cross_legs = 5000;
    assert!(sc.validate().unwrap_err().to_string().contains("survey.cross_legs"));
}
