//! The simulated sensor head: the register-level chip models (`crate::chips`) on the buses the
//! QEMU board's firmware uses, fed for each transaction's instant from the truth trajectory, the
//! sun (shared ephemeris), the underwater polarization field (`subnav_base::sky`) and the
//! sensor error models, whose grades come from `subnav_core::head` (the same numbers the
//! firmware's default filter tuning uses; [`Scenario::imu_noise_scale`] mis-tunes on purpose).
//!
//! Buses (`subnav_wire::bridge::bus_map`, the boards' too): SPI 0 CS 0 = ICM-42688-P, CS 1 =
//! the store's W25Q16JV; I2C 0 = ADS1115 of polarization units 0-3 at 0x48..0x4B and
//! MS5837-30BA at 0x76; I2C 1 = ADS1115 of units 4-7 at 0x48..0x4B; UART 0 = DVL-A50
//! (bottom track over a flat seafloor, water track without lock, the scenario's faults, scale
//! and misalignment drawn per seed); UART 1 = the modem that delivers the host's position
//! fixes at their arrival time (validity time + the scenario's latency) and the map's fixes;
//! GPIO 0 = the camera's trigger line (scenarios with a camera: `crate::map_loop`).
//!
//! This module holds only that wiring and the chips' inputs; the scenario it reads (the file
//! format, its plans, defaults and validation) is `crate::scenario`, re-exported here so the
//! paths `head::Scenario`, `head::FixPlan`, ... keep working.

use std::sync::Arc;

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::Distribution;
use subnav_core::head;
use subnav_wire::bridge::{BusRequest, BusResponse, bus_map};

use crate::chips::camera::{CameraFaults, CameraImage, CameraModel};
use crate::chips::dvl_a50::{DvlA50Model, DvlFaults, DvlGrade, DvlInput, DvlMountingModel};
use crate::chips::modem::{DeliveryTap, ModemModel};
use crate::chips::{Ads1115Model, ChipSet, Icm42688Model, ImuInput, Ms5837Model, PressureInput};
use subnav_base::imu::{DrawOrder, ImuErrors, ImuGrade, normal};
use subnav_base::sky::{self as polar, SensorErrors, Water};
use subnav_base::trajectory::Trajectory;
use subnav_link::qemu::BusHandler;

pub use crate::scenario::{
    CameraPlan, DEFAULT_SEAFLOOR_DEPTH_M, DvlPlan, FaultPlan, FixPlan, MAX_DURATION_S, MIN_FIX_PERIOD_S, Scenario, ScheduledFix,
};

/// The IMU's physical input over the dive (what the ICM-42688-P model samples): the truth's
/// specific force and body rate (through a mis-built head's IMU axes, scale and repeatable bias:
/// [`Scenario::build_seed`]) plus turn-on bias, bias random walk and white noise of the
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
    let build = sc.build_errors();
    let mut frozen: Option<[f64; 6]> = None;
    let mut spike_rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0xAAAA);
    let mut spikes = 0u64;
    move |t_us| {
        let t = t_us as f64 * 1e-6;
        let dt = (t - last_t).max(0.0);
        last_t = t;
        errors.walk(&mut rng, dt, DrawOrder::GyroFirst);
        let truth = traj.at(t);
        // A mis-built head's IMU senses in its own (turned, scaled, skewed) axes.
        let (rate, force) = match &build {
            Some(b) => b.sense(&truth.gyro_radps, &truth.specific_force_mps2),
            None => (truth.gyro_radps, truth.specific_force_mps2),
        };
        let (gyro, accel) = errors.measure(&rate, &force, &mut rng, DrawOrder::PerAxisAccelFirst);
        let mut v = [accel.x, accel.y, accel.z, gyro.x, gyro.y, gyro.z];
        if let Some((t0, axis)) = faults.imu_stuck_axis {
            if t >= t0 && axis < 6 {
                let f = frozen.get_or_insert(v);
                v[axis] = f[axis];
            }
        }
        if faults.imu_spike_probability > 0.0 && rand::Rng::random::<f64>(&mut spike_rng) < faults.imu_spike_probability {
            spikes += 1;
            let axis = (spikes % 6) as usize;
            v[axis] = if spikes % 2 == 0 { f64::NAN } else { 1e6 };
        }
        ImuInput { specific_force_mps2: [v[0], v[1], v[2]], gyro_radps: [v[3], v[4], v[5]], temp_c: 12.0 }
    }
}

/// The chips and their inputs. Implements [`BusHandler`].
///
/// The world's clock does not restart with the head: when the firmware's time goes back (the
/// head was reset: watchdog, `Reboot`), the chips see the new boot's time plus the world time of
/// the head's last transaction before it, so the vehicle, the sun and the fault windows go on
/// where they were. (The time the head spent hung and resetting is not added: the bridge sees
/// no time while the head sends nothing; under the watchdog that is about a second.)
pub struct SimHead {
    chips: ChipSet,
    /// World time of the head's last boot, µs (0 until the head resets).
    boot_world_us: u64,
    /// Last world time a request carried, and the head time it had.
    last_world_us: u64,
    last_head_us: u64,
    /// Resets of the head seen (its time going back).
    pub head_resets: u32,
}

impl BusHandler for SimHead {
    fn handle(&mut self, req: &BusRequest) -> BusResponse {
        // A reset restarts the head's clock near zero. Requests of a running head can carry
        // stamps a few ms out of order (an ADC scan is stamped at its start), which is no reset.
        const RESET_JUMP_US: u64 = 250_000;
        if req.t_us.saturating_add(RESET_JUMP_US) < self.last_head_us {
            self.boot_world_us = self.last_world_us;
            self.head_resets += 1;
            self.last_head_us = req.t_us;
        } else {
            self.last_head_us = self.last_head_us.max(req.t_us);
        }
        let req = BusRequest { t_us: req.t_us.saturating_add(self.boot_world_us), ..*req };
        self.last_world_us = self.last_world_us.max(req.t_us);
        self.chips.handle(&req)
    }
}

/// The downlink frames of the dive's position fixes with their arrival times (µs), sequence
/// numbers from 1.
pub fn fix_frames(sc: &Scenario) -> Vec<(u64, Vec<u8>)> {
    let mut out = Vec::new();
    for (k, f) in sc.fixes().iter().enumerate() {
        let seq = u16::try_from(k + 1).unwrap_or(u16::MAX);
        let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
        if let Ok(frame) = subnav_wire::encode(&subnav_wire::Downlink { seq, command: f.command() }, &mut buf) {
            out.push(((f.arrival_s * 1e6).round() as u64, frame.to_vec()));
        }
    }
    out
}

/// The DVL's physical input over the dive: the truth's body velocity and rate, the altitude
/// over the scenario's flat seafloor and the current in body axes.
pub fn dvl_input(plan: DvlPlan, traj: Arc<Trajectory>) -> impl FnMut(u64) -> DvlInput + Send + 'static {
    let lever_down_m = f64::from(head::dvl_mounting().lever_arm_body_m.z);
    move |t_us| {
        let t_s = t_us as f64 * 1e-6;
        let truth = traj.at(t_s);
        // Lock lost: the seafloor drops out of range (a trench, a steep slope).
        let floor_m = plan.seafloor_depth_m + if plan.lock_lost_s.is_some_and(|(a, b)| (a..b).contains(&t_s)) { 500.0 } else { 0.0 };
        let r_bn = truth.att_nb.inverse();
        let v_b = r_bn * truth.vel_ned_mps;
        let c_b = r_bn * Vector3::new(plan.current_ne_mps[0], plan.current_ne_mps[1], 0.0);
        DvlInput {
            vel_body_mps: [v_b.x, v_b.y, v_b.z],
            rate_body_radps: [truth.gyro_radps.x, truth.gyro_radps.y, truth.gyro_radps.z],
            altitude_m: floor_m - truth.pos_ned_m.z - lever_down_m,
            current_body_mps: [c_b.x, c_b.y, c_b.z],
        }
    }
}

/// The DVL-A50 model of a scenario (nominal mounting from `subnav_core::head`, unit errors from
/// the seed).
pub fn dvl_model(sc: &Scenario, plan: DvlPlan, traj: Arc<Trajectory>) -> DvlA50Model {
    let m = head::dvl_mounting();
    let q = m.rot_body_from_dvl;
    let mounting = DvlMountingModel {
        rot_body_from_dvl: nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            f64::from(q.w),
            f64::from(q.i),
            f64::from(q.j),
            f64::from(q.k),
        )),
        lever_arm_body_m: m.lever_arm_body_m.map(f64::from),
    };
    let mut dvl = DvlA50Model::new(DvlGrade::A50, mounting, sc.seed ^ 0x7777, dvl_input(plan, traj));
    let window = |(a, b): (f64, f64)| ((a * 1e6) as u64, (b * 1e6) as u64);
    dvl.faults = DvlFaults {
        dropout_probability: plan.dropout_probability,
        silent_window_us: plan.silent_s.map(window),
        invalid_probability: plan.invalid_probability,
        bad_checksum_probability: plan.bad_checksum_probability,
        truncate_probability: plan.truncate_probability,
        high_temperature: false,
        auto_water_track: plan.auto_water_track,
    };
    dvl
}

/// The camera of a scenario: the seafloor of `subnav_topo::scene` (texture seeded by the
/// scenario, coastal water, the sun of mid-dive) rendered at the truth pose of each trigger and
/// reduced to its features; dark (no features) while the vehicle is shallower than half the
/// survey depth (the floor out of sight).
pub fn camera_model(sc: &Scenario, plan: CameraPlan, traj: Arc<Trajectory>, deliver: crate::chips::camera::Delivery) -> CameraModel {
    use subnav_topo::polar_image::{demosaic, features, stokes};
    use subnav_topo::scene::{Scene, SceneConfig, coastal_water};
    let mut rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0x9999);
    let cfg = SceneConfig { floor_depth_m: sc.seafloor_depth_m(), seed: sc.seed, ..SceneConfig::default() };
    let depth = sc.survey.depth_m;
    let scene = Scene::new(cfg, coastal_water(), sc.sun_ned(0.5 * sc.duration_s), depth, &mut rng);
    let far = (plan.far_image_probability, plan.far_image_offset_m);
    let expose = Box::new(move |t_us: u64| {
        let truth = traj.at(t_us as f64 * 1e-6);
        let (n, e) = (truth.pos_ned_m.x, truth.pos_ned_m.y);
        let truth_ne_m = [n, e];
        if truth.pos_ned_m.z < 0.5 * depth {
            return CameraImage { features: None, truth_ne_m };
        }
        use rand::Rng as _;
        let off = if rng.random::<f64>() < far.0 { far.1 / std::f64::consts::SQRT_2 } else { 0.0 };
        let mosaic = scene.render(n + off, e + off, truth.yaw_rad, &mut rng);
        let f = features(&stokes(&demosaic(&mosaic)));
        CameraImage { features: f.iter().all(|v| v.is_finite()).then_some(f), truth_ne_m }
    });
    let mut cam = CameraModel::new(sc.seed ^ 0x8888, expose, deliver);
    let window = |(a, b): (f64, f64)| ((a * 1e6) as u64, (b * 1e6) as u64);
    cam.faults = CameraFaults {
        blackout_us: plan.blackout_s.map(window),
        drop_probability: plan.drop_probability,
        duplicate_probability: plan.duplicate_probability,
        reorder_probability: plan.reorder_probability,
    };
    cam
}

impl SimHead {
    pub fn new(sc: &Scenario) -> Self {
        Self::with_downlink_tap(sc, None)
    }

    /// The same head with `flash` as its store's chip (e.g. `W25qModel::with_file`, so the
    /// head keeps its configuration and calibration across runs).
    pub fn with_flash(self, flash: crate::chips::w25q::W25qModel) -> Self {
        self.with_flash_chip(flash)
    }

    /// The same head with `chip` as its store's flash (e.g. a [`crate::chips::w25q::SharedFlash`]
    /// that outlives the run, as a real head's flash outlives a reboot).
    pub fn with_flash_chip(mut self, chip: impl crate::chips::SpiChip + 'static) -> Self {
        let (bus, cs) = bus_map::FLASH_SPI;
        self.chips.detach_spi(bus, cs).attach_spi(bus, cs, chip);
        self
    }

    /// As [`SimHead::new`], with `tap` called for every downlink frame the modem delivers.
    pub fn with_downlink_tap(sc: &Scenario, tap: Option<DeliveryTap>) -> Self {
        Self::build(sc, tap, None)
    }

    /// As [`SimHead::with_downlink_tap`], with the camera feeding `map` and the map's fixes
    /// going to the head over the modem link (when the scenario has a camera).
    pub fn build(sc: &Scenario, tap: Option<DeliveryTap>, map: Option<crate::map_loop::MapLoop>) -> Self {
        Self::build_with_commands(sc, tap, map, Vec::new())
    }

    /// As [`SimHead::build`], with `commands` (arrival time µs, encoded downlink frame) delivered
    /// over the modem link besides the scenario's position fixes.
    pub fn build_with_commands(
        sc: &Scenario,
        tap: Option<DeliveryTap>,
        map: Option<crate::map_loop::MapLoop>,
        commands: Vec<(u64, Vec<u8>)>,
    ) -> Self {
        Self::build_live(sc, tap, map, commands, None)
    }

    /// As [`SimHead::build_with_commands`], with `live` polled for downlink frames during the run
    /// (e.g. fixes from an autopilot's GPS, `subnav mavlink`), delivered over the modem link at once.
    pub fn build_live(
        sc: &Scenario,
        tap: Option<DeliveryTap>,
        map: Option<crate::map_loop::MapLoop>,
        commands: Vec<(u64, Vec<u8>)>,
        live: Option<crate::chips::modem::LiveSource>,
    ) -> Self {
        let traj = Arc::new(sc.trajectory());
        let mut chips = ChipSet::new();

        let imu = Icm42688Model::new(imu_input(sc, traj.clone()));
        let mut imu = imu;
        if let Some((a, b)) = sc.faults.imu_nack_s {
            imu.faults.nack_window_us = Some(((a * 1e6) as u64, (b * 1e6) as u64));
        }
        if let Some((a, b)) = sc.faults.imu_timeout_s {
            imu.faults.timeout_window_us = Some(((a * 1e6) as u64, (b * 1e6) as u64));
        }
        chips.attach_spi(bus_map::IMU_SPI.0, bus_map::IMU_SPI.1, imu);
        // The store's flash: erased, in memory (`SimHead::with_flash` gives it a file).
        chips.attach_spi(bus_map::FLASH_SPI.0, bus_map::FLASH_SPI.1, crate::chips::w25q::W25qModel::new());

        // Polarization units: the field at the vehicle's depth and attitude, the units' true
        // calibration (nominal + residuals), shot/read noise; counts -> volts for the ADS1115.
        let units: Vec<_> = head::polarization_units().into_iter().flatten().collect();
        let mut water = Water::clear();
        water.c_per_m *= sc.turbidity;
        water.b_per_m *= sc.turbidity;
        water.kd_per_m *= sc.turbidity;
        let err = SensorErrors::default(); // the head's photodiode noise and exposure (subnav_core::head)
        let mut cal_rng = ChaCha8Rng::seed_from_u64(sc.seed ^ 0x2222);
        let mut true_cal: Vec<_> = units.iter().map(|u| polar::true_channels(u, &err, &mut cal_rng)).collect();
        if let Some(b) = sc.build_errors() {
            true_cal = b.polarization;
        }
        let volts_per_count = 4.096 / 32768.0;
        let sc_sun = sc.clone();
        let source = Arc::new(crate::sea_sky::PolarizationSource::new(
            sc.sea,
            sc.seed,
            water,
            units.clone(),
            traj.clone(),
            Box::new(move |t| sc_sun.sun_ned(t)),
        ));
        for (u, (bus, addr)) in bus_map::POLARIZATION_ADC_I2C.into_iter().enumerate() {
            let (n_units, true_cal, source, sc2) = (units.len(), true_cal.clone(), source.clone(), sc.clone());
            let mut rng = ChaCha8Rng::seed_from_u64(sc.seed ^ (0x3333 + u as u64));
            let model = Ads1115Model::new(addr, move |t_us| {
                let t = t_us as f64 * 1e-6;
                let occluded = sc2.faults.occluded_unit.is_some_and(|(a, b, k)| k == u && (a..b).contains(&t));
                let sun_lost = sc2.faults.sun_lost_s.is_some_and(|(a, b)| (a..b).contains(&t));
                let counts = if occluded || sun_lost || n_units <= u {
                    [head::POLARIZATION_OFFSET_COUNTS as f64; 4]
                } else {
                    source.unit_counts(u, t_us, &true_cal, &err, &mut rng).map(|c| c.map(f64::from)).unwrap_or([0.0; 4])
                };
                counts.map(|c| c * volts_per_count)
            });
            chips.attach_i2c(bus, model);
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
        chips.attach_i2c(bus_map::DEPTH_I2C.0, depth);

        if let Some(plan) = sc.dvl {
            chips.attach_uart(bus_map::DVL_UART, dvl_model(sc, plan, traj.clone()));
        }
        let mut frames = fix_frames(sc);
        frames.extend(commands);
        let mut modem = ModemModel::new(frames, tap);
        if let (Some(plan), Some(map)) = (sc.camera, map) {
            let sink = map.clone();
            let faults = sc.faults;
            let camera = camera_model(
                sc,
                plan,
                traj.clone(),
                Box::new(move |cap| {
                    // A host that is down processes no frame.
                    if !faults.host_down(cap.exposed_us as f64 * 1e-6) {
                        sink.on_capture(cap)
                    }
                }),
            );
            chips.attach_gpio(bus_map::CAMERA_TRIGGER_GPIO, camera);
            modem = modem
                .with_live_source(Box::new(move |t_us| if faults.host_down(t_us as f64 * 1e-6) { Vec::new() } else { map.poll(t_us) }));
        }
        if let Some(live) = live {
            modem = modem.with_live_source(live);
        }
        chips.attach_uart(bus_map::MODEM_UART, modem);
        SimHead { chips, boot_world_us: 0, last_world_us: 0, last_head_us: 0, head_resets: 0 }
    }
}
