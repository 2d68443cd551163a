//! Camera model: projection, distortion Jacobians, undistortion round trips (EuRoC radtan over the
//! whole image, equidistant fisheye), and the real EuRoC calibration file.

mod numdiff;
mod vision_common;

use nalgebra::SMatrix;
use numdiff::num_jac;
use povins_core::camera::{Distortion, PinholeCamera, Vec2};
use povins_core::math::Vec3;
use povins_core::Error;
use vision_common::{data_dir, Rng};

fn euroc_cam0() -> PinholeCamera {
    PinholeCamera::EUROC_CAM0
}

/// TUM-VI cam0 (512x512, Kalibr equidistant): a real fisheye calibration.
fn tumvi_cam0() -> PinholeCamera {
    PinholeCamera {
        readout_s: 0.0,
        width: 512,
        height: 512,
        fx: 190.97847715128717,
        fy: 190.9733070521226,
        cx: 254.93170605935475,
        cy: 256.8974428996504,
        distortion: Distortion::Equidistant {
            k: [
                0.0034823894022493434,
                0.0007150348452162257,
                -0.0020532361418706202,
                0.00020293673591811182,
            ],
        },
    }
}

/// Max pixel round-trip error `distort(undistort(px)) - px` over a 1-px grid of the image
/// (every pixel centre), and the number of pixels that failed to undistort.
fn round_trip_whole_image(cam: &PinholeCamera, skip_radius_px: f64) -> (f64, usize, usize) {
    let (mut worst, mut failed, mut tested) = (0.0f64, 0usize, 0usize);
    for v in 0..cam.height {
        for u in 0..cam.width {
            let (u, v) = (u as f64, v as f64);
            let r = libm::hypot(u - cam.cx, v - cam.cy);
            if r > skip_radius_px {
                continue;
            }
            tested += 1;
            match cam.undistort(u, v) {
                Ok(x) => {
                    assert_eq!(x.z, 1.0);
                    let back = cam.distort(&Vec2::new(x.x, x.y));
                    worst = worst.max((back - Vec2::new(u, v)).norm());
                }
                Err(_) => failed += 1,
            }
        }
    }
    (worst, failed, tested)
}

#[test]
fn euroc_radtan_round_trip_every_pixel() {
    let cam = euroc_cam0();
    let (worst, failed, tested) = round_trip_whole_image(&cam, f64::INFINITY);
    assert_eq!(tested, 752 * 480);
    assert_eq!(failed, 0, "undistortion failed on {failed} pixels");
    assert!(worst < 1e-6, "worst round trip {worst:e} px");
    println!("EuRoC radtan: worst pixel round trip {worst:e} px over {tested} pixels");
}

#[test]
fn euroc_radtan_corner_is_strongly_distorted() {
    // The corner ray is far from the distorted one: proves the test above exercises the model.
    let cam = euroc_cam0();
    let x = cam.undistort(0.0, 0.0).unwrap();
    let naive = Vec2::new(-cam.cx / cam.fx, -cam.cy / cam.fy);
    let shift_px = (Vec2::new(x.x, x.y) - naive).norm() * cam.fx;
    assert!(shift_px > 100.0, "corner shift only {shift_px} px");
    // Principal point maps to the optical axis (up to the tangential terms, here ~0).
    let c = cam.undistort(cam.cx, cam.cy).unwrap();
    assert!(c.x.abs() < 1e-15 && c.y.abs() < 1e-15);
}

#[test]
fn equidistant_round_trip_inside_the_image_circle() {
    let cam = tumvi_cam0();
    // Rays up to ~80 deg from the axis (theta_d ~ 1.4 rad): 1.4 * 191 px.
    let (worst, failed, tested) = round_trip_whole_image(&cam, 1.4 * cam.fx);
    assert!(tested > 150_000, "tested {tested}");
    assert_eq!(failed, 0);
    assert!(worst < 1e-6, "worst round trip {worst:e} px");
    println!("TUM-VI equidistant: worst pixel round trip {worst:e} px over {tested} pixels");
}

#[test]
fn equidistant_rejects_rays_beyond_ninety_degrees() {
    let cam = tumvi_cam0();
    // The image corner is > 90 deg off-axis for this 195-deg lens: not on the z = 1 plane.
    assert_eq!(cam.undistort(0.0, 0.0), Err(Error::Degenerate));
}

#[test]
fn normalized_to_pixel_to_normalized_round_trip() {
    let mut rng = Rng::new(7);
    for cam in [euroc_cam0(), tumvi_cam0()] {
        for _ in 0..2000 {
            let x = Vec2::new(rng.range(-0.8, 0.8), rng.range(-0.5, 0.5));
            let px = cam.distort(&x);
            let back = cam.undistort(px.x, px.y).unwrap();
            assert!(
                (Vec2::new(back.x, back.y) - x).norm() < 1e-11,
                "{x:?} -> {back:?}"
            );
        }
    }
}

#[test]
fn distortion_jacobian_matches_numerical() {
    let mut rng = Rng::new(11);
    let undistorted = PinholeCamera {
        readout_s: 0.0,
        distortion: Distortion::None,
        ..euroc_cam0()
    };
    for cam in [euroc_cam0(), tumvi_cam0(), undistorted] {
        let mut pts = vec![Vec2::zeros(), Vec2::new(1e-9, -2e-9), Vec2::new(0.9, -0.6)];
        for _ in 0..50 {
            pts.push(Vec2::new(rng.range(-1.0, 1.0), rng.range(-0.7, 0.7)));
        }
        for x in pts {
            let (_, j) = cam.distort_with_jacobian(&x);
            let jn: SMatrix<f64, 2, 2> =
                num_jac::<2, 2>(1e-6, |d| cam.distort(&(x + Vec2::new(d[0], d[1]))));
            let err = (j - jn).amax();
            assert!(
                err < 1e-5,
                "{:?} at {x:?}: {err:e}\n{j}\n{jn}",
                cam.distortion
            );
        }
    }
}

#[test]
fn project_rejects_points_behind_and_non_finite() {
    let cam = euroc_cam0();
    assert!(cam.project(&Vec3::new(0.1, 0.1, -1.0)).is_none());
    assert!(cam.project(&Vec3::new(0.1, 0.1, 0.0)).is_none());
    assert!(cam.project(&Vec3::new(f64::NAN, 0.1, 1.0)).is_none());
    assert!(cam.project(&Vec3::new(0.0, 0.0, f64::INFINITY)).is_none());
    let p = cam.project(&Vec3::new(0.2, -0.1, 2.0)).unwrap();
    assert_eq!(p, cam.distort(&Vec2::new(0.1, -0.05)));
    // The principal ray lands on the principal point.
    let c = cam.project(&Vec3::new(0.0, 0.0, 3.0)).unwrap();
    assert_eq!(c, Vec2::new(cam.cx, cam.cy));
    assert_eq!(cam.undistort(f64::NAN, 1.0), Err(Error::NonFinite));
}

#[test]
fn in_image_bounds() {
    let cam = euroc_cam0();
    assert!(cam.in_image(0.0, 0.0));
    assert!(cam.in_image(751.0, 479.0));
    assert!(!cam.in_image(751.01, 100.0));
    assert!(!cam.in_image(-0.01, 100.0));
    assert!(!cam.in_image(100.0, 479.5));
    assert!(!cam.in_image(f64::NAN, 100.0));
    assert_eq!(cam.focal(), Vec2::new(458.654, 457.296));
}

/// The calibration in the real dataset matches the constants above, and its tracks (stored as
/// radtan-distorted pixels) undistort back into the image's field of view.
#[test]
fn euroc_real_tracks_undistort() {
    let dir = data_dir().join("euroc-v101-30s-features/mav0");
    let yaml = std::fs::read_to_string(dir.join("cam0/sensor.yaml")).unwrap();
    assert!(yaml.contains("intrinsics: [458.654, 457.296, 367.215, 248.375]"));
    assert!(yaml.contains("[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]"));
    let cam = euroc_cam0();
    let csv = std::fs::read_to_string(dir.join("features0/data.csv")).unwrap();
    let mut n = 0;
    let mut worst = 0.0f64;
    for line in csv.lines().filter(|l| !l.starts_with('#')) {
        let f: Vec<f64> = line.split(',').map(|s| s.trim().parse().unwrap()).collect();
        let (u, v) = (f[2], f[3]);
        let x = cam.undistort(u, v).unwrap();
        let back = cam.distort(&Vec2::new(x.x, x.y));
        worst = worst.max((back - Vec2::new(u, v)).norm());
        // Undistorted rays of this ~100-deg lens stay within ~1.6 on the normalized plane.
        assert!(x.x.abs() < 1.6 && x.y.abs() < 1.2, "{u} {v} -> {x:?}");
        n += 1;
    }
    assert_eq!(n, 13316);
    assert!(worst < 1e-6);
}

#[test]
fn a_rolling_shutters_row_times_span_the_readout_around_the_middle_row() {
    let mut cam = euroc_cam0();
    assert_eq!(cam.row_time_s(0.0), 0.0, "a global shutter");
    cam.readout_s = 0.03;
    // Row centres at integer v: the frame spans v in [-0.5, height - 0.5].
    assert!((cam.row_time_s(-0.5) + 0.015).abs() < 1e-15);
    assert!(cam.row_time_s(239.5).abs() < 1e-15);
    assert!((cam.row_time_s(479.5) - 0.015).abs() < 1e-15);
    // The estimator's configuration accepts 0 to MAX_READOUT_S.
    let ext = povins_core::camera::CameraExtrinsic {
        p_bc: Vec3::zeros(),
        q_bc: nalgebra::UnitQuaternion::identity(),
    };
    let imu = povins_core::inertial::ImuNoise::EUROC_ADIS16448;
    let mut cfg = povins_core::estimator::EstimatorConfig::new(euroc_cam0(), ext, imu);
    assert_eq!(cfg.validate(), Ok(()));
    for (readout_s, ok) in [
        (0.03, true),
        (-1e-3, false),
        (0.21, false),
        (f64::NAN, false),
    ] {
        cfg.camera.readout_s = readout_s;
        assert_eq!(cfg.validate().is_ok(), ok, "readout {readout_s} s");
    }
}

/// The resection's reprojection Jacobian (`landmarks::resection`, right perturbation of the
/// camera pose) against central differences, at random poses and landmarks.
#[test]
fn the_resection_jacobian_matches_central_differences() {
    use povins_core::camera::CameraPose;
    use povins_core::landmarks::resection::reprojection_jacobian;
    use povins_core::math::{quat_exp, Quat};
    let mut rng = Rng::new(17);
    for _ in 0..50 {
        let pose = CameraPose {
            p_wc: Vec3::new(
                rng.range(-3.0, 3.0),
                rng.range(-3.0, 3.0),
                rng.range(-1.0, 1.0),
            ),
            q_wc: Quat::from_euler_angles(
                rng.range(-3.0, 3.0),
                rng.range(-1.5, 1.5),
                rng.range(-3.0, 3.0),
            ),
        };
        let p_c = Vec3::new(
            rng.range(-2.0, 2.0),
            rng.range(-2.0, 2.0),
            rng.range(1.0, 8.0),
        );
        let p_w = pose.q_wc * p_c + pose.p_wc;
        let x_n = [rng.range(-0.5, 0.5), rng.range(-0.5, 0.5)];
        let (_, j) = reprojection_jacobian(&pose, &p_w, &x_n).expect("in front");
        let num = num_jac::<2, 6>(1e-6, |d| {
            let moved = CameraPose {
                q_wc: pose.q_wc * quat_exp(&Vec3::new(d[0], d[1], d[2])),
                p_wc: pose.p_wc + Vec3::new(d[3], d[4], d[5]),
            };
            reprojection_jacobian(&moved, &p_w, &x_n)
                .expect("in front")
                .0
        });
        let err = (j - num).abs().max();
        assert!(err < 1e-6 * (1.0 + num.abs().max()), "{err}\n{j}\n{num}");
    }
}

/// The relative rotation's residual Jacobian (`landmarks::relative_rotation`, left perturbation
/// `R <- Exp(dtheta) R` at a fixed translation direction) against central differences.
#[test]
fn the_relative_rotation_jacobian_matches_central_differences() {
    use povins_core::landmarks::relative_rotation::residual_jacobian;
    use povins_core::math::{exp_so3, Quat};
    let mut rng = Rng::new(23);
    let unit = |rng: &mut Rng| {
        Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(0.5, 1.5),
        )
        .normalize()
    };
    for _ in 0..50 {
        let (a, b, t) = (unit(&mut rng), unit(&mut rng), unit(&mut rng));
        let q = Quat::from_euler_angles(
            rng.range(-3.0, 3.0),
            rng.range(-1.5, 1.5),
            rng.range(-3.0, 3.0),
        );
        let r = q.to_rotation_matrix().into_inner();
        let (_, j) = residual_jacobian(&a, &b, &r, &t);
        let num = num_jac::<1, 3>(1e-6, |d| {
            let moved = exp_so3(&Vec3::new(d[0], d[1], d[2])) * r;
            SMatrix::<f64, 1, 1>::new(residual_jacobian(&a, &b, &moved, &t).0)
        });
        let err = (j.transpose() - num).abs().max();
        assert!(err < 1e-7, "{err}\n{j}\n{num}");
    }
}

/// Synthetic views of 120 landmarks 1.5-8 m away from two cameras rotated by up to 5 degrees:
/// the rotation between them from the tracks alone, started at identity. Exact without noise
/// (the camera moved sideways, forward, or not at all); with 1 px of noise within 0.15 degrees
/// without translation and 0.75 degrees for a 5 cm forward move, with 5% wrong tracks (left
/// out), and within 0.5 degrees for a 20 cm sideways move. (Not asserted, measured: the
/// sideways move with 5% wrong tracks lands 2.8 degrees off, in the minimum where a rotation
/// about the vertical and a forward move explain the sideways flow: `landmarks::relative_rotation`
/// is meant for the small, continuous steps of a chain of frames.) Too few tracks or garbage
/// give `None`, not a panic.
#[test]
fn the_relative_rotation_is_found_from_the_tracks_alone() {
    use povins_core::landmarks::relative_rotation::{fit_relative_rotation, MIN_PAIRS};
    use povins_core::math::{log_so3, quat_exp, Quat};
    let mut rng = Rng::new(5);
    // (translation of B in A, pixel noise, wrong tracks, tolerance in degrees)
    let cases = [
        (Vec3::new(0.05, 0.0, 0.0), 0.0, false, 1e-4),
        (Vec3::new(0.0, 0.01, 0.05), 0.0, false, 1e-4),
        (Vec3::zeros(), 0.0, false, 1e-4),
        (Vec3::new(0.0, 0.01, 0.05), 1.0, true, 0.75),
        (Vec3::zeros(), 1.0, true, 0.15),
        (Vec3::new(0.2, 0.0, 0.0), 1.0, false, 0.5),
    ];
    for (case, (t_ab, noise_px, with_wrong, tol_deg)) in cases.into_iter().enumerate() {
        let sigma = noise_px / 460.0;
        for trial in 0..10 {
            let q_ab = quat_exp(&Vec3::new(
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
            ));
            let mut pairs = Vec::new();
            let mut wrong = 0;
            for k in 0..120 {
                // A landmark in A, seen from B at p_b = R_AB^T (p_a - t_ab).
                let p_a = Vec3::new(
                    rng.range(-3.0, 3.0),
                    rng.range(-2.0, 2.0),
                    rng.range(1.5, 8.0),
                );
                let p_b = q_ab.inverse() * (p_a - t_ab);
                let mut noisy = |p: Vec3| {
                    let x = p / p.z;
                    Vec3::new(x.x + sigma * rng.normal(), x.y + sigma * rng.normal(), 1.0)
                        .normalize()
                };
                let a = noisy(p_a);
                let mut b = noisy(p_b);
                if with_wrong && k % 20 == 0 {
                    // A wrong track: another point's bearing.
                    b = Vec3::new(rng.range(-0.6, 0.6), rng.range(-0.4, 0.4), 1.0).normalize();
                    wrong += 1;
                }
                pairs.push((a, b));
            }
            // The bearing noise the fit is told: at least a tenth of a pixel.
            let told = sigma.max(0.1 / 460.0);
            let fit = fit_relative_rotation(&pairs, &Quat::identity(), told).expect("a fit");
            let err = log_so3(&(fit.q_ab.inverse() * q_ab)).norm().to_degrees();
            assert!(
                err < tol_deg,
                "case {case} trial {trial}: {err} deg, {fit:?}"
            );
            assert!(
                fit.inliers >= 120 - wrong - 3,
                "case {case} trial {trial}: {fit:?}"
            );
            if t_ab.norm() > 0.0 && noise_px == 0.0 {
                // The direction of B's centre in A, with its sign.
                let dir = fit.t_ab.dot(&t_ab.normalize());
                assert!(dir > 0.999, "case {case} trial {trial}: {fit:?}");
            }
        }
    }
    let sigma = 1.0 / 460.0;
    let few = vec![(Vec3::z(), Vec3::z()); MIN_PAIRS - 1];
    assert!(fit_relative_rotation(&few, &Quat::identity(), sigma).is_none());
    let nan = vec![(Vec3::new(f64::NAN, 0.0, 1.0), Vec3::z()); 40];
    assert!(fit_relative_rotation(&nan, &Quat::identity(), sigma).is_none());
    let same = vec![(Vec3::z(), Vec3::z()); 40];
    let _ = fit_relative_rotation(&same, &Quat::identity(), sigma);
    let spread: Vec<(Vec3, Vec3)> = (0..40)
        .map(|k| {
            let a = Vec3::new(0.01 * k as f64, -0.02 * k as f64, 1.0).normalize();
            (a, a)
        })
        .collect();
    assert!(fit_relative_rotation(&spread, &Quat::identity(), 0.0).is_none());
}
