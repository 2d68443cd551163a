//! [`MergedSource`]: the replay's time order and pacing on an injected clock; [`Prefetch`]
//! keeps it.

use super::*;
use crate::dataset::{Calibration, Dataset, Extrinsic, FeatureFrame, LidarScan};
use povins_core::camera::FeatureObs;
use povins_core::camera::PinholeCamera;
use povins_core::inertial::ImuNoise;
use povins_core::math::Vec3;

/// 10 IMU samples every 5 ms from 1 s, frames at 1.0025 s (between samples 0 and 1), 1.010 s
/// (on sample 2) and 0.9 s (before the start), sweeps ending at 1.012 s and 1.001 s.
fn dataset() -> Dataset {
    let obs = |id| FeatureObs {
        id,
        u_px: 1.0,
        v_px: 2.0,
    };
    let pt = |t_ns| LidarPoint {
        t_ns,
        p_l: [1.0, 0.0, 0.0],
        intensity: 0.0,
    };
    Dataset {
        name: "order".into(),
        calib: Calibration {
            camera: PinholeCamera::EUROC_CAM0,
            t_bc: Extrinsic::identity(),
            td_s: 0.0,
            camera_rate_hz: 20.0,
            imu_noise: ImuNoise {
                gyro_noise_density: 1e-4,
                accel_noise_density: 1e-3,
                gyro_bias_rw: 1e-5,
                accel_bias_rw: 1e-4,
                bias_corr_time_s: None,
            },
            imu_rate_hz: 200.0,
            gravity_mps2: 9.81,
            t_bl: None,
            td_l_s: 0.0,
        },
        imu: (0..10)
            .map(|k| ImuSample {
                t_ns: 1_000_000_000 + k * 5_000_000,
                gyro_rps: Vec3::zeros(),
                accel_mps2: Vec3::new(0.0, 0.0, 9.81),
            })
            .collect(),
        features: vec![
            FeatureFrame {
                t_ns: 900_000_000,
                obs: vec![obs(9)],
            },
            FeatureFrame {
                t_ns: 1_002_500_000,
                obs: vec![obs(1)],
            },
            FeatureFrame {
                t_ns: 1_010_000_000,
                obs: vec![obs(2)],
            },
        ],
        images: Vec::new(),
        lidar: vec![
            LidarScan {
                t_ns: 1_002_000_000,
                points: vec![pt(1_002_000_000), pt(1_012_000_000)],
            },
            LidarScan {
                t_ns: 990_000_000,
                points: vec![pt(1_001_000_000)],
            },
        ],
        ground_truth: Vec::new(),
        sim_truth: None,
    }
}

/// A short name per event: `i<sample>`, `f<feature id>`, `l<first point ms>`.
fn names(src: &mut impl Source) -> Vec<String> {
    std::iter::from_fn(|| src.next().expect("in-memory streams do not fail"))
        .map(|e| match e {
            SensorEvent::Imu(s) => format!("i{}", (s.t_ns - 1_000_000_000) / 5_000_000),
            SensorEvent::Frame { obs, .. } => format!("f{}", obs[0].id),
            SensorEvent::Lidar(p) => format!("l{}", p[0].t_ns / 1_000_000),
            SensorEvent::Image { t_cam_ns, .. } => format!("c{t_cam_ns}"),
        })
        .collect()
}

#[test]
fn events_come_in_the_replay_order() {
    let ds = dataset();
    let mut src = MergedSource::new(&ds, &opts(0, 0.0)).expect("source");
    assert!(!src.is_realtime());
    // Frame 1.0025 s before sample 1, 1.010 s before sample 2 (at its stamp); the sweep ending
    // at 1.001 s before sample 1 (after the frame), the one ending at 1.012 s before sample 3;
    // the frame before the first sample is skipped, as the replay skips it.
    assert_eq!(
        names(&mut src),
        [
            "i0", "f1", "l1001", "i1", "f2", "i2", "l1002", "i3", "i4", "i5", "i6", "i7", "i8",
            "i9"
        ]
    );
    let st = src.stats();
    assert_eq!((st.imu, st.camera_read, st.sweeps_read), (10, 3, 2));
    // The same events through the prefetching helper thread.
    let src = MergedSource::new(&ds, &opts(0, 0.0)).expect("source");
    let (prefetched, inner) = Prefetch::run(src, names);
    assert_eq!(prefetched.len(), 14);
    assert_eq!(inner.stats(), st);
}

/// Frames, no pacing, from `start_ns`, LiDAR offset `td_l_s`.
fn opts(start_ns: i64, td_l_s: f64) -> MergeOptions {
    MergeOptions {
        start_ns,
        td_l_s,
        ..MergeOptions::new(CameraInput::Frames)
    }
}

#[test]
fn a_late_start_skips_what_was_due_before_it_and_td_delays_sweeps() {
    let ds = dataset();
    let mut src = MergedSource::new(&ds, &opts(1_004_000_000, 0.004)).expect("source");
    // From sample 1 (1.005 s): frame 1.0025 s is before it; the sweep ending at 1.001 s + 4 ms
    // arrives with it, the one ending at 1.012 s + 4 ms with sample 4 (1.020 s).
    assert_eq!(
        names(&mut src),
        ["l1001", "i1", "f2", "i2", "i3", "l1002", "i4", "i5", "i6", "i7", "i8", "i9"]
    );
}

/// A clock that never sleeps: it jumps to the time asked and records it.
struct FakeClock {
    t0: Instant,
    now: Instant,
    sleeps: Vec<Duration>,
}

impl Clock for FakeClock {
    fn now(&mut self) -> Instant {
        self.now
    }

    fn sleep_until(&mut self, t: Instant) {
        self.sleeps.push(t.duration_since(self.t0));
        self.now = self.now.max(t);
    }
}

#[test]
fn pacing_maps_stamps_to_wall_time_with_the_speed_factor() {
    let ds = dataset();
    let t0 = Instant::now();
    let clock = FakeClock {
        t0,
        now: t0,
        sleeps: Vec::new(),
    };
    let paced = MergeOptions {
        pacing: Pacing::Recorded(2.0),
        ..opts(0, 0.0)
    };
    let mut src = MergedSource::with_clock(&ds, &paced, clock).expect("source");
    assert!(src.is_realtime());
    let n = names(&mut src).len();
    assert_eq!(n, 14);
    // One wait per IMU sample, before the frames and sweeps released with it; at speed 2 the
    // 5 ms samples are 2.5 ms apart.
    let ms: Vec<f64> = src
        .clock()
        .sleeps
        .iter()
        .map(|d| d.as_secs_f64() * 1e3)
        .collect();
    let expected = [0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0, 22.5];
    assert_eq!(ms.len(), expected.len(), "{ms:?}");
    for (a, b) in ms.iter().zip(expected) {
        assert!((a - b).abs() < 1e-6, "{ms:?}");
    }
    let due = src.stamp_instant(1_020_000_000).expect("paced");
    assert_eq!(due.duration_since(t0), Duration::from_millis(10));
}

#[test]
fn an_unpaced_source_never_sleeps() {
    let mut p = Pacer::new(Pacing::Recorded(0.0));
    assert!(!p.is_paced());
    let t0 = Instant::now();
    let mut clock = FakeClock {
        t0,
        now: t0,
        sleeps: Vec::new(),
    };
    p.wait_for(5, &mut clock);
    assert!(clock.sleeps.is_empty());
    assert_eq!(p.instant_of(5), None);
}
