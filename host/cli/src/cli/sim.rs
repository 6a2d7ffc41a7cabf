//! `subnav sim`: write a dive scenario (JSON) for `subnav run`: a lawnmower survey at depth at a
//! date and place, water clarity, sensor grades, the DVL (on by default) and its seafloor,
//! position fixes with their latency, the camera and the map in the loop, the wind (a moving
//! sea) and the sky with a change of each mid-dive, and injected faults.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};

use super::{Format, args};
use subnav_sil::{CameraPlan, DvlPlan, FaultPlan, FixPlan, Scenario};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Where to write the scenario (JSON).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Random seed (sensor errors, fix noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Dive length, s.
    #[arg(long, default_value_t = 300.0)]
    pub duration_s: f64,
    /// UTC at boot, RFC 3339 (default: 2026-06-21T08:00:00Z, sun about 35 deg high over the Bay of Biscay).
    #[arg(long)]
    pub start: Option<String>,
    /// Latitude of the NED origin, deg.
    #[arg(long, default_value_t = 44.0, allow_hyphen_values = true)]
    pub lat_deg: f64,
    /// Longitude of the NED origin, deg.
    #[arg(long, default_value_t = -2.0, allow_hyphen_values = true)]
    pub lon_deg: f64,
    /// Survey depth, m.
    #[arg(long, default_value_t = 10.0)]
    pub depth_m: f64,
    /// Forward speed, m/s.
    #[arg(long, default_value_t = 1.0)]
    pub speed_mps: f64,
    /// Lawnmower leg length, m.
    #[arg(long, default_value_t = 60.0)]
    pub leg_m: f64,
    /// Spacing between legs, m.
    #[arg(long, default_value_t = 20.0)]
    pub spacing_m: f64,
    /// Heading of the first leg, deg (default 17.2).
    #[arg(long, allow_hyphen_values = true)]
    pub heading_deg: Option<f64>,
    /// Water clarity: attenuation scale on clear water (1 = clear, 3 = coastal).
    #[arg(long, default_value_t = 1.0)]
    pub turbidity: f64,
    /// Wind over the sea, m/s at 10 m (0..=30; 0 = flat): a moving sea under the compass.
    #[arg(long, default_value_t = 0.0, value_parser = args::f64_in(0.0..=30.0))]
    pub wind_mps: f64,
    /// The sky: clear, partly-cloudy, overcast, twilight.
    #[arg(long, default_value = "clear", value_parser = args::parse_sky)]
    pub sky: subnav_base::sky::SkyKind,
    /// From T s on the wind is MPS m/s (`T,MPS`: a sea-state change mid-dive).
    #[arg(long, value_name = "T,MPS", value_parser = args::parse_wind_change)]
    pub wind_change: Option<(f64, f64)>,
    /// From T s on the sky is KIND (`T,KIND`).
    #[arg(long, value_name = "T,KIND", value_parser = args::parse_sky_change)]
    pub sky_change: Option<(f64, subnav_base::sky::SkyKind)>,
    /// IMU noise relative to the grade the firmware is tuned for (ICM-42688-P).
    #[arg(long, default_value_t = 1.0)]
    pub imu_noise_scale: f64,
    /// Position fix (USBL-like) interval, s.
    #[arg(long, default_value_t = 5.0)]
    pub fix_period_s: f64,
    /// Position fix 1-sigma per axis, m.
    #[arg(long, default_value_t = 2.0)]
    pub fix_sigma_m: f64,
    /// Time from a fix's validity (the ping) to its arrival at the sensor head, s.
    #[arg(long, default_value_t = 1.0)]
    pub fix_latency_s: f64,
    /// Stamp fixes with their arrival time (the head then fuses them as if current; for
    /// comparison with fusion at the time of validity).
    #[arg(long)]
    pub fix_as_if_current: bool,
    /// No position fixes.
    #[arg(long)]
    pub no_fixes: bool,
    /// No DVL (without fixes either, the horizontal position is then free-inertial).
    #[arg(long)]
    pub no_dvl: bool,
    /// Depth of the flat seafloor under the survey, m (the DVL's bottom lock reaches 50 m).
    #[arg(long, default_value_t = 30.0)]
    pub seafloor_depth_m: f64,
    /// DVL fault: probability that a ping gives no report.
    #[arg(long, default_value_t = 0.02)]
    pub dvl_dropout_probability: f64,
    /// DVL fault: probability that a ping in range is reported invalid.
    #[arg(long, default_value_t = 0.01)]
    pub dvl_invalid_probability: f64,
    /// DVL fault: probability that a sentence arrives with a bad checksum / cut short.
    #[arg(long, default_value_t = 0.005)]
    pub dvl_corrupt_probability: f64,
    /// DVL fault: no output from A to B s (`A,B`).
    #[arg(long, value_name = "A,B", allow_hyphen_values = true, value_parser = args::parse_window)]
    pub dvl_silent: Option<args::Window>,
    /// Fault: the IMU NACKs every transaction from A to B s (`A,B`).
    #[arg(long, value_name = "A,B", allow_hyphen_values = true, value_parser = args::parse_window)]
    pub imu_nack: Option<args::Window>,
    /// Fault: an IMU axis stuck from T s on (`T,AXIS`; axes 0-2 accel x/y/z, 3-5 gyro x/y/z).
    #[arg(long, value_name = "T,AXIS", allow_hyphen_values = true, value_parser = args::parse_stuck_axis)]
    pub imu_stuck: Option<args::StuckAxis>,
    /// Fault: a polarization unit occluded from A to B s (`A,B,UNIT`; units 0-3).
    #[arg(long, value_name = "A,B,UNIT", allow_hyphen_values = true, value_parser = args::parse_occlusion)]
    pub occluded: Option<args::Occlusion>,
    /// Fault: probability that a depth-sensor transaction is NACKed.
    #[arg(long, default_value_t = 0.0)]
    pub depth_nack_probability: f64,
    /// Cross-hatch survey: this many legs (made odd), a quarter turn, as many across the first
    /// block, and so on, so the track keeps crossing itself (0: parallel legs).
    #[arg(long, default_value_t = 0)]
    pub cross_legs: u32,
    /// The downward camera and the topological map in the loop (the map's fixes go to the head).
    #[arg(long)]
    pub camera: bool,
    /// With --camera: the map runs but its fixes are not sent (open loop, for comparison).
    #[arg(long, requires = "camera")]
    pub no_map_fixes: bool,
    /// With --camera: from exposure to the map fix's arrival at the head, s.
    #[arg(long, default_value_t = 0.5, requires = "camera")]
    pub camera_latency_s: f64,
    /// Camera fault: dark frames from A to B s (`A,B`).
    #[arg(long, value_name = "A,B", value_parser = args::parse_window, requires = "camera")]
    pub camera_blackout: Option<args::Window>,
    /// Camera fault: probability that a frame is dropped / delivered twice / delivered late
    /// (after the next one).
    #[arg(long, default_value_t = 0.0, requires = "camera")]
    pub camera_drop_probability: f64,
    #[arg(long, default_value_t = 0.0, requires = "camera")]
    pub camera_duplicate_probability: f64,
    #[arg(long, default_value_t = 0.0, requires = "camera")]
    pub camera_reorder_probability: f64,
    /// Camera fault: probability that a frame shows a place 40 m away (a false appearance match
    /// the map's position gate must refuse).
    #[arg(long, default_value_t = 0.0, requires = "camera")]
    pub far_image_probability: f64,
    /// A mis-built head: the seed of its manufacturing errors (polarization channel gains,
    /// offsets, polarizer angles, extinction ratios; IMU biases, scale, non-orthogonality and
    /// mounting). Omitted: the ideal head. `subnav calibrate head --build-seed` calibrates it.
    #[arg(long)]
    pub build_seed: Option<u64>,
    /// Every fault class at once (`Scenario::every_fault`: the main job's survey with the map in
    /// the loop, USBL fixes, and sensor, link, camera, map and host faults at fixed fractions of
    /// --duration-s); only --seed and --duration-s apply.
    #[arg(long)]
    pub every_fault: bool,
}

/// The scenario the arguments describe (checked).
pub fn scenario(a: &Args) -> Result<Scenario> {
    if a.every_fault {
        anyhow::ensure!(a.duration_s >= 60.0 && a.duration_s <= 86_400.0, "--every-fault needs --duration-s in [60, 86400]");
        let sc = Scenario::every_fault(a.seed, a.duration_s);
        sc.validate().context("the every-fault scenario")?;
        return Ok(sc);
    }
    let mut sc = Scenario {
        seed: a.seed,
        duration_s: a.duration_s,
        lat_deg: a.lat_deg,
        lon_deg: a.lon_deg,
        build_seed: a.build_seed,
        ..Scenario::default()
    };
    if let Some(t) = &a.start {
        sc.start_utc_unix_us = super::sun::parse_time_us(t)?;
    }
    let checks = [
        (a.duration_s > 0.0 && a.duration_s <= 86_400.0, "--duration-s must be in (0, 86400]"),
        ((-90.0..=90.0).contains(&a.lat_deg), "--lat-deg must be in [-90, 90]"),
        ((-180.0..=180.0).contains(&a.lon_deg), "--lon-deg must be in [-180, 180]"),
        (a.depth_m >= 0.0 && a.depth_m <= 300.0, "--depth-m must be in [0, 300] (the MS5837-30BA's range)"),
        (a.speed_mps > 0.0 && a.speed_mps <= 5.0, "--speed-mps must be in (0, 5]"),
        (a.leg_m > 0.0 && a.spacing_m > 0.0, "--leg-m and --spacing-m must be positive"),
        (a.turbidity > 0.0 && a.turbidity.is_finite(), "--turbidity must be positive"),
        (a.imu_noise_scale >= 0.0 && a.imu_noise_scale.is_finite(), "--imu-noise-scale must be >= 0"),
        (
            a.no_fixes || (a.fix_period_s > 0.0 && a.fix_sigma_m > 0.0),
            "--fix-period-s and --fix-sigma-m must be positive (or use --no-fixes)",
        ),
        ((0.0..=1.0).contains(&a.depth_nack_probability), "--depth-nack-probability must be in [0, 1]"),
        ((0.0..=30.0).contains(&a.fix_latency_s), "--fix-latency-s must be in [0, 30]"),
        (a.seafloor_depth_m.is_finite() && a.seafloor_depth_m > a.depth_m, "--seafloor-depth-m must be deeper than --depth-m"),
        ((0.0..=1.0).contains(&a.dvl_dropout_probability), "--dvl-dropout-probability must be in [0, 1]"),
        ((0.0..=1.0).contains(&a.dvl_invalid_probability), "--dvl-invalid-probability must be in [0, 1]"),
        ((0.0..=1.0).contains(&a.dvl_corrupt_probability), "--dvl-corrupt-probability must be in [0, 1]"),
        (a.cross_legs <= 1001, "--cross-legs must be at most 1001"),
        ((0.0..=10.0).contains(&a.camera_latency_s), "--camera-latency-s must be in [0, 10]"),
        ((0.0..=1.0).contains(&a.camera_drop_probability), "--camera-drop-probability must be in [0, 1]"),
        ((0.0..=1.0).contains(&a.camera_duplicate_probability), "--camera-duplicate-probability must be in [0, 1]"),
        ((0.0..=1.0).contains(&a.camera_reorder_probability), "--camera-reorder-probability must be in [0, 1]"),
        ((0.0..=1.0).contains(&a.far_image_probability), "--far-image-probability must be in [0, 1]"),
    ];
    if let Some((_, msg)) = checks.iter().find(|(ok, _)| !ok) {
        bail!("{msg}");
    }
    sc.survey.depth_m = a.depth_m;
    sc.survey.speed_mps = a.speed_mps;
    sc.survey.leg_m = a.leg_m;
    sc.survey.spacing_m = a.spacing_m;
    sc.survey.cross_legs = a.cross_legs;
    sc.camera = a.camera.then_some(CameraPlan {
        map_fixes: !a.no_map_fixes,
        latency_s: a.camera_latency_s,
        blackout_s: a.camera_blackout.map(|w| (w.start_s, w.end_s)),
        drop_probability: a.camera_drop_probability,
        duplicate_probability: a.camera_duplicate_probability,
        reorder_probability: a.camera_reorder_probability,
        far_image_probability: a.far_image_probability,
        ..CameraPlan::default()
    });
    if let Some(h) = a.heading_deg {
        if !h.is_finite() {
            bail!("--heading-deg must be finite");
        }
        sc.survey.heading0_rad = h.to_radians();
    }
    sc.turbidity = a.turbidity;
    sc.sea = subnav_sil::SeaPlan {
        wind_mps: a.wind_mps,
        sky: a.sky,
        wind_change: a.wind_change,
        sky_change: a.sky_change,
        ..Default::default()
    };
    sc.imu_noise_scale = a.imu_noise_scale;
    sc.position_fixes = (!a.no_fixes)
        .then_some(FixPlan { as_if_current: a.fix_as_if_current, ..FixPlan::usbl(a.fix_period_s, a.fix_sigma_m, a.fix_latency_s) });
    sc.dvl = (!a.no_dvl).then_some(DvlPlan {
        seafloor_depth_m: a.seafloor_depth_m,
        dropout_probability: a.dvl_dropout_probability,
        invalid_probability: a.dvl_invalid_probability,
        bad_checksum_probability: a.dvl_corrupt_probability,
        truncate_probability: a.dvl_corrupt_probability,
        silent_s: a.dvl_silent.map(|w| (w.start_s, w.end_s)),
        ..DvlPlan::default()
    });
    let mut f = FaultPlan { depth_nack_probability: a.depth_nack_probability, ..FaultPlan::default() };
    f.imu_nack_s = a.imu_nack.map(|w| (w.start_s, w.end_s));
    f.imu_stuck_axis = a.imu_stuck.map(|s| (s.from_s, s.axis));
    f.occluded_unit = a.occluded.map(|o| (o.window.start_s, o.window.end_s, o.unit));
    sc.faults = f;
    sc.validate().context("the scenario these flags describe")?;
    Ok(sc)
}

pub fn run(args: Args, format: Format) -> Result<ExitCode> {
    let sc = scenario(&args)?;
    let json = serde_json::to_string_pretty(&sc)?;
    subnav_link::output::write_atomic(&args.out, json + "\n").with_context(|| format!("writing {}", args.out.display()))?;
    let fixes = sc.fixes().len();
    match format {
        Format::Json => println!(
            "{}",
            serde_json::json!({ "scenario": args.out, "duration_s": sc.duration_s, "seed": sc.seed, "position_fixes": fixes, "dvl": sc.dvl.is_some() })
        ),
        Format::Text => println!(
            "scenario {}: {:.0} s dive, seed {}, survey at {} m, {}, {} position fixes; run it with `subnav run {}`",
            args.out.display(),
            sc.duration_s,
            sc.seed,
            sc.survey.depth_m,
            if sc.dvl.is_some() { "DVL on" } else { "no DVL" },
            fixes,
            args.out.display()
        ),
    }
    Ok(ExitCode::SUCCESS)
}
