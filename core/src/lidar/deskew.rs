//! Body pose at a LiDAR point's time, for de-skew: the interpolation of
//! [`InsWindow::pose_at`](crate::inertial::window::InsWindow::pose_at) with the bracketing
//! interval cached, so a sweep (hundreds of points per IMU interval) pays one `Log` per interval
//! instead of a binary search, a `Log` and an `Exp` per point.
//!
//! Between states `a`, `b` with `s = (t - t_a) / (t_b - t_a)`:
//! `p_wb(t) = p_a + s (p_b - p_a)`, `q_wb(t) = q_a Exp(s dphi)`, `dphi = Log(q_a^-1 q_b)`.
//! Over one IMU interval `|s dphi|` is a few mrad, where `Exp` is evaluated by its Taylor series
//! (exact to `f64` rounding below 0.1 rad, no `sin`/`cos` call); larger angles use
//! [`quat_exp`].

use crate::inertial::window::InsWindow;
use crate::math::{log_so3, quat_exp, Quat, Vec3};
use nalgebra::Quaternion;

/// The interval of the last query and what interpolation inside it needs.
pub(crate) struct InterpCursor {
    /// Index of state `a` in the window (the hint of the next query).
    i: usize,
    /// False until the first successful query.
    valid: bool,
    t_a_ns: i64,
    t_b_ns: i64,
    /// `1 / (t_b - t_a)` in 1/ns (0 for a one-state window).
    inv_span: f64,
    p_a: Vec3,
    dp: Vec3,
    q_a: Quat,
    dphi: Vec3,
}

impl InterpCursor {
    pub(crate) fn new() -> Self {
        InterpCursor {
            i: 0,
            valid: false,
            t_a_ns: 0,
            t_b_ns: 0,
            inv_span: 0.0,
            p_a: Vec3::zeros(),
            dp: Vec3::zeros(),
            q_a: Quat::identity(),
            dphi: Vec3::zeros(),
        }
    }

    /// `(p_wb, q_wb)` at `t_ns`, or `None` outside the window's span. Any query order is
    /// correct; sorted queries are fastest.
    #[inline]
    pub(crate) fn pose_at<const K: usize>(
        &mut self,
        ins: &InsWindow<K>,
        t_ns: i64,
    ) -> Option<(Vec3, Quat)> {
        if !(self.valid && self.t_a_ns <= t_ns && t_ns <= self.t_b_ns) {
            self.load(ins, t_ns)?;
        }
        // Exact in u64: 0 <= t - t_a <= t_b - t_a < 2^64.
        let s = t_ns.wrapping_sub(self.t_a_ns) as u64 as f64 * self.inv_span;
        let p = self.p_a + self.dp * s;
        let q = self.q_a * exp_small(&(self.dphi * s));
        Some((p, q))
    }

    fn load<const K: usize>(&mut self, ins: &InsWindow<K>, t_ns: i64) -> Option<()> {
        let (i, a, b) = ins.bracket(t_ns, self.i).ok()?;
        let span = b.t_ns.wrapping_sub(a.t_ns) as u64;
        self.i = i;
        self.valid = true;
        self.t_a_ns = a.t_ns;
        self.t_b_ns = b.t_ns;
        self.inv_span = if span == 0 { 0.0 } else { 1.0 / span as f64 };
        self.p_a = a.p_wb;
        self.dp = b.p_wb - a.p_wb;
        self.q_a = a.q_wb;
        self.dphi = log_so3(&(a.q_wb.inverse() * b.q_wb));
        Some(())
    }
}

/// `Exp(phi)` as a quaternion; Taylor series below 0.1 rad, where the first dropped term
/// (`h^10 / 10!`, `h = |phi| / 2`) is below 3e-20.
#[inline]
fn exp_small(phi: &Vec3) -> Quat {
    let th2 = phi.norm_squared();
    if th2 >= 0.01 {
        return quat_exp(phi);
    }
    let h2 = 0.25 * th2;
    // cos(h) and sin(h) / (2 h) in Horner form.
    let w = 1.0 - h2 * (0.5 - h2 * (1.0 / 24.0 - h2 * (1.0 / 720.0 - h2 * (1.0 / 40320.0))));
    let k = 0.5
        * (1.0
            - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0 - h2 * (1.0 / 5040.0 - h2 * (1.0 / 362880.0)))));
    Quat::new_unchecked(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inertial::NavState;

    #[test]
    fn exp_small_matches_libm_exp_below_and_above_the_switch() {
        for &a in &[0.0, 1e-9, 1e-4, 0.003, 0.05, 0.0999, 0.1001, 0.7, 3.0] {
            let phi = Vec3::new(0.6, -0.48, 0.64) * a; // unit direction
            let d = (exp_small(&phi).coords - quat_exp(&phi).coords).amax();
            assert!(d < 4e-16, "angle {a}: {d}");
        }
    }

    #[test]
    fn cursor_agrees_with_pose_at_in_any_query_order() {
        let mut w = InsWindow::<64>::new();
        for k in 0..50i64 {
            let t = k as f64 * 0.005;
            w.push(NavState {
                p_wb: Vec3::new(t, 0.5 * t * t, -t),
                q_wb: quat_exp(&Vec3::new(0.3 * t, -0.2, 1.5 * t)),
                ..NavState::identity(k * 5_000_000)
            })
            .unwrap();
        }
        let mut c = InterpCursor::new();
        // Forward, backward, jumps, repeats, both ends, and outside.
        let times = [
            0i64,
            1,
            4_999_999,
            5_000_000,
            123_456_789,
            7_000_000,
            7_000_000,
            245_000_000,
            100_000_000,
            0,
            244_999_999,
        ];
        for &t in &times {
            let (p, q) = c.pose_at(&w, t).unwrap();
            let (p0, q0) = w.pose_at(t).unwrap();
            assert!((p - p0).amax() < 1e-15, "t {t}");
            assert!((q.coords - q0.coords).amax() < 1e-15, "t {t}");
        }
        assert!(c.pose_at(&w, -1).is_none());
        assert!(c.pose_at(&w, 245_000_001).is_none());
        // Still usable after a miss.
        assert!(c.pose_at(&w, 3).is_some());
    }
}
