//! Peer check of `subnav_topo::polar_image` (demosaicing + Stokes) against polanalyser (PyPI,
//! OpenCV bilinear demosaicing) on the same 16-bit IMX250MZR mosaic PNG: a smoothly varying
//! synthetic field (known AoP/DoLP) and a rendered seafloor scene. Interior pixels (2-pixel
//! border excluded: the two implementations pad the border differently) must agree to within
//! the 16-bit rounding OpenCV applies to its demosaiced channels.

use std::f64::consts::PI;
use std::process::Command;

use serde_json::Value;
use subnav_topo::polar_image::mosaic::mosaic_from_stokes;
use subnav_topo::polar_image::{Mosaic, demosaic, stokes};

fn peer(path: &std::path::Path) -> Value {
    let python = subnav_tests::peer_python();
    let out = Command::new(&python)
        .arg(subnav_tests::peers_dir().join("polanalyser_stokes.py"))
        .arg(path)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python.display()));
    assert!(out.status.success(), "polanalyser failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("peer JSON")
}

fn compare(m: &Mosaic, name: &str) {
    let dir = tempfile_dir();
    let p = dir.join(format!("{name}.png"));
    m.write_png(&p).expect("write png");
    // Compare with what was written (16-bit quantized), read back through our reader.
    let back = Mosaic::read_png(&p).expect("read png");
    let st = stokes(&demosaic(&back));
    let v = peer(&p);
    let (w, h) = (v["width"].as_u64().unwrap() as usize, v["height"].as_u64().unwrap() as usize);
    assert_eq!((w, h), (st.s0.width, st.s0.height));
    let get = |k: &str| -> Vec<f64> { v[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect() };
    let (s0, s1, s2, dolp, aolp) = (get("s0"), get("s1"), get("s2"), get("dolp"), get("aolp"));
    let (mut e_s, mut e_dolp, mut e_aop) = (0.0f64, 0.0f64, 0.0f64);
    for r in 2..h - 2 {
        for c in 2..w - 2 {
            let k = r * w + c;
            e_s = e_s.max((st.s0.data[k] - s0[k]).abs()).max((st.s1.data[k] - s1[k]).abs()).max((st.s2.data[k] - s2[k]).abs());
            e_dolp = e_dolp.max((st.dolp.data[k] - dolp[k]).abs());
            if dolp[k] > 0.05 {
                let mut d = (st.aop_rad.data[k] - aolp[k]).rem_euclid(PI);
                if d > PI / 2.0 {
                    d = PI - d;
                }
                e_aop = e_aop.max(d);
            }
        }
    }
    println!("{name}: max |dS| {e_s:.2e}, max |dDoLP| {e_dolp:.2e}, max |dAoP| {:.3} deg", e_aop.to_degrees());
    // OpenCV rounds each demosaiced channel to a 16-bit count: |dI| <= 0.5 / 65535 per channel.
    assert!(e_s < 4.0 / 65535.0, "{name}: Stokes differ by {e_s}");
    assert!(e_dolp < 1e-3, "{name}: DoLP differs by {e_dolp}");
    assert!(e_aop.to_degrees() < 0.1, "{name}: AoP differs by {} deg", e_aop.to_degrees());
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("subnav-peer-polanalyser-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

#[test]
fn synthetic_field_matches_polanalyser() {
    let m = mosaic_from_stokes(64, 48, 16, |r, c| {
        let s0 = 0.6 + 0.1 * (r as f64 / 13.0).sin();
        let dolp = 0.2 + 0.5 * c as f64 / 64.0;
        let aop = -1.2 + 2.4 * r as f64 / 48.0;
        [s0, s0 * dolp * (2.0 * aop).cos(), s0 * dolp * (2.0 * aop).sin()]
    });
    compare(&m, "synthetic");
}

#[test]
fn rendered_seafloor_matches_polanalyser() {
    use subnav_core::ukf::nalgebra::Vector3;
    use subnav_topo::scene::{Scene, SceneConfig, coastal_water};
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
    let (el, az) = (50f64.to_radians(), 150f64.to_radians());
    let sun = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), -el.sin());
    let scene = Scene::new(SceneConfig { size_px: 64, ..SceneConfig::default() }, coastal_water(), sun, 10.0, &mut rng);
    compare(&scene.render(12.0, 3.0, 0.7, &mut rng), "seafloor");
}
