//! Power loss while the store writes or erases: the head's own store code (`FlashStore` on the
//! W25Q driver) against the W25Q chip model, which fails inside a random program or erase of a
//! random record write or erase. After each cut the chip comes back with what it held (a
//! restart), and every key must read its old or its new value, never garbage or an error, and
//! the application must boot on it with a working store.
//!
//! CI runs 100 cuts; `SUBNAV_POWER_CUTS=1000 cargo test -p subnav-sil --test
//! store_power_loss -- --nocapture` is the documented long run (docs/RELIABILITY.md).

use std::collections::HashMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subnav_firmware::app::{App, record_keys};
use subnav_firmware::drivers::w25q::W25q;
use subnav_firmware::store::{FlashStore, RecordStore};
use subnav_sil::chips::w25q::{DirectSpi, PowerCut, W25qModel};
use subnav_wire::{
    Board, Decoded, FrameDecoder, ImuCalibration, MAX_UPLINK_FRAME, Origin, PolarizationCalibration, Record, RecordKey, RunConfigRecord,
    StoreStatus, Uplink,
};

fn random_record(key: RecordKey, rng: &mut ChaCha8Rng) -> Record {
    match key {
        RecordKey::RunConfig => Record::RunConfig(RunConfigRecord {
            nav_rate_hz: rng.random_range(1..=50),
            stream_raw: rng.random(),
            water_density_kgm3: rng.random_range(1000.0..1040.0),
            origin: rng.random::<bool>().then(|| Origin {
                lat_rad: rng.random_range(-1.0..1.0),
                lon_rad: rng.random_range(-3.0..3.0),
                alt_m: 0.0,
            }),
        }),
        RecordKey::Polarization { unit } => Record::Polarization(PolarizationCalibration {
            unit,
            gain: std::array::from_fn(|_| rng.random_range(0.9..1.1)),
            offset_counts: std::array::from_fn(|_| rng.random_range(250.0..350.0)),
            polarizer_rad: std::array::from_fn(|k| (k as f32 * 45.0 + rng.random_range(-2.0..2.0)).to_radians()),
            extinction_ratio: std::array::from_fn(|_| rng.random_range(100.0..1000.0)),
        }),
        RecordKey::Imu | RecordKey::DvlMounting => {
            let mut m = [0.0f32; 6];
            for (i, v) in m.iter_mut().enumerate() {
                *v = if matches!(i, 0 | 3 | 5) { rng.random_range(0.95..1.05) } else { rng.random_range(-0.01..0.01) };
            }
            Record::Imu(ImuCalibration {
                gyro_bias_radps: std::array::from_fn(|_| rng.random_range(-0.01..0.01)),
                accel_bias_mps2: std::array::from_fn(|_| rng.random_range(-0.1..0.1)),
                gyro_correction: m,
                accel_correction: m,
                body_from_imu_wxyz: [1.0, 0.0, 0.0, 0.0],
            })
        }
    }
}

struct Bytes(Vec<u8>);

impl subnav_firmware::telemetry::TelemetrySink for Bytes {
    fn write_frame(&mut self, frame: &[u8]) -> bool {
        self.0.extend_from_slice(frame);
        true
    }
}

#[derive(Clone, Copy)]
enum Op {
    Save(Record),
    Erase(RecordKey),
}

fn apply(chip: &mut W25qModel, op: Op) -> bool {
    let Ok(flash) = W25q::new(DirectSpi { chip, t_us: 0 }) else { return false };
    let mut store = FlashStore::new(flash);
    match op {
        Op::Save(r) => store.save(&r).is_ok(),
        Op::Erase(k) => store.erase(k).is_ok(),
    }
}

fn boot_status(chip: &mut W25qModel) -> StoreStatus {
    let flash = W25q::new(DirectSpi { chip, t_us: 0 }).expect("a restarted chip answers");
    let mut store = FlashStore::new(flash);
    let mut app = App::new(Board::QemuMps2An386);
    let mut out = Bytes(Vec::new());
    app.boot_with_store(0, &mut store, &mut out);
    let out = out.0;
    let mut dec = FrameDecoder::<MAX_UPLINK_FRAME>::new();
    out.iter()
        .find_map(|b| match dec.push::<Uplink>(*b) {
            Decoded::Message(Uplink::Boot(boot)) => Some(boot.calibration.store),
            _ => None,
        })
        .expect("the head sends Boot")
}

#[test]
fn every_key_reads_old_or_new_after_a_power_cut() {
    let cuts: usize = std::env::var("SUBNAV_POWER_CUTS").ok().and_then(|v| v.parse().ok()).unwrap_or(100);
    let keys: Vec<RecordKey> = record_keys().filter(|k| *k != RecordKey::DvlMounting).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(20_261_202);
    let mut chip = W25qModel::new();
    let mut expected: HashMap<u8, Option<Record>> = keys.iter().map(|k| (k.id(), None)).collect();
    let (mut completed, mut interrupted, mut took_new, mut erase_cuts) = (0, 0, 0, 0);
    let mut cut = 0;
    let mut writes = 0u64;
    while cut < cuts {
        // A few writes that complete between two cuts, so the map fills, wraps and collects
        // garbage (its page erases are cut too).
        for _ in 0..rng.random_range(0..12) {
            let key = keys[rng.random_range(0..keys.len())];
            let r = random_record(key, &mut rng);
            assert!(apply(&mut chip, Op::Save(r)));
            expected.insert(key.id(), Some(r));
            writes += 1;
        }
        // Every third cut goes to the next write that makes the map erase a sector (garbage
        // collection: rare, and where a store is most fragile); the writes before it complete.
        let hunt_erase = cut % 3 == 2;
        let (key, op, dry) = loop {
            let key = keys[rng.random_range(0..keys.len())];
            let op = if rng.random::<f64>() < 0.2 { Op::Erase(key) } else { Op::Save(random_record(key, &mut rng)) };
            // Count the program/erase operations this write takes, on a copy of the chip.
            let mut dry = W25qModel::from_contents(chip.contents().to_vec());
            assert!(apply(&mut dry, op), "cut {cut}: the uninterrupted operation fails");
            if !hunt_erase || !dry.erase_operations.is_empty() {
                break (key, op, dry);
            }
            assert!(apply(&mut chip, op));
            expected.insert(
                key.id(),
                match op {
                    Op::Save(r) => Some(r),
                    Op::Erase(_) => None,
                },
            );
            writes += 1;
        };
        let ops = dry.counters.programs + dry.counters.erases;
        if ops == 0 {
            // Erasing a key that is not stored writes nothing: no instant to cut.
            continue;
        }
        writes += 1;
        // Uniform over the operation's programs and erases; a hunted garbage collection is cut
        // in one of its erases.
        let at = match dry.erase_operations.as_slice() {
            e if hunt_erase && !e.is_empty() => e[rng.random_range(0..e.len())],
            _ => rng.random_range(0..ops),
        };
        chip.power_cut = Some(PowerCut { at_operation: at, seed: rng.random(), happened: false, in_erase: false });
        chip.counters = Default::default();
        let ok = apply(&mut chip, op);
        if chip.is_dead() {
            interrupted += 1;
            if chip.power_cut.is_some_and(|c| c.in_erase) {
                erase_cuts += 1;
            }
        } else {
            assert!(ok);
            completed += 1;
        }
        // Power back: the chip holds what it held when the supply failed.
        chip = W25qModel::from_contents(chip.contents().to_vec());
        let new = match op {
            Op::Save(r) => Some(r),
            Op::Erase(_) => None,
        };
        {
            let flash = W25q::new(DirectSpi { chip: &mut chip, t_us: 0 }).expect("a restarted chip answers");
            let mut store = FlashStore::new(flash);
            for k in &keys {
                let got = store.load(*k).unwrap_or_else(|e| panic!("cut {cut}: {k} reads as an error after the restart: {e}"));
                let old = expected[&k.id()];
                if *k == key {
                    assert!(got == old || got == new, "cut {cut}: {k} is neither its old nor its new value: {got:?}");
                    if got == new && got != old {
                        took_new += 1;
                    }
                } else {
                    assert_eq!(got, old, "cut {cut}: {k}, not being written, changed");
                }
                expected.insert(k.id(), got);
            }
        }
        cut += 1;
        if cut % 10 == 0 {
            let status = boot_status(&mut chip);
            assert!(matches!(status, StoreStatus::Ok | StoreStatus::Empty), "cut {cut}: the head boots with store {status:?}");
        }
    }
    println!(
        "power cuts: {cuts} over {writes} record writes/erases; {interrupted} inside a program or erase ({erase_cuts} in a sector erase), {took_new} of them left the new value, the rest the old; 0 corrupt reads, the head booted on every 10th"
    );
    assert_eq!(interrupted + completed, cuts);
    assert_eq!(interrupted, cuts, "every cut lands inside one of the operation's programs or erases");
    assert!(erase_cuts > 0, "some cuts must hit the map's page erases");
}
