//! The image front-end stage: camera images in, track frames (`push_frame`'s input) out.
//!
//! The source hands an image over undecoded ([`ImageData`]: a file path, an encoded PNG/JPEG
//! payload, or mono8 pixels a driver already has), so the IMU thread never decodes. The stage
//! runs **inside the back-end thread**, in the message order the IMU thread forwards: on an
//! image it decodes it ([`decode`], PNG/JPEG through [`crate::image_codec`]) and hands it to the
//! back end's [`Backend::push_image`] (for `povins_core::vio::Vio`: the INS prediction of the
//! window landmarks, the gyro rotation seed, the tracker, then `push_frame` with the tracks).
//!
//! Why in the back-end thread and not a thread of its own:
//! - The tracker's seeds come from the estimator's state at the image time: the predicted
//!   pixel of every window landmark (`Estimator::predict_features`, which reads the window's
//!   keyframes and landmarks) and the gyro rotation with the current bias, delay and extrinsic.
//!   That state lives on the back-end thread and changes at every keyframe. A front-end thread
//!   would have to ask the back end for it and wait for the answer (the back end must first
//!   have processed the IMU up to the image), or be given a copy of the window per image
//!   (hundreds of kB): it would wait on the back end either way, and run the tracker on a state
//!   other than the single-threaded replay's, so the deterministic mode could not be
//!   bit-identical to `povins run --frontend images`.
//! - With two cores there is no idle core for it: on core 0 it would compete with the IMU
//!   thread (whose p99 latency is the bar), on core 1 it would time-share with the back end,
//!   which has to wait for its output anyway. Measured (BENCHMARKS.md, issue 15): decoding and
//!   tracking an image take a few ms, well inside the keyframe period the back end may lag.
//!
//! The images' latencies and processing times are recorded per image ([`super::Timing`]'s
//! `image_*` and `frontend_*` histograms) and refused images counted
//! ([`super::PipelineCounters::image_failures`]).

use super::backend::elapsed_ns;
use super::stats::{PipelineCounters, Timing};
use povins_core::camera::FeatureObs;
use povins_core::estimator::{Estimator, ImuOutput, PoVins};
use povins_core::frontend::image::ImageView;
use povins_core::inertial::ImuSample;
use povins_core::lidar::LidarPoint;
use povins_core::vio::{ImageReport, Vio};
use povins_core::Error;
use std::borrow::Cow;
use std::path::PathBuf;
use std::time::Instant;

/// One camera image as a source delivers it (decoded by the front-end stage, not the IMU
/// thread).
#[derive(Debug, Clone, PartialEq)]
pub enum ImageData {
    /// Row-major 8-bit grayscale pixels.
    Mono8 {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// `width * height` bytes.
        pixels: Vec<u8>,
    },
    /// A PNG or JPEG payload.
    Encoded(Vec<u8>),
    /// A PNG or JPEG file (a dataset folder).
    File(PathBuf),
}

/// Decodes an image to `(width, height, mono8 pixels)`; the error says why it cannot be used.
pub fn decode(data: &ImageData) -> Result<(usize, usize, Cow<'_, [u8]>), String> {
    let owned =
        |m: crate::image_codec::Mono8| (m.width as usize, m.height as usize, Cow::Owned(m.pixels));
    match data {
        ImageData::Mono8 {
            width,
            height,
            pixels,
        } => {
            if width.checked_mul(*height) == Some(pixels.len()) {
                Ok((*width, *height, Cow::Borrowed(&pixels[..])))
            } else {
                Err(format!(
                    "{} bytes for {width}x{height} pixels",
                    pixels.len()
                ))
            }
        }
        ImageData::Encoded(bytes) => crate::image_codec::decode_mono8("image", bytes).map(owned),
        ImageData::File(path) => std::fs::read(path)
            .map_err(|e| format!("{}: {e}", path.display()))
            .and_then(|bytes| {
                crate::image_codec::decode_mono8("file", &bytes)
                    .map(owned)
                    .map_err(|e| format!("{}: {e}", path.display()))
            }),
    }
}

/// What the back-end thread drives: the estimator alone ([`PoVins`], fed with track frames) or
/// the estimator with the image front end ([`Vio`], fed with images too). Each method is the
/// core's own.
pub trait Backend: Send {
    /// The estimator (state, keyframes, counters, configuration).
    fn estimator(&self) -> &PoVins;
    /// `push_imu`.
    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error>;
    /// `update`.
    fn update(&mut self) -> Result<Option<ImuOutput>, Error>;
    /// `Estimator::push_frame`.
    fn push_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) -> Result<(), Error>;
    /// `Estimator::push_lidar`.
    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error>;
    /// Tracks an image and offers its tracks to the estimator (`Vio::push_image`); a back end
    /// without an image front end refuses it ([`Error::InvalidConfig`]).
    fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<ImageReport, Error>;
}

impl Backend for Estimator<10, 200, 166> {
    fn estimator(&self) -> &PoVins {
        self
    }
    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        Estimator::push_imu(self, s)
    }
    fn update(&mut self) -> Result<Option<ImuOutput>, Error> {
        Estimator::update(self)
    }
    fn push_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) -> Result<(), Error> {
        Estimator::push_frame(self, t_cam_ns, obs)
    }
    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error> {
        Estimator::push_lidar(self, points)
    }
    fn push_image(&mut self, _t_cam_ns: i64, _image: &ImageView) -> Result<ImageReport, Error> {
        Err(Error::InvalidConfig)
    }
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> Backend
    for Vio<10, 200, 166, F, BYTES, LEVELS>
{
    fn estimator(&self) -> &PoVins {
        Vio::estimator(self)
    }
    fn push_imu(&mut self, s: &ImuSample) -> Result<(), Error> {
        Vio::push_imu(self, s)
    }
    fn update(&mut self) -> Result<Option<ImuOutput>, Error> {
        Vio::update(self)
    }
    fn push_frame(&mut self, t_cam_ns: i64, obs: &[FeatureObs]) -> Result<(), Error> {
        self.estimator_mut().push_frame(t_cam_ns, obs)
    }
    fn push_lidar(&mut self, points: &[LidarPoint]) -> Result<(), Error> {
        self.estimator_mut().push_lidar(points)
    }
    fn push_image(&mut self, t_cam_ns: i64, image: &ImageView) -> Result<ImageReport, Error> {
        Vio::push_image(self, t_cam_ns, image)
    }
}

/// An image as the IMU thread forwards it.
#[derive(Debug)]
pub(crate) struct ImageMsg {
    /// Image time (camera clock), ns.
    pub t_cam_ns: i64,
    /// The undecoded image.
    pub data: ImageData,
    /// When the source returned it.
    pub arrival: Instant,
    /// The wall time its stamp was due (paced or live sources).
    pub due: Option<Instant>,
}

/// The stage: decodes `msg` and tracks it into `be`, recording the timings and counting a
/// failure (an image that cannot be decoded or that the tracker refuses: nothing changes in
/// the back end, as in the single-threaded replay).
pub(crate) fn process<E: Backend + ?Sized>(
    be: &mut E,
    msg: &ImageMsg,
    timing: &mut Timing,
    counters: &mut PipelineCounters,
) {
    let t0 = Instant::now();
    let decoded = decode(&msg.data);
    timing.frontend_decode.record(elapsed_ns(t0));
    let ok = decoded.ok().is_some_and(|(w, h, px)| {
        ImageView::new(&px, w, h, w)
            .and_then(|view| be.push_image(msg.t_cam_ns, &view))
            .is_ok()
    });
    let now = Instant::now();
    timing.frontend_image.record(elapsed_ns_between(t0, now));
    if !ok {
        counters.image_failures += 1;
        return;
    }
    timing
        .image_arrival_to_frame
        .record(elapsed_ns_between(msg.arrival, now));
    if let Some(due) = msg.due {
        timing
            .image_stamp_to_frame
            .record(elapsed_ns_between(due, now));
    }
}

/// Nanoseconds from `a` to `b` (0 when `b` is not later).
fn elapsed_ns_between(a: Instant, b: Instant) -> u64 {
    u64::try_from(b.saturating_duration_since(a).as_nanos()).unwrap_or(u64::MAX)
}
