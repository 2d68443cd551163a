//! Hand-rolled dense solver: caller-owned workspaces, symmetric block assembly, in-place LDLT,
//! Levenberg-Marquardt, Schur marginalization into a square-root prior, and Schur elimination of
//! per-landmark inverse depths.
//!
//! ## Sign and scale conventions (shared by every module here)
//! The cost is the plain sum of squared (whitened) residuals `c(x) = sum r^T r` (no factor 1/2).
//! Linearizing `r(x (+) dx) ~= r + J dx` gives
//! `c(dx) ~= c - 2 dx^T b + dx^T H dx` with `H = sum J^T J` and `b = -sum J^T r`, so the
//! Gauss-Newton step solves `H dx = b` directly: `b` is the *negative* half-gradient.
//!
//! ## Memory
//! The sliding window has ~166 error-state dimensions, so a dense `D x D` block is ~220 KB.
//! Every big buffer ([`NormalEquations`], [`Ldlt`], [`LmWorkspace`]) is a struct with a
//! `const fn new()` that the caller owns: on the host put it in a `Box`, on a microcontroller in a
//! `static` (a zero-initialized `static` lands in `.bss`, so no stack copy is ever made), e.g.
//! `static WS: Mutex<RefCell<LmWorkspace<166>>> = Mutex::new(RefCell::new(LmWorkspace::new()));`.
//! Functions take these buffers by `&mut` and never build a `D x D` temporary on the stack; the
//! only stack arrays are `D`-vectors.
//!
//! Only the upper triangle (`h[i][j]`, `i <= j`) of a symmetric matrix is ever read or written
//! unless a function says otherwise; [`NormalEquations::symmetrize`] fills the lower one for
//! consumers that want a full matrix.

mod fixed6;
pub mod ldlt;
pub mod lm;
pub mod marginalization;
pub mod normal_equations;
pub mod schur_landmarks;
pub mod shared_block;

pub use ldlt::{FactorReport, Ldlt, PivotFloor};
pub use lm::{LmConfig, LmProblem, LmSummary, LmWorkspace, Termination};
pub use marginalization::{add_prior, schur_complement, schur_complement_in_place, sqrt_prior};
pub use normal_equations::{JacobianBlock, NormalEquations};
pub use schur_landmarks::LandmarkSchur;
pub use shared_block::SharedBlock;

/// Deterministic uniform numbers in `[-0.5, 0.5)` for the solver's unit tests (a 64-bit LCG).
#[cfg(test)]
pub(crate) fn test_rng(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    }
}
