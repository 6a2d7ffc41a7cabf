//! Fixed-point angles ("turns") and a single-precision sine/cosine on them.
//!
//! Why: a Cortex-M4F has a single-precision FPU. An f32 Julian date (or an f32 angle that grows
//! linearly with time, such as the Earth's rotation angle, ~29,000 turns per 80 years) has far too
//! little resolution. Every angle that is linear in time is therefore evaluated exactly in 64-bit
//! integer arithmetic as a fraction of a turn (wrapping = reduction modulo 2 pi, for free):
//! `phase = b + rate_per_day * days + rate_per_us * us_of_day`. The per-day and per-microsecond
//! rates are computed at compile time (f64 `const fn`), so no f64 arithmetic runs on the target.
//! Only the top 32 bits are converted to f32 radians, in (-pi, pi].
//!
//! The sine/cosine here take such a phase directly (quadrant from the top bits, Taylor polynomial
//! on |x| <= pi/4). `libm`'s `sinf`/`cosf`/`tanf` are not used because their kernels compute in
//! f64, which is software emulation on a single-precision FPU.

/// 2^64 as f64.
const TWO64: f64 = 18_446_744_073_709_551_616.0;
/// Microseconds per day.
pub const US_PER_DAY: i64 = 86_400_000_000;
/// Radians per unit of the top 32 bits of a phase.
const RAD_PER_Q32: f32 = core::f32::consts::TAU / 4_294_967_296.0;
/// Units of the top 32 bits of a phase per radian.
const Q32_PER_RAD: f32 = 4_294_967_296.0 / core::f32::consts::TAU;

/// Fraction of a turn of `x` turns, as Q0.64 (compile time only).
pub const fn turns_q64(x: f64) -> u64 {
    let mut f = x - (x as i64) as f64;
    if f < 0.0 {
        f += 1.0;
    }
    // `as` saturates: f in [0, 1) maps into [0, 2^64).
    (f * TWO64) as u64
}

/// A rate of change of a phase, split so that both products are exact in 64-bit wrapping
/// arithmetic over +-100 years.
#[derive(Clone, Copy, Debug)]
pub struct Rate {
    pub per_day: u64,
    pub per_us: u64,
}

impl Rate {
    /// From turns per day (compile time only).
    pub const fn from_turns_per_day(r: f64) -> Self {
        Rate { per_day: turns_q64(r), per_us: turns_q64(r / US_PER_DAY as f64) }
    }
}

/// Time split into whole days and microseconds of the day, relative to some epoch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplitTime {
    pub days: i64,
    pub us_of_day: u64,
}

impl SplitTime {
    pub fn from_us(us: i64) -> Self {
        SplitTime { days: us.div_euclid(US_PER_DAY), us_of_day: us.rem_euclid(US_PER_DAY) as u64 }
    }
    /// Days as f32 (for the small polynomial corrections only).
    pub fn days_f32(&self) -> f32 {
        self.days as f32 + self.us_of_day as f32 * (1.0 / US_PER_DAY as f32)
    }
}

/// `b + rate * t` in turns (Q0.64, wrapping).
#[inline]
pub fn phase(b: u64, rate: Rate, t: SplitTime) -> u64 {
    b.wrapping_add(rate.per_day.wrapping_mul(t.days as u64)).wrapping_add(rate.per_us.wrapping_mul(t.us_of_day))
}

/// Phase (Q0.64 turns) to radians in [-pi, pi).
#[inline]
pub fn to_rad(p: u64) -> f32 {
    ((p >> 32) as u32 as i32) as f32 * RAD_PER_Q32
}

/// Radians (|x| < 1e6) to a phase (Q0.64 turns). Resolution of the f32 input is kept.
/// Only f32 <-> i32 conversions (single instructions on the FPU), no 64-bit float conversion.
#[inline]
pub fn from_rad(x: f32) -> u64 {
    // Subtract the nearest whole number of turns so that |rest| <= pi; the saturating cast
    // maps +pi to just below half a turn.
    let turns = x * (1.0 / core::f32::consts::TAU);
    let whole = (turns + if turns >= 0.0 { 0.5 } else { -0.5 }) as i32 as f32;
    let rest = x - whole * core::f32::consts::TAU;
    u64::from((rest * Q32_PER_RAD) as i32 as u32) << 32
}

/// Sine and cosine of a phase (Q0.64 turns). Max abs error about 1.2e-7.
#[inline]
pub fn sincos(p: u64) -> (f32, f32) {
    let q = (p >> 32) as u32;
    // Shift by 1/8 turn so that each quadrant is centred on a multiple of a quarter turn.
    let s = q.wrapping_add(1 << 29);
    let quadrant = s >> 30;
    let r = (s & ((1 << 30) - 1)) as i32 - (1 << 29);
    let x = r as f32 * RAD_PER_Q32; // |x| <= pi/4
    let x2 = x * x;
    let sn = x * (1.0 + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362_880.0)))));
    let cs = 1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40_320.0))));
    match quadrant {
        0 => (sn, cs),
        1 => (cs, -sn),
        2 => (-sn, -cs),
        _ => (-cs, sn),
    }
}

/// Sine and cosine of an angle in radians.
#[inline]
pub fn sincos_rad(x: f32) -> (f32, f32) {
    sincos(from_rad(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sincos_matches_f64() {
        let mut worst = 0.0f64;
        for i in 0..100_000u64 {
            let p = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let (s, c) = sincos(p);
            let a = (p >> 32) as f64 / 4_294_967_296.0 * core::f64::consts::TAU;
            worst = worst.max((s as f64 - a.sin()).abs()).max((c as f64 - a.cos()).abs());
        }
        assert!(worst < 3e-7, "worst {worst}");
    }

    #[test]
    fn rad_round_trip() {
        for &x in &[0.0f32, 1.0, -1.0, 3.1, -3.1, 6.5, -9.9] {
            let back = to_rad(from_rad(x)) as f64;
            let want = (x as f64 + core::f64::consts::PI).rem_euclid(core::f64::consts::TAU) - core::f64::consts::PI;
            assert!((back - want).abs() < 2e-6, "{x}: {back} vs {want}");
        }
    }

    #[test]
    fn phase_is_exact_over_a_century() {
        // Earth rotation angle rate; the per-microsecond rate quantization allows ~1e-9 turn
        // (0.001 arcsec) over a day; the per-day part is exact to ~1e-11 turn.
        let rate = Rate::from_turns_per_day(1.002_737_909_350_795);
        let t = SplitTime::from_us(36_525 * US_PER_DAY + 12_345_678_901);
        let p = phase(0, rate, t);
        let want = (1.002_737_909_350_795f64 * (36_525.0 + 12_345.678_901 / 86_400.0)).fract();
        let got = (p >> 11) as f64 / (1u64 << 53) as f64;
        assert!((got - want).abs() < 3e-9, "{got} vs {want}");
    }
}
