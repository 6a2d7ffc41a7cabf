//! The map in the loop, natively: camera triggers from the firmware, frames stamped with the
//! head's time, the mapper fed by the firmware's own solution, fixes back over the downlink.

use subnav_sil::Scenario;
use subnav_sil::run::HeadRun;
use subnav_wire::Uplink;

#[test]
fn camera_frames_follow_the_heads_triggers() {
    let mut sc = Scenario::map_survey(1);
    sc.duration_s = 120.0;
    let t0 = std::time::Instant::now();
    let run = HeadRun::native(&sc).keep_all().run().unwrap();
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

/// The main job (natively): nodes placed from the firmware's solution, loops recognised from
/// ~470 s on (block 2 flies across block 1), the fixes the map sends fused by the head, and the
/// dive within the bounds. (Most recognitions send no fix: with the DVL the head's
/// drift since a node was placed is small, and the fix only carries that drift's information.)
#[test]
fn closed_loop_dive_recognises_its_own_track_within_bounds() {
    let sc = Scenario::map_survey(1);
    let r = HeadRun::native(&sc).run().unwrap().score(&sc).unwrap();
    let m = r.map.as_ref().expect("camera");
    let s = &m.mapper;
    eprintln!(
        "max {:.2} m rms {:.2} m within {:.3}; nodes {} recognitions {} precision {:?} recall {:?} fixes {}/{} refused {}",
        r.score.horizontal_max_err_m,
        r.score.horizontal_rms_err_m,
        r.score.within_3_sigma,
        s.nodes,
        s.recognitions,
        m.score.precision,
        m.score.recall,
        m.fixes_accepted,
        m.fixes_sent,
        m.fixes_refused
    );
    assert_eq!(r.nonfinite_values, 0);
    assert!(r.score.horizontal_max_err_m <= 3.0, "max horizontal error {} m", r.score.horizontal_max_err_m);
    assert!(r.score.within_3_sigma >= 0.95, "within 3 sigma {}", r.score.within_3_sigma);
    // 1,700 m at a node per 6 m without a recognition; later blocks recognise earlier nodes.
    assert!(s.nodes >= 120, "{} nodes", s.nodes);
    assert!(s.trained);
    assert!(s.recognitions >= 100, "{} recognitions", s.recognitions);
    assert!(m.fixes_accepted >= 3, "{} fixes accepted", m.fixes_accepted);
    assert_eq!(m.fixes_refused, 0);
    assert!(m.score.precision.is_some_and(|p| p >= 0.85), "precision {:?}", m.score.precision);
    assert!(m.score.recall.is_some_and(|p| p >= 0.2), "recall {:?}", m.score.recall);
    // Every fix the head answered is one the map sent; none is refused for its time.
    assert_eq!(m.fixes_accepted + m.fixes_refused, m.fixes_sent);
    assert_eq!(m.fix_results.len() as u64, m.fixes_sent);
    assert_eq!(m.nav_wait_timeouts, 0);
    assert_eq!(m.captures_without_trigger, 0);
}

/// Bad camera input in the loop: out-of-order, duplicated and missing frames are counted, a
/// minute of dark frames does not stop the map (nodes and recognitions resume after it), and
/// images of places 40 m away are refused by the position gate.
#[test]
fn camera_faults_are_counted_and_far_images_refused() {
    let mut sc = Scenario::map_survey(2);
    sc.duration_s = 900.0;
    if let Some(c) = sc.camera.as_mut() {
        c.blackout_s = Some((300.0, 360.0));
        c.drop_probability = 0.02;
        c.duplicate_probability = 0.02;
        c.reorder_probability = 0.02;
        c.far_image_probability = 0.05;
    }
    let r = HeadRun::native(&sc).run().unwrap().score(&sc).unwrap();
    let m = r.map.as_ref().expect("camera");
    let s = &m.mapper;
    eprintln!("{s:?}");
    assert_eq!(r.nonfinite_values, 0);
    assert!(s.frames_duplicated > 5 && s.frames_out_of_order > 5 && s.frames_missing > 5, "{s:?}");
    // 60 s of dark frames at 2 Hz (plus the descent's).
    assert!(s.frames_without_features >= 110, "{} dark frames", s.frames_without_features);
    assert!(m.closures.iter().any(|c| c.t_us > 400_000_000) || s.recognitions > 0, "no recognition after the blackout");
    assert!(m.nodes.iter().any(|n| n.created_t_us > 360_000_000 && n.created_t_us < 420_000_000), "no node right after the blackout");
    // About 5 % of ~1,700 frames show a far place; the gate refuses those that look like a node.
    assert!(s.gate_refusals > 0);
    // Precision in this faulted 15-minute survey (35-53 recognitions) spreads with the seed:
    // 0.76-0.92 over seeds 1-7 with the head's eight units (2026-12-06; seed 2: 0.80), so the
    // bound is below that spread; were the gate to let the far images through (5 % of the
    // frames, tens of appearance matches), it would fall towards 0.5.
    assert!(m.score.precision.is_none_or(|p| p >= 0.7), "precision {:?}", m.score.precision);
    assert!(
        r.score.horizontal_max_err_m <= 3.0 && r.score.within_3_sigma >= 0.95,
        "max {} within {}",
        r.score.horizontal_max_err_m,
        r.score.within_3_sigma
    );
}
