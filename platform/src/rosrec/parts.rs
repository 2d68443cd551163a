//! The time-ordered merge of a topic's messages across the parts of a container that hold them
//! (ROS 1 bag chunks; MCAP chunks and runs of loose messages), written once for every
//! container: the container gives its parts' start times and a [`PartLoader`] that reads one
//! part's wanted messages.
//!
//! Parts are taken in the order the container gives them: by start time (ties: file position).
//! A part is read when its start time is not later than the earliest message held, so messages
//! come out in log-time order (ties: part order, then order in the part) even when parts overlap
//! in time or were written out of order. Only the wanted messages of the parts read and not yet
//! emitted are held, and at most [`WINDOW_PARTS`] parts at once (a pathological overlap beyond
//! that emits the earliest held message first: order may then break, never memory). A part that
//! cannot be read is an `Err` item; the merge goes on with the next part.

use crate::error::IoError;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Parts (with messages left to emit) held by a merge at once.
pub const WINDOW_PARTS: usize = 32;

/// Reads the parts of one container for a [`PartMerge`].
pub trait PartLoader {
    /// A message as the container gives it.
    type Msg;
    /// The wanted messages of part `k` (an index into the start times given to the merge), in
    /// their order in the part.
    fn load(&mut self, k: usize) -> Result<Vec<Self::Msg>, IoError>;
    /// A message's log time, ns: the merge's order.
    fn time_ns(m: &Self::Msg) -> i64;
}

/// The messages of a container's parts in log-time order (see the module docs).
pub struct PartMerge<L: PartLoader> {
    loader: L,
    /// Start time of each part, in the order parts are read.
    starts: Vec<i64>,
    next_part: usize,
    /// Held messages: (time, part, index in part).
    heap: BinaryHeap<Reverse<(i64, usize, usize)>>,
    held: Vec<Vec<Option<L::Msg>>>,
    /// Messages of each part not yet emitted.
    pending: Vec<usize>,
    /// Parts with messages not yet emitted.
    live: usize,
}

impl<L: PartLoader> PartMerge<L> {
    /// The merge over parts starting at `starts` (in the order they are to be read: by start
    /// time, then file position), read by `loader`.
    pub fn new(loader: L, starts: Vec<i64>) -> Self {
        let n = starts.len();
        PartMerge {
            loader,
            starts,
            next_part: 0,
            heap: BinaryHeap::new(),
            held: (0..n).map(|_| Vec::new()).collect(),
            pending: vec![0; n],
            live: 0,
        }
    }

    /// The loader (its state: the file handle, what it was asked).
    pub fn loader(&self) -> &L {
        &self.loader
    }

    fn load(&mut self, k: usize) -> Result<(), IoError> {
        let msgs = self.loader.load(k)?;
        for (i, m) in msgs.iter().enumerate() {
            self.heap.push(Reverse((L::time_ns(m), k, i)));
        }
        if let (Some(p), Some(h)) = (self.pending.get_mut(k), self.held.get_mut(k)) {
            *p = msgs.len();
            if !msgs.is_empty() {
                self.live += 1;
            }
            *h = msgs.into_iter().map(Some).collect();
        }
        Ok(())
    }
}

impl<L: PartLoader> Iterator for PartMerge<L> {
    type Item = Result<L::Msg, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let earliest = self.heap.peek().map(|Reverse((t, _, _))| *t);
            let due = self.starts.get(self.next_part).is_some_and(|&start| {
                earliest.is_none_or(|t| start <= t) && self.live < WINDOW_PARTS
            });
            if !due {
                break;
            }
            let k = self.next_part;
            self.next_part += 1;
            if let Err(e) = self.load(k) {
                return Some(Err(e));
            }
        }
        let Reverse((_, k, i)) = self.heap.pop()?;
        let (held, pending) = (self.held.get_mut(k)?, self.pending.get_mut(k)?);
        let msg = held.get_mut(i).and_then(Option::take)?;
        *pending -= 1;
        if *pending == 0 {
            *held = Vec::new();
            self.live -= 1;
        }
        Some(Ok(msg))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parts as (start, messages as (time, tag)); part `fail` cannot be read.
    struct Fake {
        parts: Vec<Vec<(i64, u32)>>,
        fail: Option<usize>,
        loaded: Vec<usize>,
    }

    impl PartLoader for Fake {
        type Msg = (i64, u32);
        fn load(&mut self, k: usize) -> Result<Vec<(i64, u32)>, IoError> {
            self.loaded.push(k);
            if self.fail == Some(k) {
                return Err(IoError::Corrupt {
                    file: "fake".into(),
                    what: format!("part {k}"),
                    offset: k as u64,
                    msg: "unreadable".into(),
                });
            }
            Ok(self.parts[k].clone())
        }
        fn time_ns(m: &(i64, u32)) -> i64 {
            m.0
        }
    }

    fn merge(parts: Vec<Vec<(i64, u32)>>, fail: Option<usize>) -> PartMerge<Fake> {
        let starts = parts
            .iter()
            .map(|p| p.iter().map(|m| m.0).min().unwrap_or(0))
            .collect();
        PartMerge::new(
            Fake {
                parts,
                fail,
                loaded: Vec::new(),
            },
            starts,
        )
    }

    #[test]
    fn overlapping_parts_come_out_in_time_order_ties_by_part_then_place() {
        let parts = vec![
            vec![(10, 0), (30, 1), (30, 2), (50, 3)],
            vec![(20, 4), (30, 5), (40, 6)],
            vec![(60, 7)],
        ];
        let mut m = merge(parts, None);
        let got: Vec<u32> = m.by_ref().map(|x| x.unwrap().1).collect();
        assert_eq!(got, [0, 4, 1, 2, 5, 6, 3, 7]);
        assert_eq!(m.loader().loaded, [0, 1, 2]);
    }

    #[test]
    fn a_part_is_read_only_when_its_start_is_due() {
        let parts = vec![vec![(10, 0), (20, 1)], vec![(30, 2)]];
        let mut m = merge(parts, None);
        assert_eq!(m.next().unwrap().unwrap(), (10, 0));
        assert_eq!(m.next().unwrap().unwrap(), (20, 1));
        assert_eq!(m.loader().loaded, [0]);
        assert_eq!(m.next().unwrap().unwrap(), (30, 2));
        assert!(m.next().is_none());
    }

    #[test]
    fn an_unreadable_part_is_an_error_item_and_the_merge_goes_on() {
        let parts = vec![vec![(10, 0)], vec![(20, 1)], vec![(30, 2)]];
        let got: Vec<Result<u32, String>> = merge(parts, Some(1))
            .map(|x| x.map(|m| m.1).map_err(|e| e.to_string()))
            .collect();
        assert_eq!(got.len(), 3);
        assert_eq!(got[0], Ok(0));
        assert!(
            got[1].as_ref().is_err_and(|e| e.contains("part 1")),
            "{got:?}"
        );
        assert_eq!(got[2], Ok(2));
    }

    #[test]
    fn the_window_bounds_the_parts_held() {
        // Every part starts at 0 and ends late: all would be due at once.
        let n = WINDOW_PARTS + 8;
        let parts: Vec<Vec<(i64, u32)>> = (0..n)
            .map(|k| vec![(0, k as u32), (1000 + k as i64, k as u32)])
            .collect();
        let mut m = merge(parts, None);
        assert!(m.next().is_some());
        assert_eq!(m.loader().loaded.len(), WINDOW_PARTS);
        assert_eq!(m.count(), 2 * n - 1);
    }
}
