//! Incoming MAVLink frames from any byte stream (serial, TCP, UDP datagrams), each byte
//! accounted for: frames decoded, bytes skipped while looking for a frame, frames with a bad
//! checksum, frames of messages this dialect does not know (skipped whole), frames with flags we
//! cannot read. The `mavlink` crate's readers skip bad data silently; a bridge has to say what
//! it threw away, so this small scanner frames and checks, and the crate decodes the payload.

use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavHeader, MavlinkVersion, Message};

/// What the scanner saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ScanStats {
    pub frames: u64,
    pub v1_frames: u64,
    pub skipped_bytes: u64,
    pub bad_crc: u64,
    pub unknown_message: u64,
    /// Frames whose payload the dialect refused (e.g. an enum value out of range), or with
    /// incompatibility flags other than signing.
    pub malformed: u64,
}

/// Longest frame: MAVLink 2 header 10 + payload 255 + CRC 2 + signature 13.
const MAX_FRAME: usize = 280;

#[derive(Default)]
pub struct Scanner {
    buf: Vec<u8>,
    pub stats: ScanStats,
}

#[allow(clippy::large_enum_variant)] // a return value, moved once
enum Step {
    Frame(MavHeader, MavMessage),
    /// Drop this many bytes and go on.
    Skip(usize),
    NeedMore,
}

impl Scanner {
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Forget a partial frame (e.g. at the end of a UDP datagram: frames never span two).
    pub fn end_of_datagram(&mut self) {
        self.stats.skipped_bytes += self.buf.len() as u64;
        self.buf.clear();
    }

    /// The next decoded frame, if the buffer holds one.
    pub fn next_frame(&mut self) -> Option<(MavHeader, MavMessage)> {
        loop {
            // Find a start byte.
            let start = self.buf.iter().position(|&b| b == mavlink::MAV_STX_V2 || b == mavlink::MAV_STX);
            match start {
                None => {
                    self.stats.skipped_bytes += self.buf.len() as u64;
                    self.buf.clear();
                    return None;
                }
                Some(s) if s > 0 => {
                    self.stats.skipped_bytes += s as u64;
                    self.buf.drain(..s);
                }
                Some(_) => {}
            }
            match self.step() {
                Step::Frame(h, m) => return Some((h, m)),
                Step::Skip(n) => {
                    let n = n.min(self.buf.len());
                    self.buf.drain(..n);
                }
                Step::NeedMore => {
                    if self.buf.len() > 4 * MAX_FRAME {
                        // Cannot happen with the lengths checked below; a bound all the same.
                        self.stats.skipped_bytes += self.buf.len() as u64;
                        self.buf.clear();
                    }
                    return None;
                }
            }
        }
    }

    fn step(&mut self) -> Step {
        let b = &self.buf;
        let v2 = b[0] == mavlink::MAV_STX_V2;
        let header_len = if v2 { 10 } else { 6 };
        if b.len() < header_len {
            return Step::NeedMore;
        }
        let len = usize::from(b[1]);
        let (msgid, sys, comp, seq, signed) = if v2 {
            let incompat = b[2];
            if incompat & !0x01 != 0 {
                self.stats.malformed += 1;
                self.stats.skipped_bytes += 1;
                return Step::Skip(1);
            }
            (u32::from_le_bytes([b[7], b[8], b[9], 0]), b[5], b[6], b[4], incompat & 0x01 != 0)
        } else {
            (u32::from(b[5]), b[3], b[4], b[2], false)
        };
        let total = header_len + len + 2 + if signed { 13 } else { 0 };
        if b.len() < total {
            return Step::NeedMore;
        }
        if MavMessage::default_message_from_id(msgid).is_none() {
            // Unknown to the dialect: its checksum cannot be checked; skip the whole frame.
            self.stats.unknown_message += 1;
            return Step::Skip(total);
        }
        let crc = mavlink::calculate_crc(&b[1..header_len + len], MavMessage::extra_crc(msgid));
        let sent = u16::from_le_bytes([b[header_len + len], b[header_len + len + 1]]);
        if crc != sent {
            self.stats.bad_crc += 1;
            self.stats.skipped_bytes += 1;
            return Step::Skip(1);
        }
        let version = if v2 { MavlinkVersion::V2 } else { MavlinkVersion::V1 };
        let parsed = MavMessage::parse(version, msgid, &b[header_len..header_len + len]);
        let header = MavHeader { system_id: u32::from(sys), component_id: comp, sequence: seq };
        match parsed {
            Ok(m) => {
                self.stats.frames += 1;
                if !v2 {
                    self.stats.v1_frames += 1;
                }
                self.buf.drain(..total);
                Step::Frame(header, m)
            }
            Err(_) => {
                self.stats.malformed += 1;
                Step::Skip(total)
            }
        }
    }
}

/// Encode one message as a MAVLink 2 frame.
pub fn encode_v2(header: MavHeader, m: &MavMessage) -> Vec<u8> {
    let mut out = Vec::with_capacity(64);
    // Writing into a Vec cannot fail.
    let _ = mavlink::write_v2_msg(&mut out, header, m);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega as mav;

    fn timesync(tc1: i64) -> MavMessage {
        MavMessage::TIMESYNC(mav::TIMESYNC_DATA { tc1, ts1: 42, target_system: 1, target_component: 197 })
    }

    #[test]
    fn frames_among_garbage_bad_crc_and_unknown_ids_are_all_counted() {
        let h = MavHeader { system_id: 1, component_id: 1, sequence: 7 };
        let good = encode_v2(h, &timesync(99));
        assert_eq!(good[0], 0xFD);
        // Standard MAVLink 2 header (10 bytes): the system id is one byte.
        assert_eq!(good[5], 1);
        let mut bad = good.clone();
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        // A frame of message id 0xABCDEF (not in the dialect), 3-byte payload.
        let unknown = [0xFD, 3, 0, 0, 0, 1, 1, 0xEF, 0xCD, 0xAB, 1, 2, 3, 0, 0];
        let mut s = Scanner::default();
        s.push(b"noise");
        s.push(&bad);
        s.push(&unknown);
        s.push(&good[..5]);
        assert!(s.next_frame().is_none());
        s.push(&good[5..]);
        let (hh, m) = s.next_frame().expect("the good frame");
        assert_eq!(hh.system_id, 1);
        assert_eq!(hh.sequence, 7);
        match m {
            MavMessage::TIMESYNC(t) => assert_eq!((t.tc1, t.ts1), (99, 42)),
            other => panic!("{other:?}"),
        }
        assert!(s.next_frame().is_none());
        assert_eq!(s.stats.frames, 1);
        assert_eq!(s.stats.bad_crc, 1);
        assert_eq!(s.stats.unknown_message, 1);
        assert!(s.stats.skipped_bytes >= 5, "{:?}", s.stats);
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut s = Scanner::default();
        let mut x = 0x1234_5678u32;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let b = (x >> 7) as u8;
            // Plenty of start bytes.
            s.push(&[if x.is_multiple_of(7) { 0xFD } else { b }]);
            while s.next_frame().is_some() {}
        }
        assert!(s.stats.skipped_bytes > 0);
    }
}
