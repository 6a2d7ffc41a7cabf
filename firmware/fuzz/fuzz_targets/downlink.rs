//! The sensor head's downlink path on hostile input: bytes -> frame decoder -> commands -> the
//! application's state (configuration, time, the store and its queue, fixes, reboot requests),
//! interleaved with the board loop's `poll` and `service_store`.
//!
//! The input is a script of steps; each step's first byte chooses:
//! - raw bytes straight into `App::on_downlink_bytes` (corrupt frames, partial frames, garbage);
//! - a postcard payload that, if it is a `Downlink`, is sent as a valid frame (so the fuzzer
//!   reaches the command handling behind the CRC), possibly twice (a retransmission);
//! - an earlier valid frame again (a replay);
//! - the board loop: time advances, `poll`, `service_store` on an in-memory store.
//!
//! What must hold, besides no panic: every command the head decoded (a shadow decoder sees
//! the same bytes) is acknowledged, with its own sequence number; an exact duplicate sent right
//! after its original changes no state and gets no ack that differs from the first one's; every
//! uplink frame the head sends decodes, and nothing in it is NaN where the protocol promises
//! numbers (Nav: an unknown sigma is infinite by design; Health: a NIS of an update kind that
//! has not run yet is NaN by design).
#![no_main]

use std::collections::{BTreeMap, BTreeSet};

use libfuzzer_sys::fuzz_target;
use subnav_firmware::store::{RecordStore, StoreError};
use subnav_firmware::{App, TelemetrySink};
use subnav_wire::*;

/// The uplink bytes the head wrote.
#[derive(Default)]
struct Out(Vec<u8>);

impl TelemetrySink for Out {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        self.0.extend_from_slice(frame);
        true
    }
}

#[derive(Default)]
struct MemStore(BTreeMap<u8, Record>);

impl RecordStore for MemStore {
    fn load(&mut self, key: RecordKey) -> Result<Option<Record>, StoreError> {
        Ok(self.0.get(&key.id()).copied())
    }
    fn save(&mut self, r: &Record) -> Result<(), StoreError> {
        self.0.insert(r.key().id(), *r);
        Ok(())
    }
    fn erase(&mut self, key: RecordKey) -> Result<(), StoreError> {
        self.0.remove(&key.id());
        Ok(())
    }
    fn format(&mut self) -> Result<(), StoreError> {
        self.0.clear();
        Ok(())
    }
}

/// The head's uplink decoded as it is written: each byte once, whatever the input's length.
struct UplinkSeen {
    dec: FrameDecoder<MAX_UPLINK_FRAME>,
    read: usize,
    msgs: Vec<Uplink>,
}

impl UplinkSeen {
    fn new() -> Self {
        Self { dec: FrameDecoder::new(), read: 0, msgs: Vec::new() }
    }
    /// Decodes what the head wrote since the last call.
    fn catch_up(&mut self, out: &Out) {
        for &b in out.0.get(self.read..).unwrap_or(&[]) {
            match self.dec.push::<Uplink>(b) {
                Decoded::Message(m) => self.msgs.push(m),
                Decoded::Corrupt(e) => panic!("the head sent a corrupt frame: {e}"),
                Decoded::Pending => {}
            }
        }
        self.read = out.0.len();
    }
}

fn acks(msgs: &[Uplink]) -> Vec<CommandAck> {
    msgs.iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(*a) } else { None }).collect()
}

fn state(app: &App) -> String {
    format!("{:?} {:?}", app.config, app.utc_offset_us)
}

fuzz_target!(|data: &[u8]| {
    let mut app = App::new(Board::QemuMps2An386);
    let mut store = MemStore::default();
    let mut out = Out::default();
    app.boot_with_store(0, &mut store, &mut out);
    let mut shadow = FrameDecoder::<MAX_DOWNLINK_FRAME>::new();
    let mut decoded: Vec<Downlink> = Vec::new();
    let mut sent_frames: Vec<Vec<u8>> = Vec::new();
    let mut t_us = 1u64;
    let mut seen = UplinkSeen::new();

    // Feed bytes to the head and to the shadow decoder.
    let mut feed = |app: &mut App, out: &mut Out, t_us: u64, bytes: &[u8], decoded: &mut Vec<Downlink>| {
        for &b in bytes {
            if let Decoded::Message(m) = shadow.push::<Downlink>(b) {
                decoded.push(m);
            }
        }
        app.on_downlink_bytes(t_us, bytes, out);
    };

    let mut rest = data;
    while let Some((&op, tail)) = rest.split_first() {
        let len = usize::from(tail.first().copied().unwrap_or(0) % 64);
        let body = tail.get(1..).unwrap_or(&[]);
        let (chunk, next) = body.split_at(len.min(body.len()));
        rest = next;
        match op % 4 {
            0 => feed(&mut app, &mut out, t_us, chunk, &mut decoded),
            1 | 2 => {
                let Ok(cmd) = postcard::from_bytes::<Downlink>(chunk) else { continue };
                let mut buf = [0u8; MAX_DOWNLINK_FRAME];
                let Ok(frame) = encode(&cmd, &mut buf) else { continue };
                let frame = frame.to_vec();
                // A delimiter first: whatever raw bytes came before end there.
                feed(&mut app, &mut out, t_us, &[0], &mut decoded);
                feed(&mut app, &mut out, t_us, &frame, &mut decoded);
                if op % 4 == 2 && cmd.seq != 0 {
                    // The same frame again at once: no state change, no different ack.
                    let before = state(&app);
                    seen.catch_up(&out);
                    let first: Vec<CommandAck> = acks(&seen.msgs).into_iter().filter(|a| a.seq == cmd.seq).collect();
                    let n = seen.msgs.len();
                    feed(&mut app, &mut out, t_us, &frame, &mut decoded);
                    assert_eq!(state(&app), before, "a duplicate changed the state: {cmd:?}");
                    seen.catch_up(&out);
                    for a in acks(seen.msgs.get(n..).unwrap_or(&[])) {
                        assert!(first.contains(&a), "a duplicate got another ack {a:?} than {first:?}");
                    }
                }
                sent_frames.push(frame);
            }
            _ => {
                if let Some(f) = chunk.first().and_then(|&k| sent_frames.get(usize::from(k) % sent_frames.len().max(1))).cloned() {
                    feed(&mut app, &mut out, t_us, &[0], &mut decoded);
                    feed(&mut app, &mut out, t_us, &f, &mut decoded);
                }
                t_us += 1 + u64::from(chunk.get(1).copied().unwrap_or(0)) * 10_000;
                app.service_store(t_us, &mut store, &mut out);
                let _ = app.poll(t_us, &mut out);
            }
        }
    }
    app.service_store(t_us + 1, &mut store, &mut out);
    let _ = app.poll(t_us + 1, &mut out);

    seen.catch_up(&out);
    let msgs = seen.msgs;
    let acked: BTreeSet<u16> = acks(&msgs).iter().map(|a| a.seq).collect();
    for c in &decoded {
        assert!(acked.contains(&c.seq), "command {c:?} decoded but never acknowledged");
    }
    let sent: BTreeSet<u16> = decoded.iter().map(|c| c.seq).collect();
    assert!(acked.is_subset(&sent), "an ack for a command never sent: {acked:?} vs {sent:?}");
    for m in &msgs {
        match m {
            Uplink::Nav(n) => {
                let v = n.pos_ned_m.iter().chain(&n.vel_ned_mps).chain(&n.att_nb_wxyz).chain(&n.sigma_pos_m);
                assert!(v.clone().all(|v| !v.is_nan()), "{n:?}")
            }
            // NIS is NaN for an update kind that has not run yet (by design); the rest is numbers.
            Uplink::Health(h) => assert!(h.q_diag.iter().chain([&h.lambda, &h.imu_q_scale]).all(|v| v.is_finite()), "{h:?}"),
            _ => {}
        }
    }
});
