//! The README's footprint table (bytes of the estimator for a few capacities, with and without
//! LiDAR storage, and of the image front end) is what `size_of` says.

use povins_core::estimator::Estimator;
use povins_core::frontend::image::{pyramid_bytes, FeatureTracker};
use povins_core::vio::{EurocVio, HdVio, WuxgaVio};
use std::mem::size_of;
use std::sync::Mutex;

const README: &str = include_str!("../../README.md");
/// First and last line of the table in the README.
const TABLE_HEAD: &str =
    "| type | keyframes | landmarks | LiDAR points, grid, queue, thinning cells | bytes |";

/// The LiDAR capacities of the default build (the `lidar` feature).
type WithLidar<const N: usize, const L: usize, const D: usize> =
    Estimator<N, L, D, 131_072, 256, 192, 65_536, 194_400>;

/// Every type the table lists, by the name written in its first cell (the README describes the
/// default build; without the `lidar` feature the types that take its defaults are skipped).
fn footprints() -> Vec<(&'static str, usize)> {
    let mut v = vec![
        (
            "Estimator<10, 200, 166>",
            size_of::<WithLidar<10, 200, 166>>(),
        ),
        (
            "Estimator<10, 200, 166, 0, 0, 0, 0, 0>",
            size_of::<Estimator<10, 200, 166, 0, 0, 0, 0, 0>>(),
        ),
        (
            "Estimator<5, 100, 86, 0, 0, 0, 0, 0>",
            size_of::<Estimator<5, 100, 86, 0, 0, 0, 0, 0>>(),
        ),
        (
            "Estimator<15, 300, 246>",
            size_of::<WithLidar<15, 300, 246>>(),
        ),
        (
            "Estimator<15, 300, 246, 0, 0, 0, 0, 0>",
            size_of::<Estimator<15, 300, 246, 0, 0, 0, 0, 0>>(),
        ),
        (
            "FeatureTracker<256, { pyramid_bytes(752, 480, 4) }, 4>",
            size_of::<FeatureTracker<256, { pyramid_bytes(752, 480, 4) }, 4>>(),
        ),
    ];
    if cfg!(feature = "lidar") {
        v.push(("EurocVio", size_of::<EurocVio>()));
        v.push(("HdVio", size_of::<HdVio>()));
        v.push(("WuxgaVio", size_of::<WuxgaVio>()));
    }
    v
}

/// `(name, bytes)` of every row of the README's table.
fn readme_rows() -> Vec<(String, usize)> {
    let mut lines = README
        .lines()
        .skip_while(|l| l.trim() != TABLE_HEAD)
        .skip(2);
    let mut rows = Vec::new();
    for line in lines.by_ref().take_while(|l| l.starts_with('|')) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let name = cells[1].split('`').nth(1).expect("the type in backticks");
        let bytes = cells[cells.len() - 2].replace([' ', ','], "");
        let bytes: usize = bytes
            .parse()
            .unwrap_or_else(|e| panic!("bytes of `{name}`: {bytes:?}: {e}"));
        rows.push((name.to_string(), bytes));
    }
    rows
}

#[test]
fn readme_footprint_table_is_what_size_of_says() {
    let rows = readme_rows();
    let want = footprints();
    for (name, size) in &want {
        eprintln!(
            "{name}: {size} bytes ({:.2} MiB)",
            *size as f64 / (1 << 20) as f64
        );
    }
    assert!(
        !rows.is_empty(),
        "README has no table headed {TABLE_HEAD:?}"
    );
    for (name, size) in &want {
        let Some((_, bytes)) = rows.iter().find(|(n, _)| n == name) else {
            panic!("README's footprint table has no row for `{name}` ({size} bytes)");
        };
        assert_eq!(
            bytes, size,
            "README says `{name}` is {bytes} bytes; size_of says {size}"
        );
    }
    for (name, _) in &rows {
        if !cfg!(feature = "lidar") && name.ends_with("Vio") {
            continue;
        }
        assert!(
            want.iter().any(|(n, _)| n == name),
            "README's footprint table lists `{name}`, which this test does not check"
        );
    }
}

#[test]
fn lidar_storage_is_what_the_lidar_feature_adds() {
    let with = size_of::<WithLidar<10, 200, 166>>();
    let without = size_of::<Estimator<10, 200, 166, 0, 0, 0, 0, 0>>();
    // 16-byte points, 16-byte grid cells and 4-byte thinning cells, at least.
    assert!(
        with - without >= 131_072 * 16 + 256 * 192 * 16 + 194_400 * 4,
        "{with} - {without}"
    );
    let default = size_of::<Estimator<10, 200, 166>>();
    assert_eq!(
        default,
        if cfg!(feature = "lidar") {
            with
        } else {
            without
        }
    );
}

#[test]
fn an_estimator_without_lidar_storage_refuses_a_lidar_configuration() {
    use povins_core::camera::{CameraExtrinsic, Distortion, PinholeCamera};
    use povins_core::estimator::EstimatorConfig;
    use povins_core::inertial::ImuNoise;
    use povins_core::Error;
    let camera = PinholeCamera {
        readout_s: 0.0,
        width: 752,
        height: 480,
        fx: 458.0,
        fy: 457.0,
        cx: 367.0,
        cy: 248.0,
        distortion: Distortion::None,
    };
    let ext = CameraExtrinsic {
        p_bc: nalgebra::Vector3::zeros(),
        q_bc: nalgebra::UnitQuaternion::identity(),
    };
    let mut cfg = EstimatorConfig::new(camera, ext, ImuNoise::EUROC_ADIS16448);
    // In statics: never on the test thread's stack.
    static WITHOUT: Mutex<Estimator<5, 100, 86, 0, 0, 0, 0, 0>> = Mutex::new(Estimator::empty());
    static WITH: Mutex<WithLidar<5, 100, 86>> = Mutex::new(Estimator::empty());
    let mut without = WITHOUT.lock().expect("not poisoned");
    without.configure(cfg).expect("a camera-only configuration");
    cfg.lidar.enabled = true;
    assert_eq!(without.configure(cfg), Err(Error::InvalidConfig));
    assert_eq!(WITH.lock().expect("not poisoned").configure(cfg), Ok(()));
}
