//! What the application needs from the sensors, independent of buses and chips. A board
//! implements [`SensorSuite`] on top of its drivers (real buses on the STM32 board, the host
//! bridge under QEMU); host tests implement it with fakes.

use subnav_wire::{DepthSample, DvlSample, FaultKind, FaultSource, ImuSample};

/// A failed sensor read, as reported in fault telemetry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorFault {
    pub source: FaultSource,
    pub kind: FaultKind,
}

impl core::fmt::Display for SensorFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}: {}", self.source, self.kind)
    }
}

impl core::error::Error for SensorFault {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        Some(&self.kind)
    }
}

pub trait SensorSuite {
    /// Advance non-blocking work (conversions, scans); called every scheduler tick.
    fn service(&mut self, _t_us: u64) {}
    /// One IMU sample (body FRD, SI units) for time `t_us`.
    fn read_imu(&mut self, t_us: u64) -> Result<ImuSample, SensorFault>;
    /// After `read_imu` returned `Stuck` with only gyro axes stuck: that sample and the stuck
    /// gyro axes (bit k = body axis k), for the degraded mode that keeps the five good axes.
    /// `None` otherwise (then the estimator coasts).
    fn take_degraded_imu(&mut self) -> Option<(ImuSample, u8)> {
        None
    }
    /// Raw counts (0/45/90/135 deg) of polarization unit `unit`.
    fn read_polarization(&mut self, t_us: u64, unit: u8) -> Result<[i16; 4], SensorFault>;
    /// Pressure, temperature and depth (positive down) with the given water density.
    fn read_depth(&mut self, t_us: u64, water_density_kgm3: f32) -> Result<DepthSample, SensorFault>;
    /// The next DVL velocity report completed by `t_us` (valid or not, bottom or water track),
    /// `Ok(None)` when there is none (or no DVL). Called every tick until `Ok(None)`; an error
    /// (bus, malformed sentence, bad checksum) costs only its sentence.
    fn poll_dvl(&mut self, _t_us: u64) -> Result<Option<DvlSample>, SensorFault> {
        Ok(None)
    }
    /// Pulse the camera's trigger line at `t_us`: `Ok(true)` when pulsed, `Ok(false)` when the
    /// suite has no camera.
    fn trigger_camera(&mut self, _t_us: u64) -> Result<bool, SensorFault> {
        Ok(false)
    }
}

/// Counts faults per (source, kind) and decides when to report them: the first occurrence,
/// then at most once per second per pair, so a dead sensor does not flood the link.
pub struct FaultLog {
    entries: heapless::Vec<(FaultSource, FaultKind, u32, u64), 16>,
    /// Faults that did not fit in the table (still counted here).
    pub overflow: u32,
}

impl Default for FaultLog {
    fn default() -> Self {
        Self::new()
    }
}

impl FaultLog {
    pub const fn new() -> Self {
        Self { entries: heapless::Vec::new(), overflow: 0 }
    }

    /// Record one fault at `t_us`; returns the count to report now, if any.
    pub fn record(&mut self, t_us: u64, f: SensorFault) -> Option<u32> {
        if let Some(e) = self.entries.iter_mut().find(|e| e.0 == f.source && e.1 == f.kind) {
            e.2 = e.2.saturating_add(1);
            if t_us.saturating_sub(e.3) >= 1_000_000 {
                e.3 = t_us;
                return Some(e.2);
            }
            return None;
        }
        if self.entries.push((f.source, f.kind, 1, t_us)).is_err() {
            self.overflow = self.overflow.saturating_add(1);
            return None;
        }
        Some(1)
    }

    /// Total faults of a source/kind pair since boot.
    pub fn count(&self, source: FaultSource, kind: FaultKind) -> u32 {
        self.entries.iter().find(|e| e.0 == source && e.1 == kind).map(|e| e.2).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_are_rate_limited_but_all_counted() {
        let mut log = FaultLog::new();
        let f = SensorFault { source: FaultSource::Imu, kind: FaultKind::BusNack };
        let reported: Vec<u32> = (0..300u64).filter_map(|k| log.record(k * 10_000, f)).collect();
        assert_eq!(reported, vec![1, 101, 201]);
        assert_eq!(log.count(FaultSource::Imu, FaultKind::BusNack), 300);
    }
}
