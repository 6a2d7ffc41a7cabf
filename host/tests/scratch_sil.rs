use nalgebra::{Quaternion, UnitQuaternion};
use subnav_host::sim::Scenario;
use subnav_host::sim::dive::evaluate;
use subnav_host::sim::sil::run_native;
use subnav_shared::wire::Uplink;

#[test]
fn scratch() {
    let seed: u64 = std::env::var("SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let dur: f64 = std::env::var("DUR").ok().and_then(|s| s.parse().ok()).unwrap_or(60.0);
    let sc = Scenario { duration_s: dur, seed, ..Scenario::default() };
    let t0 = std::time::Instant::now();
    let run = run_native(&sc);
    eprintln!("native {:.1} s", t0.elapsed().as_secs_f64());
    let traj = sc.trajectory();
    let mut k = 0;
    for m in &run.messages {
        match m {
            Uplink::Nav(n) if k % 20 == 0 || n.t_us < 13_000_000 && k % 2 == 0 => {
                let [w, x, y, z] = n.att_nb_wxyz.map(f64::from);
                let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
                let tr = traj.at(n.t_us as f64 * 1e-6);
                eprintln!(
                    "t {:6.1} mode {:?} yaw {:7.2} true {:7.2} sig {:6.2} pos {:?} true {:?}",
                    n.t_us as f64 * 1e-6,
                    n.mode,
                    q.euler_angles().2.to_degrees(),
                    tr.yaw_rad.to_degrees(),
                    n.sigma_att_rad[2].to_degrees(),
                    n.pos_ned_m,
                    tr.pos_ned_m.as_slice()
                );
                k += 1;
            }
            Uplink::Nav(_) => k += 1,
            Uplink::Compass(c) if c.t_us < 13_000_000 || c.t_us % 10_000_000 == 0 => {
                let tr = traj.at(c.t_us as f64 * 1e-6);
                eprintln!(
                    "  compass t {:.1} {:?} true {:.2}",
                    c.t_us as f64 * 1e-6,
                    c.heading_rad.map(|h| h.to_degrees()),
                    tr.yaw_rad.to_degrees()
                );
            }
            Uplink::Health(h) if h.t_us % 10_000_000 == 0 => eprintln!("  health {:?}", h),
            _ => {}
        }
    }
    let r = evaluate(&sc, &run.messages, Some(0), run.corrupt_frames, run.bus_transactions);
    eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
}
