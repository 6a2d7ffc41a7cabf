//! Unscented Kalman filter core (work in progress, issue 4).
