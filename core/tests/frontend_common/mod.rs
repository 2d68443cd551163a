//! Loaders for the image front end's real-data tests: EuRoC-layout PNG sequences, cameras, and
//! gyro rotations between frames. Missing data fails loudly (these tests are `#[ignore]`d by
//! default and must not pass silently).
#![allow(dead_code)]

use povins_core::camera::{Distortion, PinholeCamera};
use povins_core::frontend::image::{FeatureTracker, ImageView, TrackHints, TrackStats};
use povins_core::math::{exp_so3, Mat3, Vec3};
use std::path::{Path, PathBuf};

/// `shared/data` next to the repository root.
pub fn data_dir() -> PathBuf {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    assert!(
        p.is_dir(),
        "test data folder {} is missing (expected shared/data next to the repo root)",
        p.display()
    );
    p
}

pub fn euroc_dir() -> PathBuf {
    data_dir().join("euroc-v101-images-at-rest/mav0")
}

pub fn dmvio_dir() -> PathBuf {
    data_dir().join("dmvio-realsense-handheld-60s/mav0")
}

/// The DM-VIO RealSense camera (640x360, no distortion; `cam0/sensor.yaml`).
pub const DMVIO_CAM: PinholeCamera = PinholeCamera {
    readout_s: 0.0,
    width: 640,
    height: 360,
    fx: 453.129_882_812_5,
    fy: 453.275_482_177_7,
    cx: 321.198_181_152_3,
    cy: 176.321_121_215_8,
    distortion: Distortion::None,
};

/// DM-VIO `T_BS` rotation (camera to body = IMU).
pub const DMVIO_R_BC: [[f64; 3]; 3] = [
    [0.9999429970, -0.0093268331, 0.0052792016],
    [0.0094527379, 0.9996590007, -0.0243486997],
    [-0.0050502972, 0.0243971986, 0.9996900050],
];

/// Camera delay of the DM-VIO sequence (`t_imu = t_cam + td`), measured in its README.
pub const DMVIO_TD_NS: i64 = -50_000_000;

/// An 8-bit grayscale frame.
pub struct Frame {
    pub t_ns: i64,
    pub width: usize,
    pub height: usize,
    pub px: Vec<u8>,
}

impl Frame {
    pub fn view(&self) -> ImageView<'_> {
        ImageView::new(&self.px, self.width, self.height, self.width).unwrap()
    }
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(String::from)
        .collect()
}

pub fn decode_png(path: &Path) -> (usize, usize, Vec<u8>) {
    let f = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut rd = png::Decoder::new(std::io::BufReader::new(f))
        .read_info()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buf = vec![0u8; rd.output_buffer_size()];
    let info = rd.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Grayscale, png::BitDepth::Eight),
        "{} is not mono8",
        path.display()
    );
    let (w, h) = (info.width as usize, info.height as usize);
    let mut px = Vec::with_capacity(w * h);
    for row in buf.chunks(info.line_size).take(h) {
        px.extend_from_slice(&row[..w]);
    }
    assert_eq!(px.len(), w * h);
    (w, h, px)
}

/// Frames `start..start + count` of `mav0/cam0` (fewer if the sequence is shorter).
pub fn load_frames(mav0: &Path, start: usize, count: usize) -> Vec<Frame> {
    let cam = mav0.join("cam0");
    lines(&cam.join("data.csv"))
        .iter()
        .skip(start)
        .take(count)
        .map(|l| {
            let mut it = l.split(',');
            let t_ns: i64 = it.next().unwrap().trim().parse().unwrap();
            let name = it.next().unwrap().trim();
            let (width, height, px) = decode_png(&cam.join("data").join(name));
            Frame {
                t_ns,
                width,
                height,
                px,
            }
        })
        .collect()
}

/// Gyro samples `(t_ns, w_rps)` of `mav0/imu0/data.csv`.
pub fn load_gyro(mav0: &Path) -> Vec<(i64, Vec3)> {
    lines(&mav0.join("imu0/data.csv"))
        .iter()
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let f = |i: usize| v[i].trim().parse::<f64>().unwrap();
            (v[0].trim().parse().unwrap(), Vec3::new(f(1), f(2), f(3)))
        })
        .collect()
}

/// Body rotation from `t0` to `t1` (`R_b0_b1`) by zero-order-hold integration of the gyro.
pub fn integrate_gyro(gyro: &[(i64, Vec3)], t0: i64, t1: i64) -> Mat3 {
    let mut r = Mat3::identity();
    for w in gyro.windows(2) {
        let (a, b) = (w[0].0.max(t0), w[1].0.min(t1));
        if b > a {
            r *= exp_so3(&(w[0].1 * ((b - a) as f64 * 1e-9)));
        }
    }
    r
}

/// `R_cur_prev` in camera axes between two camera stamps, with the camera delay and `R_bc`.
pub fn camera_rotation(
    gyro: &[(i64, Vec3)],
    t_prev_cam: i64,
    t_cur_cam: i64,
    td_ns: i64,
    r_bc: &Mat3,
) -> Mat3 {
    let r_bprev_bcur = integrate_gyro(gyro, t_prev_cam + td_ns, t_cur_cam + td_ns);
    r_bc.transpose() * r_bprev_bcur.transpose() * r_bc
}

pub fn mat3(m: &[[f64; 3]; 3]) -> Mat3 {
    Mat3::from_fn(|i, j| m[i][j])
}

/// FNV-1a 64 over bit patterns.
pub struct Fnv(pub u64);

impl Fnv {
    pub fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    pub fn u64(&mut self, x: u64) {
        self.bytes(&x.to_le_bytes());
    }
    pub fn f64(&mut self, x: f64) {
        self.u64(x.to_bits());
    }
}

/// Runs `f` on a thread with a 256 MiB stack (trackers are large values).
pub fn big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(256 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap()
}

/// Per-sequence summary of a tracking run.
#[derive(Debug, Default, Clone)]
pub struct Summary {
    pub frames: usize,
    pub tracked_mean: f64,
    pub total_mean: f64,
    pub lost: [u64; 6],
    pub detected: u64,
    /// Lengths (frames tracked) of tracks that ended, and of those alive at the end.
    pub lengths: Vec<u32>,
    /// Tracks alive after the last frame and their mean age (frames), as OpenCV's peer prints.
    pub alive_end: usize,
    pub alive_mean_age: f64,
    pub ms_per_frame: f64,
}

/// Tracks `frames` with `tracker`, hints from `hint(k)` (frame index), returns the summary
/// and calls `each` after every frame.
pub fn run<const F: usize, const B: usize, const L: usize>(
    tracker: &mut FeatureTracker<F, B, L>,
    frames: &[Frame],
    camera: &PinholeCamera,
    mut hint: impl FnMut(usize) -> Option<Mat3>,
    mut each: impl FnMut(usize, &TrackStats, &FeatureTracker<F, B, L>),
) -> Summary {
    let mut s = Summary::default();
    let mut ages_prev: Vec<(u64, u32)> = Vec::new();
    let (mut tracked, mut total) = (0u64, 0u64);
    let mut elapsed = std::time::Duration::ZERO;
    for (k, f) in frames.iter().enumerate() {
        let r = hint(k);
        let hints = TrackHints {
            r_cur_prev: r,
            predictions: &[],
        };
        let t0 = std::time::Instant::now();
        let st = tracker.track(f.t_ns, &f.view(), &hints, camera).unwrap();
        elapsed += t0.elapsed();
        if k > 0 {
            tracked += u64::from(st.tracked);
        }
        total += u64::from(st.total);
        s.lost[0] += u64::from(st.lost_small_eigen);
        s.lost[1] += u64::from(st.lost_out_of_image);
        s.lost[2] += u64::from(st.lost_residual);
        s.lost[3] += u64::from(st.lost_forward_backward);
        s.lost[4] += u64::from(st.lost_ransac);
        s.lost[5] += u64::from(st.lost_nonfinite);
        s.detected += u64::from(st.detected);
        // Tracks that ended this frame.
        let alive: std::collections::HashSet<u64> =
            tracker.features().iter().map(|f| f.id).collect();
        for &(id, age) in &ages_prev {
            if !alive.contains(&id) {
                s.lengths.push(age);
            }
        }
        ages_prev = tracker
            .features()
            .iter()
            .zip(tracker.ages())
            .map(|(f, &a)| (f.id, a))
            .collect();
        each(k, &st, tracker);
    }
    s.lengths.extend(ages_prev.iter().map(|&(_, a)| a));
    s.alive_end = ages_prev.len();
    s.alive_mean_age =
        ages_prev.iter().map(|&(_, a)| f64::from(a)).sum::<f64>() / ages_prev.len().max(1) as f64;
    s.frames = frames.len();
    s.tracked_mean = tracked as f64 / (frames.len().max(2) - 1) as f64;
    s.total_mean = total as f64 / frames.len().max(1) as f64;
    s.ms_per_frame = elapsed.as_secs_f64() * 1e3 / frames.len().max(1) as f64;
    s
}

pub fn percentile(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return f64::NAN;
    }
    s[((s.len() - 1) as f64 * p).round() as usize]
}
