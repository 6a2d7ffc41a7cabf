//! The dive scenario format: what `subnav sim` writes and `subnav run` reads (serde, JSON) —
//! [`Scenario`] and its plans ([`FaultPlan`], [`FixPlan`], [`DvlPlan`], [`CameraPlan`]; the sea
//! and sky's [`crate::sea_sky::SeaPlan`]), their defaults, the named scenarios
//! ([`Scenario::map_survey`], [`Scenario::every_fault`]), the range checks of
//! [`Scenario::validate`] and what follows from a scenario alone (its trajectory, sun, seeded
//! position fixes). Kept apart from the chip wiring (`crate::head`, which feeds the chip models
//! from a scenario) so the file format can be read and changed without the bus details;
//! `crate::head` re-exports every item here, so `head::Scenario` and the like still resolve.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::Distribution;
use serde::{Deserialize, Serialize};
use subnav_base::imu::normal;
use subnav_base::trajectory::{Lawnmower, RigMotion, Trajectory};
use subnav_core::ephemeris::{self, Atmosphere, Observer};
use subnav_core::head;

/// Faults to inject, by time (s since boot).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FaultPlan {
    /// The IMU NACKs every transaction in this window.
    pub imu_nack_s: Option<(f64, f64)>,
    /// From this time on, this IMU axis (0..2 accel x/y/z, 3..5 gyro x/y/z) is frozen.
    pub imu_stuck_axis: Option<(f64, usize)>,
    /// This polarization unit is covered (reads dark) in this window.
    pub occluded_unit: Option<(f64, f64, usize)>,
    /// The depth sensor NACKs with this probability.
    pub depth_nack_probability: f64,
    /// The IMU's transactions time out (no answer) in this window.
    #[serde(default)]
    pub imu_timeout_s: Option<(f64, f64)>,
    /// With this probability an IMU sample's physical input is NaN or far beyond the chip's
    /// range (alternately): the chip outputs full scale, the driver flags it saturated.
    #[serde(default)]
    pub imu_spike_probability: f64,
    /// The sun is lost (heavy cloud) in this window: every polarization unit reads dark, at the
    /// chip (a minimal stand-in for the sky model's clouds).
    #[serde(default)]
    pub sun_lost_s: Option<(f64, f64)>,
    /// The host process is gone in this window (killed, then restarted): it sends nothing
    /// (no position fixes, no map fixes), its mapper sees no camera frame and no telemetry; the
    /// head keeps navigating and streaming into the void.
    #[serde(default)]
    pub host_outage_s: Option<(f64, f64)>,
}

impl FaultPlan {
    /// Whether the host is down at `t_s`.
    pub fn host_down(&self, t_s: f64) -> bool {
        self.host_outage_s.is_some_and(|(a, b)| (a..b).contains(&t_s))
    }
}

/// Position fixes the host sends during the dive (an acoustic positioning system such as USBL,
/// or a recognised map node): the truth at each fix time plus white noise of `sigma_m` on every
/// axis, with that covariance, stamped with that time and arriving `latency_s` later.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FixPlan {
    /// Interval between fixes, s; the first comes one interval after the rest period.
    pub period_s: f64,
    pub sigma_m: f64,
    /// From the fix's time of validity (the ping) to its arrival at the sensor head, s (USBL:
    /// 0.5-3 s).
    #[serde(default)]
    pub latency_s: f64,
    /// Stamp each fix with its arrival time instead of its time of validity: what a head that
    /// fuses every fix as if it were current does (for comparison only).
    #[serde(default)]
    pub as_if_current: bool,
    /// USBL multipath: with this probability a fix is off by `multipath_offset_m` (north-east)
    /// while claiming its usual covariance (the head's innovation gate must refuse it).
    #[serde(default)]
    pub multipath_probability: f64,
    #[serde(default = "default_multipath_offset")]
    pub multipath_offset_m: f64,
}

fn default_multipath_offset() -> f64 {
    30.0
}

impl FixPlan {
    /// Fixes every `period_s` with `sigma_m` per axis, arriving `latency_s` after their time of
    /// validity, stamped with it, no multipath.
    pub fn usbl(period_s: f64, sigma_m: f64, latency_s: f64) -> Self {
        Self {
            period_s,
            sigma_m,
            latency_s,
            as_if_current: false,
            multipath_probability: 0.0,
            multipath_offset_m: default_multipath_offset(),
        }
    }
}

/// A scheduled position fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledFix {
    /// Time of validity, s since boot.
    pub t_s: f64,
    /// When it reaches the head, s since boot.
    pub arrival_s: f64,
    /// The time the command carries, s since boot (`t_s`, or `arrival_s` if as-if-current).
    pub stamp_s: f64,
    pub pos_ned_m: [f32; 3],
    pub sigma_m: f32,
    /// A multipath outlier (off by `FixPlan::multipath_offset_m`).
    pub outlier: bool,
}

impl ScheduledFix {
    /// The downlink command (covariance `sigma^2 I`).
    pub fn command(&self) -> subnav_wire::Command {
        let v = self.sigma_m * self.sigma_m;
        subnav_wire::Command::PositionFix {
            t_us: (self.stamp_s * 1e6).round() as u64,
            pos_ned_m: self.pos_ned_m,
            cov_ned_m2: [v, 0.0, 0.0, v, 0.0, v],
        }
    }
}

/// The DVL of a dive: a flat seafloor, a uniform current and the instrument's faults.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DvlPlan {
    /// Depth of the (flat) seafloor, m: the DVL's altitude is this minus its own depth.
    pub seafloor_depth_m: f64,
    /// Water current over the ground, north and east, m/s (seen by water track).
    pub current_ne_mps: [f64; 2],
    /// A ping produces no report with this probability.
    pub dropout_probability: f64,
    /// A ping in range is reported invalid with this probability.
    pub invalid_probability: f64,
    /// A sentence has a character changed (bad checksum) / is cut short (malformed).
    pub bad_checksum_probability: f64,
    pub truncate_probability: f64,
    /// No output at all in this window, s since boot.
    pub silent_s: Option<(f64, f64)>,
    /// Without bottom lock, switch to water tracking (back when the bottom returns).
    pub auto_water_track: bool,
    /// Bottom lock lost in this window (the seafloor beyond the DVL's range), s since boot.
    #[serde(default)]
    pub lock_lost_s: Option<(f64, f64)>,
}

impl Default for DvlPlan {
    fn default() -> Self {
        Self {
            seafloor_depth_m: 30.0,
            current_ne_mps: [0.2, -0.1],
            dropout_probability: 0.02,
            invalid_probability: 0.01,
            bad_checksum_probability: 0.005,
            truncate_probability: 0.005,
            silent_s: None,
            auto_water_track: true,
            lock_lost_s: None,
        }
    }
}

/// The downward camera and the host's topological map in the loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraPlan {
    /// Send the map's fixes to the head (false: the map runs, its fixes are counted, not sent).
    pub map_fixes: bool,
    /// From exposure to the fix's arrival at the head, s.
    pub latency_s: f64,
    /// Frames exposed in this window are dark (s since boot).
    #[serde(default)]
    pub blackout_s: Option<(f64, f64)>,
    #[serde(default)]
    pub drop_probability: f64,
    #[serde(default)]
    pub duplicate_probability: f64,
    #[serde(default)]
    pub reorder_probability: f64,
    /// With this probability a frame shows a place `far_image_offset_m` north-east of the
    /// vehicle (a false appearance match the map's position gate must refuse).
    #[serde(default)]
    pub far_image_probability: f64,
    #[serde(default = "default_far_offset")]
    pub far_image_offset_m: f64,
}

fn default_far_offset() -> f64 {
    40.0
}

impl Default for CameraPlan {
    fn default() -> Self {
        Self {
            map_fixes: true,
            latency_s: 0.5,
            blackout_s: None,
            drop_probability: 0.0,
            duplicate_probability: 0.0,
            reorder_probability: 0.0,
            far_image_probability: 0.0,
            far_image_offset_m: default_far_offset(),
        }
    }
}

impl CameraPlan {
    /// The map loop's configuration for this plan.
    pub fn loop_config(&self) -> crate::map_loop::MapLoopConfig {
        crate::map_loop::MapLoopConfig {
            send_fixes: self.map_fixes,
            latency_us: (self.latency_s.max(0.0) * 1e6).round() as u64,
            live: subnav_topo::live::LiveConfig::default(),
            nav_wait: std::time::Duration::from_secs(30),
        }
    }
}

fn default_dvl() -> Option<DvlPlan> {
    Some(DvlPlan::default())
}

/// Longest dive a scenario may describe, s (one day).
pub const MAX_DURATION_S: f64 = 86_400.0;
/// Shortest interval between position fixes, s (a USBL pings at most a few times a second).
pub const MIN_FIX_PERIOD_S: f64 = 0.1;

/// A dive scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    pub seed: u64,
    /// UTC at boot (POSIX µs).
    pub start_utc_unix_us: i64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub duration_s: f64,
    pub survey: Lawnmower,
    /// Water clarity: beam attenuation c (1/m) and diffuse attenuation Kd (1/m) of the compass
    /// simulator's clear-water defaults, scaled by this factor.
    pub turbidity: f64,
    /// Scale on the IMU noise densities relative to the grade the filter is tuned for.
    pub imu_noise_scale: f64,
    pub faults: FaultPlan,
    /// Position fixes (None: no position aiding).
    #[serde(default)]
    pub position_fixes: Option<FixPlan>,
    /// The DVL (None: no velocity aiding; without fixes either, the horizontal position is then
    /// free-inertial and drifts like any MEMS INS: hundreds of metres in five minutes).
    #[serde(default = "default_dvl")]
    pub dvl: Option<DvlPlan>,
    /// The camera and the map (None: no camera).
    #[serde(default)]
    pub camera: Option<CameraPlan>,
    /// A mis-built head: the seed of its manufacturing errors (`crate::manufacturing`); None:
    /// the ideal head (nominal parts, only small calibration residuals).
    #[serde(default)]
    pub build_seed: Option<u64>,
    /// A calibration rig's motion instead of the survey (`subnav calibrate` records on it).
    #[serde(default)]
    pub rig: Option<RigMotion>,
    /// Wind, sea and sky, with their changes (default: calm and clear, the flat surface).
    #[serde(default)]
    pub sea: crate::sea_sky::SeaPlan,
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            seed: 1,
            // 2026-06-21 08:00 UTC over the Bay of Biscay: sun about 35 deg high, inside the
            // compass's well-conditioned range (a sun near the zenith makes azimuth uncertain).
            start_utc_unix_us: 1_782_028_800_000_000,
            lat_deg: 44.0,
            lon_deg: -2.0,
            duration_s: 300.0,
            survey: Lawnmower::default(),
            turbidity: 1.0,
            imu_noise_scale: 1.0,
            faults: FaultPlan::default(),
            position_fixes: Some(FixPlan::usbl(5.0, 2.0, 1.0)),
            dvl: default_dvl(),
            camera: None,
            build_seed: None,
            rig: None,
            sea: Default::default(),
        }
    }
}

/// Seafloor depth without a DVL plan (m): the camera still needs a floor to look at.
pub const DEFAULT_SEAFLOOR_DEPTH_M: f64 = 14.0;

impl Scenario {
    /// The main job: a 30-minute survey at 10 m depth and 1 m/s over a seafloor 4 m below, in a
    /// cross-hatch that keeps crossing its own track, with IMU, compass, depth, DVL, camera and
    /// map in the loop and no USBL.
    pub fn map_survey(seed: u64) -> Self {
        let mut sc =
            Scenario { seed, duration_s: 1800.0, position_fixes: None, camera: Some(CameraPlan::default()), ..Scenario::default() };
        sc.survey = Lawnmower { leg_m: 60.0, spacing_m: 15.0, cross_legs: 5, ..Lawnmower::default() };
        if let Some(d) = sc.dvl.as_mut() {
            d.seafloor_depth_m = DEFAULT_SEAFLOOR_DEPTH_M;
        }
        sc
    }

    /// Every fault class at once, for a dive of `duration_s` (issue 24; `subnav sim
    /// --every-fault`): the main job's survey (camera and map in the loop, seafloor 4 m below)
    /// with USBL fixes every 5 s, and, at fixed fractions of the dive: IMU NACKs (2 s) and bus
    /// timeouts (2 s), a covered polarization unit (5 %), the sun lost under cloud (10 %), DVL
    /// bottom lock lost (10 %: a minute of a 10-minute dive, six of an hour), a camera blackout
    /// (5 %), the host process gone (5 %) and, for the last 8 %, a stuck gyro axis; throughout:
    /// NaN / out-of-range IMU samples (0.05 %), depth NACKs (2 %), malformed, bad-checksum and
    /// invalid DVL sentences (2 % each), dropped / duplicated / reordered frames (1 % each),
    /// images of a place 40 m away (5 %) and USBL multipath fixes 30 m off (5 %).
    pub fn every_fault(seed: u64, duration_s: f64) -> Self {
        let mut sc = Scenario::map_survey(seed);
        sc.duration_s = duration_s;
        let d = duration_s;
        let w = |start: f64, len: f64| Some((start * d, start * d + len));
        sc.faults = FaultPlan {
            imu_nack_s: w(0.15, 2.0),
            imu_timeout_s: w(0.20, 2.0),
            imu_stuck_axis: Some((0.92 * d, 5)),
            occluded_unit: w(0.25, 0.05 * d).map(|(a, b)| (a, b, 1)),
            depth_nack_probability: 0.02,
            imu_spike_probability: 0.0005,
            sun_lost_s: w(0.35, 0.10 * d),
            host_outage_s: w(0.72, 0.05 * d),
        };
        sc.position_fixes = Some(FixPlan { multipath_probability: 0.05, multipath_offset_m: 30.0, ..FixPlan::usbl(5.0, 2.0, 1.0) });
        if let Some(dvl) = sc.dvl.as_mut() {
            dvl.lock_lost_s = w(0.50, 0.10 * d);
            dvl.invalid_probability = 0.02;
            dvl.bad_checksum_probability = 0.02;
            dvl.truncate_probability = 0.02;
        }
        if let Some(c) = sc.camera.as_mut() {
            c.blackout_s = w(0.62, 0.05 * d);
            c.drop_probability = 0.01;
            c.duplicate_probability = 0.01;
            c.reorder_probability = 0.01;
            c.far_image_probability = 0.05;
        }
        sc
    }

    /// Depth of the (flat) seafloor, m.
    pub fn seafloor_depth_m(&self) -> f64 {
        self.dvl.map_or(DEFAULT_SEAFLOOR_DEPTH_M, |d| d.seafloor_depth_m)
    }

    /// The map loop of this scenario (None without a camera).
    pub fn map_loop(&self) -> Option<crate::map_loop::MapLoop> {
        self.camera.map(|c| crate::map_loop::MapLoop::new(c.loop_config()))
    }

    pub fn trajectory(&self) -> Trajectory {
        match &self.rig {
            Some(rig) => Trajectory::rig(rig),
            None => Trajectory::lawnmower(&self.survey, self.duration_s + 60.0),
        }
    }

    /// The manufacturing errors of a mis-built head (None: the ideal head).
    pub fn build_errors(&self) -> Option<crate::manufacturing::BuildErrors> {
        self.build_seed.map(crate::manufacturing::BuildErrors::draw)
    }

    /// QEMU board options for the scenario's configured start (UTC at boot, NED origin).
    pub fn board_args(&self) -> Vec<String> {
        vec![
            format!("utc_unix_us={}", self.start_utc_unix_us),
            format!("lat_e7={}", (self.lat_deg * 1e7).round() as i64),
            format!("lon_e7={}", (self.lon_deg * 1e7).round() as i64),
        ]
    }

    /// The position fixes of the dive, in time order (seeded: the same for a seed).
    pub fn fixes(&self) -> Vec<ScheduledFix> {
        let Some(plan) = self.position_fixes.filter(|p| p.period_s > 0.0 && p.sigma_m > 0.0) else {
            return Vec::new();
        };
        let traj = self.trajectory();
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6666);
        let n = normal(plan.sigma_m);
        let mut out = Vec::new();
        let mut t = self.survey.rest_s + plan.period_s;
        while t <= self.duration_s {
            let p = traj.at(t).pos_ned_m;
            let mut pos_ned_m = [0, 1, 2].map(|k| (p[k] + n.sample(&mut rng)) as f32);
            use rand::Rng as _;
            // Drawn for every fix (when enabled), so the outliers do not shift the noise draws.
            let outlier = plan.multipath_probability > 0.0 && rng.random::<f64>() < plan.multipath_probability;
            if outlier {
                let d = (plan.multipath_offset_m / std::f64::consts::SQRT_2) as f32;
                pos_ned_m[0] += d;
                pos_ned_m[1] += d;
            }
            let arrival_s = t + plan.latency_s.max(0.0);
            let stamp_s = if plan.as_if_current { arrival_s } else { t };
            if !self.faults.host_down(arrival_s) {
                out.push(ScheduledFix { t_s: t, arrival_s, stamp_s, pos_ned_m, sigma_m: plan.sigma_m as f32, outlier });
            }
            t += plan.period_s;
        }
        out
    }

    /// Checks every number a scenario file can set against its range; the error names the
    /// field, the bound and the value. `subnav sim` writes only scenarios that pass and `subnav
    /// run` refuses the others, so a hand-edited file cannot hang the run (a survey that never
    /// advances), ask for gigabytes (a fix every 1e-20 s) or give silently wrong figures (a
    /// latitude of 95 deg, a year the ephemeris refuses, a fault on a unit that does not exist).
    pub fn validate(&self) -> anyhow::Result<()> {
        fn within(what: &str, v: f64, lo: f64, hi: f64) -> anyhow::Result<()> {
            anyhow::ensure!(v >= lo && v <= hi, "{what} must be in [{lo}, {hi}], got {v}");
            Ok(())
        }
        fn positive(what: &str, v: f64, hi: f64) -> anyhow::Result<()> {
            anyhow::ensure!(v > 0.0 && v <= hi, "{what} must be > 0 and <= {hi}, got {v}");
            Ok(())
        }
        fn window(what: &str, w: Option<(f64, f64)>) -> anyhow::Result<()> {
            if let Some((a, b)) = w {
                anyhow::ensure!(
                    a.is_finite() && b.is_finite() && 0.0 <= a && a <= b,
                    "{what} must be a window [start, end] of seconds with 0 <= start <= end, got [{a}, {b}]"
                );
            }
            Ok(())
        }
        positive("duration_s", self.duration_s, MAX_DURATION_S)?;
        // The ephemeris covers 150 years around J2000; 1900..2100 keeps a margin.
        let (lo_us, hi_us) = (-2_208_988_800_000_000_i64, 4_102_444_800_000_000_i64);
        anyhow::ensure!(
            (lo_us..=hi_us).contains(&self.start_utc_unix_us),
            "start_utc_unix_us must be between 1900-01-01 ({lo_us}) and 2100-01-01 ({hi_us}), got {}",
            self.start_utc_unix_us
        );
        within("lat_deg", self.lat_deg, -90.0, 90.0)?;
        within("lon_deg", self.lon_deg, -180.0, 180.0)?;
        let s = &self.survey;
        within("survey.depth_m", s.depth_m, 0.0, 300.0)?;
        positive("survey.descent_mps", s.descent_mps, 5.0)?;
        positive("survey.speed_mps", s.speed_mps, 5.0)?;
        positive("survey.leg_m", s.leg_m, 100_000.0)?;
        positive("survey.spacing_m", s.spacing_m, 10_000.0)?;
        within("survey.heading0_rad", s.heading0_rad, -100.0, 100.0)?;
        within("survey.rest_s", s.rest_s, 0.0, 3600.0)?;
        within("survey.ramp_s", s.ramp_s, 0.0, 600.0)?;
        positive("turbidity", self.turbidity, 100.0)?;
        self.sea.validate()?;
        within("imu_noise_scale", self.imu_noise_scale, 0.0, 100.0)?;
        let f = &self.faults;
        window("faults.imu_nack_s", f.imu_nack_s)?;
        if let Some((t, axis)) = f.imu_stuck_axis {
            anyhow::ensure!(
                t.is_finite() && t >= 0.0 && axis <= 5,
                "faults.imu_stuck_axis must be [time >= 0 s, axis 0..=5], got [{t}, {axis}]"
            );
        }
        if let Some((a, b, unit)) = f.occluded_unit {
            window("faults.occluded_unit", Some((a, b)))?;
            anyhow::ensure!(
                unit < head::POLARIZATION_UNITS,
                "faults.occluded_unit's unit must be 0..={}, got {unit}",
                head::POLARIZATION_UNITS - 1
            );
        }
        within("faults.depth_nack_probability", f.depth_nack_probability, 0.0, 1.0)?;
        window("faults.imu_timeout_s", f.imu_timeout_s)?;
        within("faults.imu_spike_probability", f.imu_spike_probability, 0.0, 1.0)?;
        window("faults.sun_lost_s", f.sun_lost_s)?;
        window("faults.host_outage_s", f.host_outage_s)?;
        if let Some(p) = &self.position_fixes {
            within("position_fixes.period_s", p.period_s, MIN_FIX_PERIOD_S, MAX_DURATION_S)?;
            positive("position_fixes.sigma_m", p.sigma_m, 1000.0)?;
            within("position_fixes.latency_s", p.latency_s, 0.0, 30.0)?;
            within("position_fixes.multipath_probability", p.multipath_probability, 0.0, 1.0)?;
            within("position_fixes.multipath_offset_m", p.multipath_offset_m, 0.0, 10_000.0)?;
        }
        if let Some(d) = &self.dvl {
            within("dvl.seafloor_depth_m", d.seafloor_depth_m, s.depth_m, 11_000.0)?;
            anyhow::ensure!(
                d.seafloor_depth_m > s.depth_m,
                "dvl.seafloor_depth_m ({}) must be deeper than survey.depth_m ({})",
                d.seafloor_depth_m,
                s.depth_m
            );
            within("dvl.current_ne_mps[0]", d.current_ne_mps[0], -5.0, 5.0)?;
            within("dvl.current_ne_mps[1]", d.current_ne_mps[1], -5.0, 5.0)?;
            within("dvl.dropout_probability", d.dropout_probability, 0.0, 1.0)?;
            within("dvl.invalid_probability", d.invalid_probability, 0.0, 1.0)?;
            within("dvl.bad_checksum_probability", d.bad_checksum_probability, 0.0, 1.0)?;
            within("dvl.truncate_probability", d.truncate_probability, 0.0, 1.0)?;
            window("dvl.silent_s", d.silent_s)?;
            window("dvl.lock_lost_s", d.lock_lost_s)?;
        }
        if let Some(rig) = &self.rig {
            within("rig.depth_m", rig.depth_m, 0.0, 300.0)?;
            within("rig.heading0_rad", rig.heading0_rad, -100.0, 100.0)?;
            anyhow::ensure!(rig.steps.len() <= 10_000, "rig.steps: at most 10000 steps, got {}", rig.steps.len());
            for (k, st) in rig.steps.iter().enumerate() {
                within(&format!("rig.steps[{k}].duration_s"), st.duration_s, 0.0, MAX_DURATION_S)?;
                within(&format!("rig.steps[{k}].rate_radps"), st.rate_radps, -10.0, 10.0)?;
                let n = st.axis_body.iter().map(|a| a * a).sum::<f64>().sqrt();
                anyhow::ensure!((n - 1.0).abs() < 1e-3, "rig.steps[{k}].axis_body must be a unit vector, got {:?}", st.axis_body);
            }
        }
        anyhow::ensure!(s.cross_legs <= 1001, "survey.cross_legs must be at most 1001, got {}", s.cross_legs);
        if let Some(c) = &self.camera {
            within("camera.latency_s", c.latency_s, 0.0, 10.0)?;
            window("camera.blackout_s", c.blackout_s)?;
            within("camera.drop_probability", c.drop_probability, 0.0, 1.0)?;
            within("camera.duplicate_probability", c.duplicate_probability, 0.0, 1.0)?;
            within("camera.reorder_probability", c.reorder_probability, 0.0, 1.0)?;
            within("camera.far_image_probability", c.far_image_probability, 0.0, 1.0)?;
            within("camera.far_image_offset_m", c.far_image_offset_m, 0.0, 10_000.0)?;
            anyhow::ensure!(
                self.seafloor_depth_m() > s.depth_m,
                "the seafloor ({} m) must be below the survey depth ({} m) for the camera",
                self.seafloor_depth_m(),
                s.depth_m
            );
        }
        Ok(())
    }

    pub fn observer(&self) -> Observer {
        Observer { lat_rad: self.lat_deg.to_radians() as f32, lon_rad: self.lon_deg.to_radians() as f32, height_m: 0.0 }
    }

    /// Sun direction (NED unit vector toward the sun, in air) at `t_s` after boot.
    pub fn sun_ned(&self, t_s: f64) -> Vector3<f64> {
        let unix_us = self.start_utc_unix_us + (t_s * 1e6) as i64;
        let atm = Atmosphere { pressure_hpa: 1013.25, temp_c: 15.0 };
        let p = ephemeris::sun_position(unix_us, &self.observer(), Some(&atm), ephemeris::delta_t_estimate_s(unix_us));
        match p {
            Ok(p) => {
                let v = p.ned_unit();
                Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64)
            }
            Err(_) => Vector3::new(0.0, 0.0, 1.0), // below: no light from above
        }
    }
}
