//! Air-water interface: refractive index of seawater and Snell's law for the solar zenith.

/// Refractive index of seawater, Quan & Fry (1995), Appl. Opt. 34(18) 3477, empirical fit of the
/// Austin & Halikas data: `temp_c` 0-30 C, `salinity_psu` 0-35, `wavelength_nm` 400-700 nm.
pub fn seawater_index(temp_c: f32, salinity_psu: f32, wavelength_nm: f32) -> f32 {
    let (t, s, l) = (temp_c, salinity_psu, wavelength_nm);
    1.314_05 + (1.779e-4 - 1.05e-6 * t + 1.6e-8 * t * t) * s - 2.02e-6 * t * t + (15.868 + 0.011_55 * s - 0.004_23 * t) / l
        - 4_382.0 / (l * l)
        + 1.145_5e6 / (l * l * l)
}

/// Default index: 15 C, 35 PSU, 500 nm (blue-green, where clear water transmits best).
pub fn default_index() -> f32 {
    seawater_index(15.0, 35.0, 500.0)
}

/// Refracted (in-water) zenith angle for an in-air zenith angle.
pub fn water_zenith_rad(air_zenith_rad: f32, n_water: f32) -> f32 {
    let x = (crate::ephemeris::phase::sincos_rad(air_zenith_rad).0 / n_water).clamp(-1.0, 1.0);
    libm::atan2f(x, libm::sqrtf(1.0 - x * x))
}

/// In-air zenith angle from the in-water one (inverse Snell). `None` when the in-water zenith is
/// outside the Snell window by more than `tolerance_rad` (no refracted sun can come from there);
/// inside the tolerance the result is clamped to the horizon.
pub fn air_zenith_rad(water_zenith_rad: f32, n_water: f32, tolerance_rad: f32) -> Option<f32> {
    let x = n_water * crate::ephemeris::phase::sincos_rad(water_zenith_rad).0;
    if !(x.is_finite() && water_zenith_rad >= 0.0) {
        return None;
    }
    if x <= 1.0 {
        // atan2 form: libm's asinf uses an f64 square root (software on the M4F) for x >= 0.5.
        return Some(libm::atan2f(x, libm::sqrtf(1.0 - x * x)));
    }
    // asin(1 / n) without libm's asinf (which uses an f64 square root).
    let critical = libm::atan2f(1.0, libm::sqrtf((n_water * n_water - 1.0).max(0.0)));
    if water_zenith_rad <= critical + tolerance_rad { Some(core::f32::consts::FRAC_PI_2) } else { None }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_is_seawater_like() {
        let n = seawater_index(20.0, 35.0, 550.0);
        assert!((n - 1.3408).abs() < 5e-4, "{n}");
        // Fresh water is lower, cold water higher.
        assert!(seawater_index(20.0, 0.0, 550.0) < n);
        assert!(seawater_index(2.0, 35.0, 550.0) > n);
    }

    #[test]
    fn snell_round_trip_and_window() {
        let n = 1.34;
        for deg in [0.0f32, 10.0, 30.0, 60.0, 89.0] {
            let za = deg.to_radians();
            let zw = water_zenith_rad(za, n);
            let back = air_zenith_rad(zw, n, 0.0).unwrap();
            assert!((back - za).abs() < 1e-4 * (1.0 + deg), "{deg}: {back}");
        }
        let critical = libm::asinf(1.0 / n);
        assert!((critical.to_degrees() - 48.27).abs() < 0.05);
        assert_eq!(air_zenith_rad(critical + 0.01, n, 0.02), Some(core::f32::consts::FRAC_PI_2));
        assert_eq!(air_zenith_rad(critical + 0.05, n, 0.02), None);
    }
}
