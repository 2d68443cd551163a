use super::*;
use povins_core::camera::Distortion;
use povins_core::estimator::{VisualDepth, VisualMode};
use povins_core::frontend::image::{Equalization, RansacModel};
use povins_core::lidar::{LdmMode, LidarConfig};
use povins_core::math::Vec3;

fn base() -> EstimatorConfig {
    default_base()
}

/// Bit-level equality of two configurations (Debug prints every float in its shortest
/// round-trip form).
fn same(a: &EstimatorConfig, b: &EstimatorConfig) -> bool {
    format!("{a:?}") == format!("{b:?}")
}

/// The error of parsing `text` and applying it to the defaults.
fn err(text: &str) -> String {
    let applied = RunConfigFile::parse(text).and_then(|f| {
        f.apply(&mut base())?;
        f.apply_frontend(&mut TrackerConfig::default(), &mut VioAiding::default())
    });
    match applied {
        Ok(()) => panic!("accepted {text:?}"),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn every_toml_in_the_repository_parses() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).expect("configs/") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "toml") {
            let f = RunConfigFile::read(&path).unwrap_or_else(|e| panic!("{e:#}"));
            f.apply(&mut base()).unwrap_or_else(|e| panic!("{e:#}"));
            n += 1;
        }
    }
    assert!(n >= 2, "configs/*.toml");
    // The module documentation's example.
    let doc = include_str!("mod.rs");
    let example: String = doc
        .split("//! ```toml\n")
        .nth(1)
        .and_then(|s| s.split("//! ```\n").next())
        .expect("the example")
        .lines()
        .map(|l| l.trim_start_matches("//!").trim_start_matches(' '))
        .collect::<Vec<_>>()
        .join("\n");
    let f = RunConfigFile::parse(&example).unwrap_or_else(|e| panic!("{e:#}\n{example}"));
    let mut cfg = base();
    f.apply(&mut cfg).expect("applies");
    assert_eq!(cfg.lidar.ldm, LdmMode::Direct);
    assert_eq!(cfg.lm_second.max_iterations, 4);
    assert_eq!(cfg.lm_first.max_iterations, base().lm_first.max_iterations);
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    assert_eq!((t.max_features, t.detector.min_distance_px), (200, 15.0));
}

#[test]
fn the_configs_set_what_they_say() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
    let mut cfg = base();
    RunConfigFile::read(&dir.join("euroc.toml"))
        .and_then(|f| f.apply(&mut cfg))
        .expect("euroc.toml");
    assert_eq!(cfg.imu_noise.gyro_noise_density, 2.0e-3);
    assert_eq!(cfg.imu_noise.accel_bias_rw, 3.0e-3);
    assert_eq!(cfg.static_init.accel_std_max_mps2, 0.8);
    assert_eq!(cfg.imu_noise.bias_corr_time_s, None);
    let f = RunConfigFile::read(&dir.join("dmvio.toml")).expect("dmvio.toml");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    assert_eq!(t.detector.min_distance_px, 15.0);
    let mut d = TrackerConfig::default();
    d.detector.min_distance_px = 15.0;
    assert_eq!(t, d, "only the distance changes");
}

#[test]
fn defaults_round_trip_through_the_effective_toml() {
    let cfg = base();
    let (t, a) = (TrackerConfig::default(), VioAiding::default());
    let text = effective_toml(&cfg, &t, &a).expect("serializes");
    let f = RunConfigFile::parse(&text).unwrap_or_else(|e| panic!("{e:#}\n{text}"));
    let mut back = base();
    f.apply(&mut back).expect("applies");
    assert!(same(&cfg, &back));
    // Laid over a different base, the file still gives every key back.
    let mut other = base();
    other.sigma_px = 3.0;
    other.lm_first.max_iterations = 1;
    other.lidar.enabled = true;
    f.apply(&mut other).expect("applies");
    assert!(same(&cfg, &other));
    let (mut t2, mut a2) = (TrackerConfig::default(), VioAiding::default());
    t2.max_features = 10;
    a2.predictions = false;
    f.apply_frontend(&mut t2, &mut a2).expect("frontend");
    assert_eq!((t2, a2), (t, a));
}

#[test]
fn non_defaults_round_trip_bit_for_bit() {
    let mut cfg = base();
    cfg.mode = VisualMode::InverseDepth;
    cfg.visual_depth = VisualDepth::TwoView;
    cfg.keyframe.min_parallax_px = Some(20.0);
    cfg.imu_noise.bias_corr_time_s = Some(3600.0);
    cfg.camera.distortion = Distortion::RadTan {
        k1: -0.28340811,
        k2: 0.07395907,
        p1: 0.00019359,
        p2: 1.76187114e-05,
    };
    cfg.extrinsic.q_bc = povins_core::math::Quat::from_euler_angles(0.1, -0.2, 1.3);
    cfg.extrinsic.p_bc = Vec3::new(-0.0216401454975, -0.064676986768, 0.00981073058949);
    cfg.lidar.enabled = true;
    cfg.lidar.extrinsic.q_bl = povins_core::math::Quat::from_euler_angles(3.0, 0.01, -0.5);
    cfg.lidar.association.cell_rad = 0.7f64.to_radians();
    cfg.td_s = -0.0123456789;
    let mut t = TrackerConfig {
        equalization: Equalization::CLAHE_3_8X8,
        ..TrackerConfig::default()
    };
    t.ransac.model = RansacModel::TwoPoint;
    t.detector.quality_level = 0.013;
    let a = VioAiding {
        predictions: false,
        gyro_rotation: true,
    };
    let text = effective_toml(&cfg, &t, &a).expect("serializes");
    let f = RunConfigFile::parse(&text).unwrap_or_else(|e| panic!("{e:#}\n{text}"));
    let mut back = base();
    f.apply(&mut back).expect("applies");
    assert!(same(&cfg, &back), "{text}");
    let (mut t2, mut a2) = (TrackerConfig::default(), VioAiding::default());
    f.apply_frontend(&mut t2, &mut a2).expect("frontend");
    assert_eq!((t2, a2), (t, a));
}

#[test]
fn unknown_keys_are_errors_naming_the_key_path() {
    for (text, key) in [
        ("sigma = 1.0\n", "`sigma`"),
        ("[lidar]\nenable = true\n", "`lidar.enable`"),
        (
            "[lidar.association]\nneighbors = 5\n",
            "`lidar.association.neighbors`",
        ),
        (
            "[lidar_association]\ncell_rad = 0.01\n",
            "`lidar_association`",
        ),
        ("[imu]\ngyro_noise_density = 1e-3\n", "`imu`"),
        (
            "[frontend.detector]\nmin_dist_px = 1.0\n",
            "`frontend.detector.min_dist_px`",
        ),
        ("[aiding]\ngyro = false\n", "`aiding.gyro`"),
    ] {
        let msg = err(text);
        assert!(msg.contains(key), "{text:?}: {msg}");
        assert!(msg.contains("invalid config <text>"), "{msg}");
    }
    // The valid keys are listed.
    let msg = err("[lidar]\nenable = true\n");
    assert!(
        msg.contains("enabled") && msg.contains("depth_only_opt"),
        "{msg}"
    );
}

#[test]
fn each_replaced_key_is_an_error_naming_its_replacement() {
    for &(table, old, new, _) in REPLACED {
        let text = if table.is_empty() {
            format!("{old} = 20\n")
        } else {
            format!("[{table}]\n{old} = 20\n")
        };
        let msg = err(&text);
        assert!(
            msg.contains(&format!("was replaced by `{new}`"))
                || msg.contains(&format!("was replaced by `[{table}] {new}`")),
            "{old}: {msg}"
        );
        assert!(msg.contains("invalid config <text>"), "{msg}");
    }
}

#[test]
fn each_moved_key_is_an_error_naming_its_new_place() {
    let defaults = Table::try_from(base()).expect("serializes");
    for &(old, table, new) in MOVED {
        let group = defaults[table].as_table().expect("a table");
        let values: Vec<Value> = new.iter().map(|k| group[*k].clone()).collect();
        // The old form: one value, or a pair for two new keys.
        let old_value = match values.as_slice() {
            [v] => v.clone(),
            vs => Value::Array(vs.to_vec()),
        };
        let msg = err(&format!("{old} = {old_value}\n"));
        let place = format!("`{old}` moved to `[{table}] {}`", new[0]);
        assert!(msg.contains(&place), "{old}: {msg}");
        if let Some(second) = new.get(1) {
            assert!(msg.contains(&format!("and `[{table}] {second}`")), "{msg}");
        }
        assert!(msg.contains("invalid config <text>"), "{msg}");
        // The new keys exist and take the same values.
        let text: String = new
            .iter()
            .zip(&values)
            .map(|(k, v)| format!("{k} = {v}\n"))
            .collect();
        let f = RunConfigFile::parse(&format!("[{table}]\n{text}")).expect("parses");
        let mut cfg = base();
        f.apply(&mut cfg)
            .unwrap_or_else(|e| panic!("[{table}] {text}: {e:#}"));
        assert!(same(&cfg, &base()));
    }
    // Every key of the three tables has its old name in the table.
    for table in ["zupt", "td", "cull"] {
        for key in defaults[table].as_table().expect("a table").keys() {
            let listed = MOVED
                .iter()
                .any(|&(_, t, new)| t == table && new.contains(&key.as_str()));
            let replacement = format!("[{table}] {key}");
            let new_key = REPLACED.iter().any(|&(_, _, new, _)| new == replacement);
            assert!(listed || new_key, "[{table}] {key} is not in MOVED");
        }
    }
    // The new table named like the old switch is not taken for the old key.
    let f = RunConfigFile::parse("[zupt]\nenabled = false\n").expect("parses");
    let mut cfg = base();
    f.apply(&mut cfg).expect("applies");
    assert!(!cfg.zupt.enabled);
}

#[test]
fn malformed_values_are_errors() {
    for bad in [
        "[lidar]\nldm = \"msc-based\"\n",
        "[lidar.extrinsic]\nq_bl = [0.0, 0.0, 0.0, 0.5]\n",
        "[lidar.extrinsic]\np_bl = [0.0, 0.0]\n",
        "sigma_px = -1.0\n",
        "depth_range_m = [5.0, 1.0]\n",
        "[frontend.lk]\nwindow = 20\n",
        "[frontend.reference]\nwindow = 23\n",
        "[frontend.reference]\nevery_frames = 0\n",
        "[frontend.reference]\nenable = true\n",
        "[frontend.reference]\nphotometric = \"gain\"\n",
        "[frontend.reference]\nrelative_to_median = -1.0\n",
        "frontend = 3\n",
        "mode = \"pose_only\"\n",
    ] {
        let _ = err(bad);
    }
    assert!(err("[lidar.extrinsic]\nq_bl = [0.0, 0.0, 0.0, 0.5]\n").contains("unit quaternion"));
}

#[test]
fn a_nearly_unit_quaternion_is_normalized_and_a_unit_one_kept() {
    let f = RunConfigFile::parse("[lidar.extrinsic]\nq_bl = [0.0, 0.0, 0.7072, 0.7072]\n")
        .expect("within 1e-3 of unit");
    let mut cfg = base();
    f.apply(&mut cfg).expect("applies");
    let q = cfg.lidar.extrinsic.q_bl;
    assert!((q.quaternion().norm() - 1.0).abs() < 1e-15);
    // 90 deg about z: x_l maps to y_b.
    assert!((q * Vec3::x() - Vec3::y()).norm() < 1e-12);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let f = RunConfigFile::parse(&format!(
        "[lidar.extrinsic]\nq_bl = [0.0, 0.0, {h:?}, {h:?}]\n"
    ))
    .expect("unit");
    f.apply(&mut cfg).expect("applies");
    let c = cfg.lidar.extrinsic.q_bl.coords;
    assert_eq!([c.x, c.y, c.z, c.w], [0.0, 0.0, h, h], "kept bit for bit");
}

#[test]
fn enum_variants_with_fields_switch_whole() {
    let mut cfg = base();
    assert!(matches!(cfg.camera.distortion, Distortion::RadTan { .. }));
    RunConfigFile::parse("[camera.distortion.equidistant]\nk = [0.1, 0.2, 0.3, 0.4]\n")
        .and_then(|f| f.apply(&mut cfg))
        .expect("switch variant");
    assert_eq!(
        cfg.camera.distortion,
        Distortion::Equidistant {
            k: [0.1, 0.2, 0.3, 0.4]
        }
    );
    RunConfigFile::parse("[camera]\ndistortion = \"none\"\n")
        .and_then(|f| f.apply(&mut cfg))
        .expect("unit variant");
    assert_eq!(cfg.camera.distortion, Distortion::None);
    let f = RunConfigFile::parse(
        "[frontend]\nequalization = { clahe = { clip_limit = 3.0, tiles_x = 8, tiles_y = 8 } }\n",
    )
    .expect("clahe");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    assert_eq!(t.equalization, Equalization::CLAHE_3_8X8);
    // A field of the variant in force merges; elsewhere it is incomplete.
    let f = RunConfigFile::parse("[frontend.equalization.clahe]\nclip_limit = 2.0\n").expect("ok");
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    let msg = format!(
        "{:#}",
        f.apply_frontend(&mut TrackerConfig::default(), &mut a)
            .expect_err("no clahe in force")
    );
    assert!(msg.contains("tiles_x"), "{msg}");
    assert!(matches!(
        t.equalization,
        Equalization::Clahe {
            clip_limit: 2.0,
            tiles_x: 8,
            tiles_y: 8
        }
    ));
}

#[test]
fn options_are_set_by_giving_them() {
    let mut cfg = base();
    RunConfigFile::parse(
        "[keyframe]\nmin_parallax_px = 20.0\n[imu_noise]\nbias_corr_time_s = 3600.0\n",
    )
    .and_then(|f| f.apply(&mut cfg))
    .expect("options");
    assert_eq!(cfg.keyframe.min_parallax_px, Some(20.0));
    assert_eq!(cfg.imu_noise.bias_corr_time_s, Some(3600.0));
    // Omitted, they stay.
    RunConfigFile::parse("sigma_px = 2.0\n")
        .and_then(|f| f.apply(&mut cfg))
        .expect("applies");
    assert_eq!(cfg.keyframe.min_parallax_px, Some(20.0));
}

#[test]
fn every_lidar_key_reaches_the_config_and_omitted_keys_stay() {
    let f = RunConfigFile::parse(
        r#"
        [lidar]
        enabled = true
        ldm = "direct"
        depth_outlier_rejection = false
        depth_only_opt = false
        sigma_dr_m = 0.2
        rejection_sigma_px = 2.5
        rejection_sigmas = 4.0
        td_l_s = -0.004
        [lidar.extrinsic]
        p_bl = [0.1, -0.2, 0.3]
        [lidar.association]
        neighbours = 6
        depth_range_m = [1.0, 50.0]
        span_s = 0.25
        "#,
    )
    .expect("valid file");
    let mut cfg = base();
    f.apply(&mut cfg).expect("applies");
    let l = &cfg.lidar;
    assert!(l.enabled && !l.depth_outlier_rejection && !l.depth_only_opt);
    assert_eq!(l.ldm, LdmMode::Direct);
    assert_eq!(
        (l.sigma_dr_m, l.rejection_sigma_px, l.rejection_sigmas),
        (0.2, 2.5, 4.0)
    );
    assert_eq!(l.extrinsic.p_bl, Vec3::new(0.1, -0.2, 0.3));
    assert_eq!(l.extrinsic.q_bl, LidarConfig::default().extrinsic.q_bl);
    assert_eq!(l.td_l_s, -0.004);
    let a = &l.association;
    assert_eq!(
        (a.neighbours, a.depth_range_m, a.span_s),
        (6, (1.0, 50.0), 0.25)
    );
    assert_eq!(a.cell_rad, LidarConfig::default().association.cell_rad);
    let mut cfg = base();
    RunConfigFile::parse("[lidar]\nldm = \"msc\"\n")
        .and_then(|f| f.apply(&mut cfg))
        .expect("valid");
    assert_eq!(cfg.lidar, LidarConfig::default());
}

#[test]
fn switches_override_the_file() {
    let f = RunConfigFile::parse("[lidar]\nenabled = true\nldm = \"msc\"\ndepth_only_opt = true\n")
        .expect("valid file");
    let mut cfg = base();
    f.apply(&mut cfg).expect("applies");
    let sw = LidarArgs {
        no_lidar: true,
        ldm: Some(LdmArg::Direct),
        no_depth_outlier_rejection: true,
        no_depth_only_opt: true,
    };
    assert!(sw.any());
    assert!(!LidarArgs::default().any());
    sw.apply(&mut cfg.lidar);
    assert!(!cfg.lidar.enabled);
    assert_eq!(cfg.lidar.ldm, LdmMode::Direct);
    assert!(!cfg.lidar.depth_outlier_rejection && !cfg.lidar.depth_only_opt);
}

#[test]
fn the_first_steps_check_is_switched_from_toml() {
    let f =
        RunConfigFile::parse("[frontend.provisional]\nenabled = true\nmax_misalignment_px = 0.5\n")
            .expect("parses");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    assert!(!t.provisional.enabled, "off by default");
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    let mut d = TrackerConfig::default();
    d.provisional.enabled = true;
    d.provisional.max_misalignment_px = 0.5;
    assert_eq!(t, d, "only the two keys change");
    let bad = RunConfigFile::parse("[frontend.provisional]\nenabled = true\nwindow = 4\n")
        .expect("parses");
    assert!(bad
        .apply_frontend(&mut TrackerConfig::default(), &mut VioAiding::default())
        .is_err());
}

#[test]
fn the_anchored_refinement_is_switched_from_toml() {
    let f = RunConfigFile::parse(
        "[frontend.reference]\nenabled = true\nwindow = 11\nphotometric = \"offset\"\n",
    )
    .expect("parses");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    assert!(!t.reference.enabled, "off by default");
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    let mut d = TrackerConfig::default();
    d.reference.enabled = true;
    d.reference.window = 11;
    d.reference.photometric = povins_core::frontend::image::Photometric::Offset;
    assert_eq!(t, d, "only the three keys change");
}

#[test]
fn the_lk_photometric_model_is_set_from_toml() {
    use povins_core::frontend::image::Photometric;
    let f = RunConfigFile::parse("[frontend.lk]\nphotometric = \"gain_offset\"\n").expect("parses");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    assert_eq!(t.lk.photometric, Photometric::None, "none by default");
    f.apply_frontend(&mut t, &mut a).expect("frontend");
    let mut d = TrackerConfig::default();
    d.lk.photometric = Photometric::GainOffset;
    assert_eq!(t, d, "only the one key changes");
    let bad = RunConfigFile::parse("[frontend.lk]\nphotometric = \"gain\"\n").expect("parses");
    let (mut t, mut a) = (TrackerConfig::default(), VioAiding::default());
    assert!(
        bad.apply_frontend(&mut t, &mut a).is_err(),
        "unknown model rejected"
    );
}

/// Every key the core's range checks list ([`EstimatorConfig::check_ranges`]) out of range in a
/// file gives an error naming that key, its value and the allowed range: for each key the first
/// of a few out-of-range candidates the core refuses must be reported under that key.
#[test]
fn each_checked_key_out_of_range_is_named_with_its_value_and_range() {
    let mut cfg = base();
    // The optional settings present, so that their checks are listed too.
    cfg.imu_noise.bias_corr_time_s = Some(100.0);
    cfg.keyframe.min_parallax_px = Some(10.0);
    let mut keys: Vec<&'static str> = Vec::new();
    cfg.check_ranges(&mut povins_core::ranges::Ranges::new(&mut |s, ok| {
        assert!(ok, "the defaults are in range: {s}");
        if !keys.contains(&s.key) {
            keys.push(s.key);
        }
    }));
    assert!(keys.len() > 80, "{} keys", keys.len());
    let defaults = Table::try_from(cfg).expect("serializes");
    for key in &keys {
        // A quaternion is refused on reading when it is not finite: the core's check cannot be
        // reached from a file.
        if key.ends_with(".q_bl") {
            continue;
        }
        let (path, index) = match key.split_once('[') {
            Some((p, i)) => (p, Some(i.trim_end_matches(']').parse::<usize>().unwrap())),
            None => (*key, None),
        };
        let parts: Vec<&str> = path.split('.').collect();
        let mut current = &defaults[parts[0]];
        for p in &parts[1..] {
            current = &current[*p];
        }
        let floats = [-1.0, 0.0, 2.0, 0.5, 1e9, f64::INFINITY, f64::NAN];
        let candidates: Vec<Value> = match (current, index) {
            (Value::Integer(_), _) => [0, 1, 2, 1000].map(Value::Integer).to_vec(),
            (Value::Array(a), None) => floats
                .iter()
                .map(|&f| {
                    let mut a = a.clone();
                    a[0] = Value::Float(f);
                    Value::Array(a)
                })
                .collect(),
            (Value::Array(a), Some(i)) => floats
                .iter()
                .map(|&f| {
                    let mut a = a.clone();
                    a[i] = Value::Float(f);
                    Value::Array(a)
                })
                .collect(),
            _ => floats.map(Value::Float).to_vec(),
        };
        let mut named = None;
        for v in candidates {
            let mut t = Table::new();
            t.insert(parts[parts.len() - 1].to_string(), v.clone());
            for p in parts[..parts.len() - 1].iter().rev() {
                let mut outer = Table::new();
                outer.insert(p.to_string(), Value::Table(t));
                t = outer;
            }
            let text = toml::to_string(&t).unwrap();
            let Err(e) = RunConfigFile::parse(&text).and_then(|f| f.apply(&mut cfg.clone())) else {
                continue;
            };
            let msg = format!("{e:#}");
            if msg.contains("is out of range (allowed: ") {
                named = Some(msg);
                break;
            }
        }
        let msg = named.unwrap_or_else(|| panic!("{key}: no candidate was refused"));
        assert!(
            msg.starts_with(&format!("config <text>: {key} = ")),
            "{key}: {msg}"
        );
        assert!(!msg.contains("not set in this file"), "{key}: {msg}");
    }
}

/// A setting out of range that the file does not set is reported as coming from under it.
#[test]
fn an_out_of_range_value_the_file_does_not_set_is_said_to_come_from_below() {
    let mut cfg = base();
    cfg.td_s = 5.0;
    let e = RunConfigFile::parse("sigma_px = 1.0\n")
        .and_then(|f| f.apply(&mut cfg))
        .expect_err("td_s out of range");
    let msg = format!("{e:#}");
    assert!(
        msg.starts_with("config <text>: td_s = 5 is out of range (allowed: -1..=1 (s)) (not set"),
        "{msg}"
    );
}
