//! Demosaicing and Stokes images on synthetic IMX250MZR mosaics with known AoP/DoLP (analytic).

use std::f64::consts::PI;

use subnav_topo::polar_image::mosaic::{angle_deg, mosaic_from_stokes};
use subnav_topo::polar_image::{Mosaic, demosaic, features, stokes};

fn wrap_half_pi(a: f64) -> f64 {
    let mut x = a % PI;
    if x > PI / 2.0 {
        x -= PI;
    } else if x <= -PI / 2.0 {
        x += PI;
    }
    x
}

/// A field with AoP and DoLP varying smoothly in space: the truth at pixel (r, c).
fn truth(r: usize, c: usize) -> (f64, f64, f64) {
    let s0 = 0.6 + 0.1 * (r as f64 / 13.0).sin();
    let dolp = 0.2 + 0.5 * c as f64 / 64.0;
    let aop = wrap_half_pi(-1.2 + 2.4 * r as f64 / 64.0 + 0.01 * c as f64);
    (s0, dolp, aop)
}

fn to_stokes(s0: f64, dolp: f64, aop: f64) -> [f64; 3] {
    [s0, s0 * dolp * (2.0 * aop).cos(), s0 * dolp * (2.0 * aop).sin()]
}

#[test]
fn layout_is_imx250mzr() {
    assert_eq!([angle_deg(0, 0), angle_deg(0, 1), angle_deg(1, 0), angle_deg(1, 1)], [90, 45, 135, 0]);
    assert_eq!(angle_deg(2, 3), 45);
}

#[test]
fn uniform_polarization_is_recovered_exactly() {
    for &(dolp, aop) in &[(0.0, 0.0), (0.3, 0.4), (0.9, -1.2), (1.0, PI / 2.0 - 1e-9)] {
        let m = mosaic_from_stokes(16, 12, 16, |_, _| to_stokes(0.5, dolp, aop));
        let st = stokes(&demosaic(&m));
        for k in 0..st.s0.data.len() {
            assert!((st.s0.data[k] - 0.5).abs() < 1e-12);
            assert!((st.dolp.data[k] - dolp).abs() < 1e-9, "dolp {} vs {dolp}", st.dolp.data[k]);
            if dolp > 0.0 {
                assert!(wrap_half_pi(st.aop_rad.data[k] - aop).abs() < 1e-9, "aop {} vs {aop}", st.aop_rad.data[k]);
            }
        }
    }
}

#[test]
fn smooth_field_is_recovered_in_the_interior() {
    let m = mosaic_from_stokes(64, 64, 16, |r, c| {
        let (s0, d, a) = truth(r, c);
        to_stokes(s0, d, a)
    });
    let st = stokes(&demosaic(&m));
    let (mut max_aop, mut max_dolp) = (0.0f64, 0.0f64);
    for r in 2..62 {
        for c in 2..62 {
            let (_, d, a) = truth(r, c);
            max_aop = max_aop.max(wrap_half_pi(st.aop_rad.at(r, c) - a).abs());
            max_dolp = max_dolp.max((st.dolp.at(r, c) - d).abs());
        }
    }
    // Bilinear interpolation of a field changing by 2.4 rad over 64 px: the error is second order.
    assert!(max_aop.to_degrees() < 1.0, "AoP error {} deg", max_aop.to_degrees());
    assert!(max_dolp < 0.02, "DoLP error {max_dolp}");
}

#[test]
fn png_round_trip_8_and_16_bit_and_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    for bits in [8u8, 16] {
        let m = mosaic_from_stokes(32, 32, bits, |r, c| {
            let (s0, d, a) = truth(r, c);
            to_stokes(s0, d, a)
        });
        let p = dir.path().join(format!("m{bits}.png"));
        m.write_png(&p).unwrap();
        let back = Mosaic::read_png(&p).unwrap();
        assert_eq!(back.bit_depth, bits);
        let q = if bits == 8 { 0.5 / 255.0 } else { 0.5 / 65535.0 };
        for (a, b) in back.plane.data.iter().zip(&m.plane.data) {
            assert!((a - b).abs() <= q + 1e-12);
        }
        let f = features(&stokes(&demosaic(&back)));
        assert!(f.iter().all(|v| v.is_finite()));
    }
    // Not a PNG, odd size, colour PNG: errors, no panic.
    let bad = dir.path().join("bad.png");
    std::fs::write(&bad, b"not a png").unwrap();
    assert!(Mosaic::read_png(&bad).is_err());
    let odd = mosaic_from_stokes(5, 4, 8, |_, _| [0.5, 0.0, 0.0]);
    odd.write_png(&bad).unwrap();
    assert!(format!("{:#}", Mosaic::read_png(&bad).unwrap_err()).contains("even"));
    let mut enc = png::Encoder::new(std::fs::File::create(&bad).unwrap(), 4, 4);
    enc.set_color(png::ColorType::Rgb);
    enc.write_header().unwrap().write_image_data(&[0u8; 48]).unwrap();
    assert!(format!("{:#}", Mosaic::read_png(&bad).unwrap_err()).contains("grayscale"));
    assert!(Mosaic::read_png(&dir.path().join("missing.png")).is_err());
}
