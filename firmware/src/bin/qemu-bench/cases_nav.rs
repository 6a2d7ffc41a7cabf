//! Target benchmark cases of the UKF and the navigation filter (issue 4).
//! Call `b.run("area.name", iterations, || work)`; keep iterations x instructions < 300 M.

use crate::Bench;

pub fn run(_b: &mut Bench) {}
