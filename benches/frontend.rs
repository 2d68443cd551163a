//! Criterion benches of the image front end on real frames (needs ../shared/data): pyramid,
//! grid corners (full frame and a 15-corner top-up), KLT of 150 features, and the whole tracker
//! step per frame on EuRoC V1_01 at rest (752x480) and the moving DM-VIO hand-held sequence
//! (640x360, first 100 frames) — the frames OpenCV's peer (`../shared/peers/opencv_klt.py`)
//! times — with the default configuration (with and without gyro hints) and with OpenCV's
//! settings (the same work as the peer: no forward-backward check, no RANSAC).
use criterion::{criterion_group, criterion_main, Criterion};
use povins::core::camera::{Distortion, FeatureObs, PinholeCamera};
use povins::core::frontend::image::{
    track_point, Corner, DetectorConfig, Equalization, EurocTracker, GridDetector, ImageView,
    LkConfig, LkScratch, Pyramid, PyramidFilter, RansacConfig, RansacModel, TrackHints,
    TrackerConfig,
};
use povins::core::math::{exp_so3, Mat3, Vec3};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

type Pyr = Pyramid<{ povins::core::frontend::image::pyramid_bytes(752, 480, 4) }, 4>;

struct Frame {
    t_ns: i64,
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Frame {
    fn view(&self) -> ImageView<'_> {
        ImageView::new(&self.px, self.w, self.h, self.w).unwrap()
    }
}

fn data(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel);
    assert!(
        p.is_dir(),
        "{} missing (benches need ../shared/data)",
        p.display()
    );
    p
}

fn load(mav0: &Path, count: usize) -> Vec<Frame> {
    let csv = std::fs::read_to_string(mav0.join("cam0/data.csv")).unwrap();
    csv.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .take(count)
        .map(|l| {
            let mut it = l.split(',');
            let t_ns = it.next().unwrap().trim().parse().unwrap();
            let name = it.next().unwrap().trim();
            let (w, h, px) =
                povins::platform::euroc::read_png_mono8(&mav0.join("cam0/data").join(name))
                    .unwrap();
            Frame {
                t_ns,
                w: w as usize,
                h: h as usize,
                px,
            }
        })
        .collect()
}

const DMVIO_CAM: PinholeCamera = PinholeCamera {
    readout_s: 0.0,
    width: 640,
    height: 360,
    fx: 453.129_882_812_5,
    fy: 453.275_482_177_7,
    cx: 321.198_181_152_3,
    cy: 176.321_121_215_8,
    distortion: Distortion::None,
};

/// `R_cur_prev` (camera axes) for each frame from the gyro of `mav0/imu0` with the camera-IMU
/// rotation `r_bc` and delay `td` (`t_imu = t_cam + td`).
fn gyro_rotations(mav0: &Path, frames: &[Frame], r_bc: Mat3, td: i64) -> Vec<Option<Mat3>> {
    let imu = std::fs::read_to_string(mav0.join("imu0/data.csv")).unwrap();
    let gyro: Vec<(i64, Vec3)> = imu
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l
                .split(',')
                .skip(1)
                .map(|s| s.trim().parse().unwrap())
                .collect();
            (
                l.split(',').next().unwrap().trim().parse().unwrap(),
                Vec3::new(v[0], v[1], v[2]),
            )
        })
        .collect();
    (0..frames.len())
        .map(|k| {
            (k > 0).then(|| {
                let (t0, t1) = (frames[k - 1].t_ns + td, frames[k].t_ns + td);
                let mut r = Mat3::identity();
                for w in gyro.windows(2) {
                    let (a, b) = (w[0].0.max(t0), w[1].0.min(t1));
                    if b > a {
                        r *= exp_so3(&(w[0].1 * ((b - a) as f64 * 1e-9)));
                    }
                }
                r_bc.transpose() * r.transpose() * r_bc
            })
        })
        .collect()
}

fn pyramid(f: &Frame, filter: PyramidFilter) -> Box<Pyr> {
    let mut p = Box::new(Pyr::new());
    p.build(&f.view(), 4, filter, Equalization::Off).unwrap();
    p
}

fn corners(p: &Pyr, n: usize) -> Vec<Corner> {
    let mut d = Box::new(GridDetector::new());
    let mut out = vec![Corner::default(); n];
    let st = d
        .detect(
            &p.level(0).unwrap(),
            &DetectorConfig::default(),
            &[],
            n,
            &mut out,
        )
        .unwrap();
    out.truncate(st.detected as usize);
    out
}

/// Whole tracker steps over `frames` in a loop (the tracker restarts at the end of the list,
/// outside the timing); the mean over many iterations is the per-frame cost of the sequence.
fn step_bench(
    c: &mut Criterion,
    name: &str,
    frames: &[Frame],
    cam: PinholeCamera,
    rot: Option<&[Option<Mat3>]>,
    cfg: TrackerConfig,
) {
    let mut t = Box::new(EurocTracker::new(cfg).unwrap());
    let mut k = 0usize;
    let mut t_ns = 0i64;
    c.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                if k == frames.len() {
                    k = 0;
                    t.reset();
                }
                let f = &frames[k];
                let hints = TrackHints {
                    r_cur_prev: rot.and_then(|r| r[k]),
                    predictions: &[],
                };
                t_ns += 50_000_000;
                let view = f.view();
                let t0 = Instant::now();
                let st = t.track(t_ns, &view, &hints, &cam).unwrap();
                total += t0.elapsed();
                black_box(st);
                k += 1;
            }
            total
        })
    });
}

fn benches(c: &mut Criterion) {
    let eu = load(&data("euroc-v101-images-at-rest/mav0"), 95);
    let dm_dir = data("dmvio-realsense-handheld-60s/mav0");
    let dm = load(&dm_dir, 100);
    // DM-VIO: T_BS rotation, camera delay -50 ms (its README); EuRoC: T_BS rotation, no delay.
    let dm_rbc = Mat3::new(
        0.9999429970,
        -0.0093268331,
        0.0052792016,
        0.0094527379,
        0.9996590007,
        -0.0243486997,
        -0.0050502972,
        0.0243971986,
        0.9996900050,
    );
    let rot = gyro_rotations(&dm_dir, &dm, dm_rbc, -50_000_000);
    let eu_rbc = Mat3::new(
        0.0148655429818,
        -0.999880929698,
        0.00414029679422,
        0.999557249008,
        0.0149672133247,
        0.025715529948,
        -0.0257744366974,
        0.00375618835797,
        0.999660727178,
    );
    let eu_rot = gyro_rotations(&data("euroc-v101-images-at-rest/mav0"), &eu, eu_rbc, 0);

    c.bench_function("frontend/pyramid/752x480_gauss_4_levels", |b| {
        let mut p = Box::new(Pyr::new());
        b.iter(|| {
            p.build(
                &eu[0].view(),
                4,
                PyramidFilter::Gaussian5,
                Equalization::Off,
            )
        })
    });
    c.bench_function("frontend/pyramid/752x480_box_4_levels", |b| {
        let mut p = Box::new(Pyr::new());
        b.iter(|| p.build(&eu[0].view(), 4, PyramidFilter::Box2, Equalization::Off))
    });
    c.bench_function("frontend/pyramid/752x480_gauss_4_levels_clahe", |b| {
        let mut p = Box::new(Pyr::new());
        b.iter(|| {
            p.build(
                &eu[0].view(),
                4,
                PyramidFilter::Gaussian5,
                Equalization::CLAHE_3_8X8,
            )
        })
    });

    let p0 = pyramid(&eu[0], PyramidFilter::Gaussian5);
    let cfg = DetectorConfig::default();
    c.bench_function("frontend/corners/752x480_full_150", |b| {
        let mut d = Box::new(GridDetector::new());
        let mut out = vec![Corner::default(); 150];
        b.iter(|| {
            d.reset();
            d.detect(&p0.level(0).unwrap(), &cfg, &[], 150, &mut out)
                .unwrap()
        })
    });
    let all = corners(&p0, 150);
    let existing: Vec<FeatureObs> = all
        .iter()
        .take(135)
        .enumerate()
        .map(|(i, c)| FeatureObs {
            id: i as u64,
            u_px: f64::from(c.x),
            v_px: f64::from(c.y),
        })
        .collect();
    c.bench_function("frontend/corners/752x480_topup_15_of_150", |b| {
        let mut d = Box::new(GridDetector::new());
        let mut out = vec![Corner::default(); 15];
        b.iter(|| {
            d.reset();
            d.detect(&p0.level(0).unwrap(), &cfg, &existing, 15, &mut out)
                .unwrap()
        })
    });

    for (name, fa, fb) in [
        ("frontend/klt/150_euroc_752x480_4_levels", &eu[0], &eu[1]),
        ("frontend/klt/150_dmvio_640x360_4_levels", &dm[10], &dm[11]),
    ] {
        let (pa, pb) = (
            pyramid(fa, PyramidFilter::Gaussian5),
            pyramid(fb, PyramidFilter::Gaussian5),
        );
        let pts = corners(&pa, 150);
        let lk = LkConfig::default();
        let mut s = Box::new(LkScratch::new());
        c.bench_function(name, |b| {
            b.iter(|| {
                let mut ok = 0;
                for p in &pts {
                    let p = [f64::from(p.x), f64::from(p.y)];
                    ok += usize::from(track_point(&pa, &pb, p, p, 3, &lk, &mut s).is_ok());
                }
                ok
            })
        });
    }

    let def = TrackerConfig::default();
    step_bench(
        c,
        "frontend/step/euroc_752x480_95_frames",
        &eu,
        PinholeCamera::EUROC_CAM0,
        None,
        def,
    );
    step_bench(
        c,
        "frontend/step/euroc_752x480_95_frames_gyro",
        &eu,
        PinholeCamera::EUROC_CAM0,
        Some(&eu_rot),
        def,
    );
    step_bench(
        c,
        "frontend/step/dmvio_640x360_100_frames",
        &dm,
        DMVIO_CAM,
        None,
        def,
    );
    step_bench(
        c,
        "frontend/step/dmvio_640x360_100_frames_gyro",
        &dm,
        DMVIO_CAM,
        Some(&rot),
        def,
    );
    // OpenCV's settings (no forward-backward check, no RANSAC, 15 px, no cell cap): the same work
    // as the peer script.
    let cv = TrackerConfig {
        fb_check: false,
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
    step_bench(
        c,
        "frontend/step/euroc_752x480_95_frames_opencv_settings",
        &eu,
        PinholeCamera::EUROC_CAM0,
        None,
        cv,
    );
    step_bench(
        c,
        "frontend/step/dmvio_640x360_100_frames_opencv_settings",
        &dm,
        DMVIO_CAM,
        None,
        cv,
    );
}

criterion_group! {
    name = frontend;
    config = Criterion::default().sample_size(30).measurement_time(Duration::from_secs(4));
    targets = benches
}
criterion_main!(frontend);
