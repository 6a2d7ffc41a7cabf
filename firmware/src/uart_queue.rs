//! Interrupt-fed UART receive queues (the STM32 board's downlink and DVL), and the transmit
//! queue its telemetry goes through ([`TxProducer`], [`TxConsumer`]).
//!
//! Why: a UART's receive register holds one byte. Polled from the board loop on the 1-kHz tick,
//! a 460,800-baud downlink delivers 46 bytes per millisecond and all but the last are
//! overwritten (a back-to-back position fix arrived damaged and was refused). Here the receive
//! interrupt moves each byte into a single-producer single-consumer queue
//! ([`heapless::spsc`], lock-free: the interrupt only enqueues, the loop only dequeues) and the
//! loop drains it. What is still lost is counted, never silent: bytes dropped because the
//! queue was full (the loop stalled longer than the queue covers), the UART's own overruns
//! (the interrupt came too late) and framing, noise or parity errors. The board turns new
//! losses into `Fault { source, kind: Overrun }` (queue full, overrun) and `Malformed`
//! (framing) telemetry via [`RxStats::take_new`].
//!
//! The consumer implements `embedded_io::Read` + `ReadReady`, so the DVL driver reads from the
//! queue exactly as from a UART.
//!
//! Transmit: the board loop writes whole telemetry frames into a queue (a frame that does not
//! fit is refused whole, so the link never carries half a frame; the application counts it and
//! reports `Fault(Link, TelemetryDropped)`), and the UART's transmit-empty interrupt sends it a
//! byte at a time. Writing a frame never waits for the wire, so a burst of telemetry no longer
//! stalls the sensor schedule.

use core::sync::atomic::{AtomicU32, Ordering};

use heapless::spsc::{Consumer, Producer};

/// Counters shared by the interrupt (writes) and the board loop (reads); all wrap.
#[derive(Debug, Default)]
pub struct RxStats {
    bytes: AtomicU32,
    dropped_full: AtomicU32,
    overruns: AtomicU32,
    framing: AtomicU32,
    /// The counts already reported (board loop only).
    reported_losses: AtomicU32,
    reported_framing: AtomicU32,
}

/// A snapshot of [`RxStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RxCounts {
    /// Bytes queued.
    pub bytes: u32,
    /// Bytes dropped: the queue was full.
    pub dropped_full: u32,
    /// Receive overruns reported by the UART (at least one byte lost each).
    pub overruns: u32,
    /// Framing, noise or parity errors reported by the UART.
    pub framing: u32,
}

/// New losses since the last [`RxStats::take_new`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RxLosses {
    /// Queue full plus UART overruns.
    pub overrun: u32,
    /// Framing, noise or parity errors.
    pub framing: u32,
}

impl RxStats {
    pub const fn new() -> Self {
        Self {
            bytes: AtomicU32::new(0),
            dropped_full: AtomicU32::new(0),
            overruns: AtomicU32::new(0),
            framing: AtomicU32::new(0),
            reported_losses: AtomicU32::new(0),
            reported_framing: AtomicU32::new(0),
        }
    }

    pub fn counts(&self) -> RxCounts {
        RxCounts {
            bytes: self.bytes.load(Ordering::Relaxed),
            dropped_full: self.dropped_full.load(Ordering::Relaxed),
            overruns: self.overruns.load(Ordering::Relaxed),
            framing: self.framing.load(Ordering::Relaxed),
        }
    }

    /// The losses not reported yet (board loop only: one caller).
    pub fn take_new(&self) -> RxLosses {
        let c = self.counts();
        let losses = c.dropped_full.wrapping_add(c.overruns);
        let overrun = losses.wrapping_sub(self.reported_losses.swap(losses, Ordering::Relaxed));
        let framing = c.framing.wrapping_sub(self.reported_framing.swap(c.framing, Ordering::Relaxed));
        RxLosses { overrun, framing }
    }
}

/// What the UART's status register said besides a received byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RxError {
    /// Receive overrun: a byte arrived before the previous one was read.
    Overrun,
    /// Framing, noise or parity error: the byte is unusable.
    Framing,
}

/// The interrupt's end of a receive queue.
pub struct RxProducer<'a> {
    queue: Producer<'a, u8>,
    stats: &'a RxStats,
}

impl<'a> RxProducer<'a> {
    pub fn new(queue: Producer<'a, u8>, stats: &'a RxStats) -> Self {
        Self { queue, stats }
    }

    /// A byte from the data register.
    pub fn on_byte(&mut self, byte: u8) {
        if self.queue.enqueue(byte).is_ok() {
            self.stats.bytes.fetch_add(1, Ordering::Relaxed);
        } else {
            self.stats.dropped_full.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// An error flag from the status register.
    pub fn on_error(&mut self, e: RxError) {
        let c = match e {
            RxError::Overrun => &self.stats.overruns,
            RxError::Framing => &self.stats.framing,
        };
        c.fetch_add(1, Ordering::Relaxed);
    }
}

/// The board loop's end of a receive queue.
pub struct RxConsumer<'a> {
    queue: Consumer<'a, u8>,
}

impl<'a> RxConsumer<'a> {
    pub fn new(queue: Consumer<'a, u8>) -> Self {
        Self { queue }
    }

    /// Move up to `buf.len()` queued bytes into `buf`; the count moved.
    pub fn drain(&mut self, buf: &mut [u8]) -> usize {
        let mut n = 0;
        for slot in buf.iter_mut() {
            match self.queue.dequeue() {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        n
    }
}

impl embedded_io::ErrorType for RxConsumer<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io::Read for RxConsumer<'_> {
    /// Never blocks for long on this board: callers ask [`embedded_io::ReadReady`] first (the
    /// DVL driver does); with nothing queued it returns 0 bytes rather than wait for one.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(self.drain(buf))
    }
}

impl embedded_io::ReadReady for RxConsumer<'_> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.queue.ready())
    }
}

/// Counters of a transmit queue (frames refused because the queue was full; all wrap).
#[derive(Debug, Default)]
pub struct TxStats {
    frames: AtomicU32,
    refused: AtomicU32,
}

impl TxStats {
    pub const fn new() -> Self {
        Self { frames: AtomicU32::new(0), refused: AtomicU32::new(0) }
    }

    /// Frames queued and frames refused (queue full) since boot.
    pub fn counts(&self) -> (u32, u32) {
        (self.frames.load(Ordering::Relaxed), self.refused.load(Ordering::Relaxed))
    }
}

/// The board loop's end of a transmit queue: a telemetry sink that takes whole frames.
pub struct TxProducer<'a> {
    queue: Producer<'a, u8>,
    stats: &'a TxStats,
}

impl<'a> TxProducer<'a> {
    pub fn new(queue: Producer<'a, u8>, stats: &'a TxStats) -> Self {
        Self { queue, stats }
    }

    /// Whether anything is waiting to be sent (the board then enables its transmit interrupt).
    pub fn pending(&self) -> bool {
        self.queue.len() > 0
    }
}

impl crate::TelemetrySink for TxProducer<'_> {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        // Only the interrupt dequeues, so the free space can only grow after this check.
        if self.queue.capacity() - self.queue.len() < frame.len() {
            self.stats.refused.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        for &b in frame {
            if self.queue.enqueue(b).is_err() {
                // Unreachable after the check above; counted rather than trusted.
                self.stats.refused.fetch_add(1, Ordering::Relaxed);
                return false;
            }
        }
        self.stats.frames.fetch_add(1, Ordering::Relaxed);
        true
    }
}

/// The transmit interrupt's end of the queue.
pub struct TxConsumer<'a> {
    queue: Consumer<'a, u8>,
}

impl<'a> TxConsumer<'a> {
    pub fn new(queue: Consumer<'a, u8>) -> Self {
        Self { queue }
    }

    /// The next byte for the data register (`None`: the queue is empty, disable the interrupt).
    pub fn next_byte(&mut self) -> Option<u8> {
        self.queue.dequeue()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use heapless::spsc::Queue;
    use subnav_wire::{Command, Downlink, MAX_DOWNLINK_FRAME, decode_in_place, encode};

    /// 200 downlink frames back to back at 460,800 baud (46 bytes per millisecond of wire) into
    /// the queue one byte per interrupt, the loop draining it once per 1-ms tick as the board
    /// does: every frame arrives whole and decodes, nothing is counted lost. Then a loop
    /// stalled for 100 ms: the bytes that did not fit are counted, not silent.
    #[test]
    fn two_hundred_frames_back_to_back_at_full_baud_arrive_whole() {
        let mut queue: Queue<u8, 1024> = Queue::new();
        let stats = RxStats::new();
        let (p, c) = queue.split();
        let (mut isr, mut rx) = (RxProducer::new(p, &stats), RxConsumer::new(c));
        let mut wire = std::vec::Vec::new();
        for seq in 0..200u16 {
            let cmd = Downlink {
                seq,
                command: Command::PositionFix {
                    t_us: 1_000_000 + u64::from(seq),
                    pos_ned_m: [1.0, 2.0, 3.0],
                    cov_ned_m2: [0.25, 0.0, 0.0, 0.25, 0.0, 0.25],
                },
            };
            let mut buf = [0u8; MAX_DOWNLINK_FRAME];
            let frame = encode(&cmd, &mut buf).expect("encodes");
            wire.extend_from_slice(frame);
        }
        let bytes_per_ms = 460_800 / 10 / 1000; // 8N1: 10 bits a byte
        let mut received = std::vec::Vec::new();
        for chunk in wire.chunks(bytes_per_ms) {
            for &b in chunk {
                isr.on_byte(b);
            }
            let mut buf = [0u8; 64];
            loop {
                let n = rx.drain(&mut buf);
                if n == 0 {
                    break;
                }
                received.extend_from_slice(&buf[..n]);
            }
        }
        assert_eq!(received, wire, "every byte, in order");
        let frames: std::vec::Vec<_> = received.split(|b| *b == 0).filter(|f| !f.is_empty()).collect();
        assert_eq!(frames.len(), 200);
        for (k, f) in frames.iter().enumerate() {
            let mut f = f.to_vec();
            let d: Downlink = decode_in_place(&mut f).expect("each frame decodes");
            assert_eq!(usize::from(d.seq), k);
        }
        assert_eq!(stats.take_new(), RxLosses::default());
        assert_eq!(stats.counts().bytes as usize, wire.len());

        // The loop stalls 100 ms: 4,600 bytes arrive, 1,023 fit.
        for &b in wire.iter().cycle().take(100 * bytes_per_ms) {
            isr.on_byte(b);
        }
        isr.on_error(RxError::Overrun);
        isr.on_error(RxError::Framing);
        let lost = stats.take_new();
        assert_eq!(lost.overrun as usize, 100 * bytes_per_ms - 1023 + 1, "queue full plus the UART's overrun");
        assert_eq!(lost.framing, 1);
        assert_eq!(stats.take_new(), RxLosses::default(), "reported once");
        let mut buf = [0u8; 2048];
        assert_eq!(rx.drain(&mut buf), 1023);
    }

    #[test]
    fn the_consumer_reads_like_a_uart() {
        use embedded_io::{Read, ReadReady};
        let mut queue: Queue<u8, 8> = Queue::new();
        let stats = RxStats::new();
        let (p, c) = queue.split();
        let (mut isr, mut rx) = (RxProducer::new(p, &stats), RxConsumer::new(c));
        assert_eq!(rx.read_ready(), Ok(false));
        for b in *b"$DVL" {
            isr.on_byte(b);
        }
        assert_eq!(rx.read_ready(), Ok(true));
        let mut buf = [0u8; 3];
        assert_eq!(rx.read(&mut buf), Ok(3));
        assert_eq!(&buf, b"$DV");
        assert_eq!(rx.read(&mut buf), Ok(1));
        assert_eq!(rx.read(&mut buf), Ok(0));
    }

    /// A telemetry burst larger than the transmit queue, the UART sending 46 bytes per ms: the
    /// loop never waits; whole frames are queued or refused (counted by the queue and by the
    /// application, which reports the drop), and every frame on the wire decodes.
    #[test]
    fn a_burst_fills_the_transmit_queue_and_what_does_not_fit_is_refused_whole_and_reported() {
        use crate::App;
        use subnav_wire::{Board, Decoded, FaultKind, FrameDecoder, MAX_UPLINK_FRAME, Uplink};
        let mut queue: Queue<u8, 512> = Queue::new();
        let stats = TxStats::new();
        let (p, c) = queue.split();
        let (mut tx, mut isr) = (TxProducer::new(p, &stats), TxConsumer::new(c));
        let mut app = App::new(Board::Stm32F405);
        app.boot(0, &mut tx);
        let mut wire = std::vec::Vec::new();
        // 3 s of telemetry at 10 Hz navigation, the UART draining 46 bytes per ms; then a
        // burst of 100 commands' acks (1 KB) in one tick with the UART stopped.
        for ms in 0..3_000u64 {
            app.poll(ms * 1000, &mut tx);
            for _ in 0..46 {
                match isr.next_byte() {
                    Some(b) => wire.push(b),
                    None => break,
                }
            }
        }
        let (frames_ok, refused_before) = stats.counts();
        assert_eq!(refused_before, 0, "at full rate nothing is refused");
        let mut bytes = std::vec::Vec::new();
        for seq in 1..=100u16 {
            let mut buf = [0u8; subnav_wire::MAX_DOWNLINK_FRAME];
            let cmd = Downlink { seq, command: Command::SetConfig(subnav_wire::ConfigItem::StreamRaw(true)) };
            bytes.extend_from_slice(encode(&cmd, &mut buf).expect("encodes"));
        }
        app.on_downlink_bytes(3_000_000, &bytes, &mut tx);
        let (frames_after, refused) = stats.counts();
        assert!(refused > 0 && frames_after > frames_ok, "some acks fit, the rest are refused: {frames_after} {refused}");
        // The UART catches up; the next poll reports the drop (its fault frame fits again).
        for ms in 3_001..3_200u64 {
            while let Some(b) = isr.next_byte() {
                wire.push(b);
            }
            app.poll(ms * 1000, &mut tx);
        }
        while let Some(b) = isr.next_byte() {
            wire.push(b);
        }
        let mut dec = FrameDecoder::<MAX_UPLINK_FRAME>::new();
        let msgs: std::vec::Vec<Uplink> = wire
            .iter()
            .filter_map(|b| match dec.push::<Uplink>(*b) {
                Decoded::Message(m) => Some(m),
                Decoded::Corrupt(e) => panic!("a frame on the wire is damaged: {e}"),
                Decoded::Pending => None,
            })
            .collect();
        let acks = msgs.iter().filter(|m| matches!(m, Uplink::Ack(_))).count() as u32;
        assert_eq!(acks + refused, 100, "every ack is on the wire or counted as refused");
        let dropped = msgs.iter().find_map(|m| match m {
            Uplink::Fault(f) if f.kind == FaultKind::TelemetryDropped => Some(f.count),
            _ => None,
        });
        assert_eq!(dropped, Some(refused), "the drop is reported with its count");
    }
}
