//! Node state of the factor graph: position, velocity, attitude on SO(3), accelerometer and gyro
//! biases, in the ENU navigation frame with an FLU body frame (x forward, y left, z up), as in
//! spec 002 and GTSAM's `MakeSharedU` convention (gravity = [0, 0, -g]).
//!
//! Tangent vector of a node (15): `[d_theta (body, right perturbation), d_pos_enu, d_vel_enu,
//! d_bias_acc, d_bias_gyro]`. Retraction: `R Exp(d_theta)`, the rest additive.
//!
//! Conversion to the project's NED/FRD convention (shared/wire/src/messages.rs):
//! `p_ned = T p_enu`, `v_ned = T v_enu` with `T = [[0,1,0],[1,0,0],[0,0,-1]]` (T = T^T = T^-1);
//! body FLU -> FRD is `F = diag(1,-1,-1)`; attitude `R_ned_frd = T R_enu_flu F`; IMU samples
//! convert with `F` (`acc_flu = F acc_frd`, `gyro_flu = F gyro_frd`).

use nalgebra::{Matrix3, SVector, UnitQuaternion, Vector3};

use subnav_base::so3;

/// 15-dimensional tangent vector of a node.
pub type Tangent = SVector<f64, 15>;

/// Navigation state: attitude body(FLU)->ENU, position and velocity in ENU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState {
    pub rot_enu_flu: Matrix3<f64>,
    pub pos_enu_m: Vector3<f64>,
    pub vel_enu_mps: Vector3<f64>,
}

impl NavState {
    pub fn new(rot_enu_flu: Matrix3<f64>, pos_enu_m: Vector3<f64>, vel_enu_mps: Vector3<f64>) -> Self {
        Self { rot_enu_flu, pos_enu_m, vel_enu_mps }
    }

    pub fn identity() -> Self {
        Self::new(Matrix3::identity(), Vector3::zeros(), Vector3::zeros())
    }

    pub fn is_finite(&self) -> bool {
        self.rot_enu_flu.iter().chain(self.pos_enu_m.iter()).chain(self.vel_enu_mps.iter()).all(|x| x.is_finite())
    }
}

/// IMU biases in the body (FLU) frame, GTSAM `ConstantBias` order when flattened: `[acc, gyro]`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuBias {
    pub acc_mps2: Vector3<f64>,
    pub gyro_radps: Vector3<f64>,
}

impl ImuBias {
    pub fn new(acc_mps2: Vector3<f64>, gyro_radps: Vector3<f64>) -> Self {
        Self { acc_mps2, gyro_radps }
    }
    pub fn to_array(&self) -> [f64; 6] {
        [self.acc_mps2.x, self.acc_mps2.y, self.acc_mps2.z, self.gyro_radps.x, self.gyro_radps.y, self.gyro_radps.z]
    }
}

/// One graph node: navigation state and the IMU biases at that time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeState {
    pub nav: NavState,
    pub bias: ImuBias,
}

impl NodeState {
    pub fn new(nav: NavState, bias: ImuBias) -> Self {
        Self { nav, bias }
    }

    /// `x [+] d`
    pub fn retract(&self, d: &Tangent) -> Self {
        let dth = Vector3::new(d[0], d[1], d[2]);
        let r = so3::orthonormalize(&(self.nav.rot_enu_flu * so3::exp(&dth)));
        Self {
            nav: NavState {
                rot_enu_flu: r,
                pos_enu_m: self.nav.pos_enu_m + d.fixed_rows::<3>(3),
                vel_enu_mps: self.nav.vel_enu_mps + d.fixed_rows::<3>(6),
            },
            bias: ImuBias { acc_mps2: self.bias.acc_mps2 + d.fixed_rows::<3>(9), gyro_radps: self.bias.gyro_radps + d.fixed_rows::<3>(12) },
        }
    }

    /// `other [-] self`: the tangent `d` with `self.retract(d) == other`.
    pub fn local(&self, other: &Self) -> Tangent {
        let mut d = Tangent::zeros();
        d.fixed_rows_mut::<3>(0).copy_from(&so3::log(&(self.nav.rot_enu_flu.transpose() * other.nav.rot_enu_flu)));
        d.fixed_rows_mut::<3>(3).copy_from(&(other.nav.pos_enu_m - self.nav.pos_enu_m));
        d.fixed_rows_mut::<3>(6).copy_from(&(other.nav.vel_enu_mps - self.nav.vel_enu_mps));
        d.fixed_rows_mut::<3>(9).copy_from(&(other.bias.acc_mps2 - self.bias.acc_mps2));
        d.fixed_rows_mut::<3>(12).copy_from(&(other.bias.gyro_radps - self.bias.gyro_radps));
        d
    }

    pub fn is_finite(&self) -> bool {
        self.nav.is_finite() && self.bias.to_array().iter().all(|x| x.is_finite())
    }
}

/// ENU <-> NED axis swap `T` (its own inverse).
pub fn t_enu_ned() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

/// FLU <-> FRD body axis flip `F` (its own inverse).
pub fn f_flu_frd() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// Vector ENU -> NED (and back: the map is an involution).
pub fn enu_to_ned(v: &Vector3<f64>) -> Vector3<f64> {
    t_enu_ned() * v
}

/// Attitude body(FLU)->ENU to body(FRD)->NED as the project's `[w, x, y, z]` quaternion.
pub fn attitude_ned_frd_wxyz(rot_enu_flu: &Matrix3<f64>) -> [f64; 4] {
    let r = t_enu_ned() * rot_enu_flu * f_flu_frd();
    let q = UnitQuaternion::from_matrix(&r);
    [q.w, q.i, q.j, q.k]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retract_local_roundtrip() {
        let x = NodeState::new(
            NavState::new(so3::exp(&Vector3::new(0.3, -0.1, 2.0)), Vector3::new(1.0, 2.0, -3.0), Vector3::new(0.5, 0.0, 0.1)),
            ImuBias::new(Vector3::new(0.01, 0.0, -0.02), Vector3::new(1e-3, 0.0, 2e-3)),
        );
        let d = Tangent::from_fn(|i, _| (i as f64 - 7.0) * 0.01);
        let y = x.retract(&d);
        assert!((x.local(&y) - d).norm() < 1e-12);
    }

    #[test]
    fn enu_ned_conventions() {
        // Heading north in ENU (x_body along +y_enu): in NED the body x axis is +x_ned (yaw 0).
        let yaw90 = so3::exp(&Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        let q = attitude_ned_frd_wxyz(&yaw90);
        assert!((q[0].abs() - 1.0).abs() < 1e-12, "{q:?}");
        let p = enu_to_ned(&Vector3::new(1.0, 2.0, 3.0));
        assert_eq!(p, Vector3::new(2.0, 1.0, -3.0));
    }
}
