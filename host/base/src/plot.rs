//! What the crates that draw figures with plotters share (feature `plot`): the one lookup of a
//! TrueType font for the figures' text. plotters' `ab_glyph` backend has no system font search,
//! so a font is read from `SUBNAV_FONT` or a few usual paths (DejaVu, Liberation, Arial) and
//! registered as `sans-serif`; without one, figures are drawn without text rather than failing.

use plotters::style::FontStyle;
use std::sync::OnceLock;

/// Registers a TrueType font for the figures' text, once per process (false: none found, draw
/// without text).
pub fn font_ok() -> bool {
    static OK: OnceLock<bool> = OnceLock::new();
    *OK.get_or_init(|| {
        let mut paths: Vec<String> = std::env::var("SUBNAV_FONT").into_iter().collect();
        paths.extend(
            [
                "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/TTF/DejaVuSans.ttf",
                "/usr/share/fonts/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
                "/Library/Fonts/Arial.ttf",
                "C:\\Windows\\Fonts\\arial.ttf",
            ]
            .map(String::from),
        );
        paths.into_iter().any(|p| {
            std::fs::read(&p).is_ok_and(|bytes| {
                plotters::style::register_font("sans-serif", FontStyle::Normal, Box::leak(bytes.into_boxed_slice())).is_ok()
            })
        })
    })
}
