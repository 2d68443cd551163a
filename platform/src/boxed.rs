//! Large core objects built directly on the heap, never on a stack (release and debug
//! builds alike).
//!
//! `Box::new(PoVins::new(cfg)?)` builds the estimator (about 5.6 MB) on the stack and moves
//! it into the box: optimized builds usually elide the copy, unoptimized ones do not (and keep
//! several temporaries), so the host tools used to run on 64-256 MB stacks. Here the memory
//! is allocated zeroed (`alloc_zeroed`: pages the kernel maps lazily) and the object is configured in place
//! ([`Estimator::configure`], [`Vio::configure`]), which builds nothing large on the stack.
//!
//! [`boxed_estimator`] relies on [`Estimator::empty`] being all zero bits (a zeroed
//! allocation: nothing in the executable, pages mapped lazily). [`boxed_vio`] assigns the
//! constant [`Vio::empty`] to the box (the image front end's empty state is not all zeros),
//! which costs its size in `.rodata`. Both avoid `MaybeUninit::write(Vio::empty())` and
//! `Box::new(..)`: a by-value argument is a stack temporary in unoptimized builds.

use povins_core::estimator::{Estimator, EstimatorConfig, PoVins};
use povins_core::frontend::image::tracker::FeatureTracker;
use povins_core::frontend::image::TrackerConfig;
use povins_core::vio::{Tracking, Vio};
use povins_core::Error;
use std::mem::MaybeUninit;

/// An unconfigured estimator ([`Estimator::empty`]) on the heap, built in place: the
/// allocation is zeroed and never passes through a stack. [`Estimator::configure`] it.
pub fn boxed_estimator<
    const N: usize,
    const L: usize,
    const D: usize,
    const P: usize,
    const GW: usize,
    const GH: usize,
    const Q: usize,
    const TC: usize,
>() -> Box<Estimator<N, L, D, P, GW, GH, Q, TC>> {
    let layout = std::alloc::Layout::new::<Estimator<N, L, D, P, GW, GH, Q, TC>>();
    // The estimator always holds buffers (`alloc_zeroed` needs a non-zero size).
    assert!(layout.size() > 0);
    // SAFETY: `layout` has a non-zero size.
    let ptr =
        unsafe { std::alloc::alloc_zeroed(layout) }.cast::<Estimator<N, L, D, P, GW, GH, Q, TC>>();
    if ptr.is_null() {
        std::alloc::handle_alloc_error(layout);
    }
    // SAFETY: `ptr` is a fresh allocation of the global allocator with the layout of the
    // estimator (what `Box` frees), and it holds a valid estimator: the core guarantees that
    // `Estimator::empty()` is all zero bits for every capacity (its documentation; checked by
    // `tests/estimator_static.rs`, whose `static` estimator the linker puts in `.bss`, which
    // only holds all-zero initializers; the capacities only change array lengths). So the
    // zeroed allocation is exactly the value `Estimator::empty()`.
    unsafe { Box::from_raw(ptr) }
}

/// [`PoVins`] configured with `cfg`, on the heap ([`boxed_estimator`], then
/// [`Estimator::configure`]): the same estimator as `Box::new(PoVins::new(cfg)?)`, but never
/// on a stack. [`Error::InvalidConfig`] for an invalid configuration.
pub fn boxed_povins(cfg: EstimatorConfig) -> Result<Box<PoVins>, Error> {
    let mut est: Box<PoVins> = boxed_estimator();
    est.configure(cfg)?;
    Ok(est)
}

/// A [`Vio`] (estimator and image front end) configured with `estimator` and `tracker`, on the
/// heap, never on a stack: the same object as `Box::new(Vio::new(estimator, tracker)?)`.
/// [`Error::InvalidConfig`] for an invalid configuration.
///
/// The tracker's [`Vio::empty`] is not all zero bits, so the box is initialized by assigning
/// the constant `Vio::empty()` to it (a copy from the executable's read-only data straight
/// into the heap, also in unoptimized builds: an assignment, not a by-value call), then
/// [`Vio::configure`]d in place. The price is the constant's size in `.rodata` (the type's
/// size: 7 to 12 MB per capacity, see the README's footprint table).
pub fn boxed_vio<
    const N: usize,
    const L: usize,
    const D: usize,
    const F: usize,
    const BYTES: usize,
    const LEVELS: usize,
>(
    estimator: EstimatorConfig,
    tracker: TrackerConfig,
) -> Result<Box<Vio<N, L, D, F, BYTES, LEVELS>>, Error> {
    let mut slot = Box::<Vio<N, L, D, F, BYTES, LEVELS>>::new_uninit();
    *slot = const { MaybeUninit::new(Vio::empty()) };
    // SAFETY: `slot` was just assigned a valid value (`Vio::empty()`).
    let mut vio = unsafe { slot.assume_init() };
    vio.configure(estimator, tracker)?;
    Ok(vio)
}

/// The image front end alone ([`Tracking`]) configured with `cfg` and `tracker`, on the heap,
/// never on a stack (as [`boxed_vio`]: the constant [`Tracking::empty`] assigned to the box,
/// then [`Tracking::configure`]). [`Error::InvalidConfig`] for an invalid configuration.
pub fn boxed_tracking<const F: usize, const BYTES: usize, const LEVELS: usize>(
    cfg: EstimatorConfig,
    tracker: TrackerConfig,
) -> Result<Box<Tracking<F, BYTES, LEVELS>>, Error> {
    let mut slot = Box::<Tracking<F, BYTES, LEVELS>>::new_uninit();
    *slot = const { MaybeUninit::new(Tracking::empty()) };
    // SAFETY: `slot` was just assigned a valid value (`Tracking::empty()`).
    let mut t = unsafe { slot.assume_init() };
    t.configure(cfg, tracker)?;
    Ok(t)
}

/// A [`FeatureTracker`] configured with `cfg`, on the heap, never on a stack (as
/// [`boxed_vio`]: the constant [`FeatureTracker::empty`] assigned to the box, then
/// [`FeatureTracker::configure`]). [`Error::InvalidConfig`] as [`FeatureTracker::new`].
pub fn boxed_tracker<const F: usize, const BYTES: usize, const LEVELS: usize>(
    cfg: TrackerConfig,
) -> Result<Box<FeatureTracker<F, BYTES, LEVELS>>, Error> {
    let mut slot = Box::<FeatureTracker<F, BYTES, LEVELS>>::new_uninit();
    *slot = const { MaybeUninit::new(FeatureTracker::empty()) };
    // SAFETY: `slot` was just assigned a valid value (`FeatureTracker::empty()`).
    let mut t = unsafe { slot.assume_init() };
    t.configure(cfg)?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::camera::{CameraExtrinsic, Distortion, PinholeCamera};
    use povins_core::estimator::Status;
    use povins_core::inertial::ImuNoise;
    use povins_core::vio::{EurocVio, WuxgaTracking, WuxgaVio};

    fn config() -> EstimatorConfig {
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
        EstimatorConfig::new(camera, ext, ImuNoise::EUROC_ADIS16448)
    }

    /// Runs `f` on a thread with a 256 KiB stack (the estimator is 20 times that).
    fn on_small_stack(f: impl FnOnce() + Send + 'static) {
        std::thread::Builder::new()
            .stack_size(256 << 10)
            .spawn(f)
            .expect("spawn")
            .join()
            .unwrap_or_else(|p| std::panic::resume_unwind(p));
    }

    #[test]
    fn boxed_estimator_needs_no_stack() {
        on_small_stack(|| {
            let e: Box<PoVins> = boxed_estimator();
            assert_eq!(e.status(), Status::Unconfigured);
            let e = boxed_povins(config()).expect("valid configuration");
            assert_eq!(e.status(), Status::WaitingForInit);
            assert_eq!(
                boxed_povins(EstimatorConfig::PLACEHOLDER).err(),
                Some(Error::InvalidConfig)
            );
        });
    }

    #[test]
    fn boxed_vio_needs_no_stack() {
        on_small_stack(|| {
            let v: Box<EurocVio> =
                boxed_vio(config(), TrackerConfig::default()).expect("valid configuration");
            assert_eq!(v.estimator().status(), Status::WaitingForInit);
            assert_eq!(v.tracker().config(), &TrackerConfig::default());
            assert!(v.features().is_empty());
            let bad: Result<Box<EurocVio>, _> = boxed_vio(config(), TrackerConfig::PLACEHOLDER);
            assert_eq!(bad.err(), Some(Error::InvalidConfig));
        });
    }

    /// The largest capacity (about 12 MB, 48 times the stack) and its front end alone.
    #[test]
    fn boxed_wuxga_vio_and_tracking_need_no_stack() {
        on_small_stack(|| {
            let v: Box<WuxgaVio> =
                boxed_vio(config(), TrackerConfig::default()).expect("valid configuration");
            assert!(std::mem::size_of_val(&*v) > 40 * (256 << 10));
            assert_eq!(v.estimator().status(), Status::WaitingForInit);
            assert_eq!(v.tracker().config(), &TrackerConfig::default());
            let t: Box<WuxgaTracking> =
                boxed_tracking(config(), TrackerConfig::default()).expect("valid configuration");
            assert_eq!(t.tracker().config(), &TrackerConfig::default());
            let bad: Result<Box<WuxgaTracking>, _> =
                boxed_tracking(config(), TrackerConfig::PLACEHOLDER);
            assert_eq!(bad.err(), Some(Error::InvalidConfig));
        });
    }
}
