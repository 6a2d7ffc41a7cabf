//! Uplink stream decoding with statistics: every intact frame is decoded, every corrupt one is
//! counted (and reported), and a boot message from an incompatible firmware is flagged.

use serde::Serialize;
use subnav_wire::{Compatibility, Decoded, FrameDecoder, FrameError, MAX_UPLINK_FRAME, Uplink};

/// One decoded item of the uplink stream.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    Message(Uplink),
    Corrupt(FrameError),
    /// A boot message whose protocol version or schema differs from this host's.
    Incompatible(Compatibility),
}

/// Counts over a stream, and how it covers the head's time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    pub bytes: u64,
    pub frames_ok: u64,
    pub frames_bad: u64,
    pub boots: u64,
    pub incompatible_boots: u64,
    /// The first message was not a `Boot`: the stream joined a head already running (a host
    /// restarted mid-dive, a recorder started late).
    pub joined_running_head: bool,
    /// Head time of the first and the latest time-stamped message, µs.
    pub first_head_us: Option<u64>,
    pub last_head_us: Option<u64>,
    /// Stretches of head time longer than [`HEAD_GAP_US`] with no message (the head streams
    /// navigation at 10 Hz, so each is telemetry lost between the head and this host).
    pub head_gaps: u64,
    /// The longest such stretch: (from, to) head time, µs.
    pub longest_head_gap_us: Option<(u64, u64)>,
}

/// A stretch of head time with no message longer than this is a gap in the stream, µs.
pub const HEAD_GAP_US: u64 = 1_000_000;

impl LinkStats {
    /// What the stream missed of the head's time, in words (empty when it missed nothing).
    pub fn coverage_note(&self) -> String {
        let mut parts = Vec::new();
        if self.joined_running_head {
            let at = self.first_head_us.map_or("-".into(), |t| format!("{:.1} s", t as f64 * 1e-6));
            parts.push(format!("joined a running head at head time {at} (no Boot seen: what came before is not here)"));
        }
        if let Some((a, b)) = self.longest_head_gap_us {
            parts.push(format!(
                "{} gap(s) over {:.0} s in head time, the longest {:.1} s from {:.1} s",
                self.head_gaps,
                HEAD_GAP_US as f64 * 1e-6,
                (b - a) as f64 * 1e-6,
                a as f64 * 1e-6
            ));
        }
        parts.join("; ")
    }

    /// The head time between the end of `self` (an earlier recording) and the start of
    /// `next`, µs, when `next` continues the same boot of the head (it joined a running head
    /// and its first message is later than `self`'s last); `None` otherwise (the head rebooted
    /// in between, or `next` is not later).
    pub fn gap_to(&self, next: &LinkStats) -> Option<(u64, u64)> {
        let (a, b) = (self.last_head_us?, next.first_head_us?);
        (next.joined_running_head && b > a).then_some((a, b))
    }

    /// Called for each decoded message, after `frames_ok` counted it.
    fn see(&mut self, t_us: Option<u64>, boot: bool) {
        if self.frames_ok == 1 {
            self.joined_running_head = !boot;
        }
        let Some(t_us) = t_us else { return };
        self.first_head_us.get_or_insert(t_us);
        match self.last_head_us {
            // A boot starts the head's clock again.
            _ if boot => {}
            Some(last) if t_us > last + HEAD_GAP_US => {
                self.head_gaps += 1;
                if self.longest_head_gap_us.is_none_or(|(a, b)| t_us - last > b - a) {
                    self.longest_head_gap_us = Some((last, t_us));
                }
            }
            // Late stamps (a DVL sample's time of validity) do not move the latest time back.
            Some(last) if t_us < last => return,
            _ => {}
        }
        self.last_head_us = Some(t_us);
    }
}

#[derive(Default)]
pub struct UplinkDecoder {
    frames: FrameDecoder<MAX_UPLINK_FRAME>,
    stats: LinkStats,
}

impl UplinkDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Feed bytes; `on_event` gets every message, corrupt frame and compatibility warning.
    pub fn feed(&mut self, bytes: &[u8], mut on_event: impl FnMut(LinkEvent)) {
        self.stats.bytes += bytes.len() as u64;
        for &b in bytes {
            match self.frames.push::<Uplink>(b) {
                Decoded::Pending => {}
                Decoded::Corrupt(e) => {
                    self.stats.frames_bad += 1;
                    on_event(LinkEvent::Corrupt(e));
                }
                Decoded::Message(m) => {
                    self.stats.frames_ok += 1;
                    self.stats.see(m.t_us(), matches!(m, Uplink::Boot(_)));
                    if let Uplink::Boot(boot) = &m {
                        self.stats.boots += 1;
                        let c = boot.compatibility();
                        if c != Compatibility::Compatible {
                            self.stats.incompatible_boots += 1;
                            on_event(LinkEvent::Incompatible(c));
                        }
                    }
                    on_event(LinkEvent::Message(m));
                }
            }
        }
    }

    /// Bytes of an unfinished frame at the end of the input (reported, not silently dropped).
    pub fn trailing_bytes(&self) -> usize {
        self.frames.pending_len()
    }
}

/// Human-readable explanation of an incompatibility.
pub fn describe(c: &Compatibility) -> String {
    match c {
        Compatibility::Compatible => "compatible".into(),
        Compatibility::VersionMismatch { ours, theirs } => format!(
            "firmware speaks protocol version {theirs}, this host speaks {ours}: messages after this boot may not decode; update the host or the firmware"
        ),
        Compatibility::SchemaMismatch { ours, theirs } => format!(
            "firmware message schema {theirs:#018x} differs from this host's {ours:#018x} (same protocol version): rebuild host and firmware from the same source"
        ),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use subnav_wire::{self as wire, Board, CommandAck, boot_message};

    #[test]
    fn flags_an_incompatible_boot_and_keeps_decoding() {
        let mut bytes = vec![];
        let mut buf = [0u8; MAX_UPLINK_FRAME];
        let mut boot =
            boot_message(Board::QemuMps2An386, [0, 1, 0], 0, subnav_wire::CalibrationInUse::NO_STORE, subnav_wire::ResetCause::PowerOn);
        boot.protocol_version += 1;
        bytes.extend_from_slice(wire::encode(&Uplink::Boot(boot), &mut buf).unwrap());
        bytes.extend_from_slice(wire::encode(&Uplink::Ack(CommandAck { seq: 3, result: Ok(()) }), &mut buf).unwrap());
        let mut dec = UplinkDecoder::new();
        let mut events = vec![];
        dec.feed(&bytes, |e| events.push(e));
        assert!(matches!(events[0], LinkEvent::Incompatible(Compatibility::VersionMismatch { .. })));
        assert_eq!(events.len(), 3);
        assert_eq!(dec.stats().incompatible_boots, 1);
        assert_eq!(dec.stats().frames_ok, 2);
    }

    /// An aided navigation solution at `t_us` (the link's tests' stand-in for a head's stream).
    pub(crate) fn nav(t_us: u64) -> Uplink {
        Uplink::Nav(wire::NavSolution {
            t_us,
            mode: wire::NavMode::Aided,
            pos_ned_m: [0.0; 3],
            vel_ned_mps: [0.0; 3],
            att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
            sigma_pos_m: [1.0; 3],
            sigma_vel_mps: [0.1; 3],
            sigma_att_rad: [0.01; 3],
            cov_ne_m2: 0.0,
        })
    }

    fn stats_of(msgs: &[Uplink], skip_bytes: usize) -> LinkStats {
        let mut bytes = vec![];
        let mut buf = [0u8; MAX_UPLINK_FRAME];
        for m in msgs {
            bytes.extend_from_slice(wire::encode(m, &mut buf).unwrap());
        }
        let mut dec = UplinkDecoder::new();
        dec.feed(&bytes[skip_bytes..], |_| {});
        dec.stats()
    }

    /// A host that starts mid-dive sees no Boot and a first head time well after zero; the
    /// gap to the recording before it is the head time neither has.
    #[test]
    fn a_stream_joined_mid_dive_and_its_gaps_are_reported() {
        let boot = Uplink::Boot(boot_message(
            Board::QemuMps2An386,
            [0, 1, 0],
            0,
            subnav_wire::CalibrationInUse::NO_STORE,
            subnav_wire::ResetCause::PowerOn,
        ));
        // The first host: boot, 10 Hz navigation to 20 s, one 3-s gap inside.
        let mut first = vec![boot];
        first.extend((0..=200).filter(|k| !(50..80).contains(k)).map(|k| nav(k * 100_000)));
        let a = stats_of(&first, 0);
        assert!(!a.joined_running_head);
        assert_eq!((a.first_head_us, a.last_head_us), (Some(0), Some(20_000_000)));
        assert_eq!(a.head_gaps, 1);
        assert_eq!(a.longest_head_gap_us, Some((4_900_000, 8_000_000)));
        assert!(a.coverage_note().contains("3.1 s from 4.9 s"), "{}", a.coverage_note());

        // The restarted host joins at 50 s, in the middle of a frame (an ack comes first).
        let mut second = vec![nav(49_900_000), Uplink::Ack(CommandAck { seq: 3, result: Ok(()) })];
        second.extend((500..600).map(|k| nav(k * 100_000)));
        let b = stats_of(&second, 5);
        assert_eq!(b.frames_bad, 1, "the cut frame is corrupt");
        assert!(b.joined_running_head);
        assert_eq!(b.first_head_us, Some(50_000_000));
        assert_eq!(b.head_gaps, 0);
        assert!(b.coverage_note().starts_with("joined a running head at head time 50.0 s"), "{}", b.coverage_note());
        assert_eq!(a.gap_to(&b), Some((20_000_000, 50_000_000)));
        // A recording that starts with a Boot does not continue the one before.
        assert_eq!(b.gap_to(&a), None);
        assert_eq!(a.gap_to(&stats_of(&first, 0)), None);

        // A reboot's clock going back is not a gap, and a late stamp does not move time back.
        let rebooted = [nav(30_000_000), boot, nav(100_000), nav(50_000), nav(200_000)];
        let c = stats_of(&rebooted, 0);
        assert!(c.joined_running_head);
        assert_eq!((c.head_gaps, c.last_head_us), (0, Some(200_000)));
    }
}
