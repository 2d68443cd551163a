//! The odometry of a run, chosen once: the estimator alone for feature tracks, the estimator
//! with the image front end, or the image front end alone, the front end's capacity fitting the
//! camera's images (up to 752x480: [`EurocVio`], [`EurocTracking`]; up to 1280x720: [`HdVio`],
//! [`HdTracking`]; up to 1920x1200: [`WuxgaVio`], [`WuxgaTracking`]), built on the heap
//! ([`crate::boxed`]) and driven from there on as a `dyn` [`Odometry`] ([`crate::driver`],
//! [`crate::pipeline`]).

use crate::boxed::{boxed_povins, boxed_tracking, boxed_vio};
use povins_core::estimator::{EstimatorConfig, PoVins};
use povins_core::frontend::image::TrackerConfig;
use povins_core::odometry::Odometry;
use povins_core::vio::{
    EurocTracking, EurocVio, HdTracking, HdVio, Tracking, Vio, VioAiding, WuxgaTracking, WuxgaVio,
};

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
    #[error(
        "{width}x{height} images are larger than the front end's largest capacity ({}x{})",
        LARGEST_IMAGE.0,
        LARGEST_IMAGE.1
    )]
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
    /// Images up to 1920x1200.
    Wuxga,
}

/// Each image capacity with its largest image, `(width, height)` px, smallest first (the one
/// place that knows the sizes; each type's pyramid is sized for its entry).
const CAPACITIES: [(Capacity, (u32, u32)); 3] = [
    (Capacity::Euroc, (752, 480)),
    (Capacity::Hd, (1280, 720)),
    (Capacity::Wuxga, (1920, 1200)),
];

/// The largest image any capacity takes, `(width, height)` px: 1920x1200. No front end povins
/// builds uses a larger image, so [`crate::image_codec`] and [`crate::image_raw`] refuse one
/// before decoding it (and [`BuildError::ImagesTooLarge`] a camera calibrated larger).
pub const LARGEST_IMAGE: (u32, u32) = CAPACITIES[CAPACITIES.len() - 1].1;

/// The capacity `fe` needs for `cfg`'s camera: the smallest that holds its images.
fn capacity(cfg: &EstimatorConfig, fe: &FrontEnd) -> Result<Capacity, BuildError> {
    let (width, height) = (cfg.camera.width, cfg.camera.height);
    if let FrontEnd::Tracks = fe {
        return Ok(Capacity::Tracks);
    }
    CAPACITIES
        .iter()
        .find(|(_, (w, h))| width <= *w && height <= *h)
        .map(|&(c, _)| c)
        .ok_or(BuildError::ImagesTooLarge { width, height })
}

/// Whether [`boxed_odometry`] would accept `cfg` and `fe` (the core's checks of the type it
/// would build), without building anything.
pub fn check(cfg: &EstimatorConfig, fe: &FrontEnd) -> Result<(), BuildError> {
    let r = match (capacity(cfg, fe)?, *fe) {
        (_, FrontEnd::Tracks) => PoVins::check(cfg),
        (Capacity::Hd, FrontEnd::Images { tracker, .. }) => HdVio::check(cfg, &tracker),
        (Capacity::Wuxga, FrontEnd::Images { tracker, .. }) => WuxgaVio::check(cfg, &tracker),
        (_, FrontEnd::Images { tracker, .. }) => EurocVio::check(cfg, &tracker),
        (Capacity::Hd, FrontEnd::TrackingOnly { tracker, .. }) => HdTracking::check(cfg, &tracker),
        (Capacity::Wuxga, FrontEnd::TrackingOnly { tracker, .. }) => {
            WuxgaTracking::check(cfg, &tracker)
        }
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
    let cap = capacity(&cfg, fe)?;
    let c = BuildError::Config;
    Ok(match *fe {
        FrontEnd::Tracks => {
            let mut e = boxed_povins(cfg).map_err(c)?;
            e.set_clock(clock);
            e
        }
        FrontEnd::Images { tracker, aiding } => match cap {
            Capacity::Hd => aided::<HdVio>(boxed_vio(cfg, tracker).map_err(c)?, aiding, clock),
            Capacity::Wuxga => {
                aided::<WuxgaVio>(boxed_vio(cfg, tracker).map_err(c)?, aiding, clock)
            }
            Capacity::Euroc | Capacity::Tracks => {
                aided::<EurocVio>(boxed_vio(cfg, tracker).map_err(c)?, aiding, clock)
            }
        },
        FrontEnd::TrackingOnly {
            tracker,
            gyro_rotation,
        } => {
            let aiding = VioAiding {
                predictions: false,
                gyro_rotation,
            };
            match cap {
                Capacity::Hd => {
                    aided::<HdTracking>(boxed_tracking(cfg, tracker).map_err(c)?, aiding, clock)
                }
                Capacity::Wuxga => {
                    aided::<WuxgaTracking>(boxed_tracking(cfg, tracker).map_err(c)?, aiding, clock)
                }
                Capacity::Euroc | Capacity::Tracks => {
                    aided::<EurocTracking>(boxed_tracking(cfg, tracker).map_err(c)?, aiding, clock)
                }
            }
        }
    })
}

/// The image front ends' setters ([`Vio`], [`Tracking`]), so that [`aided`] finishes any
/// capacity.
trait Aided: Odometry + Send + 'static {
    fn set_aiding(&mut self, aiding: VioAiding);
    fn set_clock(&mut self, clock: Option<fn() -> u64>);
}

impl<
        const N: usize,
        const L: usize,
        const D: usize,
        const F: usize,
        const BYTES: usize,
        const LEVELS: usize,
    > Aided for Vio<N, L, D, F, BYTES, LEVELS>
{
    fn set_aiding(&mut self, aiding: VioAiding) {
        Vio::set_aiding(self, aiding);
    }
    fn set_clock(&mut self, clock: Option<fn() -> u64>) {
        Vio::set_clock(self, clock);
    }
}

impl<const F: usize, const BYTES: usize, const LEVELS: usize> Aided for Tracking<F, BYTES, LEVELS> {
    fn set_aiding(&mut self, aiding: VioAiding) {
        Tracking::set_aiding(self, aiding);
    }
    fn set_clock(&mut self, clock: Option<fn() -> u64>) {
        Tracking::set_clock(self, clock);
    }
}

/// `fe` with its aids and clock set, as a `dyn` [`Odometry`].
fn aided<T: Aided>(
    mut fe: Box<T>,
    aiding: VioAiding,
    clock: Option<fn() -> u64>,
) -> Box<dyn Odometry + Send> {
    fe.set_aiding(aiding);
    fe.set_clock(clock);
    fe
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::{CameraExtrinsic, Distortion, PinholeCamera};
    use povins_core::inertial::ImuNoise;

    fn config(width: u32, height: u32) -> EstimatorConfig {
        let camera = PinholeCamera {
            readout_s: 0.0,
            width,
            height,
            fx: 0.6 * f64::from(width),
            fy: 0.6 * f64::from(width),
            cx: 0.5 * f64::from(width),
            cy: 0.5 * f64::from(height),
            distortion: Distortion::None,
        };
        let ext = CameraExtrinsic {
            p_bc: nalgebra::Vector3::zeros(),
            q_bc: nalgebra::UnitQuaternion::identity(),
        };
        EstimatorConfig::new(camera, ext, ImuNoise::EUROC_ADIS16448)
    }

    fn images() -> FrontEnd {
        FrontEnd::Images {
            tracker: TrackerConfig::default(),
            aiding: VioAiding::default(),
        }
    }

    fn tracking_only() -> FrontEnd {
        FrontEnd::TrackingOnly {
            tracker: TrackerConfig::default(),
            gyro_rotation: true,
        }
    }

    #[test]
    fn each_camera_gets_the_smallest_capacity_that_holds_its_images() {
        let cap = |w, h| capacity(&config(w, h), &images());
        assert_eq!(cap(752, 480), Ok(Capacity::Euroc));
        assert_eq!(cap(640, 360), Ok(Capacity::Euroc));
        assert_eq!(cap(753, 480), Ok(Capacity::Hd));
        assert_eq!(cap(1280, 720), Ok(Capacity::Hd));
        assert_eq!(cap(1280, 1024), Ok(Capacity::Wuxga));
        assert_eq!(cap(1920, 1080), Ok(Capacity::Wuxga));
        assert_eq!(cap(1920, 1200), Ok(Capacity::Wuxga));
        assert_eq!(
            capacity(&config(4000, 3000), &FrontEnd::Tracks),
            Ok(Capacity::Tracks)
        );
    }

    /// The paper's 1280x1024 camera (refused before the 1920x1200 capacity) and 1920x1200
    /// build both image front ends; they take an image of their size.
    #[test]
    fn images_up_to_1920x1200_build_the_odometry() {
        for (w, h) in [(1280u32, 1024u32), (1920, 1200)] {
            for fe in [images(), tracking_only()] {
                let cfg = config(w, h);
                assert_eq!(check(&cfg, &fe), Ok(()), "{w}x{h} {fe:?}");
                let mut odo = boxed_odometry(cfg, &fe, None)
                    .unwrap_or_else(|e| panic!("{w}x{h} {fe:?}: {e}"));
                let img = vec![128u8; (w * h) as usize];
                let view = povins_core::frontend::image::ImageView::new(
                    &img, w as usize, h as usize, w as usize,
                )
                .expect("a valid view");
                let out = odo
                    .push_image(0, &view)
                    .expect("an image of the camera's size");
                assert!(out.image.is_some());
            }
        }
    }

    #[test]
    fn images_larger_than_1920x1200_are_refused_naming_the_largest_capacity() {
        for (w, h) in [(1921u32, 1200u32), (1920, 1201), (4000, 3000)] {
            for fe in [images(), tracking_only()] {
                let cfg = config(w, h);
                let want = BuildError::ImagesTooLarge {
                    width: w,
                    height: h,
                };
                assert_eq!(check(&cfg, &fe), Err(want.clone()));
                let e = boxed_odometry(cfg, &fe, None).err().expect("refused");
                assert_eq!(e, want);
                assert_eq!(
                    e.to_string(),
                    format!(
                        "{w}x{h} images are larger than the front end's largest capacity \
                         (1920x1200)"
                    )
                );
            }
        }
    }
}
