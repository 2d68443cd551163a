use super::*;

const META_JSON: &str = include_str!("testdata/os1-128_v2.3.0_1024x10.json");

pub(super) fn meta() -> Metadata {
    Metadata::from_json(META_JSON).unwrap()
}

/// A small metadata: `rows` channels, `cols` columns per frame, 4 columns per packet.
pub(super) fn small_meta(profile: LidarProfile, rows: usize, cols: usize) -> Metadata {
    let mut m = meta();
    m.profile = profile;
    m.pixels_per_column = rows;
    m.columns_per_packet = 4;
    m.columns_per_frame = cols;
    m.column_window = [0, cols - 1];
    m.pixel_shift_by_row = vec![0; rows];
    m.beam_altitude_angles_deg = (0..rows).map(|r| 10.0 - r as f64).collect();
    m.beam_azimuth_angles_deg = (0..rows).map(|r| r as f64 * 0.5 - 1.0).collect();
    m
}

/// Builds a lidar packet: columns `first_m..first_m + 4`, pixel (c, r) range `range(c, r)`.
pub(super) fn build(
    meta: &Metadata,
    frame_id: u32,
    first_m: u16,
    valid: bool,
    range: impl Fn(usize, usize) -> u32,
) -> Vec<u8> {
    let legacy = meta.profile == LidarProfile::Legacy;
    let mut b = Vec::new();
    if !legacy && meta.header_type == HeaderType::Fusa {
        // Type u8, init id u24, frame id u32, alert flags, serial number u40 at 11.
        b.extend_from_slice(&[1, 7, 0, 0]);
        b.extend_from_slice(&frame_id.to_le_bytes());
        b.extend_from_slice(&[0x40, 0, 0, 1, 2, 3, 4, 5]);
        b.resize(32, 0);
    } else if !legacy {
        b.extend_from_slice(&1u16.to_le_bytes());
        b.extend_from_slice(&(frame_id as u16).to_le_bytes());
        b.extend_from_slice(&[7, 0, 0, 1, 2, 3, 4, 5]);
        b.resize(32, 0);
    }
    for c in 0..meta.columns_per_packet {
        let m = first_m + c as u16;
        b.extend_from_slice(&(1_000_000 + u64::from(m) * 1000).to_le_bytes());
        b.extend_from_slice(&m.to_le_bytes());
        if legacy {
            b.extend_from_slice(&(frame_id as u16).to_le_bytes());
            b.extend_from_slice(&(u32::from(m) * 88).to_le_bytes());
        } else {
            b.extend_from_slice(&u16::from(valid).to_le_bytes());
        }
        for r in 0..meta.pixels_per_column {
            let rg = range(c, r);
            match meta.profile {
                LidarProfile::Legacy => {
                    b.extend_from_slice(&rg.to_le_bytes());
                    b.extend_from_slice(&[9, 0, 20, 0, 30, 0, 0, 0]);
                }
                LidarProfile::Single => {
                    b.extend_from_slice(&rg.to_le_bytes());
                    b.extend_from_slice(&[9, 0, 20, 0, 30, 0, 0, 0]);
                }
                LidarProfile::Dual => {
                    b.extend_from_slice(&(rg | 9 << 24).to_le_bytes());
                    b.extend_from_slice(&(rg + 100).to_le_bytes());
                    b.extend_from_slice(&[20, 0, 21, 0, 30, 0, 0, 0]);
                }
                LidarProfile::LowDataRate => {
                    b.extend_from_slice(&((rg / 8) as u16).to_le_bytes());
                    b.extend_from_slice(&[9, 7]);
                }
            }
        }
        if legacy {
            let status: u32 = if valid { 0xffff_ffff } else { 0 };
            b.extend_from_slice(&status.to_le_bytes());
        }
    }
    if !legacy {
        b.extend_from_slice(&[0; 32]);
    }
    b
}

#[test]
fn fixture_metadata_parses() {
    let m = meta();
    assert_eq!(m.profile, LidarProfile::LowDataRate);
    assert_eq!((m.pixels_per_column, m.columns_per_packet), (128, 16));
    assert_eq!((m.columns_per_frame, m.columns_in_window()), (1024, 1024));
    assert_eq!(m.beam_to_lidar_transform[0][3], 15.806);
    assert_eq!(m.lidar_to_sensor_transform[2][3], 36.18);
    assert_eq!(m.imu_to_sensor_m()[1][3], -0.011775);
    assert_eq!((m.udp_port_lidar, m.udp_port_imu), (Some(7502), Some(7503)));
    assert_eq!(
        Decoder::new(&m).lidar_packet_bytes(),
        32 + 16 * (12 + 128 * 4) + 32
    );
}

#[test]
fn nested_metadata_parses_like_flat() {
    let flat: serde_json::Value = serde_json::from_str(META_JSON).unwrap();
    let g = |k: &str| flat[k].clone();
    let mut df = g("data_format");
    df.as_object_mut().unwrap().remove("udp_profile_lidar");
    let nested = serde_json::json!({
        "sensor_info": {"prod_line": g("prod_line"), "prod_sn": g("prod_sn"),
                        "build_rev": g("build_rev")},
        "lidar_data_format": df,
        "beam_intrinsics": {"beam_altitude_angles": g("beam_altitude_angles"),
                            "beam_azimuth_angles": g("beam_azimuth_angles"),
                            "lidar_origin_to_beam_origin_mm": g("lidar_origin_to_beam_origin_mm")},
        "lidar_intrinsics": {"lidar_to_sensor_transform": g("lidar_to_sensor_transform")},
        "imu_intrinsics": {"imu_to_sensor_transform": g("imu_to_sensor_transform")},
        "config_params": {"lidar_mode": g("lidar_mode"), "udp_port_lidar": 7502,
                          "udp_port_imu": 7503, "udp_profile_lidar": "RNG15_RFL8_NIR8"},
        "calibration_status": {},
    });
    assert_eq!(Metadata::from_json(&nested.to_string()).unwrap(), meta());
}

#[test]
fn metadata_errors_name_the_key() {
    let mut v: serde_json::Value = serde_json::from_str(META_JSON).unwrap();
    v.as_object_mut().unwrap().remove("beam_azimuth_angles");
    let e = Metadata::from_json(&v.to_string()).unwrap_err().to_string();
    assert!(
        e.contains("beam_azimuth_angles") && e.contains("missing"),
        "{e}"
    );
    let mut v: serde_json::Value = serde_json::from_str(META_JSON).unwrap();
    v["data_format"]["udp_profile_lidar"] = "FOO".into();
    let e = Metadata::from_json(&v.to_string()).unwrap_err().to_string();
    assert!(e.contains("udp_profile_lidar"), "{e}");
    let mut v: serde_json::Value = serde_json::from_str(META_JSON).unwrap();
    v["beam_altitude_angles"] = serde_json::json!([1.0, 2.0]);
    let e = Metadata::from_json(&v.to_string()).unwrap_err().to_string();
    assert!(
        e.contains("beam_altitude_angles") && e.contains("128"),
        "{e}"
    );
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("meta.json");
    std::fs::write(&p, "{}").unwrap();
    let e = Metadata::from_file(&p).unwrap_err().to_string();
    assert!(
        e.contains("meta.json") && e.contains("pixels_per_column"),
        "{e}"
    );
}

#[test]
fn xyz_matches_the_documented_formula() {
    let m = meta();
    let lut = XyzLut::new(&m);
    let (mid, row, r) = (100usize, 5usize, 12_345u32);
    let n = 15.806;
    let enc = 2.0 * std::f64::consts::PI * (1.0 - mid as f64 / 1024.0);
    let azi = -m.beam_azimuth_angles_deg[row].to_radians();
    let alt = m.beam_altitude_angles_deg[row].to_radians();
    let rr = f64::from(r) - n;
    let x = rr * (enc + azi).cos() * alt.cos() + n * enc.cos();
    let y = rr * (enc + azi).sin() * alt.cos() + n * enc.sin();
    let z = rr * alt.sin();
    // lidar_to_sensor: diag(-1, -1, 1), +36.18 mm in z.
    let want = [-x * 1e-3, -y * 1e-3, (z + 36.18) * 1e-3];
    let got = lut.point_m(mid, row, r).unwrap();
    for k in 0..3 {
        assert!((got[k] - want[k]).abs() < 1e-12, "{got:?} {want:?}");
    }
    assert!(lut.point_m(1024, 0, r).is_none() && lut.point_m(0, 128, r).is_none());
}

#[test]
fn every_profile_round_trips() {
    for profile in [
        LidarProfile::Legacy,
        LidarProfile::Single,
        LidarProfile::Dual,
        LidarProfile::LowDataRate,
    ] {
        let m = small_meta(profile, 3, 16);
        let d = Decoder::new(&m);
        let buf = build(&m, 42, 8, true, |c, r| (1000 + c * 10 + r) as u32 * 8);
        assert_eq!(buf.len(), d.lidar_packet_bytes(), "{profile:?}");
        let p = d.decode_lidar(&buf).unwrap();
        assert_eq!(p.frame_id, 42);
        assert_eq!(p.columns.len(), 4);
        let c = &p.columns[2];
        assert_eq!((c.measurement_id, c.t_ns, c.valid), (10, 1_010_000, true));
        assert_eq!(c.pixels[1].range_mm, (1000 + 20 + 1) * 8, "{profile:?}");
        assert_eq!(c.pixels[1].reflectivity, 9, "{profile:?}");
        match profile {
            LidarProfile::LowDataRate => assert_eq!(c.pixels[1].near_ir, 28),
            LidarProfile::Dual => {
                assert_eq!(c.pixels[1].range2_mm, (1000 + 20 + 1) * 8 + 100);
                assert_eq!((c.pixels[1].signal, c.pixels[1].signal2), (20, 21));
            }
            _ => assert_eq!((c.pixels[1].signal, c.pixels[1].near_ir), (20, 30)),
        }
        if profile == LidarProfile::Legacy {
            assert_eq!(c.encoder_count, Some(880));
            assert!(p.init_id.is_none());
        } else {
            assert_eq!((p.init_id, p.prod_sn), (Some(7), Some(0x05_0403_0201)));
        }
        let bad = build(&m, 42, 8, false, |_, _| 0);
        assert!(!d.decode_lidar(&bad).unwrap().columns[0].valid);
    }
}

#[test]
fn every_truncation_is_an_error() {
    for profile in [LidarProfile::Legacy, LidarProfile::LowDataRate] {
        let m = small_meta(profile, 3, 16);
        let d = Decoder::new(&m);
        let buf = build(&m, 1, 0, true, |_, _| 800);
        for n in 0..buf.len() {
            let e = d.decode_lidar(&buf[..n]).unwrap_err().to_string();
            assert!(
                e.contains(&format!("{n} bytes")) && e.contains(&buf.len().to_string()),
                "{e}"
            );
        }
        let mut long = buf.clone();
        long.push(0);
        assert!(d.decode_lidar(&long).is_err());
    }
    let imu = [0u8; 48];
    assert!(decode_imu(&imu).is_ok());
    for n in 0..48 {
        let e = decode_imu(&imu[..n]).unwrap_err().to_string();
        assert!(e.contains("48") && e.contains(&format!("{n} bytes")), "{e}");
    }
}

#[test]
fn bad_ids_are_errors() {
    let m = small_meta(LidarProfile::LowDataRate, 3, 16);
    let d = Decoder::new(&m);
    let buf = build(&m, 1, 14, true, |_, _| 800); // ids 14..18, past 16 columns
    let e = d.decode_lidar(&buf).unwrap_err().to_string();
    assert!(e.contains("measurement id 16"), "{e}");
    let mut buf = build(&m, 1, 0, true, |_, _| 800);
    buf[0] = 2;
    assert!(d
        .decode_lidar(&buf)
        .unwrap_err()
        .to_string()
        .contains("packet type 2"));
}

#[test]
fn imu_units() {
    let mut b = Vec::new();
    for t in [5u64, 6, 7] {
        b.extend_from_slice(&t.to_le_bytes());
    }
    for v in [1.0f32, -0.5, 0.25, 90.0, -180.0, 0.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    let p = decode_imu(&b).unwrap();
    assert_eq!((p.sys_t_ns, p.accel_t_ns, p.gyro_t_ns), (5, 6, 7));
    assert_eq!(p.accel_mps2, [9.80665, -0.5 * 9.80665, 0.25 * 9.80665]);
    assert!((p.gyro_rps[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!((p.gyro_rps[1] + std::f64::consts::PI).abs() < 1e-12);
}

#[test]
fn assembler_counts_drops_late_and_zero_ranges() {
    let m = small_meta(LidarProfile::LowDataRate, 3, 16);
    let d = Decoder::new(&m);
    let pk = |frame, first, valid| {
        d.decode_lidar(&build(&m, frame, first, valid, |c, r| {
            if r == 2 {
                0
            } else {
                8000 + (c * 8) as u32
            }
        }))
        .unwrap()
    };
    let mut a = SweepAssembler::new(&m);
    assert!(a.push(&pk(5, 0, true)).is_none());
    assert!(a.push(&pk(5, 4, false)).is_none());
    // Columns 8..12 of frame 5 are lost; 12..16 arrive.
    assert!(a.push(&pk(5, 12, true)).is_none());
    let s = a.push(&pk(6, 0, true)).expect("frame 5 emitted");
    assert_eq!(a.last_sweep().unwrap().frame_id, 5);
    assert_eq!(a.last_sweep().unwrap().missing_columns, 4);
    assert_eq!(s.points.len(), 8 * 2);
    assert_eq!(s.t_ns, 1_000_000);
    assert_eq!(s.points[2].t_ns, 1_001_000);
    let p0 = XyzLut::new(&m).point_m(0, 0, 8000).unwrap();
    assert_eq!(s.points[0].p_l, [p0[0] as f32, p0[1] as f32, p0[2] as f32]);
    assert_eq!(s.points[0].intensity, 9.0);
    assert!(a.push(&pk(5, 8, true)).is_none()); // late
    assert!(a.push(&pk(6, 0, true)).is_none()); // duplicate columns
    let last = a.finish().unwrap();
    assert_eq!(last.points.len(), 4 * 2);
    assert!(a.finish().is_none());
    let c = a.counts();
    assert_eq!(c.packets, 6);
    assert_eq!(c.sweeps, 2);
    assert_eq!(c.points, 24);
    assert_eq!(
        (c.columns, c.invalid_columns, c.duplicate_columns),
        (12, 4, 4)
    );
    assert_eq!(c.zero_range_points, 12);
    assert_eq!(c.late_packets, 1);
    assert_eq!(c.missing_columns, 4 + 12);
    assert_eq!(c.dropped_packets, 1 + 3);
}

#[test]
fn assembler_handles_frame_id_wrap_and_restart() {
    let m = small_meta(LidarProfile::Legacy, 2, 8);
    let d = Decoder::new(&m);
    let pk = |frame, first| {
        d.decode_lidar(&build(&m, frame, first, true, |_, _| 900))
            .unwrap()
    };
    let mut a = SweepAssembler::new(&m);
    assert!(a.push(&pk(65535, 0)).is_none());
    assert!(a.push(&pk(0, 0)).is_some()); // 0 follows 65535
                                          // A restarted sensor (frame ids jump back): late for a while, then taken as new.
    let mut emitted = 0;
    for _ in 0..10 {
        emitted += usize::from(a.push(&pk(40000, 0)).is_some());
    }
    assert_eq!(emitted, 1);
    assert_eq!(a.counts().late_packets, 5);
}

#[test]
fn the_fusa_header_carries_a_32_bit_frame_id() {
    for profile in [LidarProfile::Single, LidarProfile::LowDataRate] {
        let mut m = small_meta(profile, 3, 16);
        m.header_type = HeaderType::Fusa;
        let d = Decoder::new(&m);
        let buf = build(&m, 70_000, 8, true, |c, r| (1000 + c * 10 + r) as u32 * 8);
        assert_eq!(buf.len(), d.lidar_packet_bytes(), "{profile:?}");
        let p = d.decode_lidar(&buf).unwrap();
        assert_eq!(p.frame_id, 70_000);
        assert_eq!((p.init_id, p.prod_sn), (Some(7), Some(0x05_0403_0201)));
        assert!(p.columns.iter().all(|c| c.frame_id == 70_000));
        assert_eq!(p.columns[2].pixels[1].range_mm, (1000 + 20 + 1) * 8);
        // Read as a standard header, the init id's low byte is the packet type's high byte.
        let std = Decoder::new(&small_meta(profile, 3, 16));
        let e = std.decode_lidar(&buf).unwrap_err().to_string();
        assert!(
            e.contains("packet type 1793") && e.contains("STANDARD"),
            "{e}"
        );
        let mut bad = buf.clone();
        bad[0] = 2;
        let e = d.decode_lidar(&bad).unwrap_err().to_string();
        assert!(e.contains("packet type 2") && e.contains("FUSA"), "{e}");
    }
}

#[test]
fn fusa_frame_ids_wrap_at_32_bits() {
    let mut m = small_meta(LidarProfile::LowDataRate, 2, 8);
    m.header_type = HeaderType::Fusa;
    let d = Decoder::new(&m);
    let pk = |frame, first| {
        d.decode_lidar(&build(&m, frame, first, true, |_, _| 900))
            .unwrap()
    };
    let mut a = SweepAssembler::new(&m);
    assert!(a.push(&pk(65_535, 0)).is_none());
    // Past 16 bits is newer, not a wrap.
    assert!(a.push(&pk(65_536, 0)).is_some());
    assert_eq!(a.last_sweep().unwrap().frame_id, 65_535);
    assert!(a.push(&pk(u32::MAX, 0)).is_none()); // 2^32 - 65537 ahead: older, late
    assert_eq!(a.counts().late_packets, 1);
    let mut a = SweepAssembler::new(&m);
    assert!(a.push(&pk(u32::MAX, 0)).is_none());
    assert!(a.push(&pk(0, 0)).is_some()); // 0 follows 2^32 - 1
    assert_eq!(a.last_sweep().unwrap().frame_id, u32::MAX);
    // A LEGACY profile's ids stay 16-bit whatever the header type says.
    m.profile = LidarProfile::Legacy;
    assert_eq!(m.frame_id_mask(), 0xffff);
}

#[test]
fn the_header_type_is_read_from_the_metadata() {
    let mut v: serde_json::Value = serde_json::from_str(META_JSON).unwrap();
    assert_eq!(meta().header_type, HeaderType::Standard);
    v["data_format"]["header_type"] = "FUSA".into();
    let m = Metadata::from_json(&v.to_string()).unwrap();
    assert_eq!(m.header_type, HeaderType::Fusa);
    v["data_format"]["header_type"] = "SAFE".into();
    let e = Metadata::from_json(&v.to_string()).unwrap_err().to_string();
    assert!(e.contains("header_type") && e.contains("SAFE"), "{e}");
}

/// Needs shared/data: the OS1-128 capture decodes into 3 full sweeps and 30 IMU packets.
#[test]
#[ignore = "needs ../shared/data"]
fn fixture_capture_decodes() {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/fixtures/ouster");
    let m = Metadata::from_file(&dir.join("OS-1-128_v2.3.0_1024x10.json")).unwrap();
    let cap = read_pcap(&dir.join("OS-1-128_v2.3.0_1024x10_lb_n3.pcap"), &m).unwrap();
    eprintln!(
        "{:?}\n{:?}\nsweeps {} imu {} bad {} {:?}",
        cap.counts,
        cap.pcap,
        cap.scans.len(),
        cap.imu.len(),
        cap.bad_packets,
        cap.first_error
    );
    assert_eq!(cap.bad_packets, 0);
    assert_eq!(cap.counts.packets, 192);
    assert_eq!(cap.imu.len(), 30);
    assert_eq!(cap.scans.len(), 3);
}

/// A libpcap file (Ethernet link type, µs timestamps) of `frames` at times `t_us`.
fn pcap_file(frames: &[(u64, Vec<u8>)]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
    b.extend_from_slice(&2u16.to_le_bytes());
    b.extend_from_slice(&4u16.to_le_bytes());
    b.extend_from_slice(&[0; 8]);
    b.extend_from_slice(&65535u32.to_le_bytes());
    b.extend_from_slice(&1u32.to_le_bytes());
    for (t_us, f) in frames {
        b.extend_from_slice(&((t_us / 1_000_000) as u32).to_le_bytes());
        b.extend_from_slice(&((t_us % 1_000_000) as u32).to_le_bytes());
        b.extend_from_slice(&(f.len() as u32).to_le_bytes());
        b.extend_from_slice(&(f.len() as u32).to_le_bytes());
        b.extend_from_slice(f);
    }
    b
}

/// An Ethernet + IPv4 frame of protocol `proto`, fragment at `offset` (bytes, a multiple of 8).
fn ipv4_frame(proto: u8, id: u16, offset: usize, more: bool, data: &[u8]) -> Vec<u8> {
    let mut f = vec![2, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 2, 0x08, 0x00];
    let mut ip = vec![0x45, 0];
    ip.extend_from_slice(&((20 + data.len()) as u16).to_be_bytes());
    ip.extend_from_slice(&id.to_be_bytes());
    let frag = (offset / 8) as u16 | if more { 0x2000 } else { 0 };
    ip.extend_from_slice(&frag.to_be_bytes());
    ip.extend_from_slice(&[64, proto, 0, 0, 169, 254, 0, 1, 169, 254, 0, 2]);
    let sum: u32 = ip
        .chunks(2)
        .map(|w| u32::from(u16::from_be_bytes([w[0], w[1]])))
        .sum();
    let sum = (sum & 0xffff) + (sum >> 16);
    let sum = !(((sum & 0xffff) + (sum >> 16)) as u16);
    ip[10..12].copy_from_slice(&sum.to_be_bytes());
    f.extend_from_slice(&ip);
    f.extend_from_slice(data);
    f
}

fn udp(dst_port: u16, payload: &[u8]) -> Vec<u8> {
    let mut u = Vec::new();
    u.extend_from_slice(&7502u16.to_be_bytes());
    u.extend_from_slice(&dst_port.to_be_bytes());
    u.extend_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
    u.extend_from_slice(&[0, 0]);
    u.extend_from_slice(payload);
    u
}

#[test]
fn pcap_reassembles_fragments_and_counts_the_rest() {
    let big: Vec<u8> = (0..3000u32).map(|i| (i % 251) as u8).collect();
    let dgram = udp(7502, &big);
    let frag = |off: usize, end: usize| {
        let more = end < dgram.len();
        ipv4_frame(17, 77, off, more, &dgram[off..end.min(dgram.len())])
    };
    let lost = udp(7502, &big);
    let mut arp = vec![2, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 2, 0x08, 0x06];
    arp.extend_from_slice(&[0, 1, 8, 0, 6, 4, 0, 1]);
    arp.extend_from_slice(&[0; 20]);
    let mut tcp = [0u8; 20];
    tcp[12] = 0x50; // data offset: 5 words
    let frames = vec![
        (1_000_000, ipv4_frame(17, 1, 0, false, &udp(7503, &[5; 48]))),
        (1_000_100, frag(0, 1480)),
        (1_000_200, arp),
        (1_000_300, ipv4_frame(6, 2, 0, false, &tcp)),
        (1_000_400, frag(1480, 2960)),
        (1_000_500, ipv4_frame(17, 3, 0, false, &udp(9999, &[1; 10]))),
        (1_000_600, frag(2960, 4000)),
        (1_000_700, ipv4_frame(17, 9, 0, true, &lost[..1480])),
        (3_000_000, ipv4_frame(17, 10, 0, true, &lost[..1480])),
        (3_000_100, vec![1, 2, 3]),
    ];
    let bytes = pcap_file(&frames);
    let path = std::path::Path::new("mem.pcap");
    let udp = PcapUdp::new(&bytes[..], path).unwrap().ports(&[7502, 7503]);
    let mut it = udp;
    let got: Vec<UdpDatagram> = it.by_ref().map(Result::unwrap).collect();
    assert_eq!(got.len(), 2);
    assert_eq!((got[0].dst_port, got[0].payload.len()), (7503, 48));
    assert_eq!(got[0].t_capture_ns, 1_000_000_000);
    assert_eq!((got[1].dst_port, got[1].src_port), (7502, 7502));
    assert_eq!(got[1].payload, big);
    assert_eq!(got[1].t_capture_ns, 1_000_600_000);
    let c = it.counts();
    assert_eq!(c.records, 10);
    assert_eq!((c.datagrams, c.fragments, c.reassembled), (2, 5, 1));
    assert_eq!((c.non_udp, c.other_ports, c.malformed), (2, 1, 1));
    assert_eq!(c.incomplete, 1); // id 9 given up when id 10 arrived 2 s later

    // A capture cut inside its third record: an error naming that record's offset.
    let cut = &bytes[..24 + (16 + frames[0].1.len()) + (16 + frames[1].1.len()) + 20];
    let mut it = PcapUdp::new(cut, path).unwrap();
    assert!(it.next().unwrap().is_ok());
    let e = it.next().unwrap().unwrap_err().to_string();
    let off = 24 + (16 + frames[0].1.len()) + (16 + frames[1].1.len());
    assert!(
        e.contains("mem.pcap") && e.contains(&format!("offset {off}")),
        "{e}"
    );
    assert!(it.next().is_none());
    let e = PcapUdp::new(&b"not a pcap"[..], path)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("mem.pcap"), "{e}");
}
