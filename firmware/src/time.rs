//! Monotonic microseconds from a 1 kHz tick counter and the SysTick down-counter: the one
//! piece of time keeping both boards share (they differ only in core clock and in how they read
//! the two registers).

/// Extends a wrapping 32-bit millisecond count plus the SysTick current value to a 64-bit µs
/// clock.
pub struct TickClock {
    last_ms: u32,
    high: u64,
    reload: u32,
    ticks_per_us: u32,
}

impl TickClock {
    /// SysTick on the core clock `core_hz`, interrupting at 1 kHz.
    pub const fn new(core_hz: u32) -> Self {
        Self { last_ms: 0, high: 0, reload: core_hz / 1_000 - 1, ticks_per_us: core_hz / 1_000_000 }
    }

    /// The SysTick reload value to program.
    pub const fn reload(&self) -> u32 {
        self.reload
    }

    /// Time for a consistent pair (millisecond count, SysTick current value).
    pub fn now_us(&mut self, ms: u32, cvr: u32) -> u64 {
        if ms < self.last_ms {
            self.high += 1 << 32;
        }
        self.last_ms = ms;
        let sub_us = u64::from(self.reload - cvr.min(self.reload)) / u64::from(self.ticks_per_us.max(1));
        (self.high + u64::from(ms)) * 1000 + sub_us
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sub_tick_and_wrap() {
        let mut c = TickClock::new(25_000_000);
        assert_eq!(c.reload(), 24_999);
        assert_eq!(c.now_us(5, 24_999), 5_000);
        assert_eq!(c.now_us(5, 12_499), 5_500);
        assert_eq!(c.now_us(u32::MAX, 24_999), u64::from(u32::MAX) * 1000);
        assert_eq!(c.now_us(0, 24_999), (1u64 << 32) * 1000, "the ms counter wrapped");
    }
}
