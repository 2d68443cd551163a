use super::*;
use povins_core::math::quat_exp;

/// A xorshift with Box-Muller: standard normal draws.
fn gauss(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b) = (u().max(1e-300), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

/// One row of `velocity_nees`' input: `s` perturbed by errors drawn from the diagonal
/// covariance `sd^2` over `[theta, v]`, in a world rotated by `q_wv^-1` from the truth's.
fn draw(truth: &NavState, sd: &[f64; 6], q_wv: &Quat, g: &mut impl FnMut() -> f64) -> [f64; 29] {
    let d: Vec<f64> = sd.iter().map(|s| s * g()).collect();
    // The truth is the estimate with its error: R_gt = R Exp(theta), v_gt = v + dv (in the
    // estimate's world).
    let q_gt_v = q_wv.inverse() * truth.q_wb;
    let v_gt_v = q_wv.inverse() * truth.v_wb;
    let q_est = q_gt_v * quat_exp(&Vec3::new(-d[0], -d[1], -d[2]));
    let v_est = v_gt_v - Vec3::new(d[3], d[4], d[5]);
    let q = q_est.quaternion();
    let mut row = [0.0; 29];
    row[..8].copy_from_slice(&[
        f64::from_bits(truth.t_ns as u64),
        q.i,
        q.j,
        q.k,
        q.w,
        v_est.x,
        v_est.y,
        v_est.z,
    ]);
    let mut k = 8;
    for (i, s) in sd.iter().enumerate() {
        for j in i..6 {
            row[k] = if i == j { s * s } else { 0.0 };
            k += 1;
        }
    }
    row
}

fn truth(k: i64) -> NavState {
    let mut s = NavState::identity(k);
    s.q_wb = quat_exp(&Vec3::new(0.1, -0.2, 0.001 * k as f64));
    s.v_wb = Vec3::new(1.5, -0.5, 0.2);
    s
}

/// Errors drawn with the stated covariance average 3 in the body and in the aligned world; a
/// covariance four times too small, four times that; without the alignment, the world's yaw
/// offset is error while the body's velocity does not see it.
#[test]
fn consistent_errors_average_three() {
    let sd = [0.02, 0.01, 0.03, 0.1, 0.02, 0.05];
    let q_wv = Quat::from_axis_angle(&Vec3::z_axis(), 0.7);
    let mut g = gauss(7);
    let rows: Vec<_> = (0..20000)
        .map(|k| draw(&truth(k), &sd, &q_wv, &mut g))
        .collect();
    let at = |t: i64| Some(truth(t));
    let n = velocity_nees(rows.iter().map(|r| Ok(*r)), at, &q_wv)
        .unwrap()
        .unwrap();
    assert_eq!(n.samples, 20000);
    for s in [n.body, n.world] {
        assert!((s.mean - 3.0).abs() < 0.15, "{n:?}");
        assert!((s.median - 2.37).abs() < 0.15, "{n:?}");
    }
    let small: Vec<_> = rows
        .iter()
        .map(|r| {
            let mut r = *r;
            for x in &mut r[8..] {
                *x *= 0.25;
            }
            Ok(r)
        })
        .collect();
    let n4 = velocity_nees(small.into_iter(), at, &q_wv)
        .unwrap()
        .unwrap();
    assert!((n4.body.mean / n.body.mean - 4.0).abs() < 1e-6, "{n4:?}");
    assert!((n4.world.mean / n.world.mean - 4.0).abs() < 1e-6, "{n4:?}");
    let n0 = velocity_nees(rows.iter().map(|r| Ok(*r)), at, &Quat::identity())
        .unwrap()
        .unwrap();
    assert!(n0.world.mean > 30.0, "{n0:?}");
    assert_eq!(n0.body, n.body);
    // Nothing to compare: no ground truth at the stamps.
    assert_eq!(
        velocity_nees(rows.iter().map(|r| Ok(*r)), |_| None, &q_wv).unwrap(),
        None
    );
}
