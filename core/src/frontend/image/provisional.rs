//! First-steps check of new tracks: rejects corners whose patch is not explained by a single
//! surface.
//!
//! The strongest corners of a scene are often occlusion edges: the silhouette of a near object
//! against a farther, textured background makes a "corner" (a T-junction) out of two edges on
//! different surfaces. When the camera translates, the two layers move differently, the junction
//! slides along both edges, and the pixel the tracker started on is soon covered (or uncovered):
//! the track reports a point that is not a fixed point of the world. The forward-backward check
//! does not see it (the junction is tracked consistently both ways), and the anchored
//! refinement ([`super::reference`]) ends such a track only after it has slid.
//!
//! A new track keeps the level-0 patch around its detection (the storage of
//! [`super::reference::References`], which is free when the anchored refinement is off; when it
//! is on, its reference template is the same patch) and, for its first
//! [`ProvisionalConfig::frames`] steps, its frame-to-frame position is checked by an affine fit
//! ([`super::affine`]) of that patch in the new image, seeded there. One surface (any small
//! rotation, scale, shear of the patch) is explained by the affine warp: the residual stays at
//! the noise and interpolation level. Two layers moving differently are not: part of the patch
//! stays misaligned whatever the warp. The test is contrast-independent: the mean absolute
//! residual over the mean absolute gradient of the patch is the misalignment it corresponds to,
//! in pixels (a shift of `d` px of a patch with mean absolute gradient `g` makes a mean absolute
//! error of about `g d` for a random texture); a track is ended when it exceeds
//! [`ProvisionalConfig::max_misalignment_px`], or when the fit converges farther than
//! [`ProvisionalConfig::max_shift_px`] from the frame-to-frame position (the fit follows one of
//! the layers, the frame-to-frame LK the junction). Image-only: nothing in it needs ground truth.
//!
//! Integer image arithmetic (the fixed-point affine kernel and integer gradient sums); the
//! ratio is one `f64` division: bit-identical on every target.

use super::affine::{MAX_AFFINE_WINDOW, TEMPLATE_SIDE};
use super::reference::{ReferenceConfig, References};
use super::view::ImageView;
use crate::Error;

/// First-steps check parameters (`[frontend.provisional]`, every key optional).
///
/// **Off by default** (`enabled = false`): on simulated hand-held and robot sequences (seeds
/// 1-3, BENCHMARKS.md, issue 14, bar 2) the defaults below cut the wrong tracks (hidden or a
/// step > 1 px) by 30-36% (hand-held) and 1-11% (robot), with 6% fewer hand-held tracks of at
/// least 10 images (robot: -1% to +5%), but the front end's CPU time grows by about 40% (the
/// fits, and the top-up detection that replaces the rejected corners) and the end-to-end ATE
/// is not consistently better (3 of 6 sequences better, 3 worse). **Not for real cameras as
/// is**: on the real DM-VIO images the residual of correct first steps is dominated by sensor
/// noise, exposure changes and blur (the fit has no gain/bias term, the measure no noise
/// floor), and at 0.35 px it ends almost every new track (11 tracked per image instead of
/// 137); only at 3 px does it stop hurting there. `relative_to_median = 2` keeps the real
/// tracking intact (136 per image) but gives back most of the simulated gain (hand-held seed 1:
/// 15% wrong instead of 12%, 18% off). With it off the tracks are bit-identical to before.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ProvisionalConfig {
    /// Whether new tracks are checked against their detection patch (default false).
    pub enabled: bool,
    /// Steps a new track is checked for (its ages `1..=frames`), `1..=32` (default 1: a corner
    /// rejected at its first step is never reported twice; 3 rejects more edge corners but, as
    /// the detector finds the same edges again, makes many short tracks).
    pub frames: u32,
    /// Window side of the patch, px (odd, `5..=21`; the anchored refinement's window when that is
    /// on, since both share the template).
    pub window: usize,
    /// Largest accepted misalignment (mean absolute residual of the affine fit over the mean
    /// absolute gradient of the patch), px (default 0.35; 0.5 keeps more tracks and rejects
    /// less).
    pub max_misalignment_px: f32,
    /// Largest accepted distance between the converged fit and the frame-to-frame position, px.
    pub max_shift_px: f32,
    /// Noise-relative threshold: when above 0, a track is also kept unless its misalignment
    /// exceeds this times the median misalignment of the tracks checked in the same frame (an
    /// image-only estimate of what noise, blur and exposure changes make of a correct step); 0
    /// (default): the absolute threshold alone.
    pub relative_to_median: f32,
    /// Iteration cap of the fit.
    pub max_iterations: u32,
    /// Convergence of the fit: the window's corners moved less than this, px.
    pub epsilon_px: f32,
}

impl Default for ProvisionalConfig {
    fn default() -> Self {
        ProvisionalConfig {
            enabled: false,
            frames: 1,
            window: 15,
            max_misalignment_px: 0.35,
            max_shift_px: 0.5,
            relative_to_median: 0.0,
            max_iterations: 5,
            epsilon_px: 0.05,
        }
    }
}

impl ProvisionalConfig {
    /// What an unconfigured tracker holds: off, every number zero.
    pub const PLACEHOLDER: ProvisionalConfig = ProvisionalConfig {
        enabled: false,
        frames: 0,
        window: 0,
        max_misalignment_px: 0.0,
        max_shift_px: 0.0,
        relative_to_median: 0.0,
        max_iterations: 0,
        epsilon_px: 0.0,
    };

    /// Checks every parameter's range ([`Error::InvalidConfig`] otherwise). Off, nothing is
    /// checked (a placeholder is valid).
    pub fn validate(&self) -> Result<(), Error> {
        if !self.enabled {
            return Ok(());
        }
        let ok = (1..=32).contains(&self.frames)
            && !self.window.is_multiple_of(2)
            && (5..=MAX_AFFINE_WINDOW).contains(&self.window)
            && self.max_misalignment_px > 0.0
            && self.max_misalignment_px <= 100.0
            && self.max_shift_px > 0.0
            && self.max_shift_px <= 100.0
            && (0.0..=100.0).contains(&self.relative_to_median)
            && (1..=100).contains(&self.max_iterations)
            && self.epsilon_px > 0.0
            && self.epsilon_px <= 1.0;
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidConfig)
        }
    }

    /// The template settings of the shared storage when only this check uses it.
    pub fn as_reference(&self) -> ReferenceConfig {
        ReferenceConfig {
            enabled: false,
            window: self.window,
            max_iterations: self.max_iterations,
            epsilon_px: self.epsilon_px,
            ..ReferenceConfig::default()
        }
    }
}

/// Verdict of the first-steps check on one track.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// Explained by one surface (or not checkable: no template, degenerate fit).
    Keep,
    /// Not explained by one surface: end the track.
    Reject,
}

/// Mean absolute central-difference gradient `(|gx| + |gy|) / 2` over the template's
/// `win x win` interior, grey / px (0 for an invalid template).
pub fn mean_abs_gradient(pix: &[u8; TEMPLATE_SIDE * TEMPLATE_SIDE], win: usize) -> f64 {
    if win == 0 || win + 2 > TEMPLATE_SIDE {
        return 0.0;
    }
    let mut sum = 0i64;
    for r in 1..=win {
        for c in 1..=win {
            let at = |rr: usize, cc: usize| {
                i64::from(pix.get(rr * TEMPLATE_SIDE + cc).map_or(0, |&v| v))
            };
            let gx = at(r, c + 1) - at(r, c - 1);
            let gy = at(r + 1, c) - at(r - 1, c);
            sum += gx.abs() + gy.abs();
        }
    }
    // Central differences have gain 2; (|gx| + |gy|) / 2 is the mean over both axes.
    sum as f64 / (4 * win * win) as f64
}

/// What the fit of one new track measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Measured {
    /// Not checkable (no template, flat template, degenerate fit): kept.
    Unchecked,
    /// The converged fit is farther than `max_shift_px` from the frame-to-frame position.
    Shifted,
    /// The misalignment, px.
    Misalignment(f64),
}

/// Fits track `i`'s detection patch (its template in `refs`) at the frame-to-frame position
/// `pos` in the level-0 image `img`. `rc` holds the template settings (window, iterations,
/// epsilon) of the storage.
pub fn measure<const F: usize>(
    refs: &mut References<F>,
    i: usize,
    img: &ImageView,
    pos: [f64; 2],
    pc: &ProvisionalConfig,
    rc: &ReferenceConfig,
) -> Measured {
    let g = match refs.template(i) {
        Some(t) if t.is_valid() => {
            let (pix, win) = t.pixels();
            mean_abs_gradient(pix, win)
        }
        _ => return Measured::Unchecked,
    };
    if g <= 0.0 {
        return Measured::Unchecked;
    }
    let Some(fit) = refs.refine_warp(i, img, pos, rc) else {
        return Measured::Unchecked;
    };
    let (dx, dy) = (fit.pos[0] - pos[0], fit.pos[1] - pos[1]);
    let shift = f64::from(pc.max_shift_px);
    if fit.converged && dx * dx + dy * dy > shift * shift {
        return Measured::Shifted;
    }
    if fit.converged {
        refs.set_linear(i, fit.lin);
    }
    Measured::Misalignment(f64::from(fit.residual) / g)
}

/// The verdict on a measurement with the misalignment threshold `max_px`.
pub fn verdict(m: Measured, max_px: f64) -> Verdict {
    match m {
        Measured::Unchecked => Verdict::Keep,
        Measured::Shifted => Verdict::Reject,
        Measured::Misalignment(x) if x > max_px => Verdict::Reject,
        Measured::Misalignment(_) => Verdict::Keep,
    }
}

/// Checks track `i` with the absolute threshold alone ([`measure`], then [`verdict`] at
/// `max_misalignment_px`).
pub fn check<const F: usize>(
    refs: &mut References<F>,
    i: usize,
    img: &ImageView,
    pos: [f64; 2],
    pc: &ProvisionalConfig,
    rc: &ReferenceConfig,
) -> Verdict {
    let m = measure(refs, i, img, pos, pc, rc);
    verdict(m, f64::from(pc.max_misalignment_px))
}

#[cfg(test)]
#[path = "provisional_tests.rs"]
mod tests;
