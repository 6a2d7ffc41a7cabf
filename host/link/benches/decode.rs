//! Decode throughput on one core: a stream of uplink frames (the mix a sensor head sends: nav,
//! health, raw IMU/depth/polarization, compass, faults) through `UplinkDecoder`, and the same
//! stream inside a recording through the recording reader + decoder (`Session::decode`).
//!
//! `cargo bench -p subnav-host --bench decode` (results in docs/PERFORMANCE.md).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use subnav_link::UplinkDecoder;
use subnav_link::record::{Meta, Stream, Writer, read_bytes, session::Session};
use subnav_wire::*;

const FRAMES: usize = 10_000;

fn message(i: usize) -> Uplink {
    let t_us = i as u64 * 1_000;
    let f = i as f32 * 1e-3;
    match i % 8 {
        0 => Uplink::Nav(NavSolution {
            t_us,
            mode: NavMode::Aided,
            pos_ned_m: [f, -f, 10.0 + f],
            vel_ned_mps: [1.0, 0.1, 0.0],
            att_nb_wxyz: [0.99, 0.01, 0.02, 0.1],
            sigma_pos_m: [0.5; 3],
            sigma_vel_mps: [0.05; 3],
            sigma_att_rad: [0.01; 3],
            cov_ne_m2: 0.0,
        }),
        1 => Uplink::Health(FilterHealth {
            t_us,
            aid: subnav_wire::AidStatuses {
                heading: subnav_wire::AidStatus {
                    nis: 1.0,
                    test_ratio: 0.1,
                    noise_var: 1e-4,
                    fused: true,
                    fused_count: 3,
                    ..Default::default()
                },
                depth: subnav_wire::AidStatus { nis: f32::NAN, ..Default::default() },
                ..Default::default()
            },
            imu_q_scale: 1.0,
            lambda: 1.0,
            q_diag: [1e-6; 5],
            pd_repairs: 0,
            cov_unrepairable: 0,
            gate_rejects: 3,
            nonfinite_rejects: 0,
            late_fused: 0,
            late_refused: 0,
            heading_resets: 0,
            position_resets: 0,
            cpu_load_permille: 250,
        }),
        2 | 3 | 4 => {
            Uplink::Raw(RawSample::Imu(ImuSample { t_us, gyro_radps: [f, 0.001, -0.002], accel_mps2: [0.1, -0.05, -9.81], temp_c: 21.5 }))
        }
        5 => Uplink::Raw(RawSample::Depth(DepthSample { t_us, pressure_pa: 201_325.0 + f, temp_c: 12.0, depth_m: 10.0 + f })),
        6 => Uplink::Raw(RawSample::Polarization(PolarizationSample { t_us, unit: (i % 4) as u8, counts: [1200, 900, 400, 700] })),
        _ => Uplink::Compass(CompassReport {
            t_us,
            heading_rad: Some(1.2),
            sigma_heading_rad: 0.02,
            sun_rel_azimuth_rad: 0.3,
            sun_elevation_rad: 0.8,
            no_fix_reason: 0,
            units_used: 4,
        }),
    }
}

fn stream() -> Vec<u8> {
    let mut bytes = vec![];
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    for i in 0..FRAMES {
        bytes.extend_from_slice(encode(&message(i), &mut buf).expect("encode"));
    }
    bytes
}

fn bench(c: &mut Criterion) {
    let bytes = stream();
    let mut g = c.benchmark_group("decode");
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("uplink_frames", |b| {
        b.iter(|| {
            let mut dec = UplinkDecoder::new();
            let mut n = 0u64;
            dec.feed(black_box(&bytes), |_| n += 1);
            assert_eq!(n, FRAMES as u64);
            n
        })
    });
    // The same bytes in a recording, in 4 KiB chunks as a serial/TCP reader delivers them.
    let mut w = Writer::new(Vec::new(), &Meta::new("bench")).expect("writer");
    for (k, part) in bytes.chunks(4096).enumerate() {
        w.chunk(Stream::Uplink, k as u64, part).expect("chunk");
    }
    let rec = w.into_inner();
    g.bench_function("recording_read_and_decode", |b| {
        b.iter(|| {
            let loaded = read_bytes(black_box(&rec)).expect("read");
            let s = Session::decode(&loaded, None);
            assert_eq!(s.messages.len(), FRAMES);
            s.messages.len()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
