//! The simulated sensor head: the register-level chip models (`crate::chips`) on the buses the
//! QEMU board's firmware uses, fed for each transaction's instant from the truth trajectory, the
//! sun (shared ephemeris), the underwater polarization field (`subnav_base::sky`) and the
//! sensor error models, whose grades come from `subnav_core::head` (the same numbers the
//! firmware's default filter tuning uses; [`Scenario::imu_noise_scale`] mis-tunes on purpose).
//!
//! Buses (must match `firmware/src/bin/qemu`): SPI 0 CS 0 = ICM-42688-P; I2C 0 = ADS1115 at
//! 0x48..0x4B (polarization unit u on 0x48 + u) and MS5837-30BA at 0x76.

use std::sync::Arc;

use nalgebra::{Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::Distribution;
use serde::{Deserialize, Serialize};
use subnav_core::ephemeris::{self, Atmosphere, Observer};
use subnav_core::head;
use subnav_wire::bridge::{BusRequest, BusResponse};

use crate::chips::{Ads1115Model, ChipSet, Icm42688Model, ImuInput, Ms5837Model, PressureInput};
use subnav_base::imu::{DrawOrder, ImuErrors, ImuGrade, normal};
use subnav_base::sky::{self as polar, Field, SensorErrors, Water};
use subnav_base::trajectory::{Lawnmower, Trajectory};
use subnav_link::qemu::BusHandler;

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
}

/// Position fixes the host sends during the dive (an acoustic positioning system such as USBL,
/// or a recognised map node): the truth at each fix time plus white noise of `sigma_m` on every
/// axis, with that covariance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FixPlan {
    /// Interval between fixes, s; the first comes one interval after the rest period.
    pub period_s: f64,
    pub sigma_m: f64,
}

/// A scheduled position fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledFix {
    pub t_s: f64,
    pub pos_ned_m: [f32; 3],
    pub sigma_m: f32,
}

impl ScheduledFix {
    /// The downlink command (covariance `sigma^2 I`).
    pub fn command(&self) -> subnav_wire::Command {
        let v = self.sigma_m * self.sigma_m;
        subnav_wire::Command::PositionFix {
            t_us: (self.t_s * 1e6).round() as u64,
            pos_ned_m: self.pos_ned_m,
            cov_ned_m2: [v, 0.0, 0.0, v, 0.0, v],
        }
    }
}

/// How long before its time a fix is sent (firmware time): the firmware queues a fix stamped
/// ahead and applies it when its clock gets there, so the QEMU run stays repeatable as long as
/// the fix arrives within this lead.
pub const FIX_LEAD_S: f64 = 5.0;

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
    /// Position fixes (None: no position aiding; the horizontal position is then free-inertial
    /// and drifts like any MEMS INS: hundreds of metres in five minutes).
    #[serde(default)]
    pub position_fixes: Option<FixPlan>,
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
            position_fixes: Some(FixPlan { period_s: 5.0, sigma_m: 2.0 }),
        }
    }
}

impl Scenario {
    pub fn trajectory(&self) -> Trajectory {
        Trajectory::lawnmower(&self.survey, self.duration_s + 60.0)
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
            let pos_ned_m = [0, 1, 2].map(|k| (p[k] + n.sample(&mut rng)) as f32);
            out.push(ScheduledFix { t_s: t, pos_ned_m, sigma_m: plan.sigma_m as f32 });
            t += plan.period_s;
        }
        out
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

/// The IMU's physical input over the dive (what the ICM-42688-P model samples): the truth's
/// specific force and body rate plus turn-on bias, bias random walk and white noise of the
/// `subnav_core::head` grade (white noise scaled by [`Scenario::imu_noise_scale`]), and the
/// scenario's stuck-axis fault. Seeded: the same stream for a seed and the same query times.
pub fn imu_input(sc: &Scenario, traj: Arc<Trajectory>) -> impl FnMut(u64) -> ImuInput + Send + 'static {
    // IMU: truth + turn-on bias + bias random walk + white noise (grade from subnav_core::head).
    let grade = ImuGrade::from(head::IMU_ICM42688P);
    let scale = sc.imu_noise_scale;
    let rate = head::IMU_RATE_HZ as f64;
    let mut rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0x1111);
    let (gyro_bias0, accel_bias0) = ImuErrors::draw_turn_on(&grade, &mut rng, DrawOrder::GyroFirst);
    let white = (scale * grade.gyro_noise_density * rate.sqrt(), scale * grade.accel_noise_density * rate.sqrt());
    let mut errors = ImuErrors::new(grade, gyro_bias0, accel_bias0, white);
    let mut last_t = 0.0f64;
    let faults = sc.faults;
    let mut frozen: Option<[f64; 6]> = None;
    move |t_us| {
        let t = t_us as f64 * 1e-6;
        let dt = (t - last_t).max(0.0);
        last_t = t;
        errors.walk(&mut rng, dt, DrawOrder::GyroFirst);
        let truth = traj.at(t);
        let (gyro, accel) = errors.measure(&truth.gyro_radps, &truth.specific_force_mps2, &mut rng, DrawOrder::PerAxisAccelFirst);
        let mut v = [accel.x, accel.y, accel.z, gyro.x, gyro.y, gyro.z];
        if let Some((t0, axis)) = faults.imu_stuck_axis {
            if t >= t0 && axis < 6 {
                let f = frozen.get_or_insert(v);
                v[axis] = f[axis];
            }
        }
        ImuInput { specific_force_mps2: [v[0], v[1], v[2]], gyro_radps: [v[3], v[4], v[5]], temp_c: 12.0 }
    }
}

/// The chips and their inputs. Implements [`BusHandler`].
pub struct SimHead {
    chips: ChipSet,
}

impl BusHandler for SimHead {
    fn handle(&mut self, req: &BusRequest) -> BusResponse {
        self.chips.handle(req)
    }
}

impl SimHead {
    pub fn new(sc: &Scenario) -> Self {
        let traj = Arc::new(sc.trajectory());
        let mut chips = ChipSet::new();

        let imu = Icm42688Model::new(imu_input(sc, traj.clone()));
        let mut imu = imu;
        if let Some((a, b)) = sc.faults.imu_nack_s {
            imu.faults.nack_window_us = Some(((a * 1e6) as u64, (b * 1e6) as u64));
        }
        chips.attach_spi(0, 0, imu);

        // Polarization units: the field at the vehicle's depth and attitude, the units' true
        // calibration (nominal + residuals), shot/read noise; counts -> volts for the ADS1115.
        let units: Vec<_> = head::polarization_units().into_iter().flatten().collect();
        let mut water = Water::clear();
        water.c_per_m *= sc.turbidity;
        water.b_per_m *= sc.turbidity;
        water.kd_per_m *= sc.turbidity;
        let err = SensorErrors::default(); // the head's photodiode noise and exposure (subnav_core::head)
        let mut cal_rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0x2222);
        let true_cal: Vec<_> = units.iter().map(|u| polar::true_channels(u, &err, &mut cal_rng)).collect();
        let volts_per_count = 4.096 / 32768.0;
        for (u, addr) in [0x48u8, 0x49, 0x4A, 0x4B].into_iter().enumerate() {
            let (units, true_cal, tr, sc2) = (units.clone(), true_cal.clone(), traj.clone(), sc.clone());
            let mut rng = ChaCha8Rng::seed_from_u64(sc.seed ^ (0x3333 + u as u64));
            let model = Ads1115Model::new(addr, move |t_us| {
                let t = t_us as f64 * 1e-6;
                let truth = tr.at(t);
                let occluded = sc2.faults.occluded_unit.is_some_and(|(a, b, k)| k == u && (a..b).contains(&t));
                let counts = if occluded || units.len() <= u {
                    [head::POLARIZATION_OFFSET_COUNTS as f64; 4]
                } else {
                    let field = Field::new(sc2.sun_ned(t), water, truth.pos_ned_m.z.max(0.0), &mut rng);
                    let r_nb: Rotation3<f64> = truth.att_nb.to_rotation_matrix();
                    let all = polar::counts(&field, &r_nb, &units, &true_cal, &err, &mut rng);
                    all.get(u).map(|c| c.map(f64::from)).unwrap_or([0.0; 4])
                };
                counts.map(|c| c * volts_per_count)
            });
            chips.attach_i2c(0, model);
        }

        // Depth: hydrostatic pressure at the true depth + noise (grade from shared::head).
        let tr = traj.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0x4444);
        let sigma = head::DEPTH_MS5837_30BA.pressure_sigma_pa as f64;
        let mut depth = Ms5837Model::new(move |t_us| {
            let z = tr.at(t_us as f64 * 1e-6).pos_ned_m.z;
            PressureInput { pressure_pa: 101_325.0 + 1025.0 * 9.80665 * z + normal(sigma).sample(&mut rng), temp_c: 12.0 }
        });
        if sc.faults.depth_nack_probability > 0.0 {
            depth.faults =
                crate::chips::BusFaults::seeded(sc.seed ^ 0x5555).with_nack_probability(sc.faults.depth_nack_probability, sc.seed ^ 0x5555);
        }
        chips.attach_i2c(0, depth);
        SimHead { chips }
    }
}
