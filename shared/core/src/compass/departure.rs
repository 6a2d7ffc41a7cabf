//! The real field's AoP departure from the solver's single-scattering e-vector, as a table.
//!
//! Why: multiple scattering, the sky's own polarization and the particles' polarization turn
//! the real e-vector away from the single-scattering one (`d x s`, plus the Fresnel shift of
//! the refracted beam) by degrees with a low sun; the departure is mirror-symmetric about the
//! solar plane, so an even ring of units cancels part of it: without the table 4 units leave
//! a heading error of 1-2 deg with the sun 60 deg from the zenith, the head's 8 units 0.5-0.7
//! deg (docs/PERFORMANCE.md, "The compass in an independent light field"). Knowing the sun's zenith (ephemeris) and each unit's view, the
//! solver subtracts the expected departure before fitting the azimuth
//! ([`super::sun_vector::solve_azimuth`]).
//!
//! The table: the AoP departure (rad, the angle about the view direction from the model
//! e-vector to the real one, in [`super::sun_vector::rotate_back`]'s sense) at view zeniths
//! 65-80 deg by 5 (the head's units look 75 deg from the zenith, +-tilt) and relative azimuths
//! `A_sun - A_look` 0-180 deg by 15 (odd in the relative azimuth: the other half by mirror
//! symmetry), for the sun 30 and 60 deg from the zenith in air. The head's table
//! ([`OSOAA_CLEAR`]) is the mean over depth (5, 10, 20 m) and wind (0, 5 m/s) of OSOAA V2.0's
//! clear-water fields (host/base/data/OSOAA_PROVENANCE.md); the solver knows neither the depth
//! nor the wind nor the water. Between the suns: linear; a higher sun: scaled to 0 at the zenith
//! (where symmetry makes the AoP departure vanish); a lower sun: held at 60 deg's. Beyond the
//! view zeniths: held at the edge. f32: the table holds degrees-sized angles.

/// View zeniths (deg) and relative-azimuth step (deg) of a table.
pub const VIEW_ZENITHS_DEG: [f32; 4] = [65.0, 70.0, 75.0, 80.0];
pub const AZIMUTH_STEP_DEG: f32 = 15.0;
pub const AZIMUTHS: usize = 13;

/// An AoP departure table (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct AopDeparture {
    /// Sun zeniths in air (deg), ascending.
    pub sun_zenith_deg: [f32; 2],
    /// `aop_rad[sun][view zenith][relative azimuth]`.
    pub aop_rad: [[[f32; AZIMUTHS]; VIEW_ZENITHS_DEG.len()]; 2],
}

const DEG: f32 = core::f32::consts::PI / 180.0;

impl AopDeparture {
    /// The departure (rad) at a sun zenith in air, a view zenith and a relative azimuth
    /// `A_sun - A_look` (rad, any turn); 0 for non-finite input.
    pub fn at(&self, sun_zenith_rad: f32, view_zenith_rad: f32, rel_azimuth_rad: f32) -> f32 {
        if !(sun_zenith_rad.is_finite() && view_zenith_rad.is_finite() && rel_azimuth_rad.is_finite()) {
            return 0.0;
        }
        let mut phi = rel_azimuth_rad / DEG % 360.0;
        if phi < 0.0 {
            phi += 360.0;
        }
        let sign = if phi > 180.0 {
            phi = 360.0 - phi;
            -1.0
        } else {
            1.0
        };
        let nz = VIEW_ZENITHS_DEG.len();
        let z = ((view_zenith_rad / DEG - VIEW_ZENITHS_DEG[0]) / (VIEW_ZENITHS_DEG[1] - VIEW_ZENITHS_DEG[0])).clamp(0.0, (nz - 1) as f32);
        let a = (phi / AZIMUTH_STEP_DEG).clamp(0.0, (AZIMUTHS - 1) as f32);
        let (iz, ia) = ((z as usize).min(nz - 2), (a as usize).min(AZIMUTHS - 2));
        let (tz, ta) = (z - iz as f32, a - ia as f32);
        let grid = |g: &[[f32; AZIMUTHS]; VIEW_ZENITHS_DEG.len()]| -> f32 {
            let at = |iz: usize, ia: usize| g.get(iz).and_then(|r| r.get(ia)).copied().unwrap_or(0.0);
            let lo = at(iz, ia) * (1.0 - ta) + at(iz, ia + 1) * ta;
            let hi = at(iz + 1, ia) * (1.0 - ta) + at(iz + 1, ia + 1) * ta;
            lo * (1.0 - tz) + hi * tz
        };
        let [s0, s1] = self.sun_zenith_deg;
        let sz = sun_zenith_rad / DEG;
        let v = if sz <= s0 {
            grid(&self.aop_rad[0]) * (sz / s0).clamp(0.0, 1.0)
        } else if sz >= s1 {
            grid(&self.aop_rad[1])
        } else {
            let t = (sz - s0) / (s1 - s0);
            grid(&self.aop_rad[0]) * (1.0 - t) + grid(&self.aop_rad[1]) * t
        };
        sign * v
    }
}

pub use super::departure_table::OSOAA_CLEAR;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_symmetry_and_limits() {
        let mut t = AopDeparture { sun_zenith_deg: [30.0, 60.0], aop_rad: [[[0.0; AZIMUTHS]; 4]; 2] };
        t.aop_rad[0][2][2] = 0.01; // sun 30, vz 75, az 30
        t.aop_rad[1][2][2] = 0.03; // sun 60
        let at = |sz: f32, vz: f32, az: f32| t.at(sz * DEG, vz * DEG, az * DEG);
        assert!((at(30.0, 75.0, 30.0) - 0.01).abs() < 1e-6);
        assert!((at(45.0, 75.0, 30.0) - 0.02).abs() < 1e-6);
        assert!((at(70.0, 75.0, 30.0) - 0.03).abs() < 1e-6, "held beyond the lowest sun");
        assert!((at(15.0, 75.0, 30.0) - 0.005).abs() < 1e-6, "scaled to 0 at the zenith");
        assert!((at(30.0, 75.0, -30.0) + 0.01).abs() < 1e-6, "odd in the relative azimuth");
        assert!((at(30.0, 75.0, 330.0) + 0.01).abs() < 1e-6);
        assert!((at(30.0, 75.0, 22.5) - 0.005).abs() < 1e-6);
        assert!((at(30.0, 72.5, 30.0) - 0.005).abs() < 1e-6);
        assert_eq!(at(30.0, 90.0, 30.0), 0.0, "held at the 80-deg edge (0 there)");
        assert_eq!(t.at(f32::NAN, 1.0, 1.0), 0.0);
    }

    /// `A_sun - A_look`, clockwise seen from above (body FRD level: up is -z): a unit looking
    /// forward (north) with the sun to the right (east) has +90 deg.
    #[test]
    fn relative_azimuth_sign() {
        use nalgebra::Vector3;
        let up = Vector3::new(0.0f32, 0.0, -1.0);
        let look = Vector3::new(0.26f32, 0.0, -0.97).normalize();
        let sun = Vector3::new(0.0f32, 0.6, -0.8);
        let phi = super::super::sun_vector::rel_azimuth(&look, &sun, &up);
        assert!((phi - 90.0 * DEG).abs() < 1e-4, "{phi}");
        let phi = super::super::sun_vector::rel_azimuth(&sun, &look, &up);
        assert!((phi + 90.0 * DEG).abs() < 1e-4, "{phi}");
    }

    #[test]
    fn the_heads_table_is_small_and_odd_at_the_solar_plane() {
        for s in &OSOAA_CLEAR.aop_rad {
            for row in s {
                assert!(row[0].abs() < 1e-6 && row[AZIMUTHS - 1].abs() < 1e-6, "0 in the solar plane: {row:?}");
                assert!(row.iter().all(|x| x.abs() < 0.5), "{row:?}");
            }
        }
    }
}
