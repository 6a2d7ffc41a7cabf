//! The map in the loop, natively: camera triggers from the firmware, frames stamped with the
//! head's time, the mapper fed by the firmware's own solution, fixes back over the downlink.

use subnav_sil::Scenario;
use subnav_sil::sil::run_native;
use subnav_wire::Uplink;

#[test]
fn camera_frames_follow_the_heads_triggers() {
    let mut sc = Scenario::map_survey(1);
    sc.duration_s = 120.0;
    let t0 = std::time::Instant::now();
    let run = run_native(&sc, None);
    let triggers: Vec<_> = run.messages.iter().filter_map(|m| if let Uplink::Trigger(t) = m { Some(*t) } else { None }).collect();
    let map = run.map.expect("the scenario has a camera");
    eprintln!("{:?} wall; {} triggers; {:?}", t0.elapsed(), triggers.len(), map.mapper);
    // 2 Hz from boot, numbered from 0 without gaps.
    assert!((239..=241).contains(&triggers.len()), "{} triggers", triggers.len());
    assert!(triggers.iter().enumerate().all(|(k, t)| t.frame == k as u32 && t.t_us == k as u64 * 500_000));
    assert_eq!(map.captures, triggers.len() as u64);
    assert_eq!(map.captures_without_trigger, 0);
    assert_eq!(map.nav_wait_timeouts, 0);
}
