//! Division-of-focal-plane polarization images (Sony IMX250MZR layout): mosaic I/O, demosaicing,
//! Stokes images (S0, S1, S2, DoLP, AoP) and the per-image feature vector used for scene
//! recognition (spec A3).
//!
//! - [`mosaic`]: the 2x2 polarizer cell (`90 45 / 135 0` deg, angles from the image x axis,
//!   i.e. along a row), 8/16-bit grayscale PNG read/write (the `png` crate), and per-channel
//!   bilinear demosaicing: each of the four quarter-resolution channel grids is interpolated to
//!   full resolution from its 2 or 4 nearest samples (the border repeats the edge sample). This
//!   is the method of OpenCV's bilinear Bayer demosaicing that polanalyser applies to the
//!   polarization mosaic, checked against it in `tests/tests/peer_polanalyser.rs`.
//! - [`stokes`]: `S0 = (I0 + I45 + I90 + I135) / 2`, `S1 = I0 - I90`, `S2 = I45 - I135`,
//!   `DoLP = sqrt(S1^2 + S2^2) / S0`, `AoP = atan2(S2, S1) / 2` in (-pi/2, pi/2].
//! - [`features`]: the feature vector (see its doc for the list and the reasons).
//!
//! Written here: there is no maintained Rust crate for polarization mosaics; the `png` crate does
//! the file format.

pub mod features;
pub mod mosaic;
pub mod stokes;

pub use features::{FEATURE_NAMES, N_FEATURES, features};
pub use mosaic::{Mosaic, PolarChannels, demosaic};
pub use stokes::{StokesImage, stokes};

/// A single-channel image, row-major, `f64` values.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f64>,
}

impl Plane {
    pub fn new(width: usize, height: usize) -> Self {
        Plane { width, height, data: vec![0.0; width * height] }
    }

    #[inline]
    pub fn at(&self, row: usize, col: usize) -> f64 {
        self.data[row * self.width + col]
    }

    #[inline]
    pub fn set(&mut self, row: usize, col: usize, v: f64) {
        self.data[row * self.width + col] = v;
    }
}
