//! Water Linked DVL-A50 model on a UART: the bytes the instrument sends, at its rate, and its
//! answers to commands.
//!
//! Protocol (written here from the document, independently of the firmware driver): Water
//! Linked, "DVL A50/A125 serial protocol", serial protocol 2.6.x / 2.7.x,
//! <https://docs.waterlinked.com/dvl/dvl-serial-protocol/>: sections "Overview" (8-N-1, `w`,
//! direction, command, `,options`, `*xx`, line ending; this model ends lines with CR+LF),
//! "Velocity report (wrz)", "Velocity report (wrs)", "Command overview" (`wra`, `wrn`, `wr?`,
//! `wr!`, `wcv`, `wcp`, `wcs`, `wcx`), "Configuration over serial" (`range_mode` `auto` / `wt`,
//! `acoustic_enabled`) and "Checksum" (CRC-8, poly 0x07, init 0, no reflection, no xor-out;
//! two lower-case hex digits). Number formats follow the document's examples: velocities and
//! figure of merit with 3 decimals, altitude and `time` with 2, covariance entries in exponent
//! form (`9.00e-6`), times as integers.
//!
//! Physics (per ping, at the centre of ping `t`):
//! - the DVL's true velocity over the bottom, in its actual axes:
//!   `v_dvl = R_bd_actual^T (v_b + w_b x l_b)`, with `R_bd_actual = R_bd * misalignment`
//!   (the nominal mounting the navigation filter is told, times a small rotation drawn per
//!   seed) and `l_b` the lever arm;
//! - reported: `scale * v_dvl + noise` (scale error drawn per seed, white noise per axis of the
//!   grade), quantized to 1 mm/s by the 3-decimal format;
//! - bottom track (`range_mode = auto`) is valid for `min_altitude_m <= altitude <=
//!   max_altitude_m`; otherwise the report says `valid = n`, velocities 0, altitude -1, as the
//!   document's invalid example. Water track (`range_mode = wt`, `wrs`): velocity relative to
//!   the water (`v_dvl - R_bd_actual^T current_b`), valid when the bottom is farther than
//!   4.5 m (closer, bottom echoes corrupt it; reported invalid);
//! - rate: bottom track `1 / (1/15 s + altitude * 8.7 ms/m)`, i.e. 15 Hz near the bottom down to
//!   2 Hz at 50 m (the document gives the 2-15 Hz range; the altitude law is this model's);
//!   2 Hz without lock and in water track (document: 2 Hz);
//! - time of validity = ping centre on the DVL's Unix clock (`t_us + clock_offset_us`); time of
//!   transmission = validity + two-way travel of the slant range + [`PROCESSING_US`]; the bytes
//!   then leave at the baud rate (10 bits per byte), one sentence after the other.
//!
//! Grade: [`DvlGrade::A50`] is this model's assumption for a small DVL (noise, scale and
//! misalignment sigmas, altitude range), not datasheet values.
//!
//! Faults (seeded, reproducible): whole pings dropped ([`DvlFaults::dropout_probability`], or
//! silent windows), reports flagged invalid in range ([`DvlFaults::invalid_probability`]),
//! sentences with a flipped character (bad checksum) or cut before the checksum (malformed),
//! high-temperature status. Every injection is counted in [`DvlModelCounters`] so a test can
//! compare them with what the driver counted.
//!
//! Use: `bytes_ready(t_us)` / `read(t_us, buf)` give the bytes fully on the wire by `t_us`;
//! `write(t_us, bytes)` takes the firmware's commands. [`DvlUart`] wraps the model and a clock
//! as an `embedded_io` UART for native runs of the firmware driver.

use std::collections::VecDeque;
use std::fmt::Write as _;

use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Default baud rate.
pub const DEFAULT_BAUD: u32 = 115_200;
/// Processing time from the last echo to the start of transmission, µs (model assumption).
pub const PROCESSING_US: u64 = 20_000;
/// Speed of sound, m/s (the DVL's default configuration).
pub const SPEED_OF_SOUND_MPS: f64 = 1_500.0;
/// Beam angle from the vertical, rad (the A50's transducers are tilted 22.5 deg).
pub const BEAM_ANGLE_RAD: f64 = 22.5 * std::f64::consts::PI / 180.0;
/// Water tracking needs the bottom farther than this, m (document: "Water Tracking").
pub const WATER_TRACK_MIN_ALTITUDE_M: f64 = 4.5;
/// Reporting period without lock and in water track, µs (2 Hz).
pub const SLOW_PERIOD_US: u64 = 500_000;
/// Protocol version the model reports to `wcv`.
pub const PROTOCOL_VERSION: &str = "2.7.0";

/// CRC-8 of the protocol (poly 0x07, init 0x00, MSB first, no xor-out).
pub fn crc8(data: &[u8]) -> u8 {
    data.iter().fold(0u8, |mut crc, b| {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
        }
        crc
    })
}

/// `body*xx` (without line ending).
pub fn with_checksum(body: &str) -> String {
    format!("{body}*{:02x}", crc8(body.as_bytes()))
}

/// The vehicle's motion at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlInput {
    /// Velocity of the body origin (IMU) over the bottom, body FRD, m/s.
    pub vel_body_mps: [f64; 3],
    /// Body rate, FRD, rad/s.
    pub rate_body_radps: [f64; 3],
    /// Vertical distance from the DVL to the bottom, m (non-finite: no bottom in reach).
    pub altitude_m: f64,
    /// Water velocity over the bottom at the DVL's water-track layer, body axes, m/s.
    pub current_body_mps: [f64; 3],
}

/// Error budget of a DVL grade.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlGrade {
    /// White noise per axis per bottom-track report, m/s.
    pub noise_sigma_mps: f64,
    /// White noise per axis per water-track report, m/s.
    pub water_noise_sigma_mps: f64,
    /// 1-sigma of the scale factor error drawn per unit (fraction).
    pub scale_sigma: f64,
    /// 1-sigma per axis of the mounting misalignment drawn per unit, rad.
    pub misalignment_sigma_rad: f64,
    pub min_altitude_m: f64,
    pub max_altitude_m: f64,
}

impl DvlGrade {
    /// A small DVL of the A50's class (model assumption: 5 mm/s noise per report, 0.3 % scale,
    /// 0.3 deg misalignment, bottom lock from 0.05 to 50 m).
    pub const A50: Self = Self {
        noise_sigma_mps: 0.005,
        water_noise_sigma_mps: 0.02,
        scale_sigma: 0.003,
        misalignment_sigma_rad: 0.3 * std::f64::consts::PI / 180.0,
        min_altitude_m: 0.05,
        max_altitude_m: 50.0,
    };
}

/// The per-unit errors (drawn from the seed by [`DvlA50Model::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlUnitErrors {
    /// Multiplies the true velocity (1 = perfect).
    pub scale: f64,
    /// Actual DVL axes = nominal DVL axes rotated by this.
    pub misalignment: UnitQuaternion<f64>,
}

impl DvlUnitErrors {
    pub fn none() -> Self {
        Self { scale: 1.0, misalignment: UnitQuaternion::identity() }
    }

    pub fn draw(grade: &DvlGrade, rng: &mut ChaCha8Rng) -> Self {
        let mut n = || -> f64 { StandardNormal.sample(rng) };
        let scale = 1.0 + grade.scale_sigma * n();
        let s = grade.misalignment_sigma_rad;
        let axis = Vector3::new(s * n(), s * n(), s * n());
        Self { scale, misalignment: UnitQuaternion::from_scaled_axis(axis) }
    }
}

/// Nominal mounting (what the navigation filter is configured with).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlMountingModel {
    /// DVL axes -> body axes.
    pub rot_body_from_dvl: UnitQuaternion<f64>,
    /// IMU -> DVL, body axes, m.
    pub lever_arm_body_m: Vector3<f64>,
}

impl Default for DvlMountingModel {
    fn default() -> Self {
        Self { rot_body_from_dvl: UnitQuaternion::identity(), lever_arm_body_m: Vector3::zeros() }
    }
}

/// Range mode (`wcs` parameter `range_mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RangeMode {
    /// Bottom tracking (`wrz`).
    Auto,
    /// Water tracking (`wrs`).
    WaterTrack,
}

/// Fault injection.
#[derive(Debug, Clone, Default)]
pub struct DvlFaults {
    /// Each ping produces no report with this probability.
    pub dropout_probability: f64,
    /// No output at all for `start_us <= t < end_us` (pings in the window are lost).
    pub silent_window_us: Option<(u64, u64)>,
    /// A ping in range is reported `valid = n` with this probability.
    pub invalid_probability: f64,
    /// A sentence gets one character changed (checksum left as computed) with this probability.
    pub bad_checksum_probability: f64,
    /// A sentence is cut before its checksum with this probability.
    pub truncate_probability: f64,
    /// Status bit 0 (high temperature) set in every report.
    pub high_temperature: bool,
    /// Switch `range_mode` to water tracking by itself when bottom lock is lost, and back when
    /// it returns (stands in for an integrator that sends `wcs,,,,,wt,`; the real DVL does not).
    pub auto_water_track: bool,
}

/// What the model sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DvlModelCounters {
    pub pings: u64,
    pub valid_reports: u64,
    pub invalid_reports: u64,
    pub dropped: u64,
    pub bad_checksum: u64,
    pub truncated: u64,
    pub replies: u64,
}

/// The DVL-A50.
pub struct DvlA50Model {
    source: Box<dyn FnMut(u64) -> DvlInput + Send>,
    pub grade: DvlGrade,
    pub mounting: DvlMountingModel,
    pub errors: DvlUnitErrors,
    pub faults: DvlFaults,
    pub range_mode: RangeMode,
    /// `acoustic_enabled`: off = no pings except those triggered by `wcx`.
    pub acoustic_enabled: bool,
    pub baud: u32,
    /// DVL Unix clock minus the caller's clock, µs.
    pub clock_offset_us: u64,
    pub counters: DvlModelCounters,
    rng: ChaCha8Rng,
    next_ping_us: u64,
    last_report_us: Option<u64>,
    triggers: u32,
    /// Bytes with the time their last bit is on the wire (caller's clock).
    out: VecDeque<(u64, u8)>,
    /// End of the last byte queued (the UART is busy until then).
    line_free_us: u64,
    cmd: Vec<u8>,
}

impl DvlA50Model {
    /// A model with the grade's unit errors drawn from `seed` (the same seed gives the same
    /// errors, noise and faults).
    pub fn new(grade: DvlGrade, mounting: DvlMountingModel, seed: u64, source: impl FnMut(u64) -> DvlInput + Send + 'static) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let errors = DvlUnitErrors::draw(&grade, &mut rng);
        Self {
            source: Box::new(source),
            grade,
            mounting,
            errors,
            faults: DvlFaults::default(),
            range_mode: RangeMode::Auto,
            acoustic_enabled: true,
            baud: DEFAULT_BAUD,
            clock_offset_us: 1_764_547_200_000_000, // 2025-12-01T00:00:00Z
            counters: DvlModelCounters::default(),
            rng,
            next_ping_us: 0,
            last_report_us: None,
            triggers: 0,
            out: VecDeque::new(),
            line_free_us: 0,
            cmd: Vec::new(),
        }
    }

    fn byte_time_us(&self) -> f64 {
        10.0e6 / f64::from(self.baud.max(1))
    }

    /// Queue a line (CR+LF added) to start no earlier than `t_us`.
    fn send_line(&mut self, t_us: u64, line: &[u8]) {
        let start = t_us.max(self.line_free_us) as f64;
        let bt = self.byte_time_us();
        let mut k = 0usize;
        for b in line.iter().chain(b"\r\n".iter()) {
            k += 1;
            self.out.push_back(((start + bt * k as f64).ceil() as u64, *b));
        }
        self.line_free_us = (start + bt * k as f64).ceil() as u64;
    }

    fn bottom_in_range(&self, altitude_m: f64) -> bool {
        altitude_m.is_finite() && altitude_m >= self.grade.min_altitude_m && altitude_m <= self.grade.max_altitude_m
    }

    /// Period to the next ping after one at `altitude_m`.
    fn period_us(&self, altitude_m: f64) -> u64 {
        if self.range_mode == RangeMode::WaterTrack || !self.bottom_in_range(altitude_m) {
            return SLOW_PERIOD_US;
        }
        let s = 1.0 / 15.0 + altitude_m * 0.0087;
        (s.min(0.5) * 1e6) as u64
    }

    fn normal(&mut self, sigma: f64) -> f64 {
        let z: f64 = StandardNormal.sample(&mut self.rng);
        sigma * z
    }

    /// One ping at `t_us`: build and queue its report (or drop it).
    fn ping(&mut self, t_us: u64) -> u64 {
        self.counters.pings += 1;
        let input = (self.source)(t_us);
        let alt = input.altitude_m;
        let in_range = self.bottom_in_range(alt);
        if self.faults.auto_water_track {
            self.range_mode = if in_range { RangeMode::Auto } else { RangeMode::WaterTrack };
        }
        let period = self.period_us(alt);
        // Draw every random number of the ping whatever happens to it, so one fault knob does
        // not shift the noise of the others.
        let noise_sigma = match self.range_mode {
            RangeMode::Auto => self.grade.noise_sigma_mps,
            RangeMode::WaterTrack => self.grade.water_noise_sigma_mps,
        };
        let noise = Vector3::new(self.normal(noise_sigma), self.normal(noise_sigma), self.normal(noise_sigma));
        let u_drop: f64 = self.rng.random();
        let u_invalid: f64 = self.rng.random();
        let u_crc: f64 = self.rng.random();
        let u_trunc: f64 = self.rng.random();
        let u_pos: f64 = self.rng.random();
        let silent = self.faults.silent_window_us.is_some_and(|(a, b)| (a..b).contains(&t_us));
        if silent || u_drop < self.faults.dropout_probability {
            self.counters.dropped += 1;
            return period;
        }
        let r_bd = self.mounting.rot_body_from_dvl * self.errors.misalignment;
        let v_b = Vector3::from(input.vel_body_mps);
        let w_b = Vector3::from(input.rate_body_radps);
        let v_dvl = r_bd.inverse_transform_vector(&(v_b + w_b.cross(&self.mounting.lever_arm_body_m)));
        let (vel, valid) = match self.range_mode {
            RangeMode::Auto => (v_dvl, in_range),
            RangeMode::WaterTrack => {
                let c_dvl = r_bd.inverse_transform_vector(&Vector3::from(input.current_body_mps));
                (v_dvl - c_dvl, !alt.is_finite() || alt > WATER_TRACK_MIN_ALTITUDE_M)
            }
        };
        let valid = valid && u_invalid >= self.faults.invalid_probability;
        let measured = if valid { vel * self.errors.scale + noise } else { Vector3::zeros() };
        // Validity and transmission times on the DVL clock.
        let slant = if alt.is_finite() { (alt.max(0.0) / BEAM_ANGLE_RAD.cos()).min(self.grade.max_altitude_m * 1.2) } else { 0.0 };
        let travel_us = (2.0 * slant / SPEED_OF_SOUND_MPS * 1e6) as u64;
        let tx_us = t_us + travel_us + PROCESSING_US;
        let tov = t_us + self.clock_offset_us;
        let tot = tx_us + self.clock_offset_us;
        let since_ms = self.last_report_us.map_or(0.0, |l| (t_us.saturating_sub(l)) as f64 / 1000.0);
        self.last_report_us = Some(t_us);
        let fom = if valid { noise_sigma } else { 2.707 };
        let var = noise_sigma * noise_sigma;
        let cov = if valid { format!("{var:.2e};0.00e0;0.00e0;0.00e0;{var:.2e};0.00e0;0.00e0;0.00e0;{var:.2e}") } else { String::new() };
        let status = u8::from(self.faults.high_temperature);
        let mut body = String::new();
        let (vx, vy, vz) = (measured.x, measured.y, measured.z);
        let yn = if valid { 'y' } else { 'n' };
        let _ = match self.range_mode {
            RangeMode::Auto => {
                let a = if valid { alt } else { -1.0 };
                write!(body, "wrz,{vx:.3},{vy:.3},{vz:.3},{yn},{a:.2},{fom:.3},{cov},{tov},{tot},{since_ms:.2},{status}")
            }
            RangeMode::WaterTrack => write!(body, "wrs,{vx:.3},{vy:.3},{vz:.3},{yn},{fom:.3},{cov},{tov},{tot},{since_ms:.2},{status}"),
        };
        if valid {
            self.counters.valid_reports += 1;
        } else {
            self.counters.invalid_reports += 1;
        }
        let mut line = with_checksum(&body).into_bytes();
        if u_crc < self.faults.bad_checksum_probability {
            // Change one character of the body (never the leading "wr" + letter).
            let i = 4 + ((u_pos * (body.len() - 4) as f64) as usize).min(body.len() - 5);
            line[i] = if line[i] == b'7' { b'8' } else { b'7' };
            self.counters.bad_checksum += 1;
        } else if u_trunc < self.faults.truncate_probability {
            line.truncate(body.len() - 1 - ((u_pos * 8.0) as usize).min(body.len() / 2));
            self.counters.truncated += 1;
        }
        self.send_line(tx_us, &line);
        period
    }

    /// Run the pings due by `t_us` (their reports may leave later).
    fn advance(&mut self, t_us: u64) {
        // One iteration per ping (at least 1/15 s of simulated time each).
        while self.next_ping_us <= t_us {
            let t = self.next_ping_us;
            if self.acoustic_enabled {
                self.next_ping_us = t + self.ping(t).max(1);
            } else if self.triggers > 0 {
                self.triggers -= 1;
                self.next_ping_us = t + self.ping(t).max(1);
            } else {
                self.next_ping_us = t_us + 1;
            }
        }
    }

    /// Bytes fully received by `t_us`.
    pub fn bytes_ready(&mut self, t_us: u64) -> usize {
        self.advance(t_us);
        self.out.iter().take_while(|(t, _)| *t <= t_us).count()
    }

    /// Read up to `buf.len()` bytes received by `t_us`.
    pub fn read(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        self.advance(t_us);
        let mut n = 0;
        for slot in buf.iter_mut() {
            match self.out.front() {
                Some((t, b)) if *t <= t_us => {
                    *slot = *b;
                    self.out.pop_front();
                    n += 1;
                }
                _ => break,
            }
        }
        n
    }

    /// Bytes from the firmware (commands), received at `t_us`.
    pub fn write(&mut self, t_us: u64, bytes: &[u8]) {
        self.advance(t_us);
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if !self.cmd.is_empty() {
                    let cmd = std::mem::take(&mut self.cmd);
                    let reply = self.command(&cmd);
                    self.counters.replies += 1;
                    self.send_line(t_us, with_checksum(&reply).as_bytes());
                }
            } else if self.cmd.len() < 256 {
                self.cmd.push(b);
            }
        }
    }

    /// The reply body to one command line.
    fn command(&mut self, line: &[u8]) -> String {
        let Ok(text) = std::str::from_utf8(line) else { return "wr?".into() };
        let body = match text.rsplit_once('*') {
            Some((body, sum)) => {
                if u8::from_str_radix(sum, 16).ok() != Some(crc8(body.as_bytes())) || sum.len() != 2 {
                    return "wr!".into();
                }
                body
            }
            None => text,
        };
        let fields: Vec<&str> = body.split(',').collect();
        match fields.as_slice() {
            ["wcv"] => format!("wrv,{PROTOCOL_VERSION}"),
            ["wcx"] => {
                if self.triggers < 15 {
                    self.triggers += 1;
                    "wra".into()
                } else {
                    "wrn".into()
                }
            }
            ["wcp", p] => match *p {
                "0" | "1" | "2" | "3" | "6" => "wra".into(),
                _ => "wrn".into(),
            },
            ["wcs", _sos, _mount, acoustic, _dark, range, rest @ ..] if rest.len() <= 1 => {
                match *acoustic {
                    "" => {}
                    "y" => self.acoustic_enabled = true,
                    "n" => self.acoustic_enabled = false,
                    _ => return "wr?".into(),
                }
                match *range {
                    "" => {}
                    "auto" => self.range_mode = RangeMode::Auto,
                    "wt" => self.range_mode = RangeMode::WaterTrack,
                    _ => return "wrn".into(),
                }
                "wra".into()
            }
            _ => "wr?".into(),
        }
    }
}

impl super::UartChip for DvlA50Model {
    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        DvlA50Model::read(self, t_us, buf)
    }
    fn write(&mut self, t_us: u64, bytes: &[u8]) {
        DvlA50Model::write(self, t_us, bytes)
    }
}

/// Shared clock for [`DvlUart`] (µs).
pub type SimClock = std::sync::Arc<std::sync::atomic::AtomicU64>;

/// The model as an `embedded_io` UART at the time of a shared clock, for native runs of the
/// firmware driver.
pub struct DvlUart {
    pub model: DvlA50Model,
    pub clock: SimClock,
}

impl embedded_io::ErrorType for DvlUart {
    type Error = core::convert::Infallible;
}

impl embedded_io::Read for DvlUart {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let t = self.clock.load(std::sync::atomic::Ordering::Relaxed);
        Ok(self.model.read(t, buf))
    }
}

impl embedded_io::ReadReady for DvlUart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        let t = self.clock.load(std::sync::atomic::Ordering::Relaxed);
        Ok(self.model.bytes_ready(t) > 0)
    }
}

impl embedded_io::Write for DvlUart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let t = self.clock.load(std::sync::atomic::Ordering::Relaxed);
        self.model.write(t, buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    use subnav_firmware::drivers::Error;
    use subnav_firmware::drivers::dvl_a50::{DvlA50, Received, Sentence, Tracking, VelocityReport, cmd, parse_sentence};

    fn cruise(alt: f64) -> impl FnMut(u64) -> DvlInput + Send + 'static {
        move |_| DvlInput {
            vel_body_mps: [1.0, 0.2, 0.05],
            rate_body_radps: [0.0, 0.0, 0.1],
            altitude_m: alt,
            current_body_mps: [0.3, -0.1, 0.0],
        }
    }

    fn lines(m: &mut DvlA50Model, t_us: u64) -> Vec<String> {
        let mut buf = vec![0u8; 1 << 20];
        let n = m.read(t_us, &mut buf);
        String::from_utf8(buf[..n].to_vec()).unwrap().split("\r\n").filter(|s| !s.is_empty()).map(str::to_owned).collect()
    }

    /// The driver on the model through [`DvlUart`], polled every millisecond for `dur_us`.
    fn run_driver(model: DvlA50Model, dur_us: u64) -> (Vec<Received>, Vec<Error<core::convert::Infallible>>, DvlA50<DvlUart>) {
        let clock: SimClock = Arc::new(AtomicU64::new(0));
        let mut dvl = DvlA50::new(DvlUart { model, clock: clock.clone() }, DEFAULT_BAUD);
        let (mut ok, mut err) = (Vec::new(), Vec::new());
        for t in (0..=dur_us).step_by(1000) {
            clock.store(t, Ordering::Relaxed);
            loop {
                match dvl.poll(t) {
                    Ok(Some(r)) => ok.push(r),
                    Ok(None) => break,
                    Err(e) => err.push(e),
                }
            }
        }
        (ok, err, dvl)
    }

    #[test]
    fn crc8_check_value_and_document_example() {
        assert_eq!(crc8(b"123456789"), 0xf4);
        assert_eq!(
            with_checksum("wrz,0.120,-0.400,2.000,y,1.30,1.855,1e-07;0;1.4;0;1.2;0;0.2;0;1e+09,7,14,123.00,1"),
            "wrz,0.120,-0.400,2.000,y,1.30,1.855,1e-07;0;1.4;0;1.2;0;0.2;0;1e+09,7,14,123.00,1*50"
        );
    }

    #[test]
    fn perfect_unit_reports_the_lever_arm_and_mounting_exactly() {
        let mounting = DvlMountingModel {
            rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_4),
            lever_arm_body_m: Vector3::new(0.5, 0.0, 0.3),
        };
        let grade = DvlGrade { noise_sigma_mps: 0.0, ..DvlGrade::A50 };
        let mut m = DvlA50Model::new(grade, mounting, 1, cruise(10.0));
        m.errors = DvlUnitErrors::none();
        let out = lines(&mut m, 1_000_000);
        assert!(!out.is_empty());
        let Ok(Sentence::Velocity(v)) = parse_sentence(out[0].as_bytes()) else { panic!("{}", out[0]) };
        // v_b + w x l = (1, 0.2, 0.05) + (0, 0, 0.1) x (0.5, 0, 0.3) = (1, 0.25, 0.05), then
        // rotated by -45 deg about z.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let expect = [h * (1.0 + 0.25), h * (0.25 - 1.0), 0.05];
        for (a, b) in v.vel_dvl_mps.iter().zip(expect) {
            assert!((f64::from(*a) - b).abs() <= 0.0005 + 1e-6, "{:?} vs {expect:?}", v.vel_dvl_mps);
        }
        assert!(v.valid && v.tracking == Tracking::Bottom);
        assert_eq!(v.altitude_m, Some(10.0));
        // Latency: two-way slant range at 10 m + processing.
        let slant = 10.0 / BEAM_ANGLE_RAD.cos();
        assert_eq!(v.latency_us(), (2.0 * slant / SPEED_OF_SOUND_MPS * 1e6) as u64 + PROCESSING_US);
        assert_eq!(v.time_of_validity_us, m.clock_offset_us);
    }

    #[test]
    fn rate_follows_altitude_and_lock() {
        for (alt, lo, hi) in [(1.0, 13.0, 15.1), (30.0, 2.9, 3.1), (49.0, 2.0, 2.3), (80.0, 1.9, 2.1)] {
            let mut m = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 2, cruise(alt));
            let n = lines(&mut m, 10_000_000).len() as f64 / 10.0;
            assert!((lo..=hi).contains(&n), "{n} Hz at {alt} m");
        }
    }

    #[test]
    fn unit_errors_are_per_seed_and_reproducible() {
        let a = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 5, cruise(5.0));
        let b = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 5, cruise(5.0));
        let c = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 6, cruise(5.0));
        assert_eq!(a.errors, b.errors);
        assert_ne!(a.errors, c.errors);
        assert!((a.errors.scale - 1.0).abs() < 5.0 * DvlGrade::A50.scale_sigma);
        assert!(a.errors.misalignment.angle() < 5.0 * 3f64.sqrt() * DvlGrade::A50.misalignment_sigma_rad);
        let (mut a, mut b) = (a, b);
        assert_eq!(lines(&mut a, 3_000_000), lines(&mut b, 3_000_000));
        // Over many seeds the scale error has the grade's spread.
        let scales: Vec<f64> =
            (0..400).map(|s| DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), s, cruise(5.0)).errors.scale - 1.0).collect();
        let sd = (scales.iter().map(|x| x * x).sum::<f64>() / scales.len() as f64).sqrt();
        assert!((sd / DvlGrade::A50.scale_sigma - 1.0).abs() < 0.15, "scale sd {sd}");
    }

    #[test]
    fn scale_error_and_noise_show_in_the_reports() {
        let grade = DvlGrade::A50;
        let mut m = DvlA50Model::new(grade, DvlMountingModel::default(), 3, cruise(5.0));
        m.errors = DvlUnitErrors { scale: 1.01, misalignment: UnitQuaternion::identity() };
        let vx: Vec<f64> = lines(&mut m, 60_000_000)
            .iter()
            .filter_map(|l| match parse_sentence(l.as_bytes()) {
                Ok(Sentence::Velocity(v)) => Some(f64::from(v.vel_dvl_mps[0])),
                _ => None,
            })
            .collect();
        let n = vx.len() as f64;
        let mean = vx.iter().sum::<f64>() / n;
        let sd = (vx.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        assert!((mean - 1.01).abs() < 0.001, "mean {mean}");
        assert!((sd / grade.noise_sigma_mps - 1.0).abs() < 0.1, "sd {sd} over {n} reports");
    }

    #[test]
    fn out_of_range_is_invalid_or_water_track() {
        let mut m = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 4, cruise(80.0));
        for l in lines(&mut m, 2_000_000) {
            let Ok(Sentence::Velocity(v)) = parse_sentence(l.as_bytes()) else { panic!("{l}") };
            assert!(!v.valid && v.altitude_m == Some(-1.0) && v.vel_dvl_mps == [0.0; 3], "{l}");
            assert!(v.bottom_velocity().is_none());
        }
        // Automatic water tracking: wrs with the velocity relative to the water.
        let mut m =
            DvlA50Model::new(DvlGrade { water_noise_sigma_mps: 0.0, ..DvlGrade::A50 }, DvlMountingModel::default(), 4, cruise(80.0));
        m.errors = DvlUnitErrors::none();
        m.faults.auto_water_track = true;
        let out = lines(&mut m, 2_000_000);
        assert_eq!(out.len(), 4, "2 Hz in water track: {out:?}");
        for l in out {
            let Ok(Sentence::Velocity(v)) = parse_sentence(l.as_bytes()) else { panic!("{l}") };
            assert_eq!(v.tracking, Tracking::Water);
            assert!(v.valid);
            // (1, 0.2, 0.05) + 0 - current (0.3, -0.1, 0) = (0.7, 0.3, 0.05).
            assert_eq!(v.vel_dvl_mps, [0.7, 0.3, 0.05]);
            assert!(v.bottom_velocity().is_none(), "water track is never fused as bottom velocity");
        }
    }

    #[test]
    fn commands_are_answered_with_checksums() {
        let mut m = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 1, cruise(5.0));
        m.acoustic_enabled = false;
        m.write(0, with_checksum("wcv").as_bytes());
        m.write(0, b"\n");
        m.write(0, b"wcx\r\n"); // checksum optional
        m.write(0, b"wcv*00\n"); // wrong checksum
        m.write(0, b"wcq\n");
        m.write(0, b"wcs,,,,,wt,\n");
        // Replies only (about 4 ms of bytes); the triggered ping's report leaves ~27 ms later.
        let out = lines(&mut m, 10_000);
        let bodies: Vec<&str> = out.iter().map(|l| l.rsplit_once('*').unwrap().0).collect();
        for l in &out {
            assert!(parse_sentence(l.as_bytes()).is_ok(), "{l}");
        }
        assert_eq!(&bodies[..], ["wrv,2.7.0", "wra", "wr!", "wr?", "wra"], "{out:?}");
        // The triggered ping came after the replies (acoustics off otherwise): one report.
        let later = lines(&mut m, 3_000_000);
        assert_eq!(later.len(), 1, "{later:?}");
        assert!(later[0].starts_with("wrs,"), "range mode wt was set: {}", later[0]);
    }

    #[test]
    fn driver_on_the_model_counts_exactly_what_was_injected() {
        let mut m = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 11, cruise(5.0));
        m.faults = DvlFaults {
            dropout_probability: 0.05,
            invalid_probability: 0.05,
            bad_checksum_probability: 0.05,
            truncate_probability: 0.05,
            silent_window_us: Some((20_000_000, 25_000_000)),
            ..Default::default()
        };
        let (ok, err, dvl) = run_driver(m, 60_000_000);
        let dc = *dvl.counters();
        let mc = dvl.destroy().model.counters;
        println!("model sent {mc:?}\ndriver counted {dc:?}");
        assert!(mc.bad_checksum > 10 && mc.truncated > 10 && mc.dropped > 10 && mc.invalid_reports > 10, "{mc:?}");
        // Every sentence the model sent is accounted for exactly once, in the right counter.
        assert_eq!(ok.len() as u64 + err.len() as u64, mc.valid_reports + mc.invalid_reports);
        assert_eq!(u64::from(dc.bad_checksum), mc.bad_checksum);
        assert_eq!(u64::from(dc.malformed), mc.truncated);
        assert_eq!(err.iter().filter(|e| matches!(e, Error::BadCrc { .. })).count() as u64, mc.bad_checksum);
        assert_eq!(err.iter().filter(|e| matches!(e, Error::Malformed)).count() as u64, mc.truncated);
        assert_eq!(u64::from(dc.valid_reports + dc.invalid_reports), ok.len() as u64);
        assert!(u64::from(dc.invalid_reports) <= mc.invalid_reports && dc.invalid_reports > 0);
        assert_eq!(dc.overlong + dc.other_sentences + dc.replies, 0);
        // Nothing invalid is offered for fusion; every valid bottom report is.
        let fusable = ok.iter().filter(|r| matches!(r.sentence, Sentence::Velocity(v) if v.bottom_velocity().is_some())).count();
        assert_eq!(fusable as u32, dc.valid_reports);
        // Times of validity land within the 1 ms poll period (plus rounding) after the ping.
        for r in &ok {
            let (Sentence::Velocity(v), Some(t)) = (r.sentence, r.t_valid_us) else { panic!() };
            let ping = v.time_of_validity_us - DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 0, cruise(5.0)).clock_offset_us;
            assert!((ping..=ping + 1_002).contains(&t), "t_valid {t} vs ping {ping}");
        }
        // The silent window left a gap of its length in the reports.
        let gap = ok.windows(2).map(|w| w[1].rx_us - w[0].rx_us).max().unwrap();
        assert!((5_000_000..5_500_000).contains(&gap), "longest gap {gap} us");
    }

    #[test]
    fn commands_from_the_driver_reach_the_model() {
        let clock: SimClock = Arc::new(AtomicU64::new(0));
        let model = DvlA50Model::new(DvlGrade::A50, DvlMountingModel::default(), 1, cruise(80.0));
        let mut dvl = DvlA50::new(DvlUart { model, clock: clock.clone() }, DEFAULT_BAUD);
        dvl.send_command(cmd::WATER_TRACK).unwrap();
        let mut got = Vec::new();
        for t in (0..=1_500_000u64).step_by(1000) {
            clock.store(t, Ordering::Relaxed);
            while let Ok(Some(r)) = dvl.poll(t) {
                got.push(r.sentence);
            }
        }
        assert!(got.iter().any(|s| matches!(s, Sentence::Reply(subnav_firmware::drivers::dvl_a50::Reply::Ack))), "{got:?}");
        assert!(
            got.iter().any(|s| matches!(s, Sentence::Velocity(VelocityReport { tracking: Tracking::Water, valid: true, .. }))),
            "{got:?}"
        );
        assert_eq!(dvl.counters().malformed + dvl.counters().bad_checksum, 0);
    }

    /// Model -> firmware driver -> navigation filter, with a turned and offset DVL: the three
    /// agree on frames and the lever-arm sign, and the DVL holds the velocity of an IMU with an
    /// uncompensated 0.02 m/s^2 accelerometer bias on a 60 s run (seeded unit errors on).
    #[test]
    fn model_driver_and_filter_close_the_loop() {
        use subnav_core::nav::dvl::{DvlMeasurement, DvlMounting};
        use subnav_core::nav::{NavConfig, NavFilter15, NavInit};
        use subnav_wire::messages::ImuSample;
        let (amp, w) = (0.25f64, 0.2f64);
        let rate = move |t_us: u64| amp * w * (w * t_us as f64 * 1e-6).cos();
        let yaw = move |t_us: u64| amp * (w * t_us as f64 * 1e-6).sin();
        let mounting = DvlMountingModel {
            rot_body_from_dvl: UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_4),
            lever_arm_body_m: Vector3::new(0.5, 0.0, 0.3),
        };
        let model = DvlA50Model::new(DvlGrade::A50, mounting, 21, move |t| DvlInput {
            vel_body_mps: [1.0, 0.0, 0.0],
            rate_body_radps: [0.0, 0.0, rate(t)],
            altitude_m: 10.0,
            current_body_mps: [0.0; 3],
        });
        let clock: SimClock = Arc::new(AtomicU64::new(0));
        let mut dvl = DvlA50::new(DvlUart { model, clock: clock.clone() }, DEFAULT_BAUD);
        let mount = DvlMounting {
            rot_body_from_dvl: nalgebra::convert(mounting.rot_body_from_dvl),
            lever_arm_body_m: nalgebra::convert(mounting.lever_arm_body_m),
        };
        let cfg = NavConfig { init_sigma_vel_mps: 0.5, ..NavConfig::default() };
        let init = NavInit {
            t_us: 0,
            att_nb: nalgebra::UnitQuaternion::identity(),
            vel_ned_mps: nalgebra::Vector3::new(1.0, 0.3, 0.0),
            pos_ned_m: nalgebra::Vector3::new(0.0, 0.0, 10.0),
        };
        let mut nav = NavFilter15::new(cfg, init).unwrap();
        let (mut fused, mut rejected_late) = (0, 0);
        for t in (0..=60_000_000u64).step_by(1000) {
            clock.store(t, Ordering::Relaxed);
            if t > 0 && t % 10_000 == 0 {
                let r = rate(t) as f32;
                let imu = ImuSample { t_us: t, gyro_radps: [0.0, 0.0, r], accel_mps2: [0.02, r, -9.81], temp_c: 10.0 };
                nav.propagate(&imu).unwrap();
            }
            while let Ok(Some(rx)) = dvl.poll(t) {
                let (Sentence::Velocity(v), Some(t_valid)) = (rx.sentence, rx.t_valid_us) else { continue };
                let Some(b) = v.bottom_velocity() else { continue };
                let m = DvlMeasurement {
                    t_us: t_valid,
                    vel_dvl_mps: b.vel_dvl_mps,
                    covariance_m2ps2: b.covariance_m2ps2,
                    fom_mps: Some(b.fom_mps),
                    gyro_radps: [0.0, 0.0, rate(t_valid) as f32],
                };
                let rep = nav.update_dvl(&m, &mount).unwrap();
                fused += u32::from(rep.accepted);
                rejected_late += u32::from(!rep.accepted && t > 5_000_000);
            }
        }
        let y = yaw(60_000_000) as f32;
        let err = (nav.nominal().vel_ned_mps.xy() - nalgebra::Vector2::new(y.cos(), y.sin())).norm();
        println!("fused {fused} DVL reports, {rejected_late} rejected after 5 s, final horizontal velocity error {err:.4} m/s");
        // 6.5 Hz at 10 m for 60 s is ~390 reports; the first few wait for the gate release.
        assert!(fused > 350, "{fused}");
        assert_eq!(rejected_late, 0);
        assert!(err < 0.05, "horizontal velocity error {err} m/s");
    }
}
