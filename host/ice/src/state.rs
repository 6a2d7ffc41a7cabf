//! The MSCKF state: the IMU nominal state, the camera clones of the sliding window and the
//! error-state covariance over both, plus the covariance hygiene every step uses.
//!
//! Frames: world = NED with the origin and heading of the start pose (the filter's frame; yaw is
//! unobservable), body = FRD at the IMU. Error state (17 + 6 per clone):
//! `[dtheta (body frame: R = R_hat Exp(dtheta)), dv_w, dp_w, db_g, db_a, dk_sonar, de_depth_ref,
//! db_sonar, (dtheta_i, dp_i) per clone]`.
//!
//! First-estimate Jacobians (FEJ, Huang et al. 2008/2010, as in OpenVINS): the global position and
//! the yaw about gravity are unobservable, and the linearized system keeps them unobservable only
//! if every Jacobian that touches a state is evaluated at the same estimate of it. An EKF
//! re-linearizing at each updated estimate gains spurious information along those directions
//! (yaw, x/y) and becomes overconfident. So the filter keeps, besides the estimates, the *first
//! estimates*: for the IMU the propagated value before any update at that time
//! ([`FilterState::fej`]), for a clone its value when it was cloned ([`CloneState::rot_fej`],
//! [`CloneState::pos_fej`]). Propagation, the feature, depth and sonar Jacobians use them; the
//! residuals use the current estimates. `fej_enabled = false` gives the plain EKF (ablation).

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

pub const IMU_DIM: usize = 18;
pub const CLONE_DIM: usize = 6;
pub const TH: usize = 0;
pub const VEL: usize = 3;
pub const POS: usize = 6;
pub const BG: usize = 9;
pub const BA: usize = 12;
/// Residual scale of the sonar's line-of-sight speed (after the geometric compensation factor).
pub const SCALE: usize = 15;
/// Error of the depth gauge's reference reading (a constant offset of every relative depth).
pub const DEPTH_REF: usize = 16;
/// Time-correlated (first-order Gauss-Markov) error of the sonar line-of-sight speed, m/s.
pub const SONAR_BIAS: usize = 17;

#[derive(Debug, Clone, PartialEq)]
pub struct ImuState {
    pub t_s: f64,
    /// Body (FRD) -> world (NED) rotation.
    pub rot: Matrix3<f64>,
    pub vel_w_mps: Vector3<f64>,
    pub pos_w_m: Vector3<f64>,
    pub bias_gyro_radps: Vector3<f64>,
    pub bias_acc_mps2: Vector3<f64>,
    /// Sonar line-of-sight speed scale residual (1 = the geometric compensation is exact).
    pub sonar_scale: f64,
    /// Error of the depth reference reading, m (see `depth`).
    pub depth_ref_err_m: f64,
    /// Time-correlated sonar line-of-sight speed error, m/s (see `sonar`).
    pub sonar_bias_mps: f64,
}

/// A stochastic clone of the IMU pose at an image time.
#[derive(Debug, Clone, PartialEq)]
pub struct CloneState {
    pub t_s: f64,
    pub frame_id: u64,
    pub rot: Matrix3<f64>,
    pub pos_w_m: Vector3<f64>,
    /// First estimates (the values when cloned) for the Jacobians (module doc).
    pub rot_fej: Matrix3<f64>,
    pub pos_fej: Vector3<f64>,
}

impl CloneState {
    /// A clone whose first estimate is its current value.
    pub fn new(t_s: f64, frame_id: u64, rot: Matrix3<f64>, pos_w_m: Vector3<f64>) -> Self {
        Self { t_s, frame_id, rot, pos_w_m, rot_fej: rot, pos_fej: pos_w_m }
    }
    /// The (rotation, position) the Jacobians are evaluated at.
    pub fn lin(&self, fej: bool) -> (Matrix3<f64>, Vector3<f64>) {
        if fej { (self.rot_fej, self.pos_fej) } else { (self.rot, self.pos_w_m) }
    }
}

/// The IMU's first estimate at the current time: the propagated value before any update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuFej {
    pub rot: Matrix3<f64>,
    pub vel_w_mps: Vector3<f64>,
    pub pos_w_m: Vector3<f64>,
}

impl ImuFej {
    pub fn of(imu: &ImuState) -> Self {
        Self { rot: imu.rot, vel_w_mps: imu.vel_w_mps, pos_w_m: imu.pos_w_m }
    }
}

#[derive(Debug, Clone)]
pub struct FilterState {
    pub imu: ImuState,
    pub clones: Vec<CloneState>,
    /// Covariance of the error state, `18 + 6 * clones.len()` square.
    pub cov: DMatrix<f64>,
    /// First estimate of the IMU state at `imu.t_s` (module doc).
    pub fej: ImuFej,
    /// Evaluate the Jacobians at the first estimates (off: at the current ones).
    pub fej_enabled: bool,
}

impl FilterState {
    /// A filter at `imu` with covariance `cov` (18 x 18), no clones, FEJ on.
    pub fn new(imu: ImuState, cov: DMatrix<f64>) -> Self {
        let fej = ImuFej::of(&imu);
        Self { imu, clones: Vec::new(), cov, fej, fej_enabled: true }
    }

    /// The IMU (rotation, velocity, position) the Jacobians are evaluated at.
    pub fn imu_lin(&self) -> ImuFej {
        if self.fej_enabled { self.fej } else { ImuFej::of(&self.imu) }
    }

    pub fn dim(&self) -> usize {
        IMU_DIM + CLONE_DIM * self.clones.len()
    }

    pub fn clone_offset(i: usize) -> usize {
        IMU_DIM + CLONE_DIM * i
    }

    /// Apply an error-state correction to the nominal states.
    pub fn inject(&mut self, dx: &DVector<f64>) {
        let v3 = |o: usize| Vector3::new(dx[o], dx[o + 1], dx[o + 2]);
        self.imu.rot = subnav_base::so3::orthonormalize(&(self.imu.rot * subnav_base::so3::exp(&v3(TH))));
        self.imu.vel_w_mps += v3(VEL);
        self.imu.pos_w_m += v3(POS);
        self.imu.bias_gyro_radps += v3(BG);
        self.imu.bias_acc_mps2 += v3(BA);
        self.imu.sonar_scale += dx[SCALE];
        self.imu.depth_ref_err_m += dx[DEPTH_REF];
        self.imu.sonar_bias_mps += dx[SONAR_BIAS];
        for (i, c) in self.clones.iter_mut().enumerate() {
            let o = Self::clone_offset(i);
            c.rot = subnav_base::so3::orthonormalize(&(c.rot * subnav_base::so3::exp(&v3(o))));
            c.pos_w_m += v3(o + 3);
        }
    }

    /// Append a clone of the current IMU pose (IMU-based augmentation Jacobian).
    pub fn augment(&mut self, frame_id: u64) {
        let n = self.dim();
        let mut j = DMatrix::zeros(CLONE_DIM, n);
        for k in 0..3 {
            j[(k, TH + k)] = 1.0;
            j[(3 + k, POS + k)] = 1.0;
        }
        let pj = &self.cov * j.transpose();
        let jpj = &j * &pj;
        let mut p = DMatrix::zeros(n + CLONE_DIM, n + CLONE_DIM);
        p.view_mut((0, 0), (n, n)).copy_from(&self.cov);
        p.view_mut((0, n), (n, CLONE_DIM)).copy_from(&pj);
        p.view_mut((n, 0), (CLONE_DIM, n)).copy_from(&pj.transpose());
        p.view_mut((n, n), (CLONE_DIM, CLONE_DIM)).copy_from(&jpj);
        self.cov = p;
        symmetrize(&mut self.cov);
        // The clone's first estimate is the IMU's first estimate (the two must agree for the
        // unobservable directions to carry over; right after propagation they are equal).
        let lin = self.imu_lin();
        self.clones.push(CloneState {
            t_s: self.imu.t_s,
            frame_id,
            rot: self.imu.rot,
            pos_w_m: self.imu.pos_w_m,
            rot_fej: lin.rot,
            pos_fej: lin.pos_w_m,
        });
    }

    /// Remove the clones at `idx` (any order) and their rows/columns of the covariance.
    pub fn marginalize(&mut self, idx: &[usize]) {
        let keep: Vec<usize> = (0..self.clones.len()).filter(|i| !idx.contains(i)).collect();
        let mut rows: Vec<usize> = (0..IMU_DIM).collect();
        for &i in &keep {
            let o = Self::clone_offset(i);
            rows.extend(o..o + CLONE_DIM);
        }
        let m = rows.len();
        let mut p = DMatrix::zeros(m, m);
        for (a, &ra) in rows.iter().enumerate() {
            for (b, &rb) in rows.iter().enumerate() {
                p[(a, b)] = self.cov[(ra, rb)];
            }
        }
        self.cov = p;
        self.clones = keep.iter().map(|&i| self.clones[i].clone()).collect();
    }

    /// EKF update with stacked residual `r`, Jacobian `h` and noise `r_cov`, Joseph form.
    /// Returns the correction applied, or `None` if the innovation covariance is not PD.
    pub fn ekf_update(&mut self, r: &DVector<f64>, h: &DMatrix<f64>, r_cov: &DMatrix<f64>) -> Option<DVector<f64>> {
        let ph = &self.cov * h.transpose();
        let mut s = h * &ph + r_cov;
        symmetrize(&mut s);
        let chol = s.cholesky()?;
        let k = chol.solve(&ph.transpose()).transpose();
        let dx = &k * r;
        if dx.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let n = self.dim();
        let ikh = DMatrix::identity(n, n) - &k * h;
        self.cov = &ikh * &self.cov * ikh.transpose() + &k * r_cov * k.transpose();
        symmetrize(&mut self.cov);
        self.inject(&dx);
        Some(dx)
    }
}

pub fn symmetrize(p: &mut DMatrix<f64>) {
    let t = p.transpose();
    *p += t;
    *p *= 0.5;
}
