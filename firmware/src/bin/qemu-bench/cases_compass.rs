//! Target benchmark cases of the ephemeris and the polarization compass (issue 3).
//! Call `b.run("area.name", iterations, || work)`; keep iterations x instructions < 300 M.

use crate::Bench;

pub fn run(_b: &mut Bench) {}
