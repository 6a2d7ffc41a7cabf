//! CRC detection on the wire: 10^6 frames (every uplink kind, varied contents), each with 1 to 8
//! random bit flips in its COBS body, pushed through the stream decoder. A flip that turns a
//! byte into 0x00 splits the frame; every piece must then be reported corrupt too. Undetected
//! corruptions (a decoded message from a flipped frame) must be 0.
//! The count and run time are recorded in docs/RELIABILITY.md.

use subnav_wire::*;

/// splitmix64: fixed sequence, no dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32 * 200.0 - 100.0
    }
}

fn message(r: &mut Rng) -> Uplink {
    let t_us = r.next() >> 20;
    match r.below(7) {
        0 => Uplink::Nav(NavSolution {
            t_us,
            mode: NavMode::Aided,
            pos_ned_m: [r.f(), r.f(), r.f()],
            vel_ned_mps: [r.f(), r.f(), r.f()],
            att_nb_wxyz: [r.f(), r.f(), r.f(), r.f()],
            sigma_pos_m: [r.f(); 3],
            sigma_vel_mps: [r.f(); 3],
            sigma_att_rad: [r.f(); 3],
            cov_ne_m2: 0.0,
        }),
        1 => Uplink::Health(FilterHealth {
            t_us,
            aid: subnav_wire::AidStatuses {
                dvl: subnav_wire::AidStatus { nis: r.f(), test_ratio: r.f(), noise_var: r.f(), ..Default::default() },
                ..Default::default()
            },
            imu_q_scale: r.f(),
            lambda: r.f(),
            q_diag: [r.f(); 5],
            pd_repairs: r.next() as u32,
            cov_unrepairable: 0,
            gate_rejects: 3,
            nonfinite_rejects: 0,
            late_fused: 0,
            late_refused: 0,
            heading_resets: 0,
            position_resets: 0,
            cpu_load_permille: 250,
        }),
        2 => Uplink::Raw(RawSample::Imu(ImuSample {
            t_us,
            gyro_radps: [r.f(), r.f(), r.f()],
            accel_mps2: [r.f(), r.f(), r.f()],
            temp_c: r.f(),
        })),
        3 => Uplink::Raw(RawSample::Depth(DepthSample { t_us, pressure_pa: r.f(), temp_c: r.f(), depth_m: r.f() })),
        4 => Uplink::Raw(RawSample::Polarization(PolarizationSample {
            t_us,
            unit: r.below(4) as u8,
            counts: [r.next() as i16, 0, -1, r.next() as i16],
        })),
        5 => Uplink::Fault(Fault { t_us, source: FaultSource::Polarization { unit: 1 }, kind: FaultKind::BusNack, count: r.next() as u32 }),
        _ => Uplink::Compass(CompassReport {
            t_us,
            heading_rad: Some(r.f()),
            sigma_heading_rad: r.f(),
            sun_rel_azimuth_rad: r.f(),
            sun_elevation_rad: r.f(),
            no_fix_reason: 0,
            units_used: 4,
        }),
    }
}

#[test]
fn a_million_bit_flipped_frames_are_all_detected() {
    const FRAMES: usize = 1_000_000;
    let started = std::time::Instant::now();
    let mut r = Rng(0x5EED);
    let mut dec = FrameDecoder::<{ MAX_UPLINK_FRAME }>::new();
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    let (mut undetected, mut pieces_bad, mut split, mut unchanged) = (0u64, 0u64, 0u64, 0u64);
    for _ in 0..FRAMES {
        let m = message(&mut r);
        let frame = encode(&m, &mut buf).unwrap();
        let original = frame.to_vec();
        let body_len = frame.len() - 1;
        let flips = 1 + r.below(8);
        for _ in 0..flips {
            let i = r.below(body_len);
            frame[i] ^= 1 << r.below(8);
        }
        if frame[..body_len].contains(&0) {
            split += 1;
        }
        // Flips that cancel (the same bit twice) leave the frame intact: it must decode as sent.
        let intact = *frame == original[..];
        unchanged += u64::from(intact);
        for &b in frame.iter() {
            match dec.push::<Uplink>(b) {
                Decoded::Message(got) if intact => assert_eq!(format!("{got:?}"), format!("{m:?}")),
                Decoded::Message(_) => undetected += 1,
                Decoded::Corrupt(_) => pieces_bad += 1,
                Decoded::Pending => {}
            }
        }
    }
    eprintln!(
        "{FRAMES} frames with 1-8 bit flips: {} corrupted, {undetected} undetected, {pieces_bad} corrupt pieces reported, {split} frames split by a flipped-in 0x00, {unchanged} left intact by cancelling flips, {:.1} s",
        FRAMES as u64 - unchanged,
        started.elapsed().as_secs_f64()
    );
    assert_eq!(undetected, 0);
    // Every corrupted frame produced at least one corrupt report.
    assert!(pieces_bad >= FRAMES as u64 - unchanged);
    assert!(unchanged < FRAMES as u64 / 100);
}
