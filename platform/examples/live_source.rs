//! A live driver wired into the pipeline: a [`Source`] over a channel fed by a driver thread.
//!
//! The "driver" here stands still and produces a 200 Hz IMU stream (gravity only) stamped on the
//! monotonic clock; a real one reads the device (SPI, serial, a ROS 2 subscription) and sends
//! IMU samples, feature frames and LiDAR sweeps in time order the same way. The estimator lives
//! in a `static` (firmware style: `.bss`, never on a stack), starts from the static period and
//! the IMU thread publishes a pose per sample with its latency.
//!
//! Run: `cargo run --release -p povins-platform --example live_source`.

use povins_core::camera::{CameraExtrinsic, PinholeCamera};
use povins_core::estimator::{EstimatorConfig, PoVins};
use povins_core::inertial::{ImuNoise, ImuSample};
use povins_core::math::Vec3;
use povins_platform::pipeline::{self, CallbackSink, PipelineConfig, PoseOut, SensorEvent, Source};
use povins_platform::IoError;
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The estimator, all zero bits until configured.
static EST: Mutex<PoVins> = Mutex::new(PoVins::empty());

/// A source over a channel from a driver thread, stamping on the monotonic clock from `origin`.
struct LiveSource {
    rx: Receiver<SensorEvent>,
    origin: Instant,
}

impl Source for LiveSource {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        // Blocks until the driver has a sample; `None` once the driver hung up.
        Ok(self.rx.recv().ok())
    }

    fn stamp_instant(&self, t_ns: i64) -> Option<Instant> {
        Some(self.origin + Duration::from_nanos(u64::try_from(t_ns).ok()?))
    }

    fn is_realtime(&self) -> bool {
        true
    }
}

/// The driver: `secs` of a still IMU at 200 Hz, each sample sent at its stamp.
fn driver(tx: std::sync::mpsc::SyncSender<SensorEvent>, origin: Instant, secs: u64) {
    let period = Duration::from_millis(5);
    for k in 0..secs * 200 {
        let t = period * k as u32;
        let now = origin.elapsed();
        if t > now {
            std::thread::sleep(t - now);
        }
        let s = ImuSample {
            t_ns: t.as_nanos() as i64,
            gyro_rps: Vec3::new(1e-4, -2e-4, 5e-5),
            accel_mps2: Vec3::new(0.01, -0.02, 9.81),
        };
        if tx.send(SensorEvent::Imu(s)).is_err() {
            return;
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let noise = ImuNoise {
        gyro_noise_density: 1.7e-4,
        accel_noise_density: 2.0e-3,
        gyro_bias_rw: 1.9e-5,
        accel_bias_rw: 3.0e-3,
        bias_corr_time_s: None,
    };
    let ext = CameraExtrinsic {
        p_bc: Vec3::zeros(),
        q_bc: povins_core::math::Quat::identity(),
    };
    let cfg = EstimatorConfig::new(PinholeCamera::EUROC_CAM0, ext, noise);
    let mut est = EST.lock().map_err(|_| "estimator lock poisoned")?;
    est.configure(cfg)
        .map_err(|e| format!("configuration: {e}"))?;

    let origin = Instant::now();
    let (tx, rx) = sync_channel(256);
    let drv = std::thread::spawn(move || driver(tx, origin, 3));
    let mut poses = 0u64;
    let mut worst_ns = 0u64;
    let mut sink = CallbackSink::poses(|p: &PoseOut| {
        poses += 1;
        worst_ns = worst_ns.max(p.latency_ns);
    });
    let pcfg = PipelineConfig {
        imu_period_ns: 5_000_000,
        ..PipelineConfig::default()
    };
    let report = pipeline::run(
        &mut *est,
        LiveSource { rx, origin },
        &mut sink,
        &pcfg,
        |_| {},
    )?;
    drv.join().map_err(|_| "driver panicked")?;
    let lat = report.timing.arrival_to_pose.summary_ms();
    println!(
        "{} samples in, {poses} poses out (static initialization first), arrival -> pose p50 \
         {:.3} ms, p99 {:.3} ms, worst {:.3} ms; {}",
        report.counters.imu_in,
        lat.p50_ms,
        lat.p99_ms,
        worst_ns as f64 * 1e-6,
        report.rt.summary()
    );
    Ok(())
}
