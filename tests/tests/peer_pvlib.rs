//! Peer check of the MCU ephemeris (`subnav_core::ephemeris`, f32 + fixed-point phases) against
//! pvlib 0.16.1 `spa_python` (the full NREL SPA in f64) on 10,000 random instants 2020-2100,
//! latitudes within +-70 deg, random longitude, height, pressure and temperature.
//! All instants go to one python call (`tests/peers/pvlib_spa.py`).

use std::io::Write;
use std::process::{Command, Stdio};

use subnav_core::ephemeris::{Atmosphere, Observer, delta_t_estimate_s, sun_position};

const N: usize = 10_000;
/// 2020-01-01T00:00:00Z and 2100-01-01T00:00:00Z, POSIX µs.
const T0_US: i64 = 1_577_836_800_000_000;
const T1_US: i64 = 4_102_444_800_000_000;
/// The bound for the MCU path, degrees.
const MAX_ERR_DEG: f64 = 0.003;

/// splitmix64: a fixed, dependency-free random sequence.
struct Rng(u64);
impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

struct Case {
    unix_us: i64,
    lat_deg: f64,
    lon_deg: f64,
    height_m: f64,
    pressure_hpa: f64,
    temp_c: f64,
    delta_t_s: f32,
}

fn cases() -> Vec<Case> {
    let mut rng = Rng(0x5EED_2020_2100);
    (0..N)
        .map(|_| {
            let unix_us = T0_US + (rng.next_u64() % (T1_US - T0_US) as u64) as i64;
            Case {
                unix_us,
                lat_deg: rng.uniform(-70.0, 70.0),
                lon_deg: rng.uniform(-180.0, 180.0),
                height_m: rng.uniform(0.0, 3000.0).round(),
                pressure_hpa: rng.uniform(700.0, 1050.0).round(),
                temp_c: rng.uniform(-20.0, 35.0).round(),
                delta_t_s: delta_t_estimate_s(unix_us),
            }
        })
        .collect()
}

fn run_pvlib(cases: &[Case]) -> Vec<[f64; 3]> {
    let python = subnav_tests::peer_python();
    let script = subnav_tests::peers_dir().join("pvlib_spa.py");
    let mut child = Command::new(&python)
        .arg(&script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python.display()));
    let mut input = String::new();
    for c in cases {
        // f32 inputs are what the MCU path sees; give pvlib exactly the same values.
        input += &format!(
            "{},{},{},{},{},{},{}\n",
            c.unix_us, c.lat_deg as f32, c.lon_deg as f32, c.height_m, c.pressure_hpa, c.temp_c, c.delta_t_s
        );
    }
    let mut stdin = child.stdin.take().expect("stdin piped");
    let writer = std::thread::spawn(move || stdin.write_all(input.as_bytes()));
    let out = child.wait_with_output().expect("pvlib peer runs");
    writer.join().expect("writer thread").expect("write to peer");
    assert!(out.status.success(), "pvlib peer failed: {:?}", out.status);
    let text = String::from_utf8(out.stdout).expect("utf-8");
    let rows: Vec<[f64; 3]> = text
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().expect("number")).collect();
            [v[0], v[1], v[2]]
        })
        .collect();
    assert_eq!(rows.len(), cases.len(), "peer returned {} rows", rows.len());
    rows
}

#[test]
fn ephemeris_matches_pvlib_spa_python() {
    let cases = cases();
    let peer = run_pvlib(&cases);
    let deg = std::f64::consts::PI / 180.0;
    let (mut max_zen, mut max_app, mut max_az, mut max_az_arc) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut worst_az = (0.0, 0.0);
    for (c, p) in cases.iter().zip(&peer) {
        let obs = Observer {
            lat_rad: (c.lat_deg as f32 as f64 * deg) as f32,
            lon_rad: (c.lon_deg as f32 as f64 * deg) as f32,
            height_m: c.height_m as f32,
        };
        let atm = Atmosphere { pressure_hpa: c.pressure_hpa as f32, temp_c: c.temp_c as f32 };
        let s = sun_position(c.unix_us, &obs, Some(&atm), c.delta_t_s).expect("valid input");
        let app = s.apparent_zenith_rad as f64 / deg;
        let zen = s.zenith_rad as f64 / deg;
        let az = s.azimuth_rad as f64 / deg;
        let d_app = (app - p[0]).abs();
        let d_zen = (zen - p[1]).abs();
        let d_az = subnav_base::wrap_deg(az - p[2]).abs();
        max_app = max_app.max(d_app);
        max_zen = max_zen.max(d_zen);
        if d_az > max_az {
            max_az = d_az;
            worst_az = (p[1], c.lat_deg);
        }
        // Azimuth error as an arc on the sky (it diverges as 1/sin(zenith) near the zenith).
        max_az_arc = max_az_arc.max(d_az * (p[1] * deg).sin());
    }
    eprintln!(
        "ephemeris vs pvlib spa_python, {N} instants 2020-2100, |lat| <= 70 deg: max |d zenith| = {max_zen:.5} deg, \
         max |d apparent zenith| = {max_app:.5} deg, max |d azimuth| = {max_az:.5} deg (at zenith {:.3} deg, lat {:.2}), \
         max |d azimuth| * sin(zenith) = {max_az_arc:.5} deg",
        worst_az.0, worst_az.1
    );
    assert!(max_zen <= MAX_ERR_DEG, "zenith error {max_zen} deg");
    assert!(max_app <= MAX_ERR_DEG, "apparent zenith error {max_app} deg");
    assert!(max_az <= MAX_ERR_DEG, "azimuth error {max_az} deg");
}
