//! The link that brings the host's commands to the sensor head during a dive (an acoustic modem
//! or a USBL system's serial output), as a UART carrying downlink frames (`subnav_wire` framing).
//!
//! Each frame is scheduled with its arrival time: the instant its last byte reaches the head,
//! after the acoustic travel, the topside processing and the modem's own latency (the scenario
//! decides them; [`crate::head::FixPlan::latency_s`]). Bytes of a frame become readable only
//! from that instant, so the firmware sees a fix exactly when it would arrive, never earlier.
//! Under QEMU this goes through the synchronous bus bridge, which keeps a run deterministic
//! (commands written to the telemetry socket reach the emulated UART at a host-dependent
//! instant).

use std::collections::VecDeque;

/// Called with (arrival time µs, frame) when a frame's bytes become readable (e.g. to put it in
/// a recording's downlink stream).
pub type DeliveryTap = Box<dyn FnMut(u64, &[u8]) + Send>;

/// Frames produced while the dive runs (e.g. by the host's map): called with the current time,
/// returns the frames arriving now.
pub type LiveSource = Box<dyn FnMut(u64) -> Vec<Vec<u8>> + Send>;

/// Frames waiting for their arrival time, then their bytes.
pub struct ModemModel {
    scheduled: VecDeque<(u64, Vec<u8>)>,
    ready: VecDeque<u8>,
    tap: Option<DeliveryTap>,
    live: Vec<LiveSource>,
    /// Frames delivered so far.
    pub delivered: u64,
}

impl ModemModel {
    /// `frames`: (arrival time µs, encoded downlink frame), any order.
    pub fn new(mut frames: Vec<(u64, Vec<u8>)>, tap: Option<DeliveryTap>) -> Self {
        frames.sort_by_key(|(t, _)| *t);
        Self { scheduled: frames.into(), ready: VecDeque::new(), tap, live: Vec::new(), delivered: 0 }
    }

    /// Also deliver the frames `live` produces during the run (several sources: each polled in turn).
    pub fn with_live_source(mut self, live: LiveSource) -> Self {
        self.live.push(live);
        self
    }

    fn advance(&mut self, t_us: u64) {
        while self.scheduled.front().is_some_and(|(t, _)| *t <= t_us) {
            let Some((t, frame)) = self.scheduled.pop_front() else { break };
            if let Some(tap) = self.tap.as_mut() {
                tap(t, &frame);
            }
            self.ready.extend(frame);
            self.delivered += 1;
        }
        for live in self.live.iter_mut() {
            for frame in live(t_us) {
                if let Some(tap) = self.tap.as_mut() {
                    tap(t_us, &frame);
                }
                self.ready.extend(frame);
                self.delivered += 1;
            }
        }
    }
}

impl super::UartChip for ModemModel {
    fn read(&mut self, t_us: u64, buf: &mut [u8]) -> usize {
        self.advance(t_us);
        let n = buf.len().min(self.ready.len());
        for (slot, b) in buf.iter_mut().zip(self.ready.drain(..n)) {
            *slot = b;
        }
        n
    }
    /// The head sends nothing on this link (its telemetry has its own UART).
    fn write(&mut self, _t_us: u64, _bytes: &[u8]) {}
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chips::UartChip;

    #[test]
    fn frames_appear_at_their_arrival_time_not_before() {
        let mut m = ModemModel::new(vec![(2_000, vec![5, 6, 0]), (1_000, vec![1, 2, 3, 0])], None);
        let mut buf = [0u8; 16];
        assert_eq!(m.read(999, &mut buf), 0);
        assert_eq!(m.read(1_000, &mut buf), 4);
        assert_eq!(&buf[..4], &[1, 2, 3, 0]);
        assert_eq!(m.read(1_999, &mut buf), 0);
        let mut small = [0u8; 2];
        assert_eq!(m.read(5_000, &mut small), 2);
        assert_eq!(m.read(5_000, &mut small), 1);
        assert_eq!(m.delivered, 2);
    }
}
