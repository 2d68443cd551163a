//! MCAP files (profile `ros2`) with ROS 2 CDR messages, readable by Foxglove and the official
//! `mcap` tools.
//!
//! | topic | schema (`ros2msg`, message encoding `cdr`) | content |
//! |---|---|---|
//! | `/imu0` | `sensor_msgs/msg/Imu` | IMU samples |
//! | `/cam0/image_raw` | `sensor_msgs/msg/Image` | mono8 images |
//! | `/cam0/image_raw/compressed` | `sensor_msgs/msg/CompressedImage` | read only: JPEG or PNG images, decoded to mono8 |
//! | `/cam0/features` | `sensor_msgs/msg/PointCloud` | feature tracks, VINS-Mono layout |
//! | `/lidar0/points` | `sensor_msgs/msg/PointCloud2` | LiDAR sweeps, per-point `t` |
//! | `/groundtruth` | `nav_msgs/msg/Odometry` | body pose and velocity in `world` |
//! | `/groundtruth/imu_bias` | `sensor_msgs/msg/Imu` | ground-truth biases (gyro in `angular_velocity`, accel in `linear_acceleration`) |
//!
//! Field conventions are in [`crate::ros2::convert`]. Message log and publish times are the
//! header stamps; messages are written in time order. The calibration is a metadata record
//! [`CALIBRATION_METADATA`] of strings, numbers in Rust's shortest round-trip form, vectors
//! space-separated: `resolution` (`w h`), `intrinsics` (`fx fy cx cy`), `distortion_model`
//! (`radial-tangential` | `equidistant` | `none`), `distortion_coefficients` (`k1 k2 p1 p2` or
//! the four equidistant `k`), `camera_rate_hz`, `T_bc` and `T_bl` (`px py pz qx qy qz qw`: the
//! sensor origin in the body and the rotation sensor -> body; `T_bl` absent without LiDAR),
//! `td_s` (`t_imu = t_cam + td_s`), `imu_rate_hz`, `gyroscope_noise_density`,
//! `gyroscope_random_walk`, `accelerometer_noise_density`, `accelerometer_random_walk`,
//! `bias_correlation_time_s` (`none` for a random walk), `gravity_mps2`, `name`, `readout_s`
//! (a rolling shutter's readout time, s; only when not 0), and `td_l_s` (the LiDAR's time offset,
//! `t_imu = t_lidar + td_l_s`, s; only when not 0). A simulator's truth for evaluation
//! ([`crate::dataset::SimTruth`] without its per-point LiDAR edge flags) is the topic
//! [`TOPIC_SIM_TRUTH`] (message encoding `json`, no schema): one message at the camera stamp at
//! which ids are first observed, `{"t_ns": T, "landmarks": [{"id": N, "p_w": [x, y, z] | null,
//! "last_ns": T, "wrong": bool, "edge": bool}, ...]}` (`p_w` the true landmark in `world`, m;
//! `last_ns` the stamp of the id's last observation), so that an evaluation holds only the
//! tracks alive at its keyframe ([`crate::dataset::SimLandmark`]). Files written before it hold the
//! whole truth in the JSON attachment [`SIM_TRUTH_ATTACHMENT`], still read.
//!
//! Reading ignores topics it does not know, orders each topic by header stamp and rejects
//! repeated stamps. Images come from `/cam0/image_raw` (`sensor_msgs/msg/Image`, or a
//! `sensor_msgs/msg/CompressedImage` published there) or, when that topic has none, from
//! `/cam0/image_raw/compressed`; compressed payloads are decoded by [`crate::image_codec`] and
//! one that does not decode is [`IoError::Corrupt`] naming the file, the topic, the message's
//! sequence number and the codec's reason. A message that does not decode is [`IoError::Corrupt`] naming the topic, the
//! message's sequence number and the byte offset inside the message.

use crate::cdr::CdrError;
use crate::dataset::{Calibration, Dataset, Extrinsic, SimTruth};
use crate::error::IoError;
use crate::euroc::read_png_mono8;
use crate::ros2;
use crate::ros2::convert::{self, quat_from_xyzw, quat_to_xyzw};
use povins_core::camera::{Distortion, PinholeCamera, MAX_READOUT_S};
use povins_core::inertial::ImuNoise;
use povins_core::lidar::MAX_TD_L_S;
use povins_core::math::Vec3;
use std::collections::{BTreeMap, HashMap};
use std::io::Write as _;
use std::path::Path;

/// IMU topic.
pub const TOPIC_IMU: &str = "/imu0";
/// Image topic.
pub const TOPIC_IMAGE: &str = "/cam0/image_raw";
/// Compressed image topic (`image_transport` naming), read only.
pub const TOPIC_IMAGE_COMPRESSED: &str = "/cam0/image_raw/compressed";
/// Feature topic.
pub const TOPIC_FEATURES: &str = "/cam0/features";
/// LiDAR topic.
pub const TOPIC_LIDAR: &str = "/lidar0/points";
/// Ground-truth pose topic.
pub const TOPIC_GROUND_TRUTH: &str = "/groundtruth";
/// Ground-truth bias topic.
pub const TOPIC_GROUND_TRUTH_BIAS: &str = "/groundtruth/imu_bias";
/// Name of the calibration metadata record.
pub const CALIBRATION_METADATA: &str = "povins.calibration";
/// The simulator's truth, one message per camera stamp at which ids are first observed (module
/// docs).
pub const TOPIC_SIM_TRUTH: &str = "/povins/sim_truth/landmarks";
/// Name of the simulator-truth attachment (files written before [`TOPIC_SIM_TRUTH`]; read only).
pub const SIM_TRUTH_ATTACHMENT: &str = "povins.sim_truth.json";

const IMU_TYPE: &str = "sensor_msgs/msg/Imu";
const IMAGE_TYPE: &str = "sensor_msgs/msg/Image";
const COMPRESSED_IMAGE_TYPE: &str = "sensor_msgs/msg/CompressedImage";
const POINT_CLOUD_TYPE: &str = "sensor_msgs/msg/PointCloud";
const POINT_CLOUD2_TYPE: &str = "sensor_msgs/msg/PointCloud2";
const ODOMETRY_TYPE: &str = "nav_msgs/msg/Odometry";

fn invalid(path: &Path, msg: impl Into<String>) -> IoError {
    IoError::Invalid {
        path: path.into(),
        msg: msg.into(),
    }
}

fn mcap_err(path: &Path, e: mcap::McapError) -> IoError {
    IoError::Corrupt {
        file: path.into(),
        what: "mcap".into(),
        offset: 0,
        msg: e.to_string(),
    }
}

/// The simulator's truth as the attachment holds it: what the evaluation of a run reads. The
/// per-point LiDAR edge flags ([`SimTruth::lidar_edge_points`], the simulator's own statistics,
/// a flag per point: 5 MB a minute) are not written, and skipped unread (as any key povins does
/// not read) in files that have them.
#[derive(serde::Deserialize)]
#[cfg_attr(test, derive(serde::Serialize))]
struct SimTruthJson {
    landmarks_w: Vec<(u64, [f64; 3])>,
    wrong_tracks: Vec<u64>,
    edge_features: Vec<u64>,
}

/// One [`TOPIC_SIM_TRUTH`] message (module docs).
#[derive(serde::Serialize, serde::Deserialize)]
struct SimTruthMsg {
    t_ns: i64,
    landmarks: Vec<SimLandmarkJson>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct SimLandmarkJson {
    id: u64,
    p_w: Option<[f64; 3]>,
    last_ns: i64,
    wrong: bool,
    edge: bool,
}

fn num(v: f64) -> String {
    format!("{v:?}")
}

fn nums(v: &[f64]) -> String {
    v.iter().map(|x| num(*x)).collect::<Vec<_>>().join(" ")
}

fn extrinsic_str(t: &Extrinsic) -> String {
    let q = quat_to_xyzw(&t.q_ab);
    nums(&[t.p_ab.x, t.p_ab.y, t.p_ab.z, q[0], q[1], q[2], q[3]])
}

fn calibration_metadata(ds: &Dataset) -> BTreeMap<String, String> {
    let c = &ds.calib;
    let cam = &c.camera;
    let (model, k) = match cam.distortion {
        Distortion::None => ("none", [0.0; 4]),
        Distortion::RadTan { k1, k2, p1, p2 } => ("radial-tangential", [k1, k2, p1, p2]),
        Distortion::Equidistant { k } => ("equidistant", k),
    };
    let n = &c.imu_noise;
    let mut m = BTreeMap::new();
    let mut put = |k: &str, v: String| {
        m.insert(k.to_string(), v);
    };
    put("name", ds.name.clone());
    put("resolution", format!("{} {}", cam.width, cam.height));
    put("intrinsics", nums(&[cam.fx, cam.fy, cam.cx, cam.cy]));
    put("distortion_model", model.into());
    put("distortion_coefficients", nums(&k));
    if cam.readout_s != 0.0 {
        put("readout_s", num(cam.readout_s));
    }
    put("camera_rate_hz", num(c.camera_rate_hz));
    put("T_bc", extrinsic_str(&c.t_bc));
    put("td_s", num(c.td_s));
    put("imu_rate_hz", num(c.imu_rate_hz));
    put("gyroscope_noise_density", num(n.gyro_noise_density));
    put("gyroscope_random_walk", num(n.gyro_bias_rw));
    put("accelerometer_noise_density", num(n.accel_noise_density));
    put("accelerometer_random_walk", num(n.accel_bias_rw));
    put(
        "bias_correlation_time_s",
        n.bias_corr_time_s.map_or("none".into(), num),
    );
    put("gravity_mps2", num(c.gravity_mps2));
    if let Some(t) = &c.t_bl {
        put("T_bl", extrinsic_str(t));
    }
    if c.td_l_s != 0.0 {
        put("td_l_s", num(c.td_l_s));
    }
    m
}

/// Parses the calibration metadata back.
fn calibration_from_metadata(
    path: &Path,
    m: &BTreeMap<String, String>,
) -> Result<(String, Calibration), IoError> {
    let bad =
        |k: &str, why: &str| invalid(path, format!("{CALIBRATION_METADATA}: key {k:?} {why}"));
    let get = |k: &str| {
        m.get(k)
            .map(String::as_str)
            .ok_or_else(|| bad(k, "is missing"))
    };
    let vec = |k: &str, n: usize| -> Result<Vec<f64>, IoError> {
        let v: Vec<f64> = get(k)?
            .split_whitespace()
            .map(|s| s.parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| bad(k, "is not a list of finite numbers"))?;
        if v.len() != n {
            return Err(bad(k, &format!("needs {n} numbers")));
        }
        Ok(v)
    };
    let one = |k: &str| -> Result<f64, IoError> { Ok(vec(k, 1)?[0]) };
    let ext = |k: &str| -> Result<Extrinsic, IoError> {
        let v = vec(k, 7)?;
        Ok(Extrinsic {
            q_ab: quat_from_xyzw([v[3], v[4], v[5], v[6]])
                .ok_or_else(|| bad(k, "has a non-unit quaternion"))?,
            p_ab: Vec3::new(v[0], v[1], v[2]),
        })
    };
    let res: Vec<u32> = get("resolution")?
        .split_whitespace()
        .map(|s| s.parse().ok())
        .collect::<Option<_>>()
        .filter(|v: &Vec<u32>| v.len() == 2)
        .ok_or_else(|| bad("resolution", "is not `width height`"))?;
    let k = vec("intrinsics", 4)?;
    let d = vec("distortion_coefficients", 4)?;
    let distortion = match get("distortion_model")? {
        "none" => Distortion::None,
        "radial-tangential" => Distortion::RadTan {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
        },
        "equidistant" => Distortion::Equidistant {
            k: [d[0], d[1], d[2], d[3]],
        },
        _ => return Err(bad("distortion_model", "is not a known model")),
    };
    let imu_noise = ImuNoise {
        gyro_noise_density: one("gyroscope_noise_density")?,
        accel_noise_density: one("accelerometer_noise_density")?,
        gyro_bias_rw: one("gyroscope_random_walk")?,
        accel_bias_rw: one("accelerometer_random_walk")?,
        bias_corr_time_s: match get("bias_correlation_time_s")? {
            "none" => None,
            _ => Some(one("bias_correlation_time_s")?),
        },
    };
    // Optional (written only for a rolling shutter).
    let readout_s = match m.get("readout_s") {
        None => 0.0,
        Some(_) => one("readout_s")?,
    };
    if !(0.0..=MAX_READOUT_S).contains(&readout_s) {
        return Err(bad(
            "readout_s",
            &format!("is outside [0, {MAX_READOUT_S}] s"),
        ));
    }
    // Optional (written only when not 0).
    let td_l_s = match m.get("td_l_s") {
        None => 0.0,
        Some(_) => one("td_l_s")?,
    };
    if td_l_s.abs() > MAX_TD_L_S {
        return Err(bad(
            "td_l_s",
            &format!("is outside [-{MAX_TD_L_S}, {MAX_TD_L_S}] s"),
        ));
    }
    let calib = Calibration {
        camera: PinholeCamera {
            readout_s,
            width: res[0],
            height: res[1],
            fx: k[0],
            fy: k[1],
            cx: k[2],
            cy: k[3],
            distortion,
        },
        t_bc: ext("T_bc")?,
        td_s: one("td_s")?,
        camera_rate_hz: one("camera_rate_hz")?,
        imu_noise,
        imu_rate_hz: one("imu_rate_hz")?,
        gravity_mps2: one("gravity_mps2")?,
        t_bl: if m.contains_key("T_bl") {
            Some(ext("T_bl")?)
        } else {
            None
        },
        td_l_s,
    };
    Ok((m.get("name").cloned().unwrap_or_default(), calib))
}

#[cfg(test)]
mod compressed_tests;
#[cfg(test)]
mod corrupt_tests;
mod read;

use crate::recording::Recording;
pub use read::{McapRecording, REORDER};

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
enum Kind {
    Imu,
    Image,
    Lidar,
    Features,
    GroundTruth,
    SimTruth,
}

/// Writes a [`Dataset`] as MCAP (ROS 2 CDR messages, calibration as metadata, zstd chunks).
/// Images without pixels are loaded from their PNG file.
pub fn write_dataset(path: &Path, ds: &Dataset) -> Result<(), IoError> {
    write_dataset_as(path, ds, false)
}

/// [`write_dataset`] as files were written before [`TOPIC_SIM_TRUTH`]: the truth in the
/// attachment [`SIM_TRUTH_ATTACHMENT`] (tests of the reader's compatibility).
#[cfg(test)]
pub(crate) fn write_dataset_legacy_truth(path: &Path, ds: &Dataset) -> Result<(), IoError> {
    write_dataset_as(path, ds, true)
}

fn write_dataset_as(path: &Path, ds: &Dataset, legacy_truth: bool) -> Result<(), IoError> {
    let cdr = |topic: &str, e: CdrError| invalid(path, format!("{topic}: {e}"));
    let conv = |topic: &str, e: String| invalid(path, format!("{topic}: {e}"));
    // Everything is checked and encoded lazily in time order; features need the whole sequence
    // for their velocities, so they are converted up front.
    let feature_msgs = convert::features_to_msgs(&ds.features, &ds.calib.camera)
        .map_err(|e| conv(TOPIC_FEATURES, e))?;

    let f = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(std::io::BufWriter::with_capacity(1 << 20, f))
        .map_err(|e| mcap_err(path, e))?;
    let me = |e| mcap_err(path, e);
    let no_meta = BTreeMap::new();
    let channel = |w: &mut mcap::Writer<_>, topic: &str, ty: &str, schema: String| {
        let sid = w.add_schema(ty, "ros2msg", schema.as_bytes())?;
        w.add_channel(sid, topic, "cdr", &no_meta)
    };
    let mut ch: HashMap<Kind, u16> = HashMap::new();
    if !ds.imu.is_empty() {
        ch.insert(
            Kind::Imu,
            channel(&mut w, TOPIC_IMU, IMU_TYPE, ros2::imu_schema()).map_err(me)?,
        );
    }
    if !ds.images.is_empty() {
        let id = channel(&mut w, TOPIC_IMAGE, IMAGE_TYPE, ros2::image_schema()).map_err(me)?;
        ch.insert(Kind::Image, id);
    }
    if !ds.lidar.is_empty() {
        let s = ros2::point_cloud2_schema();
        ch.insert(
            Kind::Lidar,
            channel(&mut w, TOPIC_LIDAR, POINT_CLOUD2_TYPE, s).map_err(me)?,
        );
    }
    if !ds.features.is_empty() {
        let s = ros2::point_cloud_schema();
        let id = channel(&mut w, TOPIC_FEATURES, POINT_CLOUD_TYPE, s).map_err(me)?;
        ch.insert(Kind::Features, id);
    }
    let mut bias_ch = 0;
    if !ds.ground_truth.is_empty() {
        let s = ros2::odometry_schema();
        let id = channel(&mut w, TOPIC_GROUND_TRUTH, ODOMETRY_TYPE, s).map_err(me)?;
        ch.insert(Kind::GroundTruth, id);
        bias_ch = channel(
            &mut w,
            TOPIC_GROUND_TRUTH_BIAS,
            IMU_TYPE,
            ros2::imu_schema(),
        )
        .map_err(me)?;
    }

    let mut events: Vec<(i64, Kind, usize)> = Vec::new();
    events.extend(
        ds.imu
            .iter()
            .enumerate()
            .map(|(i, s)| (s.t_ns, Kind::Imu, i)),
    );
    events.extend(
        ds.images
            .iter()
            .enumerate()
            .map(|(i, s)| (s.t_ns, Kind::Image, i)),
    );
    events.extend(
        ds.lidar
            .iter()
            .enumerate()
            .map(|(i, s)| (s.t_ns, Kind::Lidar, i)),
    );
    events.extend(
        ds.features
            .iter()
            .enumerate()
            .map(|(i, s)| (s.t_ns, Kind::Features, i)),
    );
    events.extend(
        ds.ground_truth
            .iter()
            .enumerate()
            .map(|(i, s)| (s.t_ns, Kind::GroundTruth, i)),
    );
    // The truth's ids grouped by first observation, one message each (ids held from the start
    // at the first event).
    let mut truth_msgs: Vec<SimTruthMsg> = Vec::new();
    if let Some(st) = ds.sim_truth.as_ref().filter(|_| !legacy_truth) {
        let t0 = i64::try_from(events_start(ds)).unwrap_or(0);
        for l in st.landmarks(&ds.features) {
            let t = if l.first_ns == i64::MIN {
                t0
            } else {
                l.first_ns
            };
            if truth_msgs.last().is_none_or(|m| m.t_ns != t) {
                truth_msgs.push(SimTruthMsg {
                    t_ns: t,
                    landmarks: Vec::new(),
                });
            }
            if let Some(m) = truth_msgs.last_mut() {
                m.landmarks.push(SimLandmarkJson {
                    id: l.id,
                    p_w: l.p_w.map(|p| [p.x, p.y, p.z]),
                    last_ns: l.last_ns,
                    wrong: l.wrong,
                    edge: l.edge,
                });
            }
        }
        let id = w
            .add_channel(0, TOPIC_SIM_TRUTH, "json", &no_meta)
            .map_err(me)?;
        ch.insert(Kind::SimTruth, id);
    }
    events.extend(
        truth_msgs
            .iter()
            .enumerate()
            .map(|(i, m)| (m.t_ns, Kind::SimTruth, i)),
    );
    events.sort_unstable();

    let mut seq: HashMap<u16, u32> = HashMap::new();
    let mut put = |w: &mut mcap::Writer<_>, channel_id: u16, t_ns: i64, data: &[u8]| {
        let s = seq.entry(channel_id).or_insert(0);
        *s += 1;
        let time = u64::try_from(t_ns).map_err(|_| {
            invalid(
                path,
                format!("time {t_ns} ns is before 1970 and cannot be an MCAP log time"),
            )
        })?;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: *s,
            log_time: time,
            publish_time: time,
        };
        w.write_to_known_channel(&header, data).map_err(me)
    };
    for (t, kind, i) in events {
        let cid = ch.get(&kind).copied().unwrap_or(0);
        match kind {
            Kind::Imu => {
                let m = convert::imu_to_msg(&ds.imu[i])
                    .encode()
                    .map_err(|e| cdr(TOPIC_IMU, e))?;
                put(&mut w, cid, t, &m)?;
            }
            Kind::Image => {
                let im = &ds.images[i];
                let px = if !im.mono8.is_empty() {
                    im.mono8.clone()
                } else if let Some(p) = &im.path {
                    let (pw, ph, px) = read_png_mono8(p)?;
                    if (pw, ph) != (im.width, im.height) {
                        return Err(invalid(
                            p,
                            format!(
                                "image is {pw}x{ph}, the dataset says {}x{}",
                                im.width, im.height
                            ),
                        ));
                    }
                    px
                } else {
                    return Err(conv(
                        TOPIC_IMAGE,
                        format!("image at {t} ns has no pixels and no file"),
                    ));
                };
                let m = convert::image_to_msg(im, px).map_err(|e| conv(TOPIC_IMAGE, e))?;
                put(
                    &mut w,
                    cid,
                    t,
                    &m.encode().map_err(|e| cdr(TOPIC_IMAGE, e))?,
                )?;
            }
            Kind::Lidar => {
                let m = convert::lidar_to_msg(&ds.lidar[i]).map_err(|e| conv(TOPIC_LIDAR, e))?;
                put(
                    &mut w,
                    cid,
                    t,
                    &m.encode().map_err(|e| cdr(TOPIC_LIDAR, e))?,
                )?;
            }
            Kind::Features => {
                let m = feature_msgs[i]
                    .encode()
                    .map_err(|e| cdr(TOPIC_FEATURES, e))?;
                put(&mut w, cid, t, &m)?;
            }
            Kind::GroundTruth => {
                let (odom, bias) = convert::ground_truth_to_msgs(&ds.ground_truth[i]);
                let o = odom.encode().map_err(|e| cdr(TOPIC_GROUND_TRUTH, e))?;
                put(&mut w, cid, t, &o)?;
                let b = bias.encode().map_err(|e| cdr(TOPIC_GROUND_TRUTH_BIAS, e))?;
                put(&mut w, bias_ch, t, &b)?;
            }
            Kind::SimTruth => {
                let m = serde_json::to_vec(&truth_msgs[i])
                    .map_err(|e| conv(TOPIC_SIM_TRUTH, e.to_string()))?;
                put(&mut w, cid, t, &m)?;
            }
        }
    }

    w.write_metadata(&mcap::records::Metadata {
        name: CALIBRATION_METADATA.into(),
        metadata: calibration_metadata(ds),
    })
    .map_err(me)?;
    #[cfg(test)]
    if let Some(st) = ds.sim_truth.as_ref().filter(|_| legacy_truth) {
        let j = SimTruthJson {
            landmarks_w: st
                .landmarks_w
                .iter()
                .map(|(id, p)| (*id, [p.x, p.y, p.z]))
                .collect(),
            wrong_tracks: st.wrong_tracks.clone(),
            edge_features: st.edge_features.clone(),
        };
        let data = serde_json::to_vec(&j).map_err(|e| invalid(path, e.to_string()))?;
        w.attach(&mcap::Attachment {
            log_time: events_start(ds),
            create_time: events_start(ds),
            name: SIM_TRUTH_ATTACHMENT.into(),
            media_type: "application/json".into(),
            data: std::borrow::Cow::Owned(data),
        })
        .map_err(me)?;
    }
    w.finish().map_err(me)?;
    w.into_inner().flush().map_err(|e| IoError::io(path, e))
}

/// First IMU time (attachment time), 0 when unknown.
fn events_start(ds: &Dataset) -> u64 {
    ds.imu
        .first()
        .map_or(0, |s| u64::try_from(s.t_ns).unwrap_or(0))
}

/// Largest uncompressed chunk accepted, bytes.
pub const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// Walks the top-level record framing (`opcode: u8, length: u64, body`) of the file, seeking
/// from record to record, and rejects chunks that claim more than [`MAX_CHUNK_BYTES`]
/// uncompressed: the `mcap` crate allocates the claimed size up front, so a corrupt size would
/// abort the process instead of failing.
fn check_chunk_sizes(path: &Path) -> Result<(), IoError> {
    use std::io::{Read, Seek, SeekFrom};
    const CHUNK: u8 = 0x06;
    const FOOTER: u8 = 0x02;
    let mut f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let len = f.metadata().map_err(|e| IoError::io(path, e))?.len();
    let mut pos = mcap::MAGIC.len() as u64;
    // Opcode, record length, and for a chunk its start time, end time and uncompressed size.
    let mut head = [0u8; 9 + 24];
    while pos + 9 <= len {
        f.seek(SeekFrom::Start(pos))
            .map_err(|e| IoError::io(path, e))?;
        let want = usize::try_from((len - pos).min(head.len() as u64)).unwrap_or(9);
        f.read_exact(&mut head[..want])
            .map_err(|e| IoError::io(path, e))?;
        let u64_at = |o: usize| -> Option<u64> {
            head.get(o..o + 8)
                .filter(|_| o + 8 <= want)
                .and_then(|s| s.try_into().ok())
                .map(u64::from_le_bytes)
        };
        let (op, Some(rec_len)) = (head[0], u64_at(1)) else {
            break;
        };
        if op == CHUNK {
            if let Some(size) = u64_at(9 + 16) {
                if size > MAX_CHUNK_BYTES {
                    return Err(IoError::Corrupt {
                        file: path.into(),
                        what: "chunk".into(),
                        offset: pos,
                        msg: format!("uncompressed size {size} exceeds {MAX_CHUNK_BYTES} bytes"),
                    });
                }
            }
        }
        if op == FOOTER {
            break;
        }
        match pos.checked_add(9).and_then(|p| p.checked_add(rec_len)) {
            Some(next) => pos = next,
            None => break,
        }
    }
    Ok(())
}

/// Reads a whole MCAP file into a [`Dataset`]: every stream of [`McapRecording`] collected.
pub fn read_dataset(path: &Path) -> Result<Dataset, IoError> {
    let r = McapRecording::open(path)?;
    let imu = r.imu()?.collect::<Result<_, _>>()?;
    let features = r.frames()?.collect::<Result<_, _>>()?;
    let images = r.images()?.collect::<Result<_, _>>()?;
    let lidar = r.sweeps()?.collect::<Result<_, _>>()?;
    let ground_truth = r.ground_truth()?;
    let sim_truth = match r.sim_landmarks()? {
        Some(ls) => Some(SimTruth::from_landmarks(ls.collect::<Result<Vec<_>, _>>()?)),
        None => None,
    };
    Ok(Dataset {
        name: r.name().to_string(),
        calib: r.calibration().clone(),
        imu,
        features,
        images,
        lidar,
        ground_truth,
        sim_truth,
    })
}
