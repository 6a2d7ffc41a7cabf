//! Issue 23 (C): a bad LMNN setting is named in the error, not dumped as the whole config.

use nalgebra::DMatrix;
use subnav_topo::lmnn::{LmnnConfig, LmnnModel};

#[test]
fn a_bad_setting_is_named() {
    let x = DMatrix::from_row_slice(8, 1, &[0.0, 0.1, 0.2, 0.3, 5.0, 5.1, 5.2, 5.3]);
    let y = [0, 0, 0, 0, 1, 1, 1, 1];
    let cfg = LmnnConfig { k: 1, max_iter: 1, ..LmnnConfig::default() };
    let e = format!("{:#}", LmnnModel::fit(&x, &y, &cfg).unwrap_err());
    assert!(e.contains("max_iter must be at least 2, got 1") && !e.contains("LmnnConfig"), "{e}");
}
