//! Linear Stokes images from the four polarizer channels.

use super::Plane;
use super::mosaic::PolarChannels;

/// S0, S1, S2, DoLP (0..1, 0 where S0 <= 0) and AoP (rad, (-pi/2, pi/2], from the image x axis).
#[derive(Debug, Clone, PartialEq)]
pub struct StokesImage {
    pub s0: Plane,
    pub s1: Plane,
    pub s2: Plane,
    pub dolp: Plane,
    pub aop_rad: Plane,
}

pub fn stokes(ch: &PolarChannels) -> StokesImage {
    let (w, h) = (ch.i0.width, ch.i0.height);
    let mut out =
        StokesImage { s0: Plane::new(w, h), s1: Plane::new(w, h), s2: Plane::new(w, h), dolp: Plane::new(w, h), aop_rad: Plane::new(w, h) };
    for k in 0..w * h {
        let (a, b, c, d) = (ch.i0.data[k], ch.i45.data[k], ch.i90.data[k], ch.i135.data[k]);
        let s0 = 0.5 * (a + b + c + d);
        let s1 = a - c;
        let s2 = b - d;
        out.s0.data[k] = s0;
        out.s1.data[k] = s1;
        out.s2.data[k] = s2;
        out.dolp.data[k] = if s0 > 0.0 { ((s1 * s1 + s2 * s2).sqrt() / s0).min(1.0) } else { 0.0 };
        out.aop_rad.data[k] = 0.5 * s2.atan2(s1);
    }
    out
}
