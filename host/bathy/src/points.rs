//! Soundings -> world-frame 2.5D points (spec C1, eq. 1): with the pose (north, east, depth,
//! heading) and a beam (range r, angle beta from nadir, positive to starboard) the sounding lies
//! r*sin(beta) to starboard and r*cos(beta) below the vehicle. Roll/pitch and vertical motion
//! are ignored, as in the paper (2.5D map).

use super::{Beam, NavSample, Point, Survey, V2};

/// Horizontal offset (north, east) of a beam's footprint from the vehicle and its depth below it.
pub fn beam_offset(heading_rad: f64, beam: &Beam) -> (V2, f64) {
    let across = beam.range_m * beam.angle_rad.sin();
    let down = beam.range_m * beam.angle_rad.cos();
    // Starboard unit vector in NED for heading psi: (-sin psi, cos psi).
    let stbd = V2::new(-heading_rad.sin(), heading_rad.cos());
    (stbd * across, down)
}

pub fn sounding(nav: &NavSample, beam: &Beam) -> Point {
    let (h, down) = beam_offset(nav.heading_rad, beam);
    Point { north_m: nav.north_m + h.x, east_m: nav.east_m + h.y, depth_m: nav.depth_m + down }
}

/// All soundings of the survey placed with the survey's navigation, shifted per ping by
/// `-offset[i]` (the navigation offset estimate; pass zeros for dead reckoning).
pub fn survey_points(survey: &Survey, offsets: Option<&[V2]>) -> Vec<Vec<Point>> {
    survey
        .nav
        .iter()
        .zip(&survey.pings)
        .enumerate()
        .map(|(i, (nav, ping))| {
            let mut n = *nav;
            if let Some(o) = offsets.and_then(|o| o.get(i)) {
                n.north_m -= o.x;
                n.east_m -= o.y;
            }
            ping.beams.iter().map(|b| sounding(&n, b)).collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn nav(heading: f64) -> NavSample {
        NavSample { t_s: 0.0, north_m: 100.0, east_m: 50.0, depth_m: 20.0, heading_rad: heading, vel_sigma_mps: 0.01 }
    }

    #[test]
    fn nadir_beam_is_straight_below() {
        let p = sounding(&nav(0.7), &Beam { angle_rad: 0.0, range_m: 15.0 });
        assert!((p.north_m - 100.0).abs() < 1e-12 && (p.east_m - 50.0).abs() < 1e-12);
        assert!((p.depth_m - 35.0).abs() < 1e-12);
    }

    #[test]
    fn starboard_beam_heading_north_goes_east_heading_east_goes_south() {
        let b = Beam { angle_rad: 30f64.to_radians(), range_m: 20.0 };
        let p = sounding(&nav(0.0), &b);
        assert!((p.east_m - 60.0).abs() < 1e-9 && (p.north_m - 100.0).abs() < 1e-9);
        assert!((p.depth_m - (20.0 + 20.0 * 30f64.to_radians().cos())).abs() < 1e-9);
        let p = sounding(&nav(FRAC_PI_2), &b);
        assert!((p.north_m - 90.0).abs() < 1e-9 && (p.east_m - 50.0).abs() < 1e-9);
        // Port beam (negative angle) heading west goes north.
        let p = sounding(&nav(-FRAC_PI_2), &Beam { angle_rad: -b.angle_rad, range_m: 20.0 });
        assert!((p.north_m - 90.0).abs() < 1e-9);
    }
}
