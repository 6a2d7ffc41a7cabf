//! embedded-hal 1.0 `I2c` and `SpiDevice` implementations that carry each transaction over a
//! byte link to the host's chip models (see `subnav_wire::bridge`). Used by the QEMU board;
//! the drivers cannot tell the difference from a real bus.
//!
//! Every request carries the firmware's *logical* time (set with [`BridgeClient::set_time`] at
//! the start of each scheduler tick), so the host answers for that instant and a run is
//! repeatable whatever the host's speed.

use core::cell::RefCell;

use embedded_hal::{i2c, spi};
use subnav_wire::bridge::{
    Bus, BusFault, BusRequest, BusResponse, Bytes, MAX_OP_BYTES, MAX_OPS, MAX_REQUEST_FRAME, MAX_RESPONSE_FRAME, Op, ReadData,
};
use subnav_wire::{self as wire, Decoded, FrameDecoder};

/// The byte link to the host (a UART on the QEMU board, a buffer in tests).
pub trait ByteLink {
    fn write_all(&mut self, bytes: &[u8]);
    /// A received byte, if one is waiting (non-blocking).
    fn read_byte(&mut self) -> Option<u8>;
}

/// A bridge error, as embedded-hal sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BridgeError(pub BusFault);

impl core::fmt::Display for BridgeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "bridged bus transaction failed: {}", self.0)
    }
}

impl core::error::Error for BridgeError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        Some(&self.0)
    }
}

impl i2c::Error for BridgeError {
    fn kind(&self) -> i2c::ErrorKind {
        match self.0 {
            BusFault::Nack => i2c::ErrorKind::NoAcknowledge(i2c::NoAcknowledgeSource::Unknown),
            BusFault::Timeout | BusFault::Other => i2c::ErrorKind::Other,
        }
    }
}

impl spi::Error for BridgeError {
    fn kind(&self) -> spi::ErrorKind {
        spi::ErrorKind::Other
    }
}

/// Sends requests and waits for the matching response.
pub struct BridgeClient<L> {
    link: L,
    seq: u32,
    t_us: u64,
    rx: FrameDecoder<MAX_RESPONSE_FRAME>,
    tx: [u8; MAX_REQUEST_FRAME],
    /// Link polls before a transaction times out.
    pub max_polls: u32,
    /// Transactions that ended in a fault, by kind: NACK, timeout, other.
    pub faults: [u32; 3],
}

impl<L: ByteLink> BridgeClient<L> {
    pub fn new(link: L) -> Self {
        Self { link, seq: 0, t_us: 0, rx: FrameDecoder::new(), tx: [0; MAX_REQUEST_FRAME], max_polls: 20_000_000, faults: [0; 3] }
    }

    /// The instant the following transactions are stamped with.
    pub fn set_time(&mut self, t_us: u64) {
        self.t_us = t_us;
    }

    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }

    fn count(&mut self, f: BusFault) -> BusFault {
        let i = match f {
            BusFault::Nack => 0,
            BusFault::Timeout => 1,
            BusFault::Other => 2,
        };
        if let Some(c) = self.faults.get_mut(i) {
            *c = c.wrapping_add(1);
        }
        f
    }

    /// Run one transaction; returns the read bytes of all read/transfer ops, concatenated.
    pub fn transact(&mut self, bus: Bus, ops: &[Op]) -> Result<ReadData, BusFault> {
        if ops.len() > MAX_OPS {
            return Err(self.count(BusFault::Other));
        }
        let mut arr = [Op::Read { len: 0 }; MAX_OPS];
        for (slot, op) in arr.iter_mut().zip(ops) {
            *slot = *op;
        }
        self.seq = self.seq.wrapping_add(1);
        let req = BusRequest { seq: self.seq, t_us: self.t_us, bus, n_ops: ops.len() as u8, ops: arr };
        match wire::encode(&req, &mut self.tx) {
            Ok(frame) => self.link.write_all(frame),
            Err(_) => return Err(self.count(BusFault::Other)),
        }
        let mut polls = 0u32;
        loop {
            let Some(b) = self.link.read_byte() else {
                polls += 1;
                if polls >= self.max_polls {
                    return Err(self.count(BusFault::Timeout));
                }
                continue;
            };
            match self.rx.push::<BusResponse>(b) {
                Decoded::Pending | Decoded::Corrupt(_) => {}
                Decoded::Message(resp) if resp.seq == self.seq => {
                    return resp.result.map_err(|f| self.count(f));
                }
                // A stale response (to a transaction that timed out): skip it.
                Decoded::Message(_) => {}
            }
        }
    }
}

/// `DelayNs` for code running over the bridge: a delay advances the logical time stamped on the
/// following transactions (the chip models see the time pass), without burning instructions.
pub struct BridgeDelay<'a, L> {
    client: &'a RefCell<BridgeClient<L>>,
}

impl<'a, L> BridgeDelay<'a, L> {
    pub fn new(client: &'a RefCell<BridgeClient<L>>) -> Self {
        Self { client }
    }
}

impl<L: ByteLink> embedded_hal::delay::DelayNs for BridgeDelay<'_, L> {
    fn delay_ns(&mut self, ns: u32) {
        if let Ok(mut c) = self.client.try_borrow_mut() {
            c.t_us = c.t_us.saturating_add(u64::from(ns).div_ceil(1000));
        }
    }
}

/// An I2C bus on the bridge. Several devices share it through `&RefCell<BridgeClient>`.
pub struct BridgeI2c<'a, L> {
    client: &'a RefCell<BridgeClient<L>>,
    bus: u8,
}

impl<'a, L> BridgeI2c<'a, L> {
    pub fn new(client: &'a RefCell<BridgeClient<L>>, bus: u8) -> Self {
        Self { client, bus }
    }
}

impl<L: ByteLink> i2c::ErrorType for BridgeI2c<'_, L> {
    type Error = BridgeError;
}

impl<L: ByteLink> i2c::I2c for BridgeI2c<'_, L> {
    fn transaction(&mut self, address: u8, operations: &mut [i2c::Operation<'_>]) -> Result<(), Self::Error> {
        let mut ops = [Op::Read { len: 0 }; MAX_OPS];
        if operations.len() > MAX_OPS {
            return Err(BridgeError(BusFault::Other));
        }
        for (slot, op) in ops.iter_mut().zip(operations.iter()) {
            *slot = match op {
                i2c::Operation::Write(bytes) => Op::Write(Bytes::from_slice(bytes).ok_or(BridgeError(BusFault::Other))?),
                i2c::Operation::Read(buf) if buf.len() <= MAX_OP_BYTES => Op::Read { len: buf.len() as u8 },
                i2c::Operation::Read(_) => return Err(BridgeError(BusFault::Other)),
            };
        }
        let data = {
            let Ok(mut client) = self.client.try_borrow_mut() else { return Err(BridgeError(BusFault::Other)) };
            client.transact(Bus::I2c { bus: self.bus, address }, ops.get(..operations.len()).unwrap_or(&[])).map_err(BridgeError)?
        };
        scatter(
            data.as_slice(),
            operations.iter_mut().filter_map(|op| match op {
                i2c::Operation::Read(buf) => Some(&mut **buf),
                i2c::Operation::Write(_) => None,
            }),
        )
    }
}

/// An SPI device (bus + chip select) on the bridge.
pub struct BridgeSpi<'a, L> {
    client: &'a RefCell<BridgeClient<L>>,
    bus: u8,
    cs: u8,
}

impl<'a, L> BridgeSpi<'a, L> {
    pub fn new(client: &'a RefCell<BridgeClient<L>>, bus: u8, cs: u8) -> Self {
        Self { client, bus, cs }
    }
}

impl<L: ByteLink> spi::ErrorType for BridgeSpi<'_, L> {
    type Error = BridgeError;
}

impl<L: ByteLink> spi::SpiDevice for BridgeSpi<'_, L> {
    fn transaction(&mut self, operations: &mut [spi::Operation<'_, u8>]) -> Result<(), Self::Error> {
        let mut ops = [Op::Read { len: 0 }; MAX_OPS];
        let mut n = 0;
        for op in operations.iter() {
            let mapped = match op {
                spi::Operation::Write(bytes) => Op::Write(Bytes::from_slice(bytes).ok_or(BridgeError(BusFault::Other))?),
                spi::Operation::Read(buf) if buf.len() <= MAX_OP_BYTES => Op::Read { len: buf.len() as u8 },
                spi::Operation::Transfer(read, write) => {
                    // Full duplex over max(len) bytes: pad the write with zeros.
                    let len = read.len().max(write.len());
                    let mut b = Bytes::from_slice(write).ok_or(BridgeError(BusFault::Other))?;
                    if len > MAX_OP_BYTES {
                        return Err(BridgeError(BusFault::Other));
                    }
                    b.len = len as u8;
                    Op::Transfer(b)
                }
                spi::Operation::TransferInPlace(buf) => Op::Transfer(Bytes::from_slice(buf).ok_or(BridgeError(BusFault::Other))?),
                spi::Operation::DelayNs(_) => continue, // the chip models are answered in zero time
                spi::Operation::Read(_) => return Err(BridgeError(BusFault::Other)),
            };
            let slot = ops.get_mut(n).ok_or(BridgeError(BusFault::Other))?;
            *slot = mapped;
            n += 1;
        }
        let data = {
            let Ok(mut client) = self.client.try_borrow_mut() else { return Err(BridgeError(BusFault::Other)) };
            client.transact(Bus::Spi { bus: self.bus, cs: self.cs }, ops.get(..n).unwrap_or(&[])).map_err(BridgeError)?
        };
        let mut rest = data.as_slice();
        for op in operations.iter_mut() {
            let (dst, consumed): (&mut [u8], usize) = match op {
                spi::Operation::Read(buf) => {
                    let l = buf.len();
                    (&mut **buf, l)
                }
                spi::Operation::Transfer(read, write) => {
                    let l = read.len().max(write.len());
                    (&mut **read, l)
                }
                spi::Operation::TransferInPlace(buf) => {
                    let l = buf.len();
                    (&mut **buf, l)
                }
                _ => continue,
            };
            let Some((chunk, tail)) = split_checked(rest, consumed) else { return Err(BridgeError(BusFault::Other)) };
            let n = dst.len().min(chunk.len());
            if let (Some(d), Some(c)) = (dst.get_mut(..n), chunk.get(..n)) {
                d.copy_from_slice(c);
            }
            rest = tail;
        }
        Ok(())
    }
}

/// A UART on the bridge (`embedded_io` port), for serial instruments such as the DVL. Reads
/// fetch up to [`MAX_OP_BYTES`] bytes per transaction into a small buffer: `read_ready` asks
/// the host for the bytes fully received by the client's current time (the chip model keeps
/// the rest), so what the driver sees depends only on the firmware's logical time.
pub struct BridgeUart<'a, L> {
    client: &'a RefCell<BridgeClient<L>>,
    port: u8,
    buf: [u8; MAX_OP_BYTES],
    pos: usize,
    len: usize,
    /// The time of the last empty answer: no new bytes can arrive before the time moves on.
    empty_at_us: Option<u64>,
}

impl<'a, L> BridgeUart<'a, L> {
    pub fn new(client: &'a RefCell<BridgeClient<L>>, port: u8) -> Self {
        Self { client, port, buf: [0; MAX_OP_BYTES], pos: 0, len: 0, empty_at_us: None }
    }
}

impl<L: ByteLink> BridgeUart<'_, L> {
    /// Refill the buffer from the host if it is empty; returns whether bytes are buffered.
    fn fill(&mut self) -> Result<bool, BridgeError> {
        if self.pos < self.len {
            return Ok(true);
        }
        let Ok(mut client) = self.client.try_borrow_mut() else { return Err(BridgeError(BusFault::Other)) };
        if self.empty_at_us == Some(client.t_us) {
            return Ok(false);
        }
        let data = client.transact(Bus::Uart { port: self.port }, &[Op::Read { len: MAX_OP_BYTES as u8 }]).map_err(BridgeError)?;
        let got = data.as_slice();
        let n = got.len().min(MAX_OP_BYTES);
        if let (Some(d), Some(g)) = (self.buf.get_mut(..n), got.get(..n)) {
            d.copy_from_slice(g);
        }
        self.pos = 0;
        self.len = n;
        self.empty_at_us = (n == 0).then_some(client.t_us);
        Ok(n > 0)
    }
}

impl embedded_io::Error for BridgeError {
    fn kind(&self) -> embedded_io::ErrorKind {
        match self.0 {
            BusFault::Timeout => embedded_io::ErrorKind::TimedOut,
            BusFault::Nack => embedded_io::ErrorKind::NotConnected,
            BusFault::Other => embedded_io::ErrorKind::Other,
        }
    }
}

impl<L: ByteLink> embedded_io::ErrorType for BridgeUart<'_, L> {
    type Error = BridgeError;
}

impl<L: ByteLink> embedded_io::ReadReady for BridgeUart<'_, L> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        self.fill()
    }
}

impl<L: ByteLink> embedded_io::Read for BridgeUart<'_, L> {
    /// Non-blocking in practice: returns 0 when nothing has arrived by the current time (call
    /// `read_ready` first, as `embedded_io` intends for a blocking `read`).
    fn read(&mut self, out: &mut [u8]) -> Result<usize, Self::Error> {
        if out.is_empty() || !self.fill()? {
            return Ok(0);
        }
        let n = out.len().min(self.len.saturating_sub(self.pos));
        if let (Some(d), Some(s)) = (out.get_mut(..n), self.buf.get(self.pos..self.pos + n)) {
            d.copy_from_slice(s);
        }
        self.pos += n;
        Ok(n)
    }
}

impl<L: ByteLink> embedded_io::Write for BridgeUart<'_, L> {
    fn write(&mut self, bytes: &[u8]) -> Result<usize, Self::Error> {
        let n = bytes.len().min(MAX_OP_BYTES);
        let chunk = Bytes::from_slice(bytes.get(..n).unwrap_or(&[])).ok_or(BridgeError(BusFault::Other))?;
        let Ok(mut client) = self.client.try_borrow_mut() else { return Err(BridgeError(BusFault::Other)) };
        client.transact(Bus::Uart { port: self.port }, &[Op::Write(chunk)]).map_err(BridgeError)?;
        Ok(n)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// A digital output on the bridge (embedded-hal `OutputPin`), e.g. the camera's trigger line:
/// each level change is one transaction, so the host sees it at the firmware's logical time.
pub struct BridgePin<'a, L> {
    client: &'a RefCell<BridgeClient<L>>,
    pin: u8,
}

impl<'a, L> BridgePin<'a, L> {
    pub fn new(client: &'a RefCell<BridgeClient<L>>, pin: u8) -> Self {
        Self { client, pin }
    }
}

impl<L: ByteLink> BridgePin<'_, L> {
    fn set(&mut self, high: bool) -> Result<(), BridgeError> {
        let level = Bytes::from_slice(&[u8::from(high)]).ok_or(BridgeError(BusFault::Other))?;
        let Ok(mut client) = self.client.try_borrow_mut() else { return Err(BridgeError(BusFault::Other)) };
        client.transact(Bus::Gpio { pin: self.pin }, &[Op::Write(level)]).map_err(BridgeError)?;
        Ok(())
    }
}

impl embedded_hal::digital::Error for BridgeError {
    fn kind(&self) -> embedded_hal::digital::ErrorKind {
        embedded_hal::digital::ErrorKind::Other
    }
}

impl<L: ByteLink> embedded_hal::digital::ErrorType for BridgePin<'_, L> {
    type Error = BridgeError;
}

impl<L: ByteLink> embedded_hal::digital::OutputPin for BridgePin<'_, L> {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.set(false)
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.set(true)
    }
}

fn split_checked(s: &[u8], n: usize) -> Option<(&[u8], &[u8])> {
    (n <= s.len()).then(|| s.split_at(n))
}

/// Copy the concatenated read bytes into the read buffers, in order.
fn scatter<'b>(mut data: &[u8], bufs: impl Iterator<Item = &'b mut [u8]>) -> Result<(), BridgeError> {
    for buf in bufs {
        let Some((chunk, tail)) = split_checked(data, buf.len()) else { return Err(BridgeError(BusFault::Other)) };
        buf.copy_from_slice(chunk);
        data = tail;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::I2c;
    use embedded_hal::spi::SpiDevice;
    use std::collections::VecDeque;

    /// A link whose "host" answers each request with a function of it.
    struct Loop<F: FnMut(&BusRequest) -> BusResponse> {
        answer: F,
        rx: VecDeque<u8>,
        dec: FrameDecoder<MAX_REQUEST_FRAME>,
        seen: Vec<BusRequest>,
    }

    impl<F: FnMut(&BusRequest) -> BusResponse> ByteLink for Loop<F> {
        fn write_all(&mut self, bytes: &[u8]) {
            for &b in bytes {
                if let Decoded::Message(req) = self.dec.push::<BusRequest>(b) {
                    let resp = (self.answer)(&req);
                    self.seen.push(req);
                    let mut buf = [0u8; MAX_RESPONSE_FRAME];
                    self.rx.extend(wire::encode(&resp, &mut buf).unwrap().iter());
                }
            }
        }
        fn read_byte(&mut self) -> Option<u8> {
            self.rx.pop_front()
        }
    }

    fn looped<F: FnMut(&BusRequest) -> BusResponse>(answer: F) -> RefCell<BridgeClient<Loop<F>>> {
        RefCell::new(BridgeClient::new(Loop { answer, rx: VecDeque::new(), dec: FrameDecoder::new(), seen: vec![] }))
    }

    #[test]
    fn i2c_write_read_carries_time_and_scatters_reads() {
        let client = looped(|req| {
            let mut d = ReadData::EMPTY;
            d.push(&[0xAA, 0xBB, 0xCC]);
            BusResponse { seq: req.seq, result: Ok(d) }
        });
        client.borrow_mut().set_time(42_000);
        let mut i2c = BridgeI2c::new(&client, 0);
        let mut a = [0u8; 1];
        let mut b = [0u8; 2];
        i2c.transaction(0x76, &mut [i2c::Operation::Write(&[0xA2]), i2c::Operation::Read(&mut a), i2c::Operation::Read(&mut b)]).unwrap();
        assert_eq!((a, b), ([0xAA], [0xBB, 0xCC]));
        let c = client.borrow();
        let req = c.link.seen[0];
        assert_eq!(req.t_us, 42_000);
        assert_eq!(req.bus, Bus::I2c { bus: 0, address: 0x76 });
        assert_eq!(req.n_ops, 3);
    }

    #[test]
    fn nack_becomes_an_embedded_hal_nack() {
        let client = looped(|req| BusResponse { seq: req.seq, result: Err(BusFault::Nack) });
        let mut i2c = BridgeI2c::new(&client, 0);
        let e = i2c.write(0x48, &[1, 2]).unwrap_err();
        assert!(matches!(i2c::Error::kind(&e), i2c::ErrorKind::NoAcknowledge(_)));
        assert_eq!(client.borrow().faults, [1, 0, 0]);
    }

    #[test]
    fn silent_host_times_out() {
        struct Dead;
        impl ByteLink for Dead {
            fn write_all(&mut self, _: &[u8]) {}
            fn read_byte(&mut self) -> Option<u8> {
                None
            }
        }
        let client = RefCell::new(BridgeClient::new(Dead));
        client.borrow_mut().max_polls = 1000;
        let mut i2c = BridgeI2c::new(&client, 0);
        assert_eq!(i2c.write(0x48, &[1]).unwrap_err(), BridgeError(BusFault::Timeout));
    }

    #[test]
    fn spi_write_then_read() {
        let client = looped(|req| {
            let mut d = ReadData::EMPTY;
            d.push(&[1, 2, 3, 4]);
            assert!(matches!(req.ops[0], Op::Write(b) if b.as_slice() == [0x9F]));
            BusResponse { seq: req.seq, result: Ok(d) }
        });
        let mut spi = BridgeSpi::new(&client, 0, 1);
        let mut buf = [0u8; 4];
        spi.transaction(&mut [spi::Operation::Write(&[0x9F]), spi::Operation::Read(&mut buf)]).unwrap();
        assert_eq!(buf, [1, 2, 3, 4]);
    }

    #[test]
    fn short_response_is_an_error_not_a_panic() {
        let client = looped(|req| BusResponse { seq: req.seq, result: Ok(ReadData::EMPTY) });
        let mut i2c = BridgeI2c::new(&client, 0);
        let mut buf = [0u8; 2];
        assert!(i2c.read(0x48, &mut buf).is_err());
    }
}
