//! The image front end on real images: EuRoC V1_01 at rest (tracks must not drift) and the
//! hand-held DM-VIO RealSense walk (track counts and lengths, with and without gyro hints), plus
//! the cross-target determinism hash. They need `../shared/data` and fail when it is missing.

mod frontend_common;

use frontend_common::*;
use povins_core::camera::PinholeCamera;
use povins_core::frontend::image::{
    pyramid_bytes, track_point, DetectorConfig, EurocTracker, LkConfig, LkScratch, Photometric,
    Pyramid, RansacConfig, RansacModel, TrackerConfig,
};

type Pyr = Pyramid<{ pyramid_bytes(752, 480, 4) }, 4>;

/// Hash of the current implementation (x86-64 and aarch64 agree, `scripts/cross-check.sh`); any
/// change to the front end's arithmetic or decisions changes it (update deliberately).
const GOLDEN_FRONTEND_HASH: u64 = 0x973d_c23b_e7a9_a463;

const NEEDS_DATA: &str = "needs ../shared/data (large shared sequences)";

fn summary_line(name: &str, s: &Summary) {
    let lens: Vec<f64> = s.lengths.iter().map(|&l| f64::from(l)).collect();
    println!(
        "{name}: {} frames, tracked from previous {:.1}/frame, features {:.1}/frame, \
         track length mean {:.1} median {:.0} p90 {:.0} frames, lost (eig, out, residual, fb, \
         ransac, nan) {:?}, detected {}, {:.3} ms/frame (test build)",
        s.frames,
        s.tracked_mean,
        s.total_mean,
        lens.iter().sum::<f64>() / lens.len().max(1) as f64,
        percentile(&lens, 0.5),
        percentile(&lens, 0.9),
        s.lost,
        s.detected,
        s.ms_per_frame
    );
}

/// EuRoC V1_01 "at rest": the MAV still moves the image by 1.7 px (median; OpenCV's LK sees the
/// same) over the 95 frames, so drift is measured against a direct track of the same point
/// from frame 0 to frame 94: chaining 94 frame-to-frame tracks must land where the direct track
/// does. OpenCV (GFTT 150 at 20 px, LK 21x21 maxLevel 3) on the same frames: median 0.019 px,
/// p90 0.078 px over its 139 surviving tracks.
#[test]
#[ignore = "needs ../shared/data (large shared sequences)"]
fn euroc_at_rest_tracks_do_not_drift() {
    let _ = NEEDS_DATA;
    let frames = load_frames(&euroc_dir(), 0, 200);
    assert_eq!(frames.len(), 95);
    big_stack(move || {
        let cfg = TrackerConfig::default();
        let mut t = Box::new(EurocTracker::new(cfg).unwrap());
        let mut first = Vec::new();
        let s = run(
            &mut t,
            &frames,
            &PinholeCamera::EUROC_CAM0,
            |_| None,
            |k, _, t| {
                if k == 0 {
                    first = t.features().to_vec();
                }
            },
        );
        summary_line("EuRoC V1_01 at rest", &s);
        // OpenCV's GFTT finds 139 corners 20 px apart in this frame, we find 119 (candidates are
        // kept per cell, an approximation of GFTT's global greedy choice); the next frame tops
        // the features up to 149.
        assert!(first.len() >= 110, "{}", first.len());
        // Direct tracks from frame 0 to frame 94 on the same pyramids.
        let mut p0 = Box::new(Pyr::new());
        let mut p94 = Box::new(Pyr::new());
        for (p, f) in [(&mut p0, &frames[0]), (&mut p94, &frames[94])] {
            p.build(
                &f.view(),
                cfg.max_level + 1,
                cfg.pyramid_filter,
                cfg.equalization,
            )
            .unwrap();
        }
        let mut scratch = Box::new(LkScratch::new());
        let (mut drift, mut motion) = (Vec::new(), Vec::new());
        for f in t.features() {
            let Some(f0) = first.iter().find(|g| g.id == f.id) else {
                continue;
            };
            let p = [f0.u_px, f0.v_px];
            let Ok(d) = track_point(&p0, &p94, p, p, cfg.max_level, &cfg.lk, &mut scratch) else {
                continue;
            };
            drift.push(libm::hypot(f.u_px - d.pos[0], f.v_px - d.pos[1]));
            motion.push(libm::hypot(f.u_px - f0.u_px, f.v_px - f0.v_px));
        }
        let (med, p90, max) = (
            percentile(&drift, 0.5),
            percentile(&drift, 0.9),
            percentile(&drift, 1.0),
        );
        println!(
            "  first-frame features alive after 94 frames: {} of {}; image motion median {:.3} px; \
             chained vs direct track: median {med:.4} p90 {p90:.4} max {max:.4} px ({} compared)",
            motion.len(),
            first.len(),
            percentile(&motion, 0.5),
            drift.len()
        );
        assert!(
            motion.len() * 10 >= first.len() * 9,
            "only {} survived",
            motion.len()
        );
        assert!(drift.len() * 10 >= motion.len() * 9);
        assert!(med < 0.05, "median drift {med} px");
        assert!(p90 < 0.2, "p90 drift {p90} px");
        assert!(s.total_mean >= 145.0);
    });
}

/// DM-VIO, whole 60 s: the default tracker (forward-backward 0.5 px, RANSAC) with gyro hints
/// (camera delay -50 ms) and without, and in OpenCV's settings against OpenCV's figures on the
/// same 1059 frames (`../shared/peers/opencv_klt.py --frames 1059`, GFTT top-up to 150 at
/// minDistance 15 + LK 21x21 maxLevel 3: 147.8 tracked from the previous frame per frame, the
/// 150 tracks alive at the end 71.6 frames old; with its 1 px forward-backward check 140.4 and
/// 69.1).
#[test]
#[ignore = "needs ../shared/data (large shared sequences)"]
fn dmvio_handheld_track_counts_and_lengths() {
    let frames = load_frames(&dmvio_dir(), 0, 2000);
    assert_eq!(frames.len(), 1059);
    let gyro = load_gyro(&dmvio_dir());
    big_stack(move || {
        let r_bc = mat3(&DMVIO_R_BC);
        let stamps: Vec<i64> = frames.iter().map(|f| f.t_ns).collect();
        let rot = |k: usize| {
            (k > 0).then(|| camera_rotation(&gyro, stamps[k - 1], stamps[k], DMVIO_TD_NS, &r_bc))
        };
        let def = TrackerConfig::default();
        // OpenCV's peer: no forward-backward check, no RANSAC, 15 px apart, no cell cap, and
        // GFTT's relative threshold only (a token absolute floor), and LK without photometric
        // compensation (OpenCV's has none).
        let cv = TrackerConfig {
            fb_check: false,
            lk: LkConfig {
                photometric: Photometric::None,
                ..def.lk
            },
            ransac: RansacConfig {
                model: RansacModel::Off,
                ..def.ransac
            },
            detector: DetectorConfig {
                min_distance_px: 15.0,
                max_per_cell: 16,
                min_eigen: 0.5,
                ..def.detector
            },
            ..def
        };
        let cv_fb = TrackerConfig {
            fb_check: true,
            fb_threshold_px: 1.0,
            ..cv
        };
        let run_cfg = |name: &str, cfg: TrackerConfig, use_gyro: bool| {
            let mut t = Box::new(EurocTracker::new(cfg).unwrap());
            let mut min_total = u32::MAX;
            let s = run(
                &mut t,
                &frames,
                &DMVIO_CAM,
                |k| if use_gyro { rot(k) } else { None },
                |k, st, _| {
                    if k > 0 {
                        min_total = min_total.min(st.total);
                    }
                },
            );
            summary_line(&format!("DM-VIO hand-held ({name})"), &s);
            println!(
                "  min features in a frame {min_total}; tracks alive at the end {}, mean age {:.1}",
                s.alive_end, s.alive_mean_age
            );
            (s, min_total)
        };
        for use_gyro in [true, false] {
            let (s, min_total) = run_cfg(
                if use_gyro {
                    "defaults, gyro"
                } else {
                    "defaults, no hints"
                },
                def,
                use_gyro,
            );
            // Measured 132.8 (gyro) and 133.0 tracked, 145.5-145.7 features, min 69.
            assert!(s.tracked_mean >= 125.0, "{}", s.tracked_mean);
            assert!(s.total_mean >= 140.0, "{}", s.total_mean);
            assert!(min_total >= 40, "{min_total}");
            assert!(s.alive_mean_age >= 55.0, "{}", s.alive_mean_age);
        }
        let (s, _) = run_cfg("OpenCV's settings", cv, false);
        assert!(
            s.tracked_mean >= 147.8,
            "{} < OpenCV's 147.8",
            s.tracked_mean
        );
        assert!(
            s.alive_mean_age >= 71.6,
            "{} < OpenCV's 71.6",
            s.alive_mean_age
        );
        let (s, _) = run_cfg("OpenCV's settings, forward-backward 1 px", cv_fb, false);
        assert!(
            s.tracked_mean >= 140.4,
            "{} < OpenCV's 140.4",
            s.tracked_mean
        );
        // 68.6 against OpenCV's 69.1: the one figure where we trail (by half a frame).
        assert!(s.alive_mean_age >= 65.0, "{}", s.alive_mean_age);
    });
}

/// Bit-exact determinism across targets: 60 moving DM-VIO frames with gyro hints (2-point
/// RANSAC, top-up detection) and 40 EuRoC frames (radial-tangential undistortion, 8-point
/// path), hashing every track id, position and age bit pattern and every counter.
/// `scripts/cross-check.sh` runs it on x86-64 and under qemu on aarch64 and compares the line.
#[test]
#[ignore = "needs ../shared/data (large shared sequences)"]
fn frontend_determinism_hash() {
    let dm = load_frames(&dmvio_dir(), 200, 60);
    let eu = load_frames(&euroc_dir(), 0, 40);
    let gyro = load_gyro(&dmvio_dir());
    let h = big_stack(move || {
        let mut h = Fnv::new();
        let r_bc = mat3(&DMVIO_R_BC);
        let mut hash_run =
            |frames: &[Frame],
             cam: &PinholeCamera,
             gyro: Option<&[(i64, povins_core::math::Vec3)]>| {
                let mut t = Box::new(EurocTracker::new(TrackerConfig::default()).unwrap());
                let stamps: Vec<i64> = frames.iter().map(|f| f.t_ns).collect();
                run(
                    &mut t,
                    frames,
                    cam,
                    |k| {
                        let g = gyro?;
                        (k > 0).then(|| {
                            camera_rotation(g, stamps[k - 1], stamps[k], DMVIO_TD_NS, &r_bc)
                        })
                    },
                    |_, st, t| {
                        for (f, &a) in t.features().iter().zip(t.ages()) {
                            h.u64(f.id);
                            h.f64(f.u_px);
                            h.f64(f.v_px);
                            h.u64(u64::from(a));
                        }
                        for c in [
                            st.tracked,
                            st.lost_small_eigen,
                            st.lost_out_of_image,
                            st.lost_residual,
                            st.lost_forward_backward,
                            st.lost_ransac,
                            st.lk_iterations,
                            st.detected,
                            st.ransac.iterations,
                        ] {
                            h.u64(u64::from(c));
                        }
                    },
                );
            };
        hash_run(&dm, &DMVIO_CAM, Some(&gyro));
        hash_run(&eu, &PinholeCamera::EUROC_CAM0, None);
        h.0
    });
    println!("POVINS_FRONTEND_HASH={h:016x}");
    assert_eq!(h, GOLDEN_FRONTEND_HASH, "golden hash changed: {h:016x}");
}
