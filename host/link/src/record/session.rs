//! A recording decoded: uplink messages, corrupt frames, defmt log lines, downlink commands and
//! truth rows, each with the host time its bytes arrived. `export` and `report` work on this.

use serde::Serialize;
use subnav_wire::{Decoded, Downlink, FrameDecoder, MAX_DOWNLINK_FRAME, Uplink};

use super::reader::{Damage, Loaded};
use super::{Meta, Stream};
use crate::defmt_log::{DefmtTable, LogLine};
use crate::uplink::{LinkEvent, LinkStats, UplinkDecoder};

/// Something with the host time (µs since the Unix epoch) of the chunk it came in.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed<T> {
    pub t_host_us: u64,
    pub item: T,
}

/// A truth sample from a simulator (sensor-head time).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TruthRow {
    pub t_s: f64,
    pub pos_ned_m: [f64; 3],
    pub yaw_rad: f64,
}

/// Everything in a recording, decoded.
#[derive(Debug, Clone, Default)]
pub struct Session {
    pub meta: Meta,
    pub messages: Vec<Timed<Uplink>>,
    /// Corrupt uplink frames (the error text).
    pub corrupt: Vec<Timed<String>>,
    /// Incompatible boot messages (the explanation).
    pub incompatible: Vec<Timed<String>>,
    pub logs: Vec<Timed<LogLine>>,
    /// Bytes of the defmt stream (decoded into `logs` only when the firmware ELF is known).
    pub defmt_bytes: u64,
    pub defmt_malformed: u64,
    pub downlink: Vec<Timed<Downlink>>,
    pub downlink_corrupt: u64,
    pub truth: Vec<TruthRow>,
    /// Truth lines that did not parse (line text).
    pub truth_bad_lines: u64,
    pub link: LinkStats,
    /// Bytes of an unfinished uplink frame at the end.
    pub trailing_bytes: usize,
    pub damage: Vec<Damage>,
}

/// Truth rows as CSV text (`t_s,n_m,e_m,d_m,yaw_rad`, what [`parse_truth_csv`] reads; time to
/// the millisecond, positions to 0.1 mm, yaw to 1e-6 rad).
pub fn truth_csv(rows: &[TruthRow]) -> String {
    let mut out = String::from("t_s,n_m,e_m,d_m,yaw_rad\n");
    for r in rows {
        let ([n, e, d], t, yaw) = (r.pos_ned_m, r.t_s, r.yaw_rad);
        out.push_str(&format!("{t:.3},{n:.4},{e:.4},{d:.4},{yaw:.6}\n"));
    }
    out
}

/// Parse truth CSV text (`t_s,n_m,e_m,d_m,yaw_rad`, header lines and blank lines skipped).
/// Returns the rows and the number of lines that were neither a header nor a valid row.
pub fn parse_truth_csv(text: &str) -> (Vec<TruthRow>, u64) {
    const COLUMNS: [&str; 5] = ["t_s", "n_m", "e_m", "d_m", "yaw_rad"];
    let (mut rows, mut bad) = (vec![], 0u64);
    // Column positions: by name from a header line (any order, extra columns allowed), else
    // the documented order.
    let mut at = [0, 1, 2, 3, 4];
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if line.starts_with("t_s") || line.split(',').any(|f| COLUMNS.contains(&f.trim())) {
            let names: Vec<&str> = line.split(',').map(str::trim).collect();
            match COLUMNS.map(|c| names.iter().position(|n| *n == c)) {
                [Some(a), Some(b), Some(c), Some(d), Some(e)] => at = [a, b, c, d, e],
                _ => return (Vec::new(), text.lines().count() as u64), // a header without the columns: nothing is truth
            }
            continue;
        }
        let v: Vec<Option<f64>> = line.split(',').map(|f| f.trim().parse::<f64>().ok()).collect();
        match at.map(|i| v.get(i).copied().flatten()) {
            [Some(t), Some(n), Some(e), Some(d), Some(y)] if [t, n, e, d, y].iter().all(|x| x.is_finite()) => {
                rows.push(TruthRow { t_s: t, pos_ned_m: [n, e, d], yaw_rad: y })
            }
            _ => bad += 1,
        }
    }
    (rows, bad)
}

impl Session {
    /// Decode a loaded recording. `table` decodes the defmt stream (from `--elf` or the ELF
    /// named in the recording's metadata); without it, log bytes are only counted.
    pub fn decode(loaded: &Loaded, table: Option<&DefmtTable>) -> Session {
        let mut s = Session { meta: loaded.meta.clone(), damage: loaded.damage.clone(), ..Session::default() };
        let mut up = UplinkDecoder::new();
        let mut down = FrameDecoder::<MAX_DOWNLINK_FRAME>::new();
        let mut logs = table.map(|t| t.stream());
        let mut truth_text = String::new();
        for c in &loaded.chunks {
            let t = c.t_host_us;
            match c.stream {
                Stream::Uplink => up.feed(&c.data, |e| match e {
                    LinkEvent::Message(m) => s.messages.push(Timed { t_host_us: t, item: m }),
                    LinkEvent::Corrupt(err) => s.corrupt.push(Timed { t_host_us: t, item: err.to_string() }),
                    LinkEvent::Incompatible(c) => s.incompatible.push(Timed { t_host_us: t, item: crate::uplink::describe(&c) }),
                }),
                Stream::Defmt => {
                    s.defmt_bytes += c.data.len() as u64;
                    if let Some(l) = logs.as_mut() {
                        l.feed(&c.data, |line| s.logs.push(Timed { t_host_us: t, item: line }));
                    }
                }
                Stream::Downlink => {
                    for &b in &c.data {
                        match down.push::<Downlink>(b) {
                            Decoded::Message(d) => s.downlink.push(Timed { t_host_us: t, item: d }),
                            Decoded::Corrupt(_) => s.downlink_corrupt += 1,
                            Decoded::Pending => {}
                        }
                    }
                }
                Stream::Truth => truth_text.push_str(&String::from_utf8_lossy(&c.data)),
            }
        }
        s.defmt_malformed = logs.map(|l| l.malformed).unwrap_or(0);
        let (truth, bad) = parse_truth_csv(&truth_text);
        s.truth = truth;
        s.truth_bad_lines = bad;
        s.link = up.stats();
        s.trailing_bytes = up.trailing_bytes();
        s
    }

    /// Append the next recording of a series (a host restarted mid-dive): its items follow
    /// this one's; the counts add up; the metadata stays the first recording's.
    pub fn append(&mut self, next: Session) {
        self.messages.extend(next.messages);
        self.corrupt.extend(next.corrupt);
        self.incompatible.extend(next.incompatible);
        self.logs.extend(next.logs);
        self.defmt_bytes += next.defmt_bytes;
        self.defmt_malformed += next.defmt_malformed;
        self.downlink.extend(next.downlink);
        self.downlink_corrupt += next.downlink_corrupt;
        self.truth.extend(next.truth);
        self.truth_bad_lines += next.truth_bad_lines;
        let (a, b) = (self.link, next.link);
        self.link.bytes += b.bytes;
        self.link.frames_ok += b.frames_ok;
        self.link.frames_bad += b.frames_bad;
        self.link.boots += b.boots;
        self.link.incompatible_boots += b.incompatible_boots;
        self.link.last_head_us = b.last_head_us.or(a.last_head_us);
        // The time between the recordings is a gap like any other.
        let between = a.gap_to(&b).filter(|(x, y)| y - x > crate::uplink::HEAD_GAP_US);
        self.link.head_gaps += b.head_gaps + u64::from(between.is_some());
        self.link.longest_head_gap_us =
            [a.longest_head_gap_us, b.longest_head_gap_us, between].into_iter().flatten().max_by_key(|(x, y)| y - x);
        self.trailing_bytes = next.trailing_bytes;
        self.damage.extend(next.damage);
    }

    /// Messages of one kind (`Uplink::kind`), in order.
    pub fn of_kind<'a>(&'a self, kind: &'a str) -> impl Iterator<Item = &'a Timed<Uplink>> + 'a {
        self.messages.iter().filter(move |m| m.item.kind() == kind)
    }

    /// Message counts per kind, sorted by kind.
    pub fn counts(&self) -> std::collections::BTreeMap<&'static str, u64> {
        let mut m = std::collections::BTreeMap::new();
        for x in &self.messages {
            *m.entry(x.item.kind()).or_insert(0) += 1;
        }
        m
    }
}
