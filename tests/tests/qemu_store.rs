//! The persistent store under QEMU: the firmware ELF with the W25Q chip model on its SPI bus,
//! the flash kept in a file between runs. Configuration and calibration set over the downlink
//! survive a reboot; bad values are refused with reasons; an erased or damaged store gives
//! defaults and a reported fault, never a panic. Needs `SUBNAV_FIRMWARE_QEMU_ELF`.

use std::path::Path;
use std::time::Duration;

use subnav_link::LinkEvent;
use subnav_link::qemu::{Downlinker, QemuEvent};
use subnav_sil::chips::w25q::W25qModel;
use subnav_sil::run::HeadRun;
use subnav_sil::{Scenario, SimHead};
use subnav_wire::{
    Command, CommandAck, ConfigItem, FaultKind, FaultSource, PolarizationCalibration, Record, RecordKey, Refusal, StoreStatus, Uplink,
};

fn calibration(unit: u8, gain: f32) -> Record {
    Record::Polarization(PolarizationCalibration {
        unit,
        gain: [gain; 4],
        offset_counts: [300.0; 4],
        polarizer_rad: std::array::from_fn(|k| (k as f32 * 45.0 + 0.5).to_radians()),
        extinction_ratio: [500.0; 4],
    })
}

/// Run the head for `run_ms` on the flash in `flash`, sending `commands` after Boot.
fn run(flash: &Path, run_ms: u64, commands: &[Command]) -> Vec<Uplink> {
    let sc = Scenario { seed: 1, duration_s: run_ms as f64 / 1000.0, ..Default::default() };
    let head = SimHead::new(&sc).with_flash(W25qModel::with_file(flash).expect("flash image"));
    let mut sent = false;
    let mut after_boot = |e: &QemuEvent, down: &mut Downlinker| {
        if let QemuEvent::Link(LinkEvent::Message(Uplink::Boot(_))) = e {
            if !sent {
                sent = true;
                for c in commands {
                    down.send(*c).expect("send a command");
                }
            }
        }
    };
    let out = HeadRun::qemu(&sc, &subnav_tests::qemu_elf())
        .on_head(head)
        .keep_all()
        .run_ms(run_ms)
        .timeout(Duration::from_secs(120))
        .qemu_events(&mut after_boot)
        .run()
        .expect("QEMU run");
    assert_eq!(out.exit_code, Some(0), "the head must run to the end");
    out.messages
}

fn boot(msgs: &[Uplink]) -> subnav_wire::Boot {
    match msgs.first() {
        Some(Uplink::Boot(b)) => *b,
        other => panic!("first message is not Boot: {other:?}"),
    }
}

fn acks(msgs: &[Uplink]) -> Vec<CommandAck> {
    msgs.iter().filter_map(|m| if let Uplink::Ack(a) = m { Some(*a) } else { None }).filter(|a| a.seq != 0).collect()
}

fn nav_period_us(msgs: &[Uplink]) -> Vec<u64> {
    let t: Vec<u64> = msgs.iter().filter_map(|m| if let Uplink::Nav(n) = m { Some(n.t_us) } else { None }).collect();
    t.windows(2).rev().take(5).map(|w| w[1] - w[0]).collect()
}

#[test]
fn config_and_calibration_survive_a_reboot_and_a_damaged_store_gives_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let flash = dir.path().join("head.flash");
    let unit1 = RecordKey::Polarization { unit: 1 };

    // A new head: an erased store.
    let first = run(
        &flash,
        1_500,
        &[
            Command::SetRecord(calibration(1, 1.04)),
            Command::SetRecord(calibration(2, 3.0)), // gain out of range
            Command::SetConfig(ConfigItem::NavRateHz(20)),
            Command::ReadRecord(RecordKey::Polarization { unit: 9 }), // no such unit
            Command::ReadRecord(unit1),
        ],
    );
    assert_eq!(boot(&first).calibration.store, StoreStatus::Empty);
    let mut got = acks(&first);
    got.sort_by_key(|a| a.seq);
    assert_eq!(
        got,
        vec![
            CommandAck { seq: 1, result: Ok(()) },
            CommandAck { seq: 2, result: Err(Refusal::OutOfRange) },
            CommandAck { seq: 3, result: Ok(()) },
            CommandAck { seq: 4, result: Err(Refusal::OutOfRange) },
            CommandAck { seq: 5, result: Ok(()) },
        ]
    );
    let read = first.iter().find_map(|m| if let Uplink::Record(r) = m { Some(*r) } else { None }).expect("a record report");
    assert_eq!(read.stored, Some(calibration(1, 1.04)));

    // Reboot: the same flash; the configuration and the calibration are in use.
    let second = run(&flash, 1_500, &[Command::ReadRecord(unit1)]);
    let b = boot(&second);
    assert_eq!(b.calibration.store, StoreStatus::Ok);
    assert!(b.calibration.config_stored);
    assert_eq!(b.calibration.polarization_units_stored, 0b0010);
    assert!(nav_period_us(&second).iter().all(|d| *d == 50_000), "the stored 20 Hz nav rate: {:?}", nav_period_us(&second));
    let read = second.iter().find_map(|m| if let Uplink::Record(r) = m { Some(*r) } else { None }).expect("a record report");
    assert_eq!(read.stored, Some(calibration(1, 1.04)));
    assert!(!second.iter().any(|m| matches!(m, Uplink::Fault(f) if f.source == FaultSource::Store)));

    // Damage the store (garbage over its pages): defaults, a store fault, and the head runs.
    let mut image = std::fs::read(&flash).unwrap();
    let mut x = 0x2545_f491_4f6c_dd1du64;
    for b in image.iter_mut().take(32 * 1024) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        *b = x as u8;
    }
    std::fs::write(&flash, &image).unwrap();
    let third = run(&flash, 1_500, &[]);
    let b = boot(&third);
    assert!(matches!(b.calibration.store, StoreStatus::Reformatted | StoreStatus::Empty), "{:?}", b.calibration);
    assert_eq!(b.calibration.polarization_units_stored, 0);
    assert!(!b.calibration.config_stored);
    assert!(
        third.iter().any(|m| matches!(m, Uplink::Fault(f) if f.source == FaultSource::Store && f.kind == FaultKind::BadCrc))
            || b.calibration.store == StoreStatus::Empty,
        "a damaged store is reported"
    );
    assert!(nav_period_us(&third).iter().all(|d| *d == 100_000), "back on the default 10 Hz");

    // Erased (all ones): a new head again.
    std::fs::write(&flash, vec![0xFFu8; 2 * 1024 * 1024]).unwrap();
    assert_eq!(boot(&run(&flash, 500, &[])).calibration.store, StoreStatus::Empty);
}
