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

/// Serde form of a [`Quat`] (feature `serde`): the array `[x, y, z, w]`. Reading accepts a
/// quaternion whose norm is 1 within 1e-3 (a typo must not silently become some other rotation)
/// and normalizes it; one that is unit to `f64` precision is kept bit for bit, so that a written
/// configuration reads back identical.
#[cfg(feature = "serde")]
pub mod serde_quat_xyzw {
    use super::Quat;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// Largest accepted `| |q| - 1 |`.
    pub const NORM_TOLERANCE: f64 = 1e-3;

    /// The quaternion `[x, y, z, w]` if its norm is 1 within [`NORM_TOLERANCE`], normalized
    /// (kept as it is when already unit to `f64` precision).
    pub fn from_xyzw(q: [f64; 4]) -> Option<Quat> {
        let [x, y, z, w] = q;
        let n2 = x * x + y * y + z * z + w * w;
        let n = libm::sqrt(n2);
        if !n.is_finite() || (n - 1.0).abs() > NORM_TOLERANCE {
            return None;
        }
        let raw = nalgebra::Quaternion::new(w, x, y, z);
        Some(if (n - 1.0).abs() <= 1e-12 {
            Quat::new_unchecked(raw)
        } else {
            Quat::new_unchecked(raw / n)
        })
    }

    /// `[x, y, z, w]` of a quaternion.
    pub fn to_xyzw(q: &Quat) -> [f64; 4] {
        [q.i, q.j, q.k, q.w]
    }

    /// Writes `[x, y, z, w]`.
    pub fn serialize<S: Serializer>(q: &Quat, s: S) -> Result<S::Ok, S::Error> {
        to_xyzw(q).serialize(s)
    }

    /// Reads `[x, y, z, w]` (see the module docs).
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Quat, D::Error> {
        let q = <[f64; 4]>::deserialize(d)?;
        from_xyzw(q).ok_or_else(|| {
            serde::de::Error::custom(format_args!(
                "{q:?} is not a unit quaternion [x, y, z, w] (|q| must be 1 +- 1e-3)"
            ))
        })
    }
}

#[cfg(test)]
#[cfg(feature = "serde")]
mod serde_tests {
    use super::serde_quat_xyzw::{from_xyzw, to_xyzw};
    use super::Quat;

    #[test]
    fn unit_quaternions_read_back_bit_for_bit() {
        for q in [
            Quat::identity(),
            Quat::from_euler_angles(0.1, -0.2, 1.3),
            Quat::from_euler_angles(3.0, 0.01, -0.5),
        ] {
            let back = from_xyzw(to_xyzw(&q)).expect("unit");
            assert_eq!(to_xyzw(&back), to_xyzw(&q));
        }
    }

    #[test]
    fn nearly_unit_quaternions_are_normalized_and_others_rejected() {
        let q = from_xyzw([0.0, 0.0, 0.7072, 0.7072]).expect("within 1e-3");
        assert!((q.quaternion().norm() - 1.0).abs() < 1e-15);
        assert!(from_xyzw([0.0, 0.0, 0.0, 0.5]).is_none());
        assert!(from_xyzw([0.0, 0.0, 0.0, 1.01]).is_none());
        assert!(from_xyzw([f64::NAN, 0.0, 0.0, 1.0]).is_none());
    }
}
