//! Under-ice odometry (spec 004): an MSCKF-style error-state EKF fusing an IMU, an up-looking
//! stereo camera, a depth gauge and a forward-looking imaging sonar (velocity by phase correlation).

pub mod phasecorr;
