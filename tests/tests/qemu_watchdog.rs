//! A hung firmware recovers: the QEMU board's loop stops (`hang_at_ms`, once after power-on),
//! mps2-an386's CMSDK watchdog is no longer fed, its NMI marks the cause and its second expiry
//! resets the machine; the head boots again in the same QEMU process, reports
//! `ResetCause::Watchdog` with the configuration it stored before the hang, and navigates.
//! The `Reboot` command gives `ResetCause::Software`. Needs `SUBNAV_FIRMWARE_QEMU_ELF`.

use std::path::Path;
use std::time::Duration;

use subnav_link::LinkEvent;
use subnav_link::qemu::{Downlinker, QemuEvent};
use subnav_sil::chips::w25q::W25qModel;
use subnav_sil::run::HeadRun;
use subnav_sil::{Scenario, SimHead};
use subnav_wire::{Boot, Command, ConfigItem, NavMode, ResetCause, StoreStatus, Uplink};

/// Run the head on the flash in `flash` with extra board options; `commands` go out after the
/// first Boot. Returns the messages and the log lines.
fn run(flash: &Path, run_ms: u64, extra: &[&str], commands: &[Command]) -> (Vec<Uplink>, Vec<String>) {
    let sc = Scenario { seed: 3, duration_s: 60.0, ..Default::default() };
    let head = SimHead::new(&sc).with_flash(W25qModel::with_file(flash).expect("flash image"));
    let mut logs = Vec::new();
    let mut sent = false;
    let mut hook = |e: &QemuEvent, down: &mut Downlinker| match e {
        QemuEvent::Link(LinkEvent::Message(Uplink::Boot(_))) if !sent => {
            sent = true;
            for c in commands {
                down.send(*c).expect("send a command");
            }
        }
        QemuEvent::Log(l) => logs.push(l.message.clone()),
        _ => {}
    };
    let out = HeadRun::qemu(&sc, &subnav_tests::qemu_elf())
        .on_head(head)
        .keep_all()
        .run_ms(run_ms)
        .board_args(extra.iter().map(|s| s.to_string()))
        .timeout(Duration::from_secs(600))
        .qemu_events(&mut hook)
        .run()
        .expect("QEMU run");
    assert_eq!(out.exit_code, Some(0), "the head must run to the end\n{}", logs.join("\n"));
    (out.messages, logs)
}

#[test]
fn a_hung_board_loop_is_reset_by_the_watchdog_and_navigates_again_on_its_stored_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let flash = dir.path().join("head.flash");

    // Store a non-default configuration (20 Hz navigation) on a new head.
    let (first, _) = run(&flash, 1_500, &[], &[Command::SetConfig(ConfigItem::NavRateHz(20))]);
    assert!(first.iter().any(|m| matches!(m, Uplink::Ack(a) if a.seq == 1 && a.result.is_ok())));

    // Power on, navigate, hang at 3 s; the watchdog resets the head, which runs 14 s more.
    let (msgs, logs) = run(&flash, 14_000, &["hang_at_ms=3000"], &[]);
    let boots: Vec<(usize, Boot)> =
        msgs.iter().enumerate().filter_map(|(i, m)| if let Uplink::Boot(b) = m { Some((i, *b)) } else { None }).collect();
    assert_eq!(boots.len(), 2, "one power-on and one watchdog boot: {boots:?}");
    let (power_on, watchdog) = (boots[0].1, boots[1].1);
    assert_eq!(power_on.reset_cause, ResetCause::PowerOn);
    assert_eq!(watchdog.reset_cause, ResetCause::Watchdog);
    for b in [power_on, watchdog] {
        assert_eq!(b.calibration.store, StoreStatus::Ok, "{b:?}");
        assert!(b.calibration.config_stored, "{b:?}");
    }
    assert!(logs.iter().any(|l| l.contains("hang_at_ms self-test")), "the hang was logged");

    let navs = |from: usize, to: usize| -> Vec<subnav_wire::NavSolution> {
        msgs[from..to].iter().filter_map(|m| if let Uplink::Nav(n) = m { Some(*n) } else { None }).collect()
    };
    // Before the hang: 20 Hz up to 3 s, nothing after (the loop stopped).
    let before = navs(0, boots[1].0);
    let last = before.last().expect("navigation before the hang").t_us;
    assert!((2_950_000..=3_000_000).contains(&last), "last solution before the hang at {last} us");
    // After the reset: the stored 20 Hz, aligned again and aided, nothing NaN.
    let after = navs(boots[1].0, msgs.len());
    assert!(after.windows(2).all(|w| w[1].t_us - w[0].t_us == 50_000), "the stored 20 Hz after the reset");
    assert_eq!(after.len(), 281, "20 Hz for 14 s, both ends");
    assert!(after.iter().any(|n| n.mode == NavMode::Aligning));
    let end = after.last().unwrap();
    assert_eq!(end.mode, NavMode::Aided, "navigating again: {end:?}");
    assert!(
        after.iter().all(|n| n.pos_ned_m.iter().chain(&n.vel_ned_mps).chain(&n.att_nb_wxyz).chain(&n.sigma_pos_m).all(|v| !v.is_nan())),
        "no NaN after the reset"
    );
    assert!(after.iter().filter(|n| n.mode == NavMode::Aided).all(|n| n.sigma_pos_m.iter().all(|s| s.is_finite())));
}

#[test]
fn a_reboot_command_is_reported_as_a_software_reset() {
    let dir = tempfile::tempdir().unwrap();
    let (msgs, _) = run(&dir.path().join("head.flash"), 2_000, &[], &[Command::Reboot]);
    let causes: Vec<ResetCause> = msgs.iter().filter_map(|m| if let Uplink::Boot(b) = m { Some(b.reset_cause) } else { None }).collect();
    assert_eq!(causes, vec![ResetCause::PowerOn, ResetCause::Software]);
    assert!(msgs.iter().any(|m| matches!(m, Uplink::Ack(a) if a.seq == 1 && a.result.is_ok())), "the reboot was acknowledged first");
}
