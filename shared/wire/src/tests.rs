use super::*;
use crate::error_check::assert_distinct_messages;
use postcard_schema::Schema;
use proptest::prelude::*;

fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[test]
fn schema_fingerprint_matches_types() {
    let text = format!("{:?}|{:?}", <Uplink as Schema>::SCHEMA, <Downlink as Schema>::SCHEMA);
    let fp = fnv1a64(text.as_bytes());
    assert_eq!(
        fp, SCHEMA_FINGERPRINT,
        "the message types changed: set SCHEMA_FINGERPRINT = {fp:#018x} (and bump PROTOCOL_VERSION if the change is incompatible)"
    );
}

fn nav(t_us: u64) -> Uplink {
    Uplink::Nav(NavSolution {
        t_us,
        mode: NavMode::Aided,
        pos_ned_m: [1.0, -2.0, 30.5],
        vel_ned_mps: [0.5, 0.0, 0.0],
        att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
        sigma_pos_m: [0.1; 3],
        sigma_vel_mps: [0.01; 3],
        sigma_att_rad: [0.001; 3],
        cov_ne_m2: 0.0,
    })
}

fn samples() -> Vec<Uplink> {
    vec![
        Uplink::Boot(boot_message(Board::QemuMps2An386, [0, 1, 0], 0, crate::CalibrationInUse::NO_STORE, ResetCause::PowerOn)),
        nav(1_000_000),
        Uplink::Raw(RawSample::Imu(ImuSample { t_us: 5, gyro_radps: [0.0, 1e-3, -1e-3], accel_mps2: [0.0, 0.0, -9.81], temp_c: 21.0 })),
        Uplink::Raw(RawSample::Polarization(PolarizationSample { t_us: 6, unit: 3, counts: [0, -1, 32767, -32768] })),
        Uplink::Fault(Fault { t_us: 7, source: FaultSource::Polarization { unit: 2 }, kind: FaultKind::BusNack, count: 9 }),
        Uplink::Ack(CommandAck { seq: 65535, result: Err(Refusal::OutOfRange) }),
        Uplink::Compass(CompassReport {
            t_us: 8,
            heading_rad: None,
            sigma_heading_rad: f32::INFINITY,
            sun_rel_azimuth_rad: 0.0,
            sun_elevation_rad: 0.0,
            no_fix_reason: 3,
            units_used: 0,
        }),
    ]
}

#[test]
fn roundtrip_every_kind() {
    for m in samples() {
        let mut buf = [0u8; MAX_UPLINK_FRAME];
        let frame = encode(&m, &mut buf).unwrap();
        assert_eq!(*frame.last().unwrap(), 0);
        assert!(!frame[..frame.len() - 1].contains(&0), "COBS body must be zero-free");
        assert!(frame.len() <= MAX_UPLINK_FRAME);
        let n = frame.len() - 1;
        let back: Uplink = decode_in_place(&mut frame[..n]).unwrap();
        assert_eq!(back, m);
    }
}

#[test]
fn downlink_roundtrip_and_size_bound() {
    let d = Downlink { seq: 7, command: Command::PositionFix { t_us: u64::MAX, pos_ned_m: [f32::MAX; 3], cov_ned_m2: [f32::MIN; 6] } };
    let mut buf = [0u8; MAX_DOWNLINK_FRAME];
    let frame = encode(&d, &mut buf).unwrap();
    let n = frame.len() - 1;
    assert_eq!(decode_in_place::<Downlink>(&mut frame[..n]).unwrap(), d);
}

#[test]
fn buffer_too_small_is_an_error_not_a_panic() {
    let mut buf = [0u8; 8];
    assert_eq!(encode(&nav(1), &mut buf).unwrap_err(), FrameError::BufferTooSmall);
}

#[test]
fn single_bit_flip_is_detected() {
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let frame = encode(&nav(42), &mut buf).unwrap().to_vec();
    let body_len = frame.len() - 1;
    for i in 0..body_len {
        for bit in 0..8 {
            let mut f = frame[..body_len].to_vec();
            f[i] ^= 1 << bit;
            if f[i] == 0 {
                continue; // becomes a delimiter: the stream test covers splitting
            }
            assert!(decode_in_place::<Uplink>(&mut f).is_err(), "flip at byte {i} bit {bit} undetected");
        }
    }
}

#[test]
fn stream_with_garbage_keeps_every_intact_frame() {
    let msgs = samples();
    let mut stream = vec![0x13, 0x77, 0x00]; // mid-frame join
    for (i, m) in msgs.iter().enumerate() {
        let mut buf = [0u8; MAX_UPLINK_FRAME];
        stream.extend_from_slice(encode(m, &mut buf).unwrap());
        if i % 2 == 0 {
            stream.extend_from_slice(&[0x55, 0xAA, 0x01, 0x00]); // a corrupt frame
        }
    }
    let mut dec = FrameDecoder::<{ MAX_UPLINK_FRAME }>::new();
    let mut got = vec![];
    for b in stream {
        if let Decoded::Message(m) = dec.push::<Uplink>(b) {
            got.push(m);
        }
    }
    assert_eq!(got, msgs);
    assert_eq!(dec.frames_ok, msgs.len() as u64);
    assert_eq!(dec.frames_bad, 1 + msgs.len().div_ceil(2) as u64);
}

#[test]
fn overlong_frame_is_reported_and_decoder_recovers() {
    let mut dec = FrameDecoder::<16>::new();
    for _ in 0..100 {
        assert_eq!(dec.push::<Uplink>(0x42), Decoded::Pending);
    }
    assert_eq!(dec.push::<Uplink>(0), Decoded::Corrupt(FrameError::Overlong));
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let m = Uplink::Ack(CommandAck { seq: 1, result: Ok(()) });
    let frame = encode(&m, &mut buf).unwrap().to_vec();
    let mut out = None;
    for b in frame {
        if let Decoded::Message(x) = dec.push::<Uplink>(b) {
            out = Some(x);
        }
    }
    assert_eq!(out, Some(m));
}

#[test]
fn boot_compatibility() {
    let b = boot_message(Board::Stm32F405, [1, 2, 3], 0, crate::CalibrationInUse::NO_STORE, ResetCause::PowerOn);
    assert_eq!(b.compatibility(), Compatibility::Compatible);
    let old = Boot { protocol_version: PROTOCOL_VERSION + 1, ..b };
    assert!(matches!(old.compatibility(), Compatibility::VersionMismatch { .. }));
    let other = Boot { schema_fingerprint: SCHEMA_FINGERPRINT ^ 1, ..b };
    assert!(matches!(other.compatibility(), Compatibility::SchemaMismatch { .. }));
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let mut dec = FrameDecoder::<{ MAX_UPLINK_FRAME }>::new();
        for b in &bytes {
            let _ = dec.push::<Uplink>(*b);
        }
        let mut down = FrameDecoder::<{ MAX_DOWNLINK_FRAME }>::new();
        for b in &bytes {
            let _ = down.push::<Downlink>(*b);
        }
    }
}

#[test]
fn errors_display_distinct_messages() {
    use crate::bridge::BusFault;
    assert_distinct_messages(
        "FrameError",
        &[
            &FrameError::BufferTooSmall,
            &FrameError::Cobs,
            &FrameError::TooShort,
            &FrameError::Crc,
            &FrameError::Payload,
            &FrameError::Overlong,
        ],
    );
    assert_distinct_messages(
        "Refusal",
        &[&Refusal::OutOfRange, &Refusal::NotFinite, &Refusal::NotSupported, &Refusal::NotPositiveDefinite, &Refusal::Busy],
    );
    assert_distinct_messages("BusFault", &[&BusFault::Nack, &BusFault::Timeout, &BusFault::Other]);
    assert_distinct_messages(
        "FaultKind",
        &[
            &FaultKind::BusNack,
            &FaultKind::BusTimeout,
            &FaultKind::BusOther,
            &FaultKind::BadCrc,
            &FaultKind::IdentityMismatch,
            &FaultKind::Stuck,
            &FaultKind::Saturated,
            &FaultKind::NonFinite,
            &FaultKind::CorruptFrame,
            &FaultKind::Overrun,
            &FaultKind::TelemetryDropped,
            &FaultKind::Occluded,
        ],
    );
    let sources = [
        FaultSource::Imu,
        FaultSource::Polarization { unit: 3 },
        FaultSource::Depth,
        FaultSource::Link,
        FaultSource::Filter,
        FaultSource::Scheduler,
    ];
    let names: Vec<String> = sources.iter().map(|s| s.to_string()).collect();
    for (i, n) in names.iter().enumerate() {
        assert!(!n.is_empty());
        assert!(names.iter().skip(i + 1).all(|o| o != n), "FaultSource {n:?} repeated");
    }
    assert!(names[1].contains('3'), "the polarization unit number is shown: {}", names[1]);
    let fault = Fault { t_us: 1_500_000, source: FaultSource::Depth, kind: FaultKind::BusNack, count: 4 };
    let text = fault.to_string();
    assert!(text.contains("depth sensor") && text.contains("NACK") && text.contains('4'), "{text}");
}
