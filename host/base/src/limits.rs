//! Size limits on what a file can make the host allocate: the one check per input kind that
//! keeps a small hostile file from asking for gigabytes (a 200-byte PNG declaring 60000 x 60000
//! pixels wanted 28.8 GB; a CSV of 100,000 rows an n x n matrix of 80 GB). Each check's error
//! names the input, its size and the bound.

/// Largest image side accepted, pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Largest image accepted, pixels (64 Mpx: 512 MB as f64 grey).
pub const MAX_IMAGE_PIXELS: u64 = 64 << 20;

/// Largest grid a survey may make, cells (64 M cells: 512 MB of f64).
pub const MAX_GRID_CELLS: f64 = (64u64 << 20) as f64;

/// Checks the grid a survey spanning `north_m` x `east_m` would make at `cell_m`.
pub fn check_grid(what: &str, north_m: f64, east_m: f64, cell_m: f64) -> Result<(), String> {
    let cells = (north_m / cell_m + 3.0) * (east_m / cell_m + 3.0);
    if !(cells.is_finite() && cells <= MAX_GRID_CELLS) {
        return Err(format!(
            "{what} spans {north_m:.0} m x {east_m:.0} m: at {cell_m} m cells its grid would have {cells:.3e} cells, more than {MAX_GRID_CELLS:.3e}"
        ));
    }
    Ok(())
}

/// Checks an image's declared size (from its header, before decoding it).
pub fn check_image_size(what: &str, width: u32, height: u32) -> Result<(), String> {
    let px = u64::from(width) * u64::from(height);
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE || px > MAX_IMAGE_PIXELS {
        return Err(format!(
            "{what} declares {width} x {height} pixels: images must be 1..={MAX_IMAGE_SIDE} pixels a side and at most {MAX_IMAGE_PIXELS} pixels"
        ));
    }
    Ok(())
}

/// Checks a row count against a bound (`what` names the table and what the rows are used for).
pub fn check_rows(what: &str, rows: usize, max: usize) -> Result<(), String> {
    if rows > max {
        return Err(format!("{what} has {rows} rows, more than the {max} this method accepts"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_sizes() {
        assert!(check_image_size("a.png", 640, 480).is_ok());
        assert!(check_image_size("a.png", 8192, 8192).is_ok());
        let e = check_image_size("a.png", 60_000, 60_000).unwrap_err();
        assert!(e.contains("a.png") && e.contains("60000 x 60000") && e.contains("16384"), "{e}");
        assert!(check_image_size("a.png", 0, 10).is_err());
        assert!(check_image_size("a.png", 16_384, 16_384).is_err());
        assert!(check_rows("t.csv", 10, 10).is_ok());
        assert!(check_rows("t.csv", 11, 10).unwrap_err().contains("11 rows"));
    }
}
