//! The sliding window of keyframes and the map from state blocks to error-state columns.
//!
//! Keyframes are addressed by *position*, `0` = oldest. Each keyframe keeps its navigation state
//! (at the IMU time of its image), its camera time delay and the preintegration from the
//! previous keyframe to it (unused for position 0).

use crate::factors::KeyframePose;
use crate::inertial::preintegration::Preintegration;
use crate::inertial::NavState;
use crate::Error;

/// IMU samples a keyframe interval can hold (re-integration needs them all): 1.28 s at 400 Hz,
/// far above the 0.475 s forced-keyframe interval.
pub const MAX_INTERVAL_SAMPLES: usize = 512;

/// Preintegration type used by the window.
pub type Preint = Preintegration<MAX_INTERVAL_SAMPLES>;

/// One keyframe.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Image time on the camera clock, ns.
    pub t_cam_ns: i64,
    /// State at the IMU time of the image (`t_cam + td` at creation).
    pub state: NavState,
    /// Camera-IMU time delay estimate of this keyframe, s.
    pub td_s: f64,
    /// The images show the platform at rest since before the previous keyframe (so over the
    /// whole interval to this one): zero-velocity factors apply.
    pub at_rest: bool,
    /// Storage of the preintegration from the previous keyframe to this one, valid with
    /// `has_preint` (it stays in its window slot: intervals are swapped in and out, never moved
    /// by value, see [`Window::push`]).
    preint: Preint,
    has_preint: bool,
}

impl Keyframe {
    /// A blank slot (all bits zero).
    const fn empty() -> Self {
        Keyframe {
            t_cam_ns: 0,
            state: NavState::ZERO,
            td_s: 0.0,
            at_rest: false,
            preint: Preint::empty(),
            has_preint: false,
        }
    }

    /// Preintegration from the previous keyframe to this one (`None` for the first keyframe of
    /// a new window; the oldest keyframe after a marginalization keeps its own).
    pub fn preint(&self) -> Option<&Preint> {
        self.has_preint.then_some(&self.preint)
    }

    /// The preintegration, mutable.
    pub fn preint_mut(&mut self) -> Option<&mut Preint> {
        if self.has_preint {
            Some(&mut self.preint)
        } else {
            None
        }
    }
}

/// Ring of at most `N` keyframes. Every slot holds its keyframe's storage (preintegration
/// included) for good: adding and dropping keyframes never moves one by value.
#[derive(Clone)]
pub struct Window<const N: usize> {
    slots: [Keyframe; N],
    head: usize,
    count: usize,
}

impl<const N: usize> Default for Window<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Window<N> {
    /// An empty window; `const` so it can initialize a `static`.
    pub const fn new() -> Self {
        Window {
            slots: [const { Keyframe::empty() }; N],
            head: 0,
            count: 0,
        }
    }

    /// Keyframes in the window.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True when there are no keyframes.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// True when `N` keyframes are held.
    pub fn is_full(&self) -> bool {
        self.count == N
    }

    fn slot(&self, pos: usize) -> Option<usize> {
        (pos < self.count && N > 0).then(|| (self.head + pos) % N)
    }

    /// Body poses and delays of the keyframes in window order (unused slots: the identity).
    pub fn poses(&self) -> [KeyframePose; N] {
        core::array::from_fn(|k| match self.get(k) {
            Some(kf) => KeyframePose {
                p_wb: kf.state.p_wb,
                q_wb: kf.state.q_wb,
                td: kf.td_s,
            },
            None => KeyframePose {
                p_wb: crate::math::Vec3::zeros(),
                q_wb: crate::math::Quat::identity(),
                td: 0.0,
            },
        })
    }

    /// Keyframe at `pos`.
    pub fn get(&self, pos: usize) -> Option<&Keyframe> {
        self.slot(pos).and_then(|s| self.slots.get(s))
    }

    /// Mutable keyframe at `pos`.
    pub fn get_mut(&mut self, pos: usize) -> Option<&mut Keyframe> {
        let s = self.slot(pos)?;
        self.slots.get_mut(s)
    }

    /// The newest keyframe.
    pub fn last(&self) -> Option<&Keyframe> {
        self.count.checked_sub(1).and_then(|p| self.get(p))
    }

    /// Appends a keyframe: time on the camera clock, state at the IMU time of the image, delay,
    /// rest flag, and the preintegration from the previous keyframe (`None` for the first one).
    /// The preintegration is swapped into the slot, not copied: `interval` gets the slot's old
    /// storage back, to restart in place ([`Preint::restart_with`]).
    /// [`Error::CapacityExceeded`] (and nothing changes) if the window is full.
    pub fn push(
        &mut self,
        t_cam_ns: i64,
        state: NavState,
        td_s: f64,
        at_rest: bool,
        interval: Option<&mut Preint>,
    ) -> Result<(), Error> {
        if self.count >= N {
            return Err(Error::CapacityExceeded);
        }
        let s = (self.head + self.count) % N;
        let Some(slot) = self.slots.get_mut(s) else {
            return Err(Error::CapacityExceeded);
        };
        slot.t_cam_ns = t_cam_ns;
        slot.state = state;
        slot.td_s = td_s;
        slot.at_rest = at_rest;
        slot.has_preint = interval.is_some();
        if let Some(p) = interval {
            core::mem::swap(&mut slot.preint, p);
        }
        self.count += 1;
        Ok(())
    }

    /// Removes the oldest keyframe (its slot's storage stays for reuse). False when empty.
    pub fn drop_oldest(&mut self) -> bool {
        if self.count == 0 {
            return false;
        }
        if let Some(slot) = self.slots.get_mut(self.head) {
            slot.has_preint = false;
        }
        self.head = (self.head + 1) % N;
        self.count -= 1;
        true
    }

    /// Removes everything (the slots' storage stays for reuse).
    pub fn clear(&mut self) {
        for s in self.slots.iter_mut() {
            s.has_preint = false;
        }
        self.head = 0;
        self.count = 0;
    }

    /// Back to the state [`Window::new`] builds (every slot blank), in place.
    pub fn reset_to_new(&mut self) {
        for s in self.slots.iter_mut() {
            s.t_cam_ns = 0;
            s.state = NavState::ZERO;
            s.td_s = 0.0;
            s.at_rest = false;
            s.preint.reset_to_empty();
            s.has_preint = false;
        }
        self.head = 0;
        self.count = 0;
    }
}

/// Width of a keyframe's error state `[p, theta, v, bg, ba]`.
pub const KF_DIM: usize = 15;
/// Width of the extrinsic error state `[p_bc, theta_bc]`.
pub const EXT_DIM: usize = 6;

/// A block of the error state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Block {
    /// Keyframe at a window position (15 columns).
    Kf(u8),
    /// The camera-IMU extrinsic (6 columns).
    Ext,
    /// Time delay of the keyframe at a window position (1 column).
    Td(u8),
}

impl Block {
    /// Number of error-state columns of the block.
    pub fn dim(self) -> usize {
        match self {
            Block::Kf(_) => KF_DIM,
            Block::Ext => EXT_DIM,
            Block::Td(_) => 1,
        }
    }
}

/// Column of every state block in one linear system.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layout<const N: usize> {
    kf: [Option<usize>; N],
    td: [Option<usize>; N],
    ext: Option<usize>,
    n: usize,
}

impl<const N: usize> Layout<N> {
    fn empty() -> Self {
        Layout {
            kf: [None; N],
            td: [None; N],
            ext: None,
            n: 0,
        }
    }

    fn place(&mut self, b: Block) {
        match b {
            Block::Kf(k) => {
                if let Some(c) = self.kf.get_mut(k as usize) {
                    *c = Some(self.n);
                }
            }
            Block::Td(k) => {
                if let Some(c) = self.td.get_mut(k as usize) {
                    *c = Some(self.n);
                }
            }
            Block::Ext => self.ext = Some(self.n),
        }
        self.n += b.dim();
    }

    /// The solve layout: keyframes in window order, then the extrinsic, then the time delays.
    pub fn solve(count: usize, ext: bool, td: bool) -> Self {
        let mut l = Self::empty();
        for k in 0..count.min(N) {
            l.place(Block::Kf(k as u8));
        }
        if ext {
            l.place(Block::Ext);
        }
        if td {
            for k in 0..count.min(N) {
                l.place(Block::Td(k as u8));
            }
        }
        l
    }

    /// The marginalization layout: the oldest keyframe (and its delay) first, so the first
    /// [`Layout::marginalized_dim`] columns are eliminated, then the rest in solve order.
    pub fn marginalize_oldest(count: usize, ext: bool, td: bool) -> Self {
        let mut l = Self::empty();
        l.place(Block::Kf(0));
        if td {
            l.place(Block::Td(0));
        }
        for k in 1..count.min(N) {
            l.place(Block::Kf(k as u8));
        }
        if ext {
            l.place(Block::Ext);
        }
        if td {
            for k in 1..count.min(N) {
                l.place(Block::Td(k as u8));
            }
        }
        l
    }

    /// Columns eliminated by the marginalization layout.
    pub fn marginalized_dim(td: bool) -> usize {
        KF_DIM + usize::from(td)
    }

    /// Total dimension.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// First column of a block, if present.
    pub fn col(&self, b: Block) -> Option<usize> {
        match b {
            Block::Kf(k) => self.kf.get(k as usize).copied().flatten(),
            Block::Td(k) => self.td.get(k as usize).copied().flatten(),
            Block::Ext => self.ext,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_are_dense_and_ordered() {
        let s: Layout<4> = Layout::solve(3, true, true);
        assert_eq!(s.dim(), 3 * 15 + 6 + 3);
        assert_eq!(s.col(Block::Kf(2)), Some(30));
        assert_eq!(s.col(Block::Ext), Some(45));
        assert_eq!(s.col(Block::Td(0)), Some(51));
        assert_eq!(s.col(Block::Kf(3)), None);
        let m: Layout<4> = Layout::marginalize_oldest(3, false, true);
        assert_eq!(m.col(Block::Kf(0)), Some(0));
        assert_eq!(m.col(Block::Td(0)), Some(15));
        assert_eq!(m.col(Block::Kf(1)), Some(16));
        assert_eq!(m.col(Block::Td(2)), Some(47));
        assert_eq!(m.dim(), 48);
        assert_eq!(Layout::<4>::marginalized_dim(true), 16);
    }
}
