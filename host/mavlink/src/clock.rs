//! Three clocks: the head's (`t_us` since its boot, every time of validity), the companion's
//! (this process, µs since the bridge started) and the autopilot's (µs since its boot).
//!
//! Head -> companion ([`HeadClock`]): for a simulated head run in this process the map is known
//! (the run paces itself: head time `t` happens at `start + t / speed`); for a real link it is
//! estimated from the arrivals, as the minimum of (arrival - head time) over a sliding window
//! (the smallest transport delay: ArduPilot's `JitterCorrection` does the same for offboard
//! stamps). Companion -> autopilot ([`TimeSync`]): MAVLink's `TIMESYNC` exchange; the offset of
//! the round trip with the smallest delay among the recent ones (a long round trip says little
//! about where in it the autopilot read its clock).

use std::collections::VecDeque;

/// Maps the head's clock to the companion's.
#[derive(Debug, Clone)]
pub enum HeadClock {
    /// Head time `t_us` happens at companion time `start_us + t_us / speed`.
    Known { start_us: i64, speed: f64 },
    /// Estimated from arrivals: offset (companion - head / rate) of the fastest arrival in the
    /// current and the previous window. `rate`: head seconds per companion second (1 on a live
    /// link; a recording replayed at 10x: 10).
    Estimated { window_us: i64, rate: f64, current: Option<(i64, i64)>, previous: Option<i64>, last_head_us: Option<u64>, reboots: u32 },
}

impl HeadClock {
    /// An estimating clock with windows of `window_s`.
    pub fn estimated(window_s: f64) -> Self {
        Self::estimated_at(window_s, 1.0)
    }

    /// As [`Self::estimated`] for a head whose clock runs `rate` times ours (a replay).
    pub fn estimated_at(window_s: f64, rate: f64) -> Self {
        HeadClock::Estimated { window_us: (window_s * 1e6) as i64, rate, current: None, previous: None, last_head_us: None, reboots: 0 }
    }

    /// A message with head time `head_us` arrived at companion time `rx_us`.
    pub fn observe(&mut self, head_us: u64, rx_us: i64) {
        let HeadClock::Estimated { window_us, rate, current, previous, last_head_us, reboots } = self else { return };
        // The head rebooted (its clock went back by more than a second): start again.
        if last_head_us.is_some_and(|l| head_us.saturating_add(1_000_000) < l) {
            *current = None;
            *previous = None;
            *reboots += 1;
        }
        *last_head_us = Some(head_us);
        let off = rx_us - (head_us as f64 / *rate) as i64;
        match current {
            Some((start, min)) if rx_us - *start < *window_us => *min = (*min).min(off),
            Some((_, min)) => {
                *previous = Some(*min);
                *current = Some((rx_us, off));
            }
            None => *current = Some((rx_us, off)),
        }
    }

    /// Companion time of head time `head_us` (None before the first arrival).
    pub fn to_companion_us(&self, head_us: u64) -> Option<i64> {
        match self {
            HeadClock::Known { start_us, speed } => Some(*start_us + (head_us as f64 / speed) as i64),
            HeadClock::Estimated { current, previous, rate, .. } => {
                let cur = current.map(|(_, m)| m);
                let off = match (cur, *previous) {
                    (Some(a), Some(b)) => a.min(b),
                    (a, b) => a.or(b)?,
                };
                Some((head_us as f64 / rate) as i64 + off)
            }
        }
    }

    /// Head time of companion time `t_us` (None before the first arrival or before the head's boot).
    pub fn to_head_us(&self, t_us: i64) -> Option<u64> {
        let off0 = self.to_companion_us(0)?;
        let head = match self {
            HeadClock::Known { speed, .. } => ((t_us - off0) as f64 * speed) as i64,
            HeadClock::Estimated { rate, .. } => ((t_us - off0) as f64 * rate) as i64,
        };
        u64::try_from(head).ok()
    }
}

/// One round trip of `TIMESYNC`.
#[derive(Debug, Clone, Copy)]
struct Sample {
    rtt_ns: i64,
    /// Autopilot minus companion, ns.
    offset_ns: i64,
}

/// The `TIMESYNC` exchange with the autopilot (both sides' clocks in ns on the wire).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TimeSync {
    #[serde(skip)]
    samples: VecDeque<Sample>,
    #[serde(skip)]
    outstanding: VecDeque<i64>,
    /// Disagreeing good samples in a row (the autopilot rebooted if they persist).
    #[serde(skip)]
    disagreeing: u32,
    pub requests: u64,
    pub replies: u64,
    /// Replies refused: not an answer to one of our requests, negative or over-long round trip.
    pub refused: u64,
    /// Estimates restarted because the autopilot's clock jumped (a reboot).
    pub restarts: u32,
    /// Current estimate (autopilot - companion, µs) and the round trip it came from (µs).
    pub offset_us: Option<i64>,
    pub rtt_us: Option<i64>,
}

/// Round trips longer than this are refused, ns.
pub const MAX_RTT_NS: i64 = 500_000_000;
/// Round trips up to this count towards convergence, ns.
pub const GOOD_RTT_NS: i64 = 50_000_000;
/// Good round trips before the estimate is used.
pub const SAMPLES_TO_CONVERGE: usize = 3;

impl TimeSync {
    /// The request to send at companion time `now_ns` (`tc1 = 0`, `ts1 = now`).
    pub fn request(&mut self, now_ns: i64) -> (i64, i64) {
        self.requests += 1;
        self.outstanding.push_back(now_ns);
        while self.outstanding.len() > 16 {
            self.outstanding.pop_front();
        }
        (0, now_ns)
    }

    /// A reply (`tc1`: the autopilot's time, `ts1`: our request's time) received at `now_ns`.
    /// Returns whether it was used.
    pub fn on_reply(&mut self, tc1_ns: i64, ts1_ns: i64, now_ns: i64) -> bool {
        let Some(pos) = self.outstanding.iter().position(|&t| t == ts1_ns) else {
            self.refused += 1;
            return false;
        };
        self.outstanding.remove(pos);
        let rtt = now_ns - ts1_ns;
        if !(0..=MAX_RTT_NS).contains(&rtt) || tc1_ns <= 0 {
            self.refused += 1;
            return false;
        }
        self.replies += 1;
        let s = Sample { rtt_ns: rtt, offset_ns: tc1_ns - (ts1_ns + rtt / 2) };
        if let Some(cur) = self.offset_us {
            // 50 ms off the estimate, three times in a row: the autopilot's clock jumped.
            if rtt <= GOOD_RTT_NS && (s.offset_ns / 1000 - cur).abs() > 50_000 {
                self.disagreeing += 1;
                if self.disagreeing < 3 {
                    return false;
                }
                self.samples.clear();
                self.restarts += 1;
            }
            self.disagreeing = 0;
        }
        self.samples.push_back(s);
        while self.samples.len() > 16 {
            self.samples.pop_front();
        }
        let good: Vec<&Sample> = self.samples.iter().filter(|s| s.rtt_ns <= GOOD_RTT_NS).collect();
        if good.len() >= SAMPLES_TO_CONVERGE
            && let Some(best) = good.iter().min_by_key(|s| s.rtt_ns)
        {
            self.offset_us = Some(best.offset_ns / 1000);
            self.rtt_us = Some(best.rtt_ns / 1000);
        } else {
            self.offset_us = None;
            self.rtt_us = None;
        }
        true
    }

    pub fn converged(&self) -> bool {
        self.offset_us.is_some()
    }

    /// Autopilot time of companion time `t_us` once converged.
    pub fn to_autopilot_us(&self, t_us: i64) -> Option<i64> {
        self.offset_us.map(|o| t_us + o)
    }

    /// Companion time of autopilot time `t_us` once converged.
    pub fn to_companion_us(&self, t_us: i64) -> Option<i64> {
        self.offset_us.map(|o| t_us - o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timesync_converges_on_the_fastest_round_trip_and_refuses_strangers() {
        let mut ts = TimeSync::default();
        // Autopilot clock = companion + 1000 s. Round trips 30, 10, 40 ms, the autopilot reading
        // its clock at 1/3 of each (asymmetric): the 10-ms one is closest.
        let truth_ns = 1_000_000_000_000i64;
        for (k, rtt) in [30_000_000i64, 10_000_000, 40_000_000].into_iter().enumerate() {
            let t0 = k as i64 * 1_000_000_000;
            let (tc1, ts1) = ts.request(t0);
            assert_eq!(tc1, 0);
            assert!(!ts.converged());
            assert!(ts.on_reply(t0 + rtt / 3 + truth_ns, ts1, t0 + rtt));
        }
        assert!(ts.converged());
        let err_us = ts.offset_us.unwrap() - truth_ns / 1000;
        assert!(err_us.abs() <= 10_000 / 6 + 1, "{err_us}");
        assert_eq!(ts.rtt_us, Some(10_000));
        // Not an answer to us, and a reply with a negative round trip: refused.
        assert!(!ts.on_reply(5, 123, 10));
        let (_, ts1) = ts.request(10_000_000_000);
        assert!(!ts.on_reply(5, ts1, 9_000_000_000));
        assert_eq!(ts.refused, 2);
        assert_eq!(ts.to_autopilot_us(0), ts.offset_us);
    }

    #[test]
    fn timesync_restarts_when_the_autopilot_clock_jumps() {
        let mut ts = TimeSync::default();
        let mut t = 0i64;
        let mut exchange = |ts: &mut TimeSync, off: i64| {
            t += 1_000_000_000;
            let (_, ts1) = ts.request(t);
            ts.on_reply(t + 5_000_000 + off, ts1, t + 10_000_000)
        };
        for _ in 0..3 {
            exchange(&mut ts, 7_000_000_000_000);
        }
        assert_eq!(ts.offset_us, Some(7_000_000_000));
        // The autopilot rebooted: its clock is now close to ours. Two odd replies are not
        // enough; the third restarts the estimate.
        assert!(!exchange(&mut ts, 3_000_000_000));
        assert!(!exchange(&mut ts, 3_000_000_000));
        assert!(exchange(&mut ts, 3_000_000_000));
        assert_eq!(ts.restarts, 1);
        assert!(!ts.converged());
        exchange(&mut ts, 3_000_000_000);
        exchange(&mut ts, 3_000_000_000);
        assert_eq!(ts.offset_us, Some(3_000_000));
    }

    #[test]
    fn head_clock_estimated_from_the_fastest_arrival_and_restarted_on_reboot() {
        let mut c = HeadClock::estimated(10.0);
        assert!(c.to_companion_us(0).is_none());
        // Arrivals 5-25 ms after head time + 2 s.
        for (k, d) in [25_000i64, 5_000, 12_000].into_iter().enumerate() {
            let h = k as u64 * 100_000;
            c.observe(h, 2_000_000 + h as i64 + d);
        }
        assert_eq!(c.to_companion_us(1_000_000), Some(3_005_000));
        assert_eq!(c.to_head_us(3_005_000), Some(1_000_000));
        // Reboot: head time back from 5 s to 0, at companion 50 s.
        c.observe(5_000_000, 7_010_000);
        c.observe(0, 50_000_000);
        assert_eq!(c.to_companion_us(0), Some(50_000_000));
        // A replay at 10x: head time runs ten times ours.
        let mut r = HeadClock::estimated_at(10.0, 10.0);
        r.observe(1_000_000, 500_000);
        r.observe(2_000_000, 600_000);
        assert_eq!(r.to_companion_us(3_000_000), Some(700_000));
        assert_eq!(r.to_head_us(700_000), Some(3_000_000));
        let known = HeadClock::Known { start_us: 1_000, speed: 2.0 };
        assert_eq!(known.to_companion_us(2_000_000), Some(1_001_000));
        assert_eq!(known.to_head_us(1_001_000), Some(2_000_000));
    }
}
