//! Rolling shutter: a frame's rows are read out one after the other over
//! [`crate::camera::PinholeCamera::readout_s`], so a feature in row `v` is seen
//! [`crate::camera::PinholeCamera::row_time_s`]`(v)` after the frame's stamp (its middle row),
//! from a camera that has moved since. [`transfer_to_stamp`] moves each observation, at
//! ingestion ([`super::TrackTable`]), to where the camera at the stamp sees the point, so the
//! rest of the estimator sees a global-shutter frame.
//!
//! With the camera's rotation `R(t)` and position `o(t)`, a point `P_r` (camera frame) seen at the
//! row time `r` is `P_0 = R(0)^T R(r) P_r + R(0)^T (o(r) - o(0))` at the stamp. Over a row time
//! (at most half the readout) the rotation is `Exp(phi)`, `phi = w r + dw r^2 / 2` (rate and
//! angular acceleration in the camera frame), and the translation `v_c r`; `P_r = (x, 1) / rho`
//! with the point's inverse depth `rho`.
//!
//! Why not the first-order model (VINS-Mono: `x - (td + r) v` with the feature velocity `v`): on
//! the simulated hand-held rig with a 30 ms readout it leaves 0.43 px RMS even with the true
//! velocity, almost all of it the angular acceleration's term, and the estimate 2.4-4x worse than
//! with a global shutter; the transfer recovers it (BENCHMARKS.md, "Rolling shutter").

use crate::math::{exp_so3, Vec3};

/// Where the camera at the frame's stamp sees a point observed at `x` in a row read out `row_s`
/// after the stamp (a rolling shutter), at inverse depth `rho` (1/m), for a camera turning at
/// `w_c` (rad/s) with the angular acceleration `dw_c` (rad/s^2) and moving at `v_c` (m/s), all
/// in the camera frame at the stamp (`super::CameraMotion`'s fields): with the camera's rotation
/// over the row time `phi = w row_s + dw row_s^2 / 2` (its angular acceleration matters: a
/// hand-held camera's `dw` of 10-30 rad/s^2 moves the rows of a 30 ms readout by about 0.5 px
/// more than its rate alone) and its translation `v_c row_s`,
/// `rho P_stamp = Exp(phi) (x, 1) + rho v_c row_s`. The translation needs the depth (`rho = 0`:
/// far, no translation). `x` itself if the result is not in front.
pub fn transfer_to_stamp(
    x: [f64; 2],
    row_s: f64,
    rho: f64,
    w_c: [f64; 3],
    dw_c: [f64; 3],
    v_c: [f64; 3],
) -> [f64; 2] {
    let phi = Vec3::from(w_c) * row_s + Vec3::from(dw_c) * (0.5 * row_s * row_s);
    let p = exp_so3(&phi) * Vec3::new(x[0], x[1], 1.0) + Vec3::from(v_c) * (rho * row_s);
    if p.z > 1e-6 && p.x.is_finite() && p.y.is_finite() {
        [p.x / p.z, p.y / p.z]
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Mat3;

    /// A camera turning about a fixed axis with constant angular acceleration and moving at a
    /// constant velocity: its pose `r` s after the stamp (rotation world <- camera, origin).
    fn pose(r: f64, w: &Vec3, dw: &Vec3, v_w: &Vec3) -> (Mat3, Vec3) {
        (exp_so3(&(w * r + dw * (0.5 * r * r))), v_w * r)
    }

    fn project(p: &Vec3) -> [f64; 2] {
        [p.x / p.z, p.y / p.z]
    }

    #[test]
    fn a_row_seen_later_is_moved_to_the_stamp() {
        // Rate and acceleration about one axis: `phi = w r + dw r^2 / 2` is then exact.
        let axis = Vec3::new(0.3, -0.8, 0.5).normalize();
        let (w, dw) = (axis * 2.5, axis * 30.0);
        let v_w = Vec3::new(0.8, -0.2, 1.1);
        // The stamp's camera frame is the world here.
        let (w3, dw3, v3) = ([w.x, w.y, w.z], [dw.x, dw.y, dw.z], [v_w.x, v_w.y, v_w.z]);
        for (p_w, r) in [
            (Vec3::new(0.4, -0.3, 2.0), 0.015),
            (Vec3::new(-1.5, 0.9, 4.0), -0.012),
            (Vec3::new(0.1, 0.2, 30.0), 0.007),
        ] {
            let (rot, o) = pose(r, &w, &dw, &v_w);
            let p_r = rot.transpose() * (p_w - o);
            let x_r = project(&p_r);
            let got = transfer_to_stamp(x_r, r, 1.0 / p_r.z, w3, dw3, v3);
            let want = project(&p_w);
            // The translation is linear in `r` and the rotation exact: equal to rounding.
            assert!(
                (got[0] - want[0]).abs() < 1e-12 && (got[1] - want[1]).abs() < 1e-12,
                "{got:?} != {want:?}"
            );
            // Without the angular acceleration the row is off by `dw r^2 / 2`: a pixel or so at
            // f = 460 px; the test sees the term.
            let off = transfer_to_stamp(x_r, r, 1.0 / p_r.z, w3, [0.0; 3], v3);
            let d = ((off[0] - want[0]).powi(2) + (off[1] - want[1]).powi(2)).sqrt();
            assert!(d > 0.5 * 30.0 * r * r * 0.5, "{d}");
        }
        // A global-shutter row and a point that would land behind the camera are left alone.
        let at_rest = [0.0; 3];
        assert_eq!(
            transfer_to_stamp([0.3, -0.2], 0.0, 0.5, w3, dw3, v3),
            [0.3, -0.2]
        );
        let spin = [0.0, 200.0, 0.0];
        let behind = transfer_to_stamp([0.3, -0.2], 0.01, 0.0, spin, at_rest, at_rest);
        assert_eq!(behind, [0.3, -0.2]);
    }
}
