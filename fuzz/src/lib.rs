//! One function per fuzz target ("run one input"): each feeds arbitrary bytes to a reader's
//! public entry point, or (the estimator) a well-typed operation sequence decoded from them to
//! the core's API. The fuzz targets (`fuzz/fuzz_targets/*.rs`) call these, and so does
//! `tests/fuzz_corpora.rs` of the root package (it includes this file with `#[path]`), which
//! replays every file of `fuzz/corpus/*` and `fuzz/artifacts/*` in a normal `cargo test`.
//!
//! A function returns normally whatever the input (errors are expected and dropped); a panic,
//! a hang or an abort is a bug. Readers that only open paths get the bytes as a file in a
//! per-thread scratch folder (`$POVINS_FUZZ_SCRATCH`, else `/dev/shm`, else the temp folder).
//!
//! This file uses only `povins_core`, `povins_platform`, `povins_host_tools`, `arbitrary` and
//! std, so that both crates can compile it.
#![allow(dead_code)]

use arbitrary::{Arbitrary, Unstructured};
use povins_core::camera::{Distortion, FeatureObs, PinholeCamera};
use povins_core::estimator::{EstimatorConfig, PoVins};
use povins_core::inertial::{ImuSample, NavState};
use povins_core::lidar::LidarPoint;
use povins_core::math::Vec3;
use povins_platform::euroc::rows::{FeatureRows, ImageRows, ImuRows, LidarRows};
use povins_platform::recording::Recording;
use povins_platform::rosrec::{calib_msgs, decode, Encoding, MessageLog};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A target's "run one input".
pub type RunOne = fn(&[u8]);

/// Every target: name and "run one input".
pub const TARGETS: &[(&str, RunOne)] = &[
    ("euroc_csv", euroc_csv),
    ("euroc_yaml", euroc_yaml),
    ("kalibr_yaml", kalibr_yaml),
    ("rosbag1", rosbag1),
    ("mcap", mcap),
    ("ros_msgs", ros_msgs),
    ("image", image),
    ("config_toml", config_toml),
    ("estimator", estimator),
    ("ouster_packets", ouster_packets),
];

/// Most messages or rows read from one input (the inputs are small; this bounds a loop
/// that a reader failing to advance would otherwise make endless: a hang, found as a timeout).
const MAX_ITEMS: usize = 100_000;

// ---------------------------------------------------------------------------------------------
// Scratch files

thread_local! {
    static SCRATCH: RefCell<Option<PathBuf>> = const { RefCell::new(None) };
}

/// This thread's scratch folder (created once).
pub fn scratch() -> PathBuf {
    SCRATCH.with(|s| {
        s.borrow_mut()
            .get_or_insert_with(|| {
                static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
                let base = std::env::var_os("POVINS_FUZZ_SCRATCH")
                    .map(PathBuf::from)
                    .or_else(|| Some(PathBuf::from("/dev/shm")).filter(|p| p.is_dir()))
                    .unwrap_or_else(std::env::temp_dir);
                let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let dir = base.join(format!("povins-fuzz-{}-{n}", std::process::id()));
                std::fs::create_dir_all(&dir).expect("cannot create the fuzz scratch folder");
                dir
            })
            .clone()
    })
}

/// Removes this thread's scratch folder (the corpus test calls it at its end).
pub fn remove_scratch() {
    SCRATCH.with(|s| {
        if let Some(d) = s.borrow_mut().take() {
            let _ = std::fs::remove_dir_all(d);
        }
    });
}

/// Writes `bytes` to `name` (may hold `/`) in the scratch folder.
fn put(name: &str, bytes: &[u8]) -> PathBuf {
    let p = scratch().join(name);
    if let Some(d) = p.parent() {
        std::fs::create_dir_all(d).expect("scratch folder");
    }
    std::fs::write(&p, bytes).expect("cannot write a scratch file");
    p
}

/// The first byte (selects what the rest is fed to) and the rest.
fn split(data: &[u8]) -> (u8, &[u8]) {
    match data.split_first() {
        Some((s, rest)) => (*s, rest),
        None => (0, data),
    }
}

fn drain<T, E>(it: impl Iterator<Item = Result<T, E>>) {
    for r in it.take(MAX_ITEMS) {
        if r.is_err() {
            break;
        }
    }
}

// ---------------------------------------------------------------------------------------------
// EuRoC

fn camera() -> PinholeCamera {
    PinholeCamera {
        distortion: Distortion::None,
        ..PinholeCamera::EUROC_CAM0
    }
}

/// `euroc_csv`: the first byte picks the file kind (IMU, features, LiDAR, camera list, ground
/// truth, or the tail/row scans run when a folder is opened); the rest is the `data.csv`.
pub fn euroc_csv(data: &[u8]) {
    let (sel, body) = split(data);
    let p = put("csv/data.csv", body);
    match sel % 6 {
        0 => {
            if let Ok(r) = ImuRows::open(&p) {
                drain(r)
            }
        }
        1 => {
            if let Ok(r) = FeatureRows::open(&p) {
                drain(r)
            }
        }
        2 => {
            if let Ok(r) = LidarRows::open(&p) {
                drain(r)
            }
        }
        3 => {
            if let Ok(r) = ImageRows::open(&p, &scratch().join("csv/data"), &camera()) {
                drain(r)
            }
        }
        4 => {
            let _ = povins_platform::trajectory::read_euroc_groundtruth(&p);
        }
        _ => {
            let _ = povins_platform::euroc::rows::last_stamp(&p);
            let _ = povins_platform::euroc::rows::count_rows(&p);
        }
    }
}

const IMU_YAML: &str =
    include_str!("../../tests/data/euroc-v101-30s-features/mav0/imu0/sensor.yaml");
const CAM_YAML: &str =
    include_str!("../../tests/data/euroc-v101-30s-features/mav0/cam0/sensor.yaml");
const LIDAR_YAML: &str = "sensor_type: lidar\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n";
const IMU_CSV: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n1403715273262142976,-0.099134701513277898,0.14730578886832138,0.02722713633111154,8.1476917083333333,-0.37592158333333331,-2.4026292499999999\n1403715273267142912,-0.099134701513277898,0.14032447186034408,0.029321531433504733,8.033280791666666,-0.40861041666666664,-2.4026292499999999\n";

/// Writes an EuRoC folder `name` with the given sensor.yaml files (`None`: absent) and a
/// two-row IMU log, and opens it.
fn euroc_folder(
    name: &str,
    imu: &[u8],
    cam: Option<&[u8]>,
    lidar: Option<&[u8]>,
) -> Result<povins_platform::euroc::EurocFolder, povins_platform::IoError> {
    let root = scratch().join(name);
    let _ = std::fs::remove_dir_all(&root);
    put(&format!("{name}/mav0/imu0/data.csv"), IMU_CSV.as_bytes());
    put(&format!("{name}/mav0/imu0/sensor.yaml"), imu);
    if let Some(c) = cam {
        put(&format!("{name}/mav0/cam0/sensor.yaml"), c);
    }
    if let Some(l) = lidar {
        put(&format!("{name}/mav0/lidar0/sensor.yaml"), l);
    }
    povins_platform::euroc::EurocFolder::open(&root)
}

/// `euroc_yaml`: the first byte picks which `sensor.yaml` of an EuRoC folder is the rest
/// (imu0, cam0, lidar0; the others are valid), and the folder is opened.
pub fn euroc_yaml(data: &[u8]) {
    let (sel, body) = split(data);
    let (imu, cam, lidar) = match sel % 3 {
        0 => (body, CAM_YAML.as_bytes(), None),
        1 => (IMU_YAML.as_bytes(), body, None),
        _ => (IMU_YAML.as_bytes(), CAM_YAML.as_bytes(), Some(body)),
    };
    let _ = euroc_folder("yaml", imu, Some(cam), lidar);
}

// ---------------------------------------------------------------------------------------------
// Kalibr

/// `kalibr_yaml`: an even first byte makes the rest a camchain (camera `cam0`), an odd one an
/// `imu.yaml`.
pub fn kalibr_yaml(data: &[u8]) {
    let (sel, body) = split(data);
    let text = String::from_utf8_lossy(body);
    let path = Path::new("fuzz.yaml");
    if sel % 2 == 0 {
        let _ = povins_platform::kalibr::camchain_from_str(path, &text, "cam0");
    } else {
        let _ = povins_platform::kalibr::imu_from_str(path, &text);
    }
}

// ---------------------------------------------------------------------------------------------
// Containers

/// Reads every topic of a message log and decodes its messages as a run would.
fn read_log(log: &dyn MessageLog) {
    let _ = log.describe();
    let _ = log.warnings();
    let mut budget = MAX_ITEMS;
    for t in log.topics() {
        for m in log.messages(&t.topic) {
            if budget == 0 {
                return;
            }
            budget -= 1;
            let Ok(m) = m else { continue };
            let _ = log.locate(m.offset);
            match t.msg_type.as_str() {
                decode::IMU_TYPE => {
                    let _ = decode::imu(t.encoding, &m.data);
                }
                decode::IMAGE_TYPE | decode::COMPRESSED_IMAGE_TYPE => {
                    let _ = decode::image(t.encoding, &t.msg_type, &m.data);
                }
                "sensor_msgs/CameraInfo" => {
                    let _ = calib_msgs::camera_info(t.encoding, &m.data).map(|c| c.camera());
                }
                "tf2_msgs/TFMessage" => {
                    let _ = calib_msgs::tf_message(t.encoding, &m.data);
                }
                _ => {
                    let _ = calib_msgs::frame_id(t.encoding, &m.data);
                }
            }
        }
    }
}

/// `rosbag1`: the bytes are a whole `.bag` file, opened and read as a run reads it.
pub fn rosbag1(data: &[u8]) {
    let p = put("in.bag", data);
    if let Ok(log) = povins_platform::containers::open_log(&p) {
        read_log(log.as_ref());
    }
}

/// `mcap`: the bytes are a whole `.mcap` file, read as a ROS recording (any MCAP) and as
/// povins' own MCAP ([`povins_platform::mcap_io`]).
pub fn mcap(data: &[u8]) {
    let p = put("in.mcap", data);
    let _ = povins_platform::containers::is_ros_recording(&p);
    if let Ok(log) = povins_platform::containers::open_log(&p) {
        read_log(log.as_ref());
    }
    let _ = povins_platform::mcap_io::read_dataset(&p);
}

/// The OS1-128 metadata the crate ships for its tests (BSD-3, Ouster; see its README).
fn ouster_meta() -> &'static povins_platform::ouster::Metadata {
    static META: OnceLock<povins_platform::ouster::Metadata> = OnceLock::new();
    META.get_or_init(|| {
        let json = include_str!("../../platform/src/ouster/testdata/os1-128_v2.3.0_1024x10.json");
        povins_platform::ouster::Metadata::from_json(json).expect("shipped metadata")
    })
}

/// `ouster_packets`: byte 0 picks a small packet layout (profile, 1-4 rows, 1-4 columns per
/// packet, 16 columns per frame, a column window that may wrap, the standard or the `FUSA`
/// header); the rest is decoded as one OS1-128 lidar packet, an IMU packet, a run of
/// small-layout lidar packets into the sweep assembler, metadata JSON and a pcap capture.
pub fn ouster_packets(data: &[u8]) {
    use povins_platform::ouster::{
        decode_imu, Decoder, HeaderType, LidarProfile, Metadata, PcapUdp, SweepAssembler,
    };
    let Some((&sel, rest)) = data.split_first() else {
        return;
    };
    let base = ouster_meta();
    let _ = Decoder::new(base).decode_lidar(rest);
    let _ = decode_imu(rest);
    let sel = usize::from(sel);
    let profiles = [
        LidarProfile::Legacy,
        LidarProfile::Single,
        LidarProfile::Dual,
        LidarProfile::LowDataRate,
    ];
    let mut m = base.clone();
    m.profile = profiles[sel % 4];
    m.pixels_per_column = 1 + (sel >> 2) % 4;
    m.columns_per_packet = 1 + (sel >> 4) % 4;
    m.columns_per_frame = 16;
    m.column_window = [(sel >> 6 & 1) * 5, 9];
    m.header_type = if sel & 0x80 == 0 {
        HeaderType::Standard
    } else {
        HeaderType::Fusa
    };
    m.beam_altitude_angles_deg.truncate(m.pixels_per_column);
    m.beam_azimuth_angles_deg.truncate(m.pixels_per_column);
    m.pixel_shift_by_row.truncate(m.pixels_per_column);
    let dec = Decoder::new(&m);
    let mut asm = SweepAssembler::new(&m);
    for chunk in rest.chunks(dec.lidar_packet_bytes()).take(MAX_ITEMS) {
        if let Ok(p) = dec.decode_lidar(chunk) {
            let _ = asm.push(&p);
        }
    }
    let _ = asm.finish();
    if let Ok(text) = std::str::from_utf8(rest) {
        let _ = Metadata::from_json(text);
    }
    if let Ok(udp) = PcapUdp::new(rest, Path::new("in.pcap")) {
        let _ = udp.take(MAX_ITEMS).count();
    }
}

// ---------------------------------------------------------------------------------------------
// Messages

/// The decoders of [`ros_msgs`], by `selector / 2 % len` (bit 0 of the selector: CDR when set,
/// else ROS 1).
pub const MSG_KINDS: &[&str] = &[
    "sensor_msgs/Imu",
    "sensor_msgs/Image",
    "sensor_msgs/CompressedImage",
    "sensor_msgs/CameraInfo",
    "tf2_msgs/TFMessage",
    "std_msgs/Header",
    "sensor_msgs/PointCloud2",
    "sensor_msgs/PointCloud",
    "nav_msgs/Odometry",
    "livox_ros_driver/CustomMsg",
];

/// The selector byte of [`ros_msgs`] for a message type and encoding (`None`: no decoder).
pub fn msg_selector(msg_type: &str, enc: Encoding) -> Option<u8> {
    let i = MSG_KINDS.iter().position(|k| *k == msg_type)?;
    Some((i as u8) * 2 + u8::from(enc == Encoding::Cdr))
}

/// `ros_msgs`: the first byte picks the decoder and encoding ([`MSG_KINDS`]), the rest is the
/// serialized message. CDR-only types (PointCloud, Odometry: povins reads them from MCAP files)
/// ignore the encoding bit. LiDAR clouds are decoded as a run reads them (any layout, and with
/// `selector / 2 / len` picking a forced layout or the spin assumption for clouds without time).
pub fn ros_msgs(data: &[u8]) {
    use povins_platform::ros2::{convert, msgs};
    let (sel, msg) = split(data);
    let enc = if sel & 1 == 1 {
        Encoding::Cdr
    } else {
        Encoding::Ros1
    };
    match usize::from(sel / 2) % MSG_KINDS.len() {
        0 => {
            let _ = decode::imu(enc, msg);
        }
        1 => {
            let _ = decode::image(enc, decode::IMAGE_TYPE, msg);
        }
        2 => {
            let _ = decode::image(enc, decode::COMPRESSED_IMAGE_TYPE, msg);
        }
        3 => {
            let _ = calib_msgs::camera_info(enc, msg).map(|c| c.camera());
        }
        4 => {
            let _ = calib_msgs::tf_message(enc, msg);
        }
        5 => {
            let _ = calib_msgs::frame_id(enc, msg);
        }
        6 | 9 => {
            use povins_platform::cloud::{livox, CloudOptions, Layout, NoTime};
            let variant = usize::from(sel / 2) / MSG_KINDS.len();
            let opts = CloudOptions {
                layout: match variant % 8 {
                    0 | 7 => None,
                    k => Layout::ALL.get(k - 1).copied(),
                },
                no_time: match variant % 3 {
                    0 => NoTime::Stamp,
                    k => NoTime::Spin {
                        period_ns: 100_000_000,
                        clockwise: k == 1,
                        stamp_is_end: variant.is_multiple_of(2),
                    },
                },
            };
            let ty = if sel / 2 % MSG_KINDS.len() as u8 == 6 {
                decode::POINT_CLOUD2_TYPE
            } else {
                livox::CUSTOM_MSG_TYPE
            };
            let _ = decode::sweep(enc, ty, msg, &opts);
        }
        7 => {
            let _ = msgs::PointCloud::decode(msg).map(|m| convert::features_from_msg(&m));
        }
        _ => {
            if let Ok(o) = msgs::Odometry::decode(msg) {
                let _ = convert::ground_truth_from_msgs(&o, None);
                if let Ok(imu) = msgs::Imu::decode(msg) {
                    let _ = convert::ground_truth_from_msgs(&o, Some(&imu));
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Images

/// Raw encodings tried by [`image`].
const RAW_ENCODINGS: &[&str] = &[
    "mono8",
    "mono16",
    "bgr8",
    "rgb8",
    "bgra8",
    "rgba8",
    "8UC1",
    "16UC1",
    "bayer_rggb8",
    "yuv422",
    "",
];

/// `image`: a payload starting like PNG or JPEG goes through the runner's image path
/// ([`povins_platform::images::decode`] of an encoded image); any other input is a raw image:
/// encoding index, width, height, step (u16 little-endian each), big-endian flag, pixels.
pub fn image(data: &[u8]) {
    use povins_platform::images::{decode, ImageData};
    if data.starts_with(b"\x89PNG") || data.starts_with(&[0xFF, 0xD8]) {
        let _ = decode(&ImageData::Encoded(data.to_vec()));
        return;
    }
    let mut u = Unstructured::new(data);
    let enc = RAW_ENCODINGS[usize::from(u.arbitrary::<u8>().unwrap_or(0)) % RAW_ENCODINGS.len()];
    let w = u32::from(u.arbitrary::<u16>().unwrap_or(0));
    let h = u32::from(u.arbitrary::<u16>().unwrap_or(0));
    let step = u32::from(u.arbitrary::<u16>().unwrap_or(0));
    let be = u.arbitrary::<bool>().unwrap_or(false);
    let px = u.take_rest();
    let _ = povins_platform::image_raw::mono8_from_raw(enc, w, h, step, be, px);
    let _ = decode(&ImageData::Mono8 {
        width: w as usize,
        height: h as usize,
        pixels: px.to_vec(),
    });
}

// ---------------------------------------------------------------------------------------------
// Configuration

/// The EuRoC estimator configuration a run of `tests/data/euroc-v101-30s-features` with
/// `configs/euroc.toml` uses (LiDAR enabled, identity extrinsic).
pub fn euroc_config() -> EstimatorConfig {
    static CFG: OnceLock<EstimatorConfig> = OnceLock::new();
    *CFG.get_or_init(|| {
        let folder = euroc_folder(
            "config",
            IMU_YAML.as_bytes(),
            Some(CAM_YAML.as_bytes()),
            None,
        )
        .expect("the EuRoC calibration opens");
        let mut cfg = povins_host_tools::runner::config_for(&folder as &dyn Recording);
        povins_host_tools::config::RunConfigFile::parse(include_str!("../../configs/euroc.toml"))
            .expect("configs/euroc.toml parses")
            .apply(&mut cfg)
            .expect("configs/euroc.toml applies");
        cfg.lidar.enabled = true;
        cfg
    })
}

/// `config_toml`: the bytes are a `--config` file, parsed and laid over the EuRoC
/// configuration, the front end's settings and the input options.
pub fn config_toml(data: &[u8]) {
    use povins_host_tools::config::{input::InputOptions, RunConfigFile};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(f) = RunConfigFile::parse(text) else {
        return;
    };
    let mut cfg = euroc_config();
    let _ = f.apply(&mut cfg);
    let mut tracker = Default::default();
    let mut aiding = Default::default();
    let _ = f.apply_frontend(&mut tracker, &mut aiding);
    let _ = povins_host_tools::config::effective_toml(&cfg, &tracker, &aiding);
    let _ = InputOptions::from_file(&f);
}

// ---------------------------------------------------------------------------------------------
// Estimator

/// A float: mostly plausible, sometimes extreme or not a number.
#[derive(Debug, Clone, Copy)]
pub struct F(pub f64);

impl<'a> Arbitrary<'a> for F {
    fn arbitrary(u: &mut Unstructured<'a>) -> arbitrary::Result<Self> {
        Ok(F(match u.arbitrary::<u8>()? {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => f64::MAX,
            4 => f64::MIN_POSITIVE,
            5 => -0.0,
            6..=15 => u.arbitrary::<f64>()?,
            _ => f64::from(u.arbitrary::<i16>()?) / 256.0,
        }))
    }
}

fn v3(a: [F; 3]) -> Vec3 {
    Vec3::new(a[0].0, a[1].0, a[2].0)
}

/// The operations of the `estimator` target, by the first byte of each (`% OPS`); the fields
/// follow as `arbitrary` decodes them. Times are relative to the latest time pushed (a `dt` may
/// be zero or negative: out of order).
///
/// - 0 `Imu { dt_us: i32, gyro: [F; 3], accel: [F; 3] }`: a sample `dt_us` after the latest time;
/// - 1 `ImuAt { t_ns: i64, gyro, accel }`: a sample at an absolute time;
/// - 2 `Frame { dt_us: i32, obs: Vec<(u16, F, F)> }`: a frame of observations `(id, u, v)`;
/// - 3 `GridFrame { dt_us: i32, n: u8, shift: i8 }`: `n` in-image observations on a grid;
/// - 4 `Lidar { pts: Vec<(i32, [f32; 3], f32)> }`: a sweep, points `(dt_us, xyz, intensity)`;
/// - 5 `Replay { n: u8 }`: the next `n` real EuRoC samples and the frames between them, each
///   sample followed by `update` until `None` (so sequences reach initialization and the window);
/// - 6 `Update` (until `None`, bounded); 7 `Reset`;
/// - 8 `Initialize { dt_us: i32, p, q: [F; 4], v, bg, ba }` at the latest time plus `dt_us`;
/// - 9 `EndInput`: `end_input`, then `update` until `None` (bounded).
pub const OPS: u8 = 10;

/// An operation decoded to the core's types (built before the estimator runs, so that running
/// allocates nothing).
#[derive(Debug, Clone)]
enum Cmd {
    Imu {
        dt_ns: i64,
        abs: bool,
        g: Vec3,
        a: Vec3,
    },
    Frame {
        dt_ns: i64,
        obs: Vec<FeatureObs>,
    },
    Lidar {
        pts: Vec<(i64, [f32; 3], f32)>,
    },
    Replay(usize),
    Update,
    Reset,
    EndInput,
    Init {
        dt_ns: i64,
        s: NavState,
    },
}

/// The real stream `Op::Replay` plays: IMU and feature frames of the first seconds of
/// `tests/data/euroc-v101-30s-features` (embedded at compile time).
struct Real {
    imu: Vec<ImuSample>,
    frames: Vec<(i64, Vec<FeatureObs>)>,
}

const REAL_SECONDS: f64 = 6.0;

fn real() -> &'static Real {
    static R: OnceLock<Real> = OnceLock::new();
    R.get_or_init(|| {
        let imu_csv = include_str!("../../tests/data/euroc-v101-30s-features/mav0/imu0/data.csv");
        let feat_csv =
            include_str!("../../tests/data/euroc-v101-30s-features/mav0/features0/data.csv");
        let mut imu = Vec::new();
        for l in imu_csv.lines().filter(|l| !l.starts_with('#')) {
            let f: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().unwrap_or(0.0))
                .collect();
            let t: i64 = l
                .split(',')
                .next()
                .unwrap_or("0")
                .trim()
                .parse()
                .unwrap_or(0);
            imu.push(ImuSample {
                t_ns: t,
                gyro_rps: Vec3::new(f[1], f[2], f[3]),
                accel_mps2: Vec3::new(f[4], f[5], f[6]),
            });
        }
        let t_end = imu[0].t_ns + (REAL_SECONDS * 1e9) as i64;
        imu.retain(|s| s.t_ns <= t_end);
        let mut frames: Vec<(i64, Vec<FeatureObs>)> = Vec::new();
        for l in feat_csv.lines().filter(|l| !l.starts_with('#')) {
            let f: Vec<&str> = l.split(',').map(str::trim).collect();
            let t: i64 = f[0].parse().unwrap_or(0);
            if t > t_end {
                break;
            }
            let o = FeatureObs {
                id: f[1].parse().unwrap_or(0),
                u_px: f[2].parse().unwrap_or(0.0),
                v_px: f[3].parse().unwrap_or(0.0),
            };
            match frames.last_mut() {
                Some((tl, obs)) if *tl == t => obs.push(o),
                _ => frames.push((t, vec![o])),
            }
        }
        Real { imu, frames }
    })
}

fn us(dt_us: i32) -> i64 {
    i64::from(dt_us) * 1000
}

fn cmd(u: &mut Unstructured<'_>) -> arbitrary::Result<Cmd> {
    Ok(match u.arbitrary::<u8>()? % OPS {
        op @ (0 | 1) => {
            let (dt_ns, abs) = if op == 0 {
                (us(u.arbitrary()?), false)
            } else {
                (u.arbitrary()?, true)
            };
            Cmd::Imu {
                dt_ns,
                abs,
                g: v3(u.arbitrary()?),
                a: v3(u.arbitrary()?),
            }
        }
        2 => {
            let dt_ns = us(u.arbitrary()?);
            let obs: Vec<(u16, F, F)> = u.arbitrary()?;
            Cmd::Frame {
                dt_ns,
                obs: obs
                    .iter()
                    .map(|(id, u, v)| FeatureObs {
                        id: u64::from(*id),
                        u_px: u.0,
                        v_px: v.0,
                    })
                    .collect(),
            }
        }
        3 => {
            let dt_ns = us(u.arbitrary()?);
            let n: u8 = u.arbitrary()?;
            let shift = f64::from(u.arbitrary::<i8>()?);
            Cmd::Frame {
                dt_ns,
                obs: (0..u64::from(n))
                    .map(|i| FeatureObs {
                        id: i,
                        u_px: 40.0 + (i % 16) as f64 * 42.0 + shift,
                        v_px: 40.0 + (i / 16) as f64 * 25.0 - shift,
                    })
                    .collect(),
            }
        }
        4 => {
            let pts: Vec<(i32, [f32; 3], f32)> = u.arbitrary()?;
            Cmd::Lidar {
                pts: pts.iter().map(|(dt, p, i)| (us(*dt), *p, *i)).collect(),
            }
        }
        5 => Cmd::Replay(usize::from(u.arbitrary::<u8>()?)),
        6 => Cmd::Update,
        7 => Cmd::Reset,
        9 => Cmd::EndInput,
        _ => {
            let dt_ns = us(u.arbitrary()?);
            let p = v3(u.arbitrary()?);
            let q = nalgebra_quat(u.arbitrary()?);
            let v = v3(u.arbitrary()?);
            let bg = v3(u.arbitrary()?);
            let ba = v3(u.arbitrary()?);
            Cmd::Init {
                dt_ns,
                s: NavState {
                    t_ns: 0,
                    p_wb: p,
                    q_wb: q,
                    v_wb: v,
                    bg,
                    ba,
                },
            }
        }
    })
}

fn cmds(data: &[u8]) -> Vec<Cmd> {
    let mut u = Unstructured::new(data);
    let mut out = Vec::new();
    while !u.is_empty() && out.len() < 512 {
        match cmd(&mut u) {
            Ok(c) => out.push(c),
            Err(_) => break,
        }
    }
    out
}

fn nalgebra_quat(q: [F; 4]) -> povins_core::math::Quat {
    // A unit quaternion built without normalizing (NaN and unnormalized ones included).
    povins_core::math::Quat::new_unchecked(nalgebra::Quaternion::new(
        q[0].0, q[1].0, q[2].0, q[3].0,
    ))
}

/// Updates until `None` (or too many outputs).
fn update_all(est: &mut PoVins) {
    for _ in 0..10_000 {
        match est.update() {
            Ok(Some(_)) | Err(_) => {}
            Ok(None) => return,
        }
    }
}

fn run(est: &mut PoVins, cmds: &[Cmd], lidar_buf: &mut [LidarPoint]) {
    let real = real();
    let (mut ri, mut fi) = (0usize, 0usize);
    let mut t = real.imu[0].t_ns;
    for c in cmds {
        match c {
            Cmd::Imu { dt_ns, abs, g, a } => {
                let t_ns = if *abs {
                    *dt_ns
                } else {
                    t.saturating_add(*dt_ns)
                };
                t = t_ns;
                let _ = est.push_imu(&ImuSample {
                    t_ns,
                    gyro_rps: *g,
                    accel_mps2: *a,
                });
                update_all(est);
            }
            Cmd::Frame { dt_ns, obs } => {
                t = t.saturating_add(*dt_ns);
                let _ = est.push_frame(t, obs);
            }
            Cmd::Lidar { pts } => {
                let n = pts.len().min(lidar_buf.len());
                for (b, (dt, p, i)) in lidar_buf.iter_mut().zip(pts) {
                    *b = LidarPoint {
                        t_ns: t.saturating_add(*dt),
                        p_l: *p,
                        intensity: *i,
                    };
                }
                let _ = est.push_lidar(&lidar_buf[..n]);
            }
            Cmd::Replay(n) => {
                for _ in 0..*n {
                    let Some(s) = real.imu.get(ri) else { break };
                    ri += 1;
                    while let Some(f) = real.frames.get(fi).filter(|f| f.0 <= s.t_ns) {
                        let _ = est.push_frame(f.0, &f.1);
                        fi += 1;
                    }
                    t = s.t_ns;
                    let _ = est.push_imu(s);
                    update_all(est);
                }
            }
            Cmd::Update => update_all(est),
            Cmd::Reset => est.reset(),
            Cmd::EndInput => {
                est.end_input();
                update_all(est);
            }
            Cmd::Init { dt_ns, s } => {
                let s = NavState {
                    t_ns: t.saturating_add(*dt_ns),
                    ..*s
                };
                let _ = est.initialize(s);
            }
        }
    }
    let _ = est.status();
    let _ = est.counters();
}

thread_local! {
    static EST: RefCell<Option<Box<PoVins>>> = const { RefCell::new(None) };
}

/// `estimator`: the bytes decode to a sequence of [`Op`]s run on a freshly configured EuRoC
/// estimator (one per thread, reconfigured for each input). `guard(true)` is called before the
/// first operation and `guard(false)` after the last (the fuzz target checks there that the
/// core allocates nothing).
pub fn estimator_guarded(data: &[u8], guard: &dyn Fn(bool)) {
    let cmds = cmds(data);
    let cfg = euroc_config();
    let _ = real();
    let mut lidar_buf = vec![
        LidarPoint {
            t_ns: 0,
            p_l: [0.0; 3],
            intensity: 0.0
        };
        4096
    ];
    EST.with(|e| {
        let mut e = e.borrow_mut();
        let est = e.get_or_insert_with(|| {
            povins_platform::boxed::boxed_povins(cfg).expect("the EuRoC configuration is valid")
        });
        est.configure(cfg)
            .expect("the EuRoC configuration is valid");
        guard(true);
        run(est, &cmds, &mut lidar_buf);
        guard(false);
    });
}

/// [`estimator_guarded`] without the allocation guard.
pub fn estimator(data: &[u8]) {
    estimator_guarded(data, &|_| {});
}
