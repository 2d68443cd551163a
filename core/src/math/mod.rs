//! Small geometry kernel shared by every layer: SO(3) maps and their Jacobians, all on `f64` with
//! `libm` transcendental functions (bit-identical across targets).

pub mod so3;

pub use so3::{exp_so3, jr_inv_so3, jr_so3, log_so3, quat_exp, skew};

/// 3-vector of `f64`.
pub type Vec3 = nalgebra::Vector3<f64>;
/// 3x3 matrix of `f64`.
pub type Mat3 = nalgebra::Matrix3<f64>;
/// Unit quaternion of `f64` (Hamilton).
pub type Quat = nalgebra::UnitQuaternion<f64>;

/// The zero [`Vec3`], as a constant (for `const` constructors).
pub const VEC3_ZERO: Vec3 = Vec3::new(0.0, 0.0, 0.0);

/// The identity [`Quat`], as a constant (for `const` constructors).
pub const QUAT_IDENTITY: Quat = Quat::new_unchecked(nalgebra::Quaternion::new(1.0, 0.0, 0.0, 0.0));
