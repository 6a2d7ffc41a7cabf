//! The IMX250MZR polarizer mosaic: layout, PNG I/O and bilinear demosaicing.

use std::io::{BufReader, BufWriter};
use std::path::Path;

use anyhow::{Context, Result, bail};

use super::Plane;

/// Polarizer angle (deg) of the pixel at (row, col): the 2x2 cell is `90 45 / 135 0`.
pub fn angle_deg(row: usize, col: usize) -> u32 {
    match (row % 2, col % 2) {
        (0, 0) => 90,
        (0, _) => 45,
        (_, 0) => 135,
        _ => 0,
    }
}

/// (row, col) offset of a channel's samples in the 2x2 cell.
fn offset(angle_deg: u32) -> (usize, usize) {
    match angle_deg {
        90 => (0, 0),
        45 => (0, 1),
        135 => (1, 0),
        _ => (1, 1),
    }
}

/// A raw mosaic, intensities normalised to [0, 1] (counts / full scale).
#[derive(Debug, Clone, PartialEq)]
pub struct Mosaic {
    pub plane: Plane,
    /// Bits per sample of the source (8 or 16).
    pub bit_depth: u8,
}

impl Mosaic {
    /// Read an 8- or 16-bit grayscale PNG. Width and height must be even and at least 4.
    pub fn read_png(path: &Path) -> Result<Self> {
        let f = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
        Self::decode_png(BufReader::new(f)).with_context(|| format!("{}", path.display()))
    }

    pub fn decode_png<R: std::io::Read>(r: R) -> Result<Self> {
        let mut dec = png::Decoder::new(r);
        dec.set_transformations(png::Transformations::IDENTITY);
        let mut reader = dec.read_info().context("not a PNG")?;
        let (w, h) = (reader.info().width, reader.info().height);
        subnav_base::limits::check_image_size("the PNG", w, h).map_err(anyhow::Error::msg)?;
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).context("PNG image data")?;
        if info.color_type != png::ColorType::Grayscale {
            bail!("a polarization mosaic must be a grayscale PNG, this one is {:?}", info.color_type);
        }
        let (w, h) = (info.width as usize, info.height as usize);
        if w < 4 || h < 4 || w % 2 != 0 || h % 2 != 0 {
            bail!("mosaic size {w}x{h}: width and height must be even and >= 4 (2x2 polarizer cells)");
        }
        let mut plane = Plane::new(w, h);
        let bit_depth = match info.bit_depth {
            png::BitDepth::Eight => {
                for (o, &b) in plane.data.iter_mut().zip(&buf[..w * h]) {
                    *o = b as f64 / 255.0;
                }
                8
            }
            png::BitDepth::Sixteen => {
                for (o, c) in plane.data.iter_mut().zip(buf[..w * h * 2].chunks_exact(2)) {
                    *o = u16::from_be_bytes([c[0], c[1]]) as f64 / 65535.0;
                }
                16
            }
            d => bail!("bit depth {d:?}: only 8- and 16-bit mosaics are supported"),
        };
        Ok(Mosaic { plane, bit_depth })
    }

    /// Write as a grayscale PNG of `bit_depth` (8 or 16) bits; values are clipped to [0, 1].
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut enc = png::Encoder::new(BufWriter::new(f), self.plane.width as u32, self.plane.height as u32);
        enc.set_color(png::ColorType::Grayscale);
        let data: Vec<u8> = if self.bit_depth == 8 {
            enc.set_depth(png::BitDepth::Eight);
            self.plane.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect()
        } else {
            enc.set_depth(png::BitDepth::Sixteen);
            self.plane.data.iter().flat_map(|v| ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_be_bytes()).collect()
        };
        let mut w = enc.write_header()?;
        w.write_image_data(&data)?;
        w.finish()?;
        Ok(())
    }
}

/// The four full-resolution channel images.
#[derive(Debug, Clone, PartialEq)]
pub struct PolarChannels {
    pub i0: Plane,
    pub i45: Plane,
    pub i90: Plane,
    pub i135: Plane,
}

/// Bilinear interpolation of one channel's quarter grid to full resolution.
fn demosaic_channel(m: &Plane, angle: u32) -> Plane {
    let (r0, c0) = offset(angle);
    let (nr, nc) = (m.height / 2, m.width / 2);
    // Sample (i, j) of the channel grid sits at pixel (r0 + 2i, c0 + 2j).
    let sample = |i: usize, j: usize| m.at(r0 + 2 * i, c0 + 2 * j);
    // For a pixel coordinate p and grid offset p0: the two bracketing samples and the weight of the upper.
    let bracket = |p: usize, p0: usize, n: usize| -> (usize, usize, f64) {
        let u = (p as f64 - p0 as f64) / 2.0;
        if u <= 0.0 {
            (0, 0, 0.0)
        } else if u >= (n - 1) as f64 {
            (n - 1, n - 1, 0.0)
        } else {
            let lo = u.floor() as usize;
            (lo, lo + 1, u - lo as f64)
        }
    };
    let mut out = Plane::new(m.width, m.height);
    for r in 0..m.height {
        let (i0, i1, wr) = bracket(r, r0, nr);
        for c in 0..m.width {
            let (j0, j1, wc) = bracket(c, c0, nc);
            let top = sample(i0, j0) * (1.0 - wc) + sample(i0, j1) * wc;
            let bot = sample(i1, j0) * (1.0 - wc) + sample(i1, j1) * wc;
            out.set(r, c, top * (1.0 - wr) + bot * wr);
        }
    }
    out
}

/// Demosaic a mosaic into its four polarizer channels.
pub fn demosaic(m: &Mosaic) -> PolarChannels {
    PolarChannels {
        i0: demosaic_channel(&m.plane, 0),
        i45: demosaic_channel(&m.plane, 45),
        i90: demosaic_channel(&m.plane, 90),
        i135: demosaic_channel(&m.plane, 135),
    }
}

/// Build a mosaic from per-pixel Stokes parameters `(S0, S1, S2)` (ideal polarizers):
/// `I_theta = (S0 + S1 cos 2 theta + S2 sin 2 theta) / 2`.
pub fn mosaic_from_stokes(width: usize, height: usize, bit_depth: u8, mut f: impl FnMut(usize, usize) -> [f64; 3]) -> Mosaic {
    let mut plane = Plane::new(width, height);
    for r in 0..height {
        for c in 0..width {
            let [s0, s1, s2] = f(r, c);
            let th = (angle_deg(r, c) as f64).to_radians();
            plane.set(r, c, 0.5 * (s0 + s1 * (2.0 * th).cos() + s2 * (2.0 * th).sin()));
        }
    }
    Mosaic { plane, bit_depth }
}
