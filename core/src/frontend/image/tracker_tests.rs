//! Tests of `tracker.rs` (included as its `#[cfg(test)]` module).
extern crate std;
use super::super::testutil::{
    big_stack, noise, render, render_rotated, small_tracker_config as cfg, test_camera as cam,
    texture,
};
use super::*;
use crate::math::{exp_so3, Vec3};
use std::vec::Vec;

const W: usize = 320;
const H: usize = 240;
type Small = FeatureTracker<64, { pyramid_bytes(W, H, 4) }, 4>;

fn view(img: &[u8]) -> ImageView<'_> {
    ImageView::new(img, W, H, W).unwrap()
}

#[test]
fn tracks_a_translating_texture_with_stable_ids_and_ages() {
    big_stack(|| {
        let mut t = Small::new(cfg()).unwrap();
        let (sx, sy) = (1.3, -0.6);
        let mut first: Vec<FeatureObs> = Vec::new();
        for k in 0..6 {
            let img = render(W, H, sx * k as f64, sy * k as f64, texture);
            let st = t
                .track(k * 50_000_000, &view(&img), &TrackHints::NONE, &cam())
                .unwrap();
            if k == 0 {
                assert_eq!(st.detected, 40);
                first = t.features().to_vec();
            } else {
                assert_eq!(st.previous, 40);
                // Features near the border may leave; the rest must be tracked.
                assert!(st.tracked >= 36, "{st:?}");
                assert_eq!(st.ransac_run, RansacRun::SkippedLowFlow);
            }
            assert_eq!(st.total, 40);
        }
        // Every feature of the first frame still alive sits at its start + 5 shifts.
        let mut alive = 0;
        for (f, &age) in t.features().iter().zip(t.ages()) {
            if let Some(f0) = first.iter().find(|g| g.id == f.id) {
                assert_eq!(age, 5);
                let e = libm::hypot(f.u_px - f0.u_px - 5.0 * sx, f.v_px - f0.v_px - 5.0 * sy);
                // Five chained tracks, each stopped within epsilon_px = 0.03 (single shifts
                // are tracked to 0.015 px: see the LK tests).
                assert!(e < 0.1, "id {} error {e:.4} px", f.id);
                alive += 1;
            }
        }
        assert!(alive >= 30, "{alive}");
        // Ids are sorted and new ids continue after the old ones.
        assert!(t.features().windows(2).all(|p| p[0].id < p[1].id));
    });
}

#[test]
fn rotation_and_prediction_seeding() {
    big_stack(|| {
        let r1 = exp_so3(&Vec3::new(0.0, 0.0, 0.0));
        // 0.12 rad yaw + some roll: ~36 px of image motion, beyond a single level's reach.
        let r2 = exp_so3(&Vec3::new(0.01, 0.12, 0.03));
        let (a, b) = (render_rotated(&r1), render_rotated(&r2));
        let r_cur_prev = r2.transpose() * r1;
        let c = TrackerConfig {
            rotation_max_level: 0,
            predicted_max_level: 0,
            fb_max_level: 0,
            max_level: 0,
            ..cfg()
        };
        // The true position of a first-frame feature in the second image.
        let truth = |f: &FeatureObs| {
            let x = r_cur_prev * Vec3::new((f.u_px - 159.5) / 300.0, (f.v_px - 119.5) / 300.0, 1.0);
            [300.0 * x.x / x.z + 159.5, 300.0 * x.y / x.z + 119.5]
        };
        let correct = |t: &Small, before: &[FeatureObs]| {
            t.features()
                .iter()
                .filter(|f| {
                    before.iter().find(|b| b.id == f.id).is_some_and(|b| {
                        let p = truth(b);
                        libm::hypot(f.u_px - p[0], f.v_px - p[1]) < 1.0
                    })
                })
                .count()
        };
        // Without hints and a single level, the big motion is lost (the few survivors of
        // this quasi-periodic texture are mostly a period off).
        let mut t = Small::new(c).unwrap();
        t.track(0, &view(&a), &TrackHints::NONE, &cam()).unwrap();
        let before = t.features().to_vec();
        t.track(1, &view(&b), &TrackHints::NONE, &cam()).unwrap();
        let n = correct(&t, &before);
        assert!(n < 5, "{n} correct tracks without hints");
        // With the gyro rotation the seed is right and one level suffices.
        let mut t = Small::new(c).unwrap();
        t.track(0, &view(&a), &TrackHints::NONE, &cam()).unwrap();
        let hints = TrackHints {
            r_cur_prev: Some(r_cur_prev),
            predictions: &[],
        };
        let st = t.track(1, &view(&b), &hints, &cam()).unwrap();
        // Features whose rotated seed leaves the image fall back to their previous position
        // (and are then lost: too far for one level).
        assert!(st.seeded_rotation >= 30, "{st:?}");
        assert_eq!(st.seeded_rotation + st.seeded_previous, st.previous);
        assert!(st.tracked >= 30, "{st:?}");
        assert_eq!(st.tracked, st.seeded_rotation);
        assert_eq!(correct(&t, &before), st.tracked as usize);
        // Pure rotation (36 px of motion, no parallax): the 8-point model would be
        // degenerate, Auto runs the 2-point model with the gyro rotation.
        assert_eq!(st.ransac_run, RansacRun::TwoPoint);
        // Predictions (here: the exact rotation-only projection) take precedence.
        let mut t = Small::new(c).unwrap();
        t.track(0, &view(&a), &TrackHints::NONE, &cam()).unwrap();
        let preds: Vec<(u64, [f64; 2])> = before
            .iter()
            .map(|f| {
                let x =
                    r_cur_prev * Vec3::new((f.u_px - 159.5) / 300.0, (f.v_px - 119.5) / 300.0, 1.0);
                (f.id, [300.0 * x.x / x.z + 159.5, 300.0 * x.y / x.z + 119.5])
            })
            .chain([(9999, [1.0, 1.0]), (0, [f64::NAN, 0.0])])
            .collect();
        let hints = TrackHints {
            r_cur_prev: None,
            predictions: &preds,
        };
        let st = t.track(1, &view(&b), &hints, &cam()).unwrap();
        // Predictions outside the image, unknown ids and NaN are ignored (id 0's NaN entry
        // comes after its valid one); the others seed the features.
        assert!(st.seeded_prediction >= 30, "{st:?}");
        assert_eq!(st.seeded_prediction + st.seeded_previous, st.previous);
        assert!(st.tracked >= 30, "{st:?}");
        let in_image = |p: &[f64; 2]| (0.0..319.0).contains(&p[0]) && (0.0..239.0).contains(&p[1]);
        for f in t.features().iter().filter(|f| f.id < 40) {
            let (_, p) = preds.iter().find(|p| p.0 == f.id).unwrap();
            if !in_image(p) {
                continue; // seeded at its previous position instead
            }
            // The patches are warped: the 0.12 rad yaw compresses the image by up to 9% near
            // the left edge (1 / (cos b - x sin b)^2 at x = -0.44), so a 21 px window's edges
            // move ~0.9 px relative to its centre and a translation-only LK is biased by up
            // to a few tenths of a pixel. (Pure shifts: 0.015 px, see the LK tests.)
            assert!(
                libm::hypot(f.u_px - p[0], f.v_px - p[1]) < 1.0,
                "{f:?} vs {p:?}"
            );
        }
    });
}

#[test]
fn occluded_features_are_dropped() {
    big_stack(|| {
        let mut t = Small::new(cfg()).unwrap();
        let a = render(W, H, 0.0, 0.0, texture);
        t.track(0, &view(&a), &TrackHints::NONE, &cam()).unwrap();
        // Frame 2: the same view with a 100x100 block replaced by another texture.
        let mut b = render(W, H, 0.7, 0.4, texture);
        let other = render(W, H, 0.0, 0.0, |x, y| {
            texture(y * 1.7 + 40.0, 90.0 - x * 1.3)
        });
        for y in 60..160 {
            for x in 100..200 {
                b[y * W + x] = other[y * W + x];
            }
        }
        let inside =
            |f: &FeatureObs| (95.0..205.0).contains(&f.u_px) && (55.0..165.0).contains(&f.v_px);
        let n_in = t.features().iter().filter(|f| inside(f)).count();
        assert!(n_in >= 4, "{n_in}");
        let old: Vec<u64> = t
            .features()
            .iter()
            .filter(|f| inside(f))
            .map(|f| f.id)
            .collect();
        let st = t.track(1, &view(&b), &TrackHints::NONE, &cam()).unwrap();
        let lost = st.lost_forward_backward
            + st.lost_residual
            + st.lost_small_eigen
            + st.lost_out_of_image;
        assert!(lost as usize >= old.len() - 1, "{st:?}");
        let survivors = t.features().iter().filter(|f| old.contains(&f.id)).count();
        assert!(
            survivors <= 1,
            "{survivors} occluded tracks survived: {st:?}"
        );
    });
}

#[test]
fn odd_images_and_bad_input_never_panic() {
    big_stack(|| {
        let mut t = Small::new(cfg()).unwrap();
        let black = std::vec![0u8; W * H];
        let white = std::vec![255u8; W * H];
        let tex = render(W, H, 0.0, 0.0, texture);
        let mut time = 0i64;
        let mut step = |t: &mut Small, img: &[u8]| {
            time += 1;
            t.track(time, &view(img), &TrackHints::NONE, &cam())
        };
        let st = step(&mut t, &black).unwrap();
        assert_eq!(st.total, 0);
        let st = step(&mut t, &white).unwrap();
        assert_eq!(st.total, 0);
        let st = step(&mut t, &tex).unwrap();
        assert_eq!(st.total, 40);
        // Texture -> black: everything is lost and counted.
        let st = step(&mut t, &black).unwrap();
        assert_eq!(st.tracked, 0);
        assert_eq!(
            st.lost_small_eigen
                + st.lost_residual
                + st.lost_forward_backward
                + st.lost_out_of_image
                + st.lost_ransac
                + st.lost_nonfinite,
            40
        );
        // Noise frames.
        for s in 0..4 {
            let n = noise(W, H, s + 1);
            let st = step(&mut t, &n).unwrap();
            assert!(st.total <= 40);
        }
        // Time must increase; nothing changes on error.
        let before = t.features().to_vec();
        assert_eq!(
            t.track(0, &view(&tex), &TrackHints::NONE, &cam()),
            Err(Error::TimeNotIncreasing)
        );
        assert_eq!(t.features(), &before[..]);
        // Image and camera sizes must agree.
        let small = std::vec![0u8; 100 * 100];
        let v = ImageView::new(&small, 100, 100, 100).unwrap();
        assert_eq!(
            t.track(1000, &v, &TrackHints::NONE, &cam()),
            Err(Error::DimensionMismatch)
        );
        // A size change with a matching camera resets the tracks.
        let c2 = PinholeCamera {
            readout_s: 0.0,
            width: 100,
            height: 100,
            ..cam()
        };
        let st = t.track(1001, &v, &TrackHints::NONE, &c2).unwrap();
        assert!(st.reset);
        assert_eq!((st.previous, st.total), (0, 0));
        // Bad camera and non-finite rotation.
        let bad = PinholeCamera {
            readout_s: 0.0,
            fx: f64::NAN,
            ..cam()
        };
        assert_eq!(
            t.track(2000, &view(&tex), &TrackHints::NONE, &bad),
            Err(Error::InvalidConfig)
        );
        let mut r = Mat3::identity();
        r[(1, 1)] = f64::INFINITY;
        let h = TrackHints {
            r_cur_prev: Some(r),
            predictions: &[],
        };
        assert_eq!(
            t.track(2001, &view(&tex), &h, &cam()),
            Err(Error::NonFinite)
        );
        // An image larger than the pyramid capacity.
        let big = std::vec![0u8; 640 * 480];
        let vb = ImageView::new(&big, 640, 480, 640).unwrap();
        let c3 = PinholeCamera {
            readout_s: 0.0,
            width: 640,
            height: 480,
            ..cam()
        };
        assert_eq!(
            t.track(3000, &vb, &TrackHints::NONE, &c3),
            Err(Error::CapacityExceeded)
        );
        // The tracker still works afterwards.
        let st = t
            .track(4000, &view(&tex), &TrackHints::NONE, &cam())
            .unwrap();
        assert_eq!(st.total, 40);
    });
}

#[test]
fn config_validation() {
    assert!(TrackerConfig::default().validate().is_ok());
    let too_many = TrackerConfig {
        max_features: 65,
        ..cfg()
    };
    assert!(matches!(Small::new(too_many), Err(Error::InvalidConfig)));
    let too_deep = TrackerConfig {
        max_level: 4,
        ..cfg()
    };
    assert!(matches!(Small::new(too_deep), Err(Error::InvalidConfig)));
    let bad_pred = TrackerConfig {
        predicted_max_level: 3,
        max_level: 2,
        ..cfg()
    };
    assert_eq!(bad_pred.validate(), Err(Error::InvalidConfig));
    let even = TrackerConfig {
        lk: LkConfig {
            window: 20,
            ..LkConfig::default()
        },
        ..cfg()
    };
    assert_eq!(even.validate(), Err(Error::InvalidConfig));
}
