//! `sensor_msgs/msg/CompressedImage` reading: MCAP files written here with PNG and JPEG payloads.

use super::*;
use crate::dataset::Calibration;
use crate::ros2::msgs::CompressedImage;
use crate::ros2::Header;
use povins_core::inertial::ImuSample;

pub(super) fn dataset() -> Dataset {
    Dataset {
        name: "compressed".into(),
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
        imu: (0..20)
            .map(|k| ImuSample {
                t_ns: 1_000_000_000 + k * 5_000_000,
                gyro_rps: Vec3::zeros(),
                accel_mps2: Vec3::new(0.0, 0.0, 9.81),
            })
            .collect(),
        features: Vec::new(),
        images: Vec::new(),
        lidar: Vec::new(),
        ground_truth: Vec::new(),
        sim_truth: None,
    }
}

/// One image message: topic, schema, stamp, format, payload.
type Msg<'a> = (&'a str, &'a str, i64, &'a str, Vec<u8>);

fn write(path: &Path, msgs: &[Msg<'_>]) {
    let ds = dataset();
    let f = std::fs::File::create(path).unwrap();
    let mut w = mcap::WriteOptions::new().profile("ros2").create(f).unwrap();
    let meta = BTreeMap::new();
    let imu_schema = w
        .add_schema(IMU_TYPE, "ros2msg", ros2::imu_schema().as_bytes())
        .unwrap();
    let imu_ch = w.add_channel(imu_schema, TOPIC_IMU, "cdr", &meta).unwrap();
    let mut channels: HashMap<(String, String), u16> = HashMap::new();
    for (k, s) in ds.imu.iter().enumerate() {
        let h = mcap::records::MessageHeader {
            channel_id: imu_ch,
            sequence: k as u32 + 1,
            log_time: s.t_ns as u64,
            publish_time: s.t_ns as u64,
        };
        let data = convert::imu_to_msg(s).encode().unwrap();
        w.write_to_known_channel(&h, &data).unwrap();
    }
    for (k, (topic, ty, t, format, data)) in msgs.iter().enumerate() {
        let key = (topic.to_string(), ty.to_string());
        let ch = match channels.get(&key) {
            Some(&c) => c,
            None => {
                let sid = w
                    .add_schema(ty, "ros2msg", ros2::compressed_image_schema().as_bytes())
                    .unwrap();
                let c = w.add_channel(sid, topic, "cdr", &meta).unwrap();
                channels.insert(key, c);
                c
            }
        };
        let m = CompressedImage {
            header: Header::new(*t, "cam0"),
            format: format.to_string(),
            data: data.clone(),
        };
        let h = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: k as u32 + 1,
            log_time: *t as u64,
            publish_time: *t as u64,
        };
        w.write_to_known_channel(&h, &m.encode().unwrap()).unwrap();
    }
    w.write_metadata(&mcap::records::Metadata {
        name: CALIBRATION_METADATA.into(),
        metadata: calibration_metadata(&ds),
    })
    .unwrap();
    w.finish().unwrap();
}

fn gradient(w: u32, h: u32) -> Vec<u8> {
    (0..w * h)
        .map(|i| ((i % w) * 200 / w + (i / w) * 50 / h) as u8)
        .collect()
}

fn png_gray(w: u32, h: u32, px: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(px).unwrap();
    }
    out
}

fn jpeg_rgb(w: u32, h: u32, gray: &[u8]) -> Vec<u8> {
    let rgb: Vec<u8> = gray.iter().flat_map(|&v| [v, v, v]).collect();
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
        .encode(&rgb, w, h, image::ColorType::Rgb8)
        .unwrap();
    out
}

const C: &str = TOPIC_IMAGE_COMPRESSED;
const CT: &str = COMPRESSED_IMAGE_TYPE;

#[test]
fn png_and_jpeg_messages_decode_to_mono8() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.mcap");
    let g = gradient(64, 40);
    let t0 = 1_000_000_000;
    let jpeg = jpeg_rgb(64, 40, &g);
    write(
        &path,
        &[
            (C, CT, t0 + 50_000_000, "bgr8; jpeg compressed bgr8", jpeg),
            (C, CT, t0, "png", png_gray(64, 40, &g)),
        ],
    );
    let ds = read_dataset(&path).unwrap();
    assert_eq!(ds.images.len(), 2);
    // Ordered by stamp: the PNG first, exact; the JPEG close.
    assert_eq!(ds.images[0].t_ns, t0);
    assert_eq!((ds.images[0].width, ds.images[0].height), (64, 40));
    assert_eq!(ds.images[0].mono8, g);
    let im = &ds.images[1].mono8;
    let err = im.iter().zip(&g).map(|(a, b)| a.abs_diff(*b)).max();
    assert!(err.unwrap() <= 8, "{err:?}");
}

#[test]
fn compressed_on_the_raw_topic_is_read_and_preferred() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.mcap");
    let g = gradient(32, 16);
    let t0 = 1_000_000_000;
    write(
        &path,
        &[
            (TOPIC_IMAGE, CT, t0, "png", png_gray(32, 16, &g)),
            (C, CT, t0, "png", png_gray(32, 16, &g)),
            (C, CT, t0 + 1, "png", png_gray(32, 16, &g)),
        ],
    );
    let ds = read_dataset(&path).unwrap();
    assert_eq!(ds.images.len(), 1, "the compressed topic is a fallback");
    assert_eq!(ds.images[0].mono8, g);
}

#[test]
fn corrupt_payloads_name_file_topic_message_and_codec() {
    let dir = tempfile::tempdir().unwrap();
    let g = gradient(64, 40);
    let t0 = 1_000_000_000;
    let jpeg = jpeg_rgb(64, 40, &g);
    let png = png_gray(64, 40, &g);
    let mut garbage = png[..8].to_vec();
    garbage.extend(std::iter::repeat_n(0xAB, 300));
    let mut garbage_jpeg = jpeg[..2].to_vec();
    garbage_jpeg.extend((0..400u32).map(|i| (i * 7919 % 251) as u8));
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("truncated-jpeg", jpeg[..jpeg.len() / 3].to_vec(), "JPEG"),
        ("garbage-jpeg", garbage_jpeg, "JPEG"),
        ("truncated-png", png[..png.len() / 2].to_vec(), "PNG"),
        ("garbage-png", garbage, "PNG"),
        (
            "not-an-image",
            b"GIF89a....".to_vec(),
            "neither JPEG nor PNG",
        ),
        ("empty", Vec::new(), "empty"),
    ];
    for (name, bad, why) in cases {
        let path = dir.path().join(format!("{name}.mcap"));
        let first = png_gray(64, 40, &g);
        write(
            &path,
            &[(C, CT, t0, "png", first), (C, CT, t0 + 1, "jpeg", bad)],
        );
        let msg = match read_dataset(&path) {
            Err(e @ IoError::Corrupt { .. }) => e.to_string(),
            other => panic!("{name}: {other:?}"),
        };
        assert!(msg.contains(&format!("{name}.mcap")), "{msg}");
        assert!(msg.contains(C) && msg.contains("message 2"), "{msg}");
        assert!(msg.contains(why), "{name}: {msg}");
    }
}
