//! A recorded sequence read incrementally: its calibration up front, then each sensor's stream
//! pulled message by message ([`Stream`]), so nothing holds the whole recording. The replay
//! ([`crate::source::MergedSource`]) merges the streams into the one arrival order.
//!
//! Implementations: EuRoC ASL folders ([`crate::euroc::EurocFolder`]), MCAP files
//! ([`crate::mcap_io::McapRecording`]) and sequences in memory ([`Dataset`], what the simulator
//! produces). [`crate::open_recording`] chooses by path.
//!
//! Frames as in [`crate::dataset`]: IMU samples in the body (IMU) frame `b`, feature observations
//! in raw distorted pixels, LiDAR points in the LiDAR frame `l`, ground truth the body in the
//! world `w` (z up).

use crate::dataset::{
    Calibration, Dataset, FeatureFrame, ImageFrame, LidarScan, SimLandmark, SimTruth,
};
use crate::error::IoError;
use povins_core::inertial::{ImuSample, NavState};

/// One sensor's messages in recorded order; an error ends the stream (it names the file and
/// the record).
pub type Stream<'a, T> = Box<dyn Iterator<Item = Result<T, IoError>> + Send + 'a>;

/// Which streams a recording has.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Contents {
    /// IMU samples.
    pub imu: bool,
    /// Feature tracks (an external front end's output).
    pub frames: bool,
    /// Camera images.
    pub images: bool,
    /// LiDAR sweeps.
    pub lidar: bool,
    /// Ground truth of the body in the world.
    pub ground_truth: bool,
    /// Stamps of the first and last IMU sample, ns, when known without reading the stream (for
    /// progress over the recording's time).
    pub imu_span_ns: Option<(i64, i64)>,
    /// Camera images, when known without reading them.
    pub image_count: Option<usize>,
}

/// A recorded sequence (see the module docs).
pub trait Recording: Send + Sync {
    /// Human-readable name (folder or file stem, or scenario).
    fn name(&self) -> &str;
    /// The sensors' calibration.
    fn calibration(&self) -> &Calibration;
    /// Which streams it has.
    fn contents(&self) -> Contents;
    /// The IMU samples, increasing in time.
    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError>;
    /// The feature frames, increasing in time (empty when it has none).
    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError>;
    /// The camera images, increasing in time, undecoded (empty when it has none).
    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError>;
    /// The LiDAR sweeps in recorded order (empty when it has none).
    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError>;
    /// The ground truth, increasing in time (for evaluation and ground-truth starts; empty when
    /// it has none), one state at a time: an evaluation passes over it without holding it.
    fn ground_truth_stream(&self) -> Result<Stream<'_, NavState>, IoError>;
    /// The whole ground truth in memory ([`Recording::ground_truth_stream`] collected).
    fn ground_truth(&self) -> Result<Vec<NavState>, IoError> {
        self.ground_truth_stream()?.collect()
    }
    /// What only a simulator knows (for evaluation), when the recording holds it in memory
    /// (a file streams it: [`Recording::sim_landmarks`]).
    fn sim_truth(&self) -> Option<&SimTruth> {
        None
    }
    /// Whether the recording carries a simulator's truth ([`Recording::sim_landmarks`]).
    fn has_sim_truth(&self) -> bool {
        self.sim_truth().is_some()
    }
    /// The simulator's truth one id at a time, by increasing first observation (`None` when
    /// the recording carries none): an evaluation passes over it beside the run's keyframes and
    /// holds only the ids alive at each. By default [`Recording::sim_truth`]'s ids, each held
    /// for the whole run.
    fn sim_landmarks(&self) -> Result<Option<Stream<'_, SimLandmark>>, IoError> {
        Ok(self
            .sim_truth()
            .map(|t| -> Stream<'_, SimLandmark> { Box::new(t.landmarks(&[]).into_iter().map(Ok)) }))
    }
    /// What was wrong in the recording but read past (samples dropped for their stamps, parts
    /// skipped, a missing index): complete once the streams have ended. A line that starts with
    /// [`NOTE`] is information, not a warning ([`label`]).
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }
}

/// Cloned items of a slice as a stream.
fn slice_stream<T: Clone + Send + Sync>(v: &[T]) -> Stream<'_, T> {
    Box::new(v.iter().cloned().map(Ok))
}

impl Recording for Dataset {
    fn name(&self) -> &str {
        &self.name
    }

    fn calibration(&self) -> &Calibration {
        &self.calib
    }

    fn contents(&self) -> Contents {
        Contents {
            imu: !self.imu.is_empty(),
            frames: !self.features.is_empty(),
            images: !self.images.is_empty(),
            lidar: !self.lidar.is_empty(),
            ground_truth: !self.ground_truth.is_empty(),
            imu_span_ns: self
                .imu
                .first()
                .zip(self.imu.last())
                .map(|(a, b)| (a.t_ns, b.t_ns)),
            image_count: Some(self.images.len()),
        }
    }

    fn imu(&self) -> Result<Stream<'_, ImuSample>, IoError> {
        Ok(slice_stream(&self.imu))
    }

    fn frames(&self) -> Result<Stream<'_, FeatureFrame>, IoError> {
        Ok(slice_stream(&self.features))
    }

    fn images(&self) -> Result<Stream<'_, ImageFrame>, IoError> {
        Ok(slice_stream(&self.images))
    }

    fn sweeps(&self) -> Result<Stream<'_, LidarScan>, IoError> {
        Ok(slice_stream(&self.lidar))
    }

    fn ground_truth_stream(&self) -> Result<Stream<'_, NavState>, IoError> {
        Ok(slice_stream(&self.ground_truth))
    }

    fn sim_truth(&self) -> Option<&SimTruth> {
        self.sim_truth.as_ref()
    }
}

/// The start of a [`Recording::warnings`] line that is information (what a LiDAR topic gave).
pub const NOTE: &str = "note: ";

/// A [`Recording::warnings`] line as the user sees it: `("note", text)` or `("warning", line)`.
pub fn label(line: &str) -> (&'static str, &str) {
    match line.strip_prefix(NOTE) {
        Some(text) => ("note", text),
        None => ("warning", line),
    }
}
