//! Every error type of the crate: a non-empty message per variant, different from the others,
//! and usable as `&dyn core::error::Error`.

use crate::compass::unit::ModelError;
use crate::compass::{NoFix, UnitReject};
use crate::depth_adaptive::AdaptError;
use crate::ephemeris::EphemerisError;
use crate::nav::NavError;
use crate::ukf::UkfError;
use crate::ukf::weights::WeightError;
use subnav_wire::error_check::assert_distinct_messages;

#[test]
fn ephemeris_error() {
    use EphemerisError::*;
    assert_distinct_messages("EphemerisError", &[&NonFinite, &LatitudeOutOfRange, &TimeOutOfRange]);
}

#[test]
fn ukf_errors() {
    use UkfError::*;
    assert_distinct_messages("UkfError", &[&NonFiniteInput, &NonFiniteResult, &NotPositiveDefinite, &CovarianceUnrepairable, &BadConfig]);
    assert_distinct_messages("WeightError", &[&WeightError::WrongPointCount, &WeightError::BadParameters]);
}

#[test]
fn nav_error() {
    let filter = [
        NavError::Filter(UkfError::NonFiniteInput),
        NavError::Filter(UkfError::NonFiniteResult),
        NavError::Filter(UkfError::NotPositiveDefinite),
        NavError::Filter(UkfError::CovarianceUnrepairable),
        NavError::Filter(UkfError::BadConfig),
    ];
    let mut all: Vec<&dyn core::error::Error> =
        vec![&NavError::BadConfig, &NavError::NonFinite, &NavError::BadTime, &NavError::TooOld, &NavError::FromFuture];
    all.extend(filter.iter().map(|e| e as &dyn core::error::Error));
    assert_distinct_messages("NavError", &all);
    // The wrapped UKF error is the source and appears in the message.
    let e = NavError::Filter(UkfError::NotPositiveDefinite);
    let source = core::error::Error::source(&e).map(|s| s.to_string());
    assert_eq!(source, Some(UkfError::NotPositiveDefinite.to_string()));
    assert!(e.to_string().contains(&UkfError::NotPositiveDefinite.to_string()), "{e}");
    assert!(core::error::Error::source(&NavError::BadTime).is_none());
}

#[test]
fn compass_errors() {
    assert_distinct_messages("ModelError", &[&ModelError::BadGeometry, &ModelError::Singular, &ModelError::BadCalibration]);
    use UnitReject::*;
    assert_distinct_messages("UnitReject", &[&Saturated, &Dark, &LowDolp, &NonFinite]);
    // Every telemetry code 1..=16 is a variant (from_code), so this covers all of NoFix.
    let all: Vec<NoFix> = (1..=u8::MAX).filter_map(NoFix::from_code).collect();
    assert_eq!(all.len(), 16, "NoFix variants");
    let refs: Vec<&dyn core::error::Error> = all.iter().map(|e| e as &dyn core::error::Error).collect();
    assert_distinct_messages("NoFix", &refs);
}

#[test]
fn adapt_error() {
    use AdaptError::*;
    assert_distinct_messages("AdaptError", &[&NonFinite, &BadAlpha, &OutOfRange]);
}
