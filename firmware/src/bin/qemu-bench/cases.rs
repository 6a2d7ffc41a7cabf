//! Benchmark cases. Each area adds a function here and calls it from `run_all`.
//! Inputs go through `core::hint::black_box` so the compiler cannot fold the work away.

use core::hint::black_box;

use subnav_wire::{self as wire, MAX_UPLINK_FRAME, NavMode, NavSolution, Uplink};

use crate::Bench;

#[path = "cases_compass.rs"]
mod compass;
#[path = "cases_nav.rs"]
mod nav;

pub fn run_all(b: &mut Bench) {
    wire_cases(b);
    compass::run(b);
    nav::run(b);
}

fn wire_cases(b: &mut Bench) {
    let nav = Uplink::Nav(NavSolution {
        t_us: 123_456_789,
        mode: NavMode::Aided,
        pos_ned_m: [12.5, -3.25, 30.0],
        vel_ned_mps: [1.0, 0.1, 0.0],
        att_nb_wxyz: [0.99, 0.01, 0.02, 0.1],
        sigma_pos_m: [0.5; 3],
        sigma_vel_mps: [0.05; 3],
        sigma_att_rad: [0.01; 3],
        cov_ne_m2: 0.0,
    });
    let mut buf = [0u8; MAX_UPLINK_FRAME];
    b.run("wire.encode_nav_frame", 1000, || wire::encode(black_box(&nav), &mut buf).map(|f| f.len()).unwrap_or(0));
}
