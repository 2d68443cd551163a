//! The one path from a sensor message to the estimator: [`handle`] turns a [`SensorEvent`] into
//! the [`Odometry`] calls (decoding an image on the way) and reports what came back to an
//! [`Observer`]; [`run`] drives a whole [`Source`] through it on the calling thread. The threaded
//! pipeline's back end calls the same [`handle`] ([`crate::pipeline`]), so a single-threaded
//! replay and the pipeline in deterministic mode feed the estimator the same calls in the same
//! order because they share this code.
//!
//! Per event:
//! - IMU sample: [`Odometry::push_imu`], then [`Odometry::update`] until nothing is due (an
//!   update's error skips that sample, as the estimator documents; a refused sample still
//!   drains what was queued before it). Every output goes to [`Observer::output`].
//! - Feature frame: [`Odometry::push_frame`]; the predictions and tracks to
//!   [`Observer::frame`] (a refused frame is counted by the estimator).
//! - Image: decoded ([`crate::images::decode`]) and [`Odometry::push_image`]; an image that
//!   cannot be decoded or is refused goes to [`Observer::image_failed`] with the reason.
//! - LiDAR sweep: [`Odometry::push_lidar`] (a refused sweep is counted by the estimator).
//! - The source's end ([`run`]): [`Odometry::end_input`], then [`Odometry::update`] until nothing
//!   is due (what the estimator held back for later input). The threaded pipeline's back end
//!   does the same at its source's end ([`crate::pipeline`]).

use crate::error::IoError;
use crate::images::decode;
use crate::source::{SensorEvent, Source};
use povins_core::frontend::image::ImageView;
use povins_core::odometry::{FrameOutput, Odometry, Output};
use std::time::Instant;

/// What a driver's caller sees (all methods default to doing nothing).
pub trait Observer {
    /// An IMU sample was taken from the source (its stamp, ns): progress.
    fn imu(&mut self, _t_ns: i64) {}
    /// A processed IMU sample's output.
    fn output(&mut self, _out: &Output<'_>) {}
    /// A frame or image the odometry took (`image`: how the image arrived; `None` for a frame
    /// of tracks).
    fn frame(&mut self, _out: &FrameOutput<'_>, _image: Option<&ImageIn<'_>>) {}
    /// An image that could not be decoded or that the front end refused, with why.
    fn image_failed(&mut self, _t_cam_ns: i64, _why: String) {}
}

/// An image as the odometry was given it.
#[derive(Debug, Clone, Copy)]
pub struct ImageIn<'a> {
    /// The decoded pixels.
    pub view: &'a ImageView<'a>,
    /// The source's time reading and decoding it before it arrived, ns.
    pub prepared_ns: u64,
    /// The decoding here, ns.
    pub decode_ns: u64,
}

/// An observer that ignores everything.
impl Observer for () {}

/// What [`handle`] did with an event (for the caller's timing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handled {
    /// An IMU sample: whether it was accepted, and the outputs drained.
    Imu {
        /// The odometry queued it.
        accepted: bool,
        /// Outputs drained after it.
        outputs: u32,
        /// One of them carried a keyframe.
        keyframe: bool,
    },
    /// A feature frame (queued or refused).
    Frame,
    /// An image: decoding time and whether it reached the estimator.
    Image {
        /// Decoding, ns.
        decode_ns: u64,
        /// Decoded and tracked.
        ok: bool,
    },
    /// A LiDAR sweep (queued or refused).
    Lidar,
}

/// Hands one event to `odo` and its results to `obs` (see the module docs).
pub fn handle(odo: &mut dyn Odometry, ev: &SensorEvent, obs: &mut dyn Observer) -> Handled {
    match ev {
        SensorEvent::Imu(s) => {
            let accepted = odo.push_imu(s).is_ok();
            let (outputs, keyframe) = drain(odo, obs);
            Handled::Imu {
                accepted,
                outputs,
                keyframe,
            }
        }
        SensorEvent::Frame {
            t_cam_ns,
            obs: tracks,
        } => {
            if let Ok(out) = odo.push_frame(*t_cam_ns, tracks) {
                obs.frame(&out, None);
            }
            Handled::Frame
        }
        SensorEvent::Image {
            t_cam_ns,
            data,
            prepared_ns,
        } => {
            let t0 = Instant::now();
            let decoded = decode(data);
            let decode_ns = elapsed_ns(t0);
            let ok = match decoded {
                Err(e) => {
                    obs.image_failed(*t_cam_ns, e);
                    false
                }
                Ok((w, h, px)) => match ImageView::new(&px, w, h, w) {
                    Err(e) => {
                        obs.image_failed(
                            *t_cam_ns,
                            format!("image at {t_cam_ns} ns ({w}x{h}): {e}"),
                        );
                        false
                    }
                    Ok(view) => match odo.push_image(*t_cam_ns, &view) {
                        Ok(out) => {
                            let image = ImageIn {
                                view: &view,
                                prepared_ns: *prepared_ns,
                                decode_ns,
                            };
                            obs.frame(&out, Some(&image));
                            true
                        }
                        Err(e) => {
                            obs.image_failed(
                                *t_cam_ns,
                                format!("image at {t_cam_ns} ns ({w}x{h}) refused: {e}"),
                            );
                            false
                        }
                    },
                },
            };
            Handled::Image { decode_ns, ok }
        }
        SensorEvent::Lidar(points) => {
            let _ = odo.push_lidar(points);
            Handled::Lidar
        }
    }
}

/// [`Odometry::update`] until nothing is due, every output to `obs` (an error skips that
/// sample); how many outputs, and whether one carried a keyframe.
fn drain(odo: &mut dyn Odometry, obs: &mut dyn Observer) -> (u32, bool) {
    let (mut outputs, mut keyframe) = (0, false);
    loop {
        match odo.update() {
            Ok(Some(o)) => {
                outputs += 1;
                keyframe |= o.keyframe.is_some();
                obs.output(&o);
            }
            Ok(None) => return (outputs, keyframe),
            Err(_) => continue,
        }
    }
}

/// What a whole [`run`] measured.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RunStats {
    /// Events handled.
    pub events: u64,
    /// Time spent in [`handle`] (the odometry's calls and the images' decoding here), s.
    pub odometry_s: f64,
}

/// Drives every event of `source` through `odo` on the calling thread ([`handle`]), reporting
/// to `obs`; at the source's end, what the odometry held back for later input is processed
/// ([`Odometry::end_input`]). A source error ends the run with that error.
pub fn run(
    odo: &mut dyn Odometry,
    source: &mut dyn Source,
    obs: &mut dyn Observer,
) -> Result<RunStats, IoError> {
    let mut stats = RunStats::default();
    let mut busy_ns: u64 = 0;
    while let Some(ev) = source.next()? {
        if let SensorEvent::Imu(s) = &ev {
            obs.imu(s.t_ns);
        }
        let t0 = Instant::now();
        handle(odo, &ev, obs);
        busy_ns = busy_ns.saturating_add(elapsed_ns(t0));
        stats.events += 1;
    }
    let t0 = Instant::now();
    odo.end_input();
    drain(odo, obs);
    busy_ns = busy_ns.saturating_add(elapsed_ns(t0));
    stats.odometry_s = busy_ns as f64 * 1e-9;
    Ok(stats)
}

/// Nanoseconds since `t0`.
pub fn elapsed_ns(t0: Instant) -> u64 {
    u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX)
}
