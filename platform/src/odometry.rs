//! The odometry of a run, chosen once: the estimator alone for feature tracks, the estimator
//! with the image front end, or the image front end alone, the front end's capacity fitting the
//! camera's images (up to 752x480: [`EurocVio`], [`EurocTracking`]; up to 1280x720: [`HdVio`],
//! [`HdTracking`]), built on the heap ([`crate::boxed`]) and driven from there on as a `dyn`
//! [`Odometry`] ([`crate::driver`], [`crate::pipeline`]).

use crate::boxed::{boxed_povins, boxed_tracking, boxed_vio};
use povins_core::estimator::{EstimatorConfig, PoVins};
use povins_core::frontend::image::TrackerConfig;
use povins_core::odometry::Odometry;
use povins_core::vio::{EurocTracking, EurocVio, HdTracking, HdVio, VioAiding};

/// What feeds the estimator's camera updates.
#[derive(Debug, Clone, Copy, PartialEq)]
// A configuration built once per run and passed by reference: its size does not matter.
#[allow(clippy::large_enum_variant)]
pub enum FrontEnd {
    /// Feature tracks from elsewhere (a recording's `features0`, an external tracker).
    Tracks,
    /// Camera images through the core's front end.
    Images {
        /// The tracker's settings.
        tracker: TrackerConfig,
        /// Which INS aids the tracker gets.
        aiding: VioAiding,
    },
    /// Camera images through the core's front end alone, no estimator
    /// ([`povins_core::vio::Tracking`]: the rotation seed from the configured delay and
    /// extrinsic, no predictions).
    TrackingOnly {
        /// The tracker's settings.
        tracker: TrackerConfig,
        /// Seed with the gyro rotation.
        gyro_rotation: bool,
    },
}

/// Why no odometry could be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BuildError {
    /// A configuration was refused by the core.
    #[error("invalid estimator or front-end configuration: {0}")]
    Config(povins_core::Error),
    /// No front-end capacity fits the camera's images.
    #[error("{width}x{height} images are larger than the front end's largest capacity (1280x720)")]
    ImagesTooLarge {
        /// The camera's width, px.
        width: u32,
        /// The camera's height, px.
        height: u32,
    },
}

/// The front end's capacity for a camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Capacity {
    /// No image front end.
    Tracks,
    /// Images up to 752x480.
    Euroc,
    /// Images up to 1280x720.
    Hd,
}

/// The capacity `fe` needs for `cfg`'s camera (the one place that knows the sizes).
fn capacity(cfg: &EstimatorConfig, fe: &FrontEnd) -> Result<Capacity, BuildError> {
    let (width, height) = (cfg.camera.width, cfg.camera.height);
    Ok(match fe {
        FrontEnd::Tracks => Capacity::Tracks,
        _ if width <= 752 && height <= 480 => Capacity::Euroc,
        _ if width <= 1280 && height <= 720 => Capacity::Hd,
        _ => return Err(BuildError::ImagesTooLarge { width, height }),
    })
}

/// Whether [`boxed_odometry`] would accept `cfg` and `fe` (the core's checks of the type it
/// would build), without building anything.
pub fn check(cfg: &EstimatorConfig, fe: &FrontEnd) -> Result<(), BuildError> {
    let r = match (capacity(cfg, fe)?, *fe) {
        (_, FrontEnd::Tracks) => PoVins::check(cfg),
        (Capacity::Hd, FrontEnd::Images { tracker, .. }) => HdVio::check(cfg, &tracker),
        (_, FrontEnd::Images { tracker, .. }) => EurocVio::check(cfg, &tracker),
        (Capacity::Hd, FrontEnd::TrackingOnly { tracker, .. }) => HdTracking::check(cfg, &tracker),
        (_, FrontEnd::TrackingOnly { tracker, .. }) => EurocTracking::check(cfg, &tracker),
    };
    r.map_err(BuildError::Config)
}

/// An odometry configured with `cfg` and fed by `fe`, on the heap (see the module docs), its
/// steps timed on `clock` (monotonic, ns; none: every timing in its outputs is zero).
pub fn boxed_odometry(
    cfg: EstimatorConfig,
    fe: &FrontEnd,
    clock: Option<fn() -> u64>,
) -> Result<Box<dyn Odometry + Send>, BuildError> {
    let hd = capacity(&cfg, fe)? == Capacity::Hd;
    let c = BuildError::Config;
    Ok(match *fe {
        FrontEnd::Tracks => {
            let mut e = boxed_povins(cfg).map_err(c)?;
            e.set_clock(clock);
            e
        }
        FrontEnd::Images { tracker, aiding } => {
            if hd {
                let mut v: Box<HdVio> = boxed_vio(cfg, tracker).map_err(c)?;
                v.set_aiding(aiding);
                v.set_clock(clock);
                v
            } else {
                let mut v: Box<EurocVio> = boxed_vio(cfg, tracker).map_err(c)?;
                v.set_aiding(aiding);
                v.set_clock(clock);
                v
            }
        }
        FrontEnd::TrackingOnly {
            tracker,
            gyro_rotation,
        } => {
            let aiding = VioAiding {
                predictions: false,
                gyro_rotation,
            };
            if hd {
                let mut t: Box<HdTracking> = boxed_tracking(cfg, tracker).map_err(c)?;
                t.set_aiding(aiding);
                t.set_clock(clock);
                t
            } else {
                let mut t: Box<EurocTracking> = boxed_tracking(cfg, tracker).map_err(c)?;
                t.set_aiding(aiding);
                t.set_clock(clock);
                t
            }
        }
    })
}
