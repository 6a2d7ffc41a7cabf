//! Typed clap value parsers shared by the subcommands: the one seed syntax, the fault windows
//! of `subnav sim`, and bounded numbers. Each parser returns a `String` error that clap prints
//! after the flag's name (`error: invalid value '5..2' for '--seeds <SEEDS>': ...`), so bad
//! input ends with a usage error, never a panic.
//!
//! Numbers: every number a user can set has a range, checked in one place ([`bounded`]) by
//! the value parsers [`f64_in`], [`f64_positive_upto`] and [`int_in`]. The error names the
//! bound (`must be a number in 0..=86400, got inf`); clap adds the flag. The bounds keep a
//! value from panicking a conversion (`Duration::from_secs_f64(-1)`), overflowing a capacity
//! (`--upsample 18446744073709551615`) or asking for gigabytes (`--duration-s 1e9`).
//!
//! Seeds: `--seed N` selects one seeded run; `--seeds SEEDS` selects several, written `N` (one
//! seed), `A..B` (A to B exclusive, as a Rust range) or `A..=B` (A to B inclusive), at most
//! [`MAX_SEEDS`] of them (`0..18446744073709551615` panicked one command and ran the others
//! until killed).
//!
//! Bounds on work (each keeps a command finite): [`MAX_SEEDS`] seeded runs, [`MAX_REPEATS`]
//! timing repeats, [`MAX_TIMEOUT_S`] of wall-clock limit, [`MIN_SPEED`] times real time at the
//! slowest, [`MAX_SIM_DURATION_S`] of simulated time.

use std::fmt;
use std::fmt::Display;
use std::ops::RangeInclusive;
use std::str::FromStr;

/// Checks a number against its range: `Ok(v)` inside, else an error naming `what`, the bound
/// and the value (NaN is outside every range). The one check behind the numeric value parsers,
/// also usable on numbers read from files.
pub fn bounded<T: PartialOrd + Display + Copy>(what: &str, v: T, range: &RangeInclusive<T>) -> Result<T, String> {
    if range.contains(&v) { Ok(v) } else { Err(format!("{what} must be in {}..={}, got {v}", range.start(), range.end())) }
}

/// A clap value parser: a number in `range` (inclusive; finite because the range is).
pub fn f64_in(range: RangeInclusive<f64>) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number (expected {}..={})", range.start(), range.end()))?;
        bounded("the value", v, &range)
    }
}

/// A clap value parser: a number in `(0, max]` (durations, distances, periods).
pub fn f64_positive_upto(max: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number (expected > 0 and <= {max})"))?;
        if v > 0.0 && v <= max { Ok(v) } else { Err(format!("the value must be > 0 and <= {max}, got {v}")) }
    }
}

/// A clap value parser: an integer in `range` (inclusive).
pub fn int_in<T>(range: RangeInclusive<T>) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: FromStr + PartialOrd + Display + Copy + Send + Sync + 'static,
{
    move |s: &str| {
        let v: T = s.trim().parse().map_err(|_| format!("{s:?} is not an integer in {}..={}", range.start(), range.end()))?;
        bounded("the value", v, &range)
    }
}

/// Longest simulated dive or mission a flag may ask for, s (one day; `subnav sim`'s bound).
pub const MAX_SIM_DURATION_S: f64 = 86_400.0;

/// Most seeds one `--seeds` range may hold (each is a whole run).
pub const MAX_SEEDS: u64 = 10_000;

/// Most repeats of a timing loop (`phasecorr --time-repeat`).
pub const MAX_REPEATS: u32 = 10_000;

/// Longest wall-clock limit (`--timeout-s`), s: a week.
pub const MAX_TIMEOUT_S: u64 = 604_800;

/// Slowest pacing of a run (`run --speed`), times real time: a day's dive then takes 10 days.
pub const MIN_SPEED: f64 = 0.1;

/// A non-empty contiguous set of seeds, `first .. first + count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Seeds {
    pub first: u64,
    /// At least 1.
    pub count: u64,
}

impl Seeds {
    /// One seed.
    pub const fn one(seed: u64) -> Self {
        Self { first: seed, count: 1 }
    }

    /// The seeds as a range (`first..first + count`).
    pub fn range(&self) -> std::ops::Range<u64> {
        self.first..self.first + self.count
    }
}

impl fmt::Display for Seeds {
    /// The canonical spelling: `N` for one seed, `A..B` otherwise (parses back to the same set).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.count == 1 { write!(f, "{}", self.first) } else { write!(f, "{}..{}", self.first, self.first + self.count) }
    }
}

fn seed_number(s: &str, what: &str) -> Result<u64, String> {
    s.trim().parse::<u64>().map_err(|_| format!("{what} {s:?} is not a non-negative integer"))
}

/// Parses `N`, `A..B` (exclusive) or `A..=B` (inclusive) into a non-empty set of seeds.
pub fn parse_seeds(s: &str) -> Result<Seeds, String> {
    const FORMS: &str = "expected N, A..B (B exclusive) or A..=B (B inclusive)";
    let (first, end_exclusive) = if let Some((a, b)) = s.split_once("..=") {
        let (a, b) = (seed_number(a, "start")?, seed_number(b, "end")?);
        (a, b.checked_add(1).ok_or_else(|| format!("end {b} is too large"))?)
    } else if let Some((a, b)) = s.split_once("..") {
        (seed_number(a, "start")?, seed_number(b, "end")?)
    } else {
        let n = seed_number(s, "seed").map_err(|e| format!("{e}; {FORMS}"))?;
        (n, n.checked_add(1).ok_or_else(|| format!("seed {n} is too large"))?)
    };
    if end_exclusive <= first {
        return Err(format!("{s:?} is an empty range; {FORMS}"));
    }
    if end_exclusive - first > MAX_SEEDS {
        return Err(format!(
            "{s:?} holds {} seeds, more than the {MAX_SEEDS} one command runs (each seed is a whole run)",
            end_exclusive - first
        ));
    }
    Ok(Seeds { first, count: end_exclusive - first })
}

/// A time window `[start_s, end_s]` of the dive, written `A,B` (seconds, A <= B).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub start_s: f64,
    pub end_s: f64,
}

/// A stuck IMU axis from a time on, written `T,AXIS` (AXIS 0-2 accel x/y/z, 3-5 gyro x/y/z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StuckAxis {
    pub from_s: f64,
    pub axis: usize,
}

/// An occluded polarization unit over a window, written `A,B,UNIT` (UNIT 0-3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Occlusion {
    pub window: Window,
    pub unit: usize,
}

/// Splits `s` into exactly `n` comma-separated fields (`form` names them in the error).
fn fields<'a>(s: &'a str, n: usize, form: &str) -> Result<Vec<&'a str>, String> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    if v.len() != n {
        return Err(format!("expected {form} ({n} comma-separated values), got {} value(s)", v.len()));
    }
    Ok(v)
}

fn seconds(s: &str, what: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{what} {s:?} is not a number of seconds"))?;
    if !v.is_finite() {
        return Err(format!("{what} {s:?} is not finite"));
    }
    Ok(v)
}

fn index(s: &str, what: &str, max: usize) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(i) if i <= max => Ok(i),
        _ => Err(format!("{what} must be an integer 0..={max}, got {s:?}")),
    }
}

fn window(a: &str, b: &str) -> Result<Window, String> {
    let w = Window { start_s: seconds(a, "start")?, end_s: seconds(b, "end")? };
    if w.end_s < w.start_s {
        return Err(format!("the window ends ({}) before it starts ({})", w.end_s, w.start_s));
    }
    Ok(w)
}

/// Parses `A,B` (seconds, A <= B).
pub fn parse_window(s: &str) -> Result<Window, String> {
    let f = fields(s, 2, "A,B")?;
    window(f[0], f[1])
}

/// Parses `T,AXIS` (seconds, axis 0..=5).
pub fn parse_stuck_axis(s: &str) -> Result<StuckAxis, String> {
    let f = fields(s, 2, "T,AXIS")?;
    Ok(StuckAxis { from_s: seconds(f[0], "time")?, axis: index(f[1], "the axis", 5)? })
}

/// Parses `A,B,UNIT` (seconds, A <= B, unit 0..=3).
pub fn parse_occlusion(s: &str) -> Result<Occlusion, String> {
    let f = fields(s, 3, "A,B,UNIT")?;
    Ok(Occlusion { window: window(f[0], f[1])?, unit: index(f[2], "the unit", 3)? })
}

/// Parses a sky kind (`clear`, `partly-cloudy`, `overcast`, `twilight`).
pub fn parse_sky(s: &str) -> Result<subnav_base::sky::SkyKind, String> {
    subnav_base::sky::SkyKind::parse(s.trim()).ok_or_else(|| {
        let all: Vec<&str> = subnav_base::sky::SkyKind::ALL.iter().map(|k| k.name()).collect();
        format!("unknown sky {s:?}: one of {}", all.join(", "))
    })
}

/// Parses `T,MPS` (seconds, wind 0..=30 m/s).
pub fn parse_wind_change(s: &str) -> Result<(f64, f64), String> {
    let f = fields(s, 2, "T,MPS")?;
    let w: f64 = f[1].trim().parse().map_err(|_| format!("the wind {:?} is not a number", f[1]))?;
    Ok((seconds(f[0], "time")?, bounded("the wind (m/s)", w, &(0.0..=30.0))?))
}

/// Parses `T,KIND` (seconds, a sky kind).
pub fn parse_sky_change(s: &str) -> Result<(f64, subnav_base::sky::SkyKind), String> {
    let f = fields(s, 2, "T,KIND")?;
    Ok((seconds(f[0], "time")?, parse_sky(f[1])?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn seeds_good() {
        assert_eq!(parse_seeds("7"), Ok(Seeds::one(7)));
        assert_eq!(parse_seeds("0..20"), Ok(Seeds { first: 0, count: 20 }));
        assert_eq!(parse_seeds("1..=100"), Ok(Seeds { first: 1, count: 100 }));
        assert_eq!(parse_seeds(" 3 ..= 3 "), Ok(Seeds::one(3)));
        assert_eq!(parse_seeds("5..6").map(|s| s.range()), Ok(5..6));
        for s in ["9", "0..20", "4..=4"] {
            let p = parse_seeds(s).unwrap();
            assert_eq!(parse_seeds(&p.to_string()), Ok(p), "{s}");
        }
    }

    #[test]
    fn seeds_bad() {
        for s in ["", "x", "-1", "1.5", "5..2", "3..3", "4..=3", "..5", "1..", "1..=", "a..b", "1,2", "18446744073709551615"] {
            assert!(parse_seeds(s).is_err(), "{s:?} parsed");
        }
        assert!(parse_seeds("5..2").unwrap_err().contains("empty range"));
    }

    /// `fgo monte-carlo --seeds 0..18446744073709551615` panicked (capacity overflow) and the
    /// same range ran `run`, `filter monte-carlo`, `bathy simulate`, `ice simulate` and
    /// `calibrate compare` until killed: the count is bounded, with the bound in the error.
    #[test]
    fn seed_ranges_have_a_bound() {
        for s in ["0..18446744073709551615", "0..=18446744073709551614", "5..10006"] {
            let e = parse_seeds(s).unwrap_err();
            assert!(e.contains("10000") && e.contains("seeds"), "{s}: {e}");
        }
        assert_eq!(parse_seeds("5..10005"), Ok(Seeds { first: 5, count: MAX_SEEDS }));
        assert_eq!(parse_seeds("18446744073709551614"), Ok(Seeds::one(u64::MAX - 1)));
    }

    #[test]
    fn windows_good_and_bad() {
        assert_eq!(parse_window("100,101"), Ok(Window { start_s: 100.0, end_s: 101.0 }));
        assert_eq!(parse_window(" 1.5 , 2 "), Ok(Window { start_s: 1.5, end_s: 2.0 }));
        for s in ["", "1", "1,2,3", "a,2", "2,1", "NaN,1", "1,inf"] {
            assert!(parse_window(s).is_err(), "{s:?} parsed");
        }
        assert_eq!(parse_stuck_axis("10,5"), Ok(StuckAxis { from_s: 10.0, axis: 5 }));
        for s in ["10,6", "10,9", "10,-1", "10,1.5", "10", "x,1"] {
            assert!(parse_stuck_axis(s).is_err(), "{s:?} parsed");
        }
        assert_eq!(parse_occlusion("30,40,2"), Ok(Occlusion { window: Window { start_s: 30.0, end_s: 40.0 }, unit: 2 }));
        for s in ["30,40,4", "30,40", "40,30,1", "30,40,x"] {
            assert!(parse_occlusion(s).is_err(), "{s:?} parsed");
        }
    }

    #[test]
    fn bounded_numbers() {
        let d = f64_positive_upto(MAX_SIM_DURATION_S);
        assert_eq!(d("300"), Ok(300.0));
        assert_eq!(d("86400"), Ok(86_400.0));
        for s in ["0", "-1", "nan", "NaN", "inf", "-inf", "1e300", "86400.5", "x", ""] {
            assert!(d(s).is_err(), "{s:?} accepted");
        }
        let e = f64_in(0.0..=90.0);
        assert_eq!(e("0"), Ok(0.0));
        assert!(e("90.1").unwrap_err().contains("0..=90"));
        assert!(e("nan").is_err());
        let k = int_in(1usize..=100);
        assert_eq!(k("3"), Ok(3));
        for s in ["0", "101", "18446744073709551615", "-1", "1.5"] {
            assert!(k(s).is_err(), "{s:?} accepted");
        }
        assert_eq!(bounded("x", 5i64, &(0..=4)), Err("x must be in 0..=4, got 5".into()));
    }

    #[derive(Parser, Debug)]
    struct T {
        #[arg(long, value_parser = parse_seeds)]
        seeds: Option<Seeds>,
        #[arg(long, value_parser = parse_stuck_axis)]
        imu_stuck: Option<StuckAxis>,
    }

    /// Through clap: a usage error that names the flag and the value, not a panic.
    #[test]
    fn clap_error_names_the_flag() {
        let t = T::try_parse_from(["t", "--seeds", "0..=4"]).unwrap();
        assert_eq!(t.seeds, Some(Seeds { first: 0, count: 5 }));
        let e = T::try_parse_from(["t", "--seeds", "5..2"]).unwrap_err();
        assert_eq!(e.kind(), clap::error::ErrorKind::ValueValidation);
        let msg = e.to_string();
        assert!(msg.contains("--seeds") && msg.contains("5..2") && msg.contains("empty range"), "{msg}");
        let msg = T::try_parse_from(["t", "--imu-stuck", "10,9"]).unwrap_err().to_string();
        assert!(msg.contains("--imu-stuck") && msg.contains("0..=5"), "{msg}");
    }
}
