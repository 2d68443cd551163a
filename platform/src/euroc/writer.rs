//! The EuRoC ASL layout written message by message: [`EurocWriter::create`] writes the
//! calibration (`imu0`, `cam0` and, with a LiDAR extrinsic, `lidar0` `sensor.yaml`), then each
//! pushed sample, image, feature frame or sweep is appended to its `data.csv` (a buffered file
//! per stream, opened at its first message) and each image is written as a PNG file at once, so
//! memory does not grow with the sequence. [`super::write_dataset`] (a whole [`Dataset`] in
//! memory) and `povins convert` (any recording, streamed) write through it, so both give the same
//! bytes. The layout is the one [`super::EurocFolder`] reads (see [`super`]).
//!
//! [`Dataset`]: crate::dataset::Dataset

use super::{png_io, CAM_HEADER, FEATURES_HEADER, IMU_HEADER, LIDAR_HEADER};
use crate::dataset::{Calibration, Extrinsic, FeatureFrame, ImageFrame, LidarScan};
use crate::error::IoError;
use crate::trajectory::write_euroc_groundtruth;
use povins_core::camera::Distortion;
use povins_core::inertial::{ImuSample, NavState};
use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::path::{Path, PathBuf};

/// What an [`EurocWriter`] wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Written {
    /// IMU samples (`imu0/data.csv` rows).
    pub imu: u64,
    /// Camera images (`cam0/data/*.png`).
    pub images: u64,
    /// Feature frames (`features0/data.csv`).
    pub frames: u64,
    /// LiDAR sweeps (`lidar0/data.csv`).
    pub sweeps: u64,
    /// LiDAR points.
    pub points: u64,
    /// Ground-truth states (`state_groundtruth_estimate0/data.csv`).
    pub ground_truth: u64,
}

/// One buffered `data.csv` whose write errors name it.
struct Csv {
    path: PathBuf,
    w: BufWriter<File>,
}

impl Csv {
    fn create(path: PathBuf, header: &str) -> Result<Self, IoError> {
        let f = File::create(&path).map_err(|e| IoError::io(&path, e))?;
        let mut csv = Csv {
            w: BufWriter::with_capacity(1 << 16, f),
            path,
        };
        csv.row(format_args!("{header}"))?;
        Ok(csv)
    }

    fn row(&mut self, args: std::fmt::Arguments<'_>) -> Result<(), IoError> {
        writeln!(self.w, "{args}").map_err(|e| IoError::io(&self.path, e))
    }

    fn finish(mut self) -> Result<(), IoError> {
        self.w.flush().map_err(|e| IoError::io(&self.path, e))
    }
}

/// An EuRoC ASL folder being written (see the module docs). Call [`EurocWriter::finish`] to
/// flush it; a writer dropped without it may leave the last rows unwritten.
pub struct EurocWriter {
    mav0: PathBuf,
    imu: Csv,
    images: Option<Csv>,
    features: Option<Csv>,
    lidar: Option<Csv>,
    written: Written,
}

impl EurocWriter {
    /// Creates `dir/mav0` with the calibration's `sensor.yaml` files (no `cam0` for a
    /// calibration without a camera) and an `imu0/data.csv` holding its header.
    pub fn create(dir: &Path, calib: &Calibration) -> Result<Self, IoError> {
        let mav0 = dir.join("mav0");
        let imu_dir = mav0.join("imu0");
        mkdir(&imu_dir)?;
        write_file(&imu_dir.join("sensor.yaml"), &imu_yaml(calib))?;
        let imu = Csv::create(imu_dir.join("data.csv"), IMU_HEADER)?;
        // A recording without a camera (the zero-size placeholder, `dataset::no_camera`) gets no
        // cam0: that is how a reader knows.
        if calib.camera.width > 0 {
            let cam_dir = mav0.join("cam0");
            mkdir(&cam_dir)?;
            write_file(&cam_dir.join("sensor.yaml"), &camera_yaml(calib))?;
        }
        if let Some(t) = &calib.t_bl {
            let ldir = mav0.join("lidar0");
            mkdir(&ldir)?;
            let mut y = String::from("%YAML:1.0\nsensor_type: lidar\ncomment: written by povins\n");
            t_bs_yaml(&mut y, t);
            if calib.td_l_s != 0.0 {
                let _ = writeln!(
                    y,
                    "timeshift_lidar_imu: {:?} # t_imu = t_lidar + shift",
                    calib.td_l_s
                );
            }
            write_file(&ldir.join("sensor.yaml"), &y)?;
        }
        Ok(EurocWriter {
            mav0,
            imu,
            images: None,
            features: None,
            lidar: None,
            written: Written::default(),
        })
    }

    /// Appends an IMU sample.
    pub fn imu(&mut self, s: &ImuSample) -> Result<(), IoError> {
        let (g, a) = (s.gyro_rps, s.accel_mps2);
        self.imu.row(format_args!(
            "{},{:?},{:?},{:?},{:?},{:?},{:?}",
            s.t_ns, g.x, g.y, g.z, a.x, a.y, a.z
        ))?;
        self.written.imu += 1;
        Ok(())
    }

    /// Writes an image as `cam0/data/<t_ns>.png`: its pixels encoded, or its source file copied
    /// when it has only a path (nothing to do when that file is already the destination).
    pub fn image(&mut self, im: &ImageFrame) -> Result<(), IoError> {
        let cam_dir = self.mav0.join("cam0");
        let data_dir = cam_dir.join("data");
        let csv = match &mut self.images {
            Some(c) => c,
            None => {
                mkdir(&data_dir)?;
                self.images
                    .insert(Csv::create(cam_dir.join("data.csv"), CAM_HEADER)?)
            }
        };
        let dst = data_dir.join(format!("{}.png", im.t_ns));
        if !im.mono8.is_empty() {
            png_io::write_mono8(&dst, im.width, im.height, &im.mono8)?;
        } else if let Some(src) = &im.path {
            let same = match (std::fs::canonicalize(src), std::fs::canonicalize(&dst)) {
                (Ok(a), Ok(b)) => a == b,
                _ => false,
            };
            if !same {
                std::fs::copy(src, &dst).map_err(|e| IoError::io(src, e))?;
            }
        } else {
            return Err(IoError::Invalid {
                path: dst,
                msg: "image has neither pixels nor a source file".into(),
            });
        }
        csv.row(format_args!("{},{}.png", im.t_ns, im.t_ns))?;
        self.written.images += 1;
        Ok(())
    }

    /// Appends a feature frame (a row per observation).
    pub fn frame(&mut self, fr: &FeatureFrame) -> Result<(), IoError> {
        let csv = match &mut self.features {
            Some(c) => c,
            None => {
                let fdir = self.mav0.join("features0");
                mkdir(&fdir)?;
                self.features
                    .insert(Csv::create(fdir.join("data.csv"), FEATURES_HEADER)?)
            }
        };
        for o in &fr.obs {
            csv.row(format_args!(
                "{},{},{:?},{:?}",
                fr.t_ns, o.id, o.u_px, o.v_px
            ))?;
        }
        self.written.frames += 1;
        Ok(())
    }

    /// Appends a LiDAR sweep (a row per point); a sweep without points cannot be stored and is
    /// an error.
    pub fn sweep(&mut self, s: &LidarScan) -> Result<(), IoError> {
        let ldir = self.mav0.join("lidar0");
        if s.points.is_empty() {
            return Err(IoError::Invalid {
                path: ldir,
                msg: format!(
                    "sweep at {} ns has no points; a CSV cannot store it",
                    s.t_ns
                ),
            });
        }
        let csv = match &mut self.lidar {
            Some(c) => c,
            None => {
                mkdir(&ldir)?;
                self.lidar
                    .insert(Csv::create(ldir.join("data.csv"), LIDAR_HEADER)?)
            }
        };
        for p in &s.points {
            csv.row(format_args!(
                "{},{},{:?},{:?},{:?},{:?}",
                s.t_ns, p.t_ns, p.p_l[0], p.p_l[1], p.p_l[2], p.intensity
            ))?;
        }
        self.written.sweeps += 1;
        self.written.points += s.points.len() as u64;
        Ok(())
    }

    /// Writes the ground truth (`state_groundtruth_estimate0/data.csv`; nothing when empty).
    pub fn ground_truth(&mut self, states: &[NavState]) -> Result<(), IoError> {
        if states.is_empty() {
            return Ok(());
        }
        let gdir = self.mav0.join("state_groundtruth_estimate0");
        mkdir(&gdir)?;
        write_euroc_groundtruth(&gdir.join("data.csv"), states)?;
        self.written.ground_truth += states.len() as u64;
        Ok(())
    }

    /// What was written so far.
    pub fn written(&self) -> Written {
        self.written
    }

    /// Flushes every file; returns what was written.
    pub fn finish(self) -> Result<Written, IoError> {
        self.imu.finish()?;
        for csv in [self.images, self.features, self.lidar]
            .into_iter()
            .flatten()
        {
            csv.finish()?;
        }
        Ok(self.written)
    }
}

/// `imu0/sensor.yaml` of `c` (identity `T_BS`: the body frame is the IMU frame).
fn imu_yaml(c: &Calibration) -> String {
    let mut y = String::from("%YAML:1.0\nsensor_type: imu\ncomment: written by povins\n");
    t_bs_yaml(&mut y, &Extrinsic::identity());
    let n = &c.imu_noise;
    let _ = writeln!(y, "rate_hz: {:?}", c.imu_rate_hz);
    let _ = writeln!(y, "gyroscope_noise_density: {:?}", n.gyro_noise_density);
    let _ = writeln!(y, "gyroscope_random_walk: {:?}", n.gyro_bias_rw);
    let _ = writeln!(
        y,
        "accelerometer_noise_density: {:?}",
        n.accel_noise_density
    );
    let _ = writeln!(y, "accelerometer_random_walk: {:?}", n.accel_bias_rw);
    let _ = writeln!(y, "gravity_magnitude: {:?}", c.gravity_mps2);
    if let Some(t) = n.bias_corr_time_s {
        let _ = writeln!(y, "bias_correlation_time: {t:?}");
    }
    y
}

/// `cam0/sensor.yaml` of `c`.
fn camera_yaml(c: &Calibration) -> String {
    let cam = &c.camera;
    let mut y = String::from("%YAML:1.0\nsensor_type: camera\ncomment: written by povins\n");
    t_bs_yaml(&mut y, &c.t_bc);
    let (model, coeffs) = match cam.distortion {
        Distortion::None => ("none", [0.0; 4]),
        Distortion::RadTan { k1, k2, p1, p2 } => ("radial-tangential", [k1, k2, p1, p2]),
        Distortion::Equidistant { k } => ("equidistant", k),
    };
    let _ = writeln!(y, "rate_hz: {:?}", c.camera_rate_hz);
    let _ = writeln!(y, "resolution: [{}, {}]", cam.width, cam.height);
    let _ = writeln!(y, "camera_model: pinhole");
    let _ = writeln!(
        y,
        "intrinsics: [{:?}, {:?}, {:?}, {:?}] # fu, fv, cu, cv",
        cam.fx, cam.fy, cam.cx, cam.cy
    );
    let _ = writeln!(y, "distortion_model: {model}");
    let _ = writeln!(
        y,
        "distortion_coefficients: [{:?}, {:?}, {:?}, {:?}]",
        coeffs[0], coeffs[1], coeffs[2], coeffs[3]
    );
    let _ = writeln!(y, "timeshift_cam_imu: {:?} # t_imu = t_cam + shift", c.td_s);
    if cam.readout_s != 0.0 {
        let _ = writeln!(
            y,
            "readout_s: {:?} # rolling shutter: rows top to bottom, stamp = middle row",
            cam.readout_s
        );
    }
    y
}

fn t_bs_yaml(out: &mut String, t: &Extrinsic) {
    let m = t.q_ab.to_rotation_matrix();
    let m = m.matrix();
    let p = t.p_ab;
    let _ = writeln!(out, "T_BS:\n  cols: 4\n  rows: 4");
    let _ = writeln!(
        out,
        "  data: [{:?}, {:?}, {:?}, {:?},\n         {:?}, {:?}, {:?}, {:?},\n         {:?}, {:?}, {:?}, {:?},\n         0.0, 0.0, 0.0, 1.0]",
        m[(0, 0)], m[(0, 1)], m[(0, 2)], p.x,
        m[(1, 0)], m[(1, 1)], m[(1, 2)], p.y,
        m[(2, 0)], m[(2, 1)], m[(2, 2)], p.z
    );
}

fn write_file(path: &Path, text: &str) -> Result<(), IoError> {
    std::fs::write(path, text).map_err(|e| IoError::io(path, e))
}

fn mkdir(p: &Path) -> Result<(), IoError> {
    std::fs::create_dir_all(p).map_err(|e| IoError::io(p, e))
}
