//! What a run's evaluation reads back after the run, kept on disk while the run goes rather
//! than in memory: the IMU-rate and keyframe poses (64 bytes a pose: an hour at 200 Hz is
//! 46 MB) and, with simulator truth, the LiDAR-depth events. Each log is an anonymous
//! temporary file (`tempfile::tempfile`: in `$TMPDIR`, gone when the log is dropped or the
//! process ends), written in native byte order and read back by the same process, exactly.
//!
//! Writing cannot fail the run as it goes (the sinks return nothing): the first error is kept
//! and reported when the log is read.

use crate::runner::KeyframeDepthEvents;
use anyhow::{anyhow, Context, Result};
use povins_core::estimator::{DepthEvent, DepthEventKind};
use povins_core::math::{Quat, Vec3};
use povins_platform::trajectory::StampedPose;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};

/// An append-only temporary file.
#[derive(Debug)]
struct Spill {
    w: Option<BufWriter<File>>,
    error: Option<String>,
}

impl Spill {
    fn new() -> Self {
        match tempfile::tempfile() {
            Ok(f) => Spill {
                w: Some(BufWriter::new(f)),
                error: None,
            },
            Err(e) => Spill {
                w: None,
                error: Some(format!("cannot create a temporary file: {e}")),
            },
        }
    }

    fn write(&mut self, bytes: &[u8]) {
        if let Some(w) = &mut self.w {
            if let Err(e) = w.write_all(bytes) {
                self.error = Some(format!("cannot write a temporary file: {e}"));
                self.w = None;
            }
        }
    }

    /// Writes out what is buffered, so that [`Spill::reader`] reads it.
    fn flush(&mut self) {
        if let Some(Err(e)) = self.w.as_mut().map(|w| w.flush()) {
            self.error = Some(format!("cannot write a temporary file: {e}"));
            self.w = None;
        }
    }

    /// A reader from the start, of what was written before the last [`Spill::flush`].
    fn reader(&self) -> Result<BufReader<&File>> {
        if let Some(e) = &self.error {
            return Err(anyhow!("the evaluation's log of the run: {e}"));
        }
        let mut f = self
            .w
            .as_ref()
            .context("the evaluation's log of the run is closed")?
            .get_ref();
        f.seek(SeekFrom::Start(0))
            .context("the evaluation's log of the run: cannot read a temporary file")?;
        Ok(BufReader::new(f))
    }
}

/// Rows of `K` numbers in the order they came (see the module docs).
#[derive(Debug)]
pub struct RowLog<const K: usize> {
    spill: Spill,
    n: usize,
    /// Rows written out ([`RowLog::flush`]): what [`RowLog::rows`] reads.
    flushed: usize,
}

impl<const K: usize> Default for RowLog<K> {
    fn default() -> Self {
        RowLog {
            spill: Spill::new(),
            n: 0,
            flushed: 0,
        }
    }
}

impl<const K: usize> RowLog<K> {
    /// Appends a row (its bits, exactly).
    pub fn push(&mut self, row: &[f64; K]) {
        for v in row {
            self.spill.write(&v.to_bits().to_ne_bytes());
        }
        self.n += 1;
    }

    /// Rows logged.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether none are.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Writes out the rows pushed so far, for [`RowLog::rows`].
    pub fn flush(&mut self) {
        self.spill.flush();
        self.flushed = self.n;
    }

    /// The rows up to the last [`RowLog::flush`], from the first: one pass (one at a time).
    pub fn rows(&self) -> Result<impl Iterator<Item = Result<[f64; K]>> + '_> {
        let n = self.flushed;
        let mut r = self.spill.reader()?;
        Ok((0..n).map(move |_| {
            let mut v = [0f64; K];
            for x in v.iter_mut() {
                let mut c = [0u8; 8];
                r.read_exact(&mut c)
                    .context("the evaluation's log of the run: cannot read a temporary file")?;
                *x = f64::from_bits(u64::from_ne_bytes(c));
            }
            Ok(v)
        }))
    }
}

/// Poses in the order they came (see the module docs): stamp (its bits), position, quaternion
/// (x y z w).
#[derive(Debug, Default)]
pub struct PoseLog(RowLog<8>);

impl PoseLog {
    /// Appends a pose.
    pub fn push(&mut self, p: &StampedPose) {
        let q = p.q_wb.quaternion();
        self.0.push(&[
            f64::from_bits(p.t_ns as u64),
            p.p_wb.x,
            p.p_wb.y,
            p.p_wb.z,
            q.i,
            q.j,
            q.k,
            q.w,
        ]);
    }

    /// Poses logged.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether none are.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Writes out the poses pushed so far, for [`PoseLog::poses`].
    pub fn flush(&mut self) {
        self.0.flush();
    }

    /// The poses up to the last [`PoseLog::flush`], from the first: one pass (one at a time).
    pub fn poses(&self) -> Result<impl Iterator<Item = Result<StampedPose>> + '_> {
        Ok(self.0.rows()?.map(|v| {
            let v = v?;
            Ok(StampedPose {
                t_ns: v[0].to_bits() as i64,
                p_wb: Vec3::new(v[1], v[2], v[3]),
                q_wb: Quat::new_unchecked(nalgebra::Quaternion::new(v[7], v[4], v[5], v[6])),
            })
        }))
    }
}

/// Bytes of a keyframe's header (camera time, event count) and of an event (id, kind, depth).
const STEP_BYTES: usize = 8 + 4;
const EVENT_BYTES: usize = 8 + 1 + 8;

/// LiDAR-depth events per keyframe, in the order they came (see the module docs).
#[derive(Debug, Default)]
pub struct EventLog {
    spill: Option<Spill>,
    steps: usize,
}

impl EventLog {
    /// A log that keeps the events.
    pub fn new() -> Self {
        EventLog {
            spill: Some(Spill::new()),
            steps: 0,
        }
    }

    /// Appends a keyframe's events.
    pub fn push(&mut self, t_cam_ns: i64, events: &[DepthEvent]) {
        let Some(spill) = &mut self.spill else {
            return;
        };
        let n = u32::try_from(events.len()).unwrap_or(u32::MAX);
        let mut h = [0u8; STEP_BYTES];
        h[..8].copy_from_slice(&t_cam_ns.to_ne_bytes());
        h[8..].copy_from_slice(&n.to_ne_bytes());
        spill.write(&h);
        for e in events.iter().take(n as usize) {
            let mut b = [0u8; EVENT_BYTES];
            b[..8].copy_from_slice(&e.id.to_ne_bytes());
            b[8] = match e.kind {
                DepthEventKind::Associated => 0,
                DepthEventKind::Rejected => 1,
                DepthEventKind::Culled => 2,
            };
            b[9..].copy_from_slice(&e.depth_m.to_bits().to_ne_bytes());
            spill.write(&b);
        }
        self.steps += 1;
    }

    /// Whether the log keeps events.
    pub fn is_kept(&self) -> bool {
        self.spill.is_some()
    }

    /// Calls `f` with each keyframe's events, from the first; an error when the log cannot be
    /// read (or keeps nothing).
    pub fn for_each(&mut self, mut f: impl FnMut(&KeyframeDepthEvents)) -> Result<()> {
        let steps = self.steps;
        let spill = self
            .spill
            .as_mut()
            .context("the run's LiDAR events were not kept")?;
        spill.flush();
        let mut r = spill.reader()?;
        let read = |r: &mut BufReader<&File>, b: &mut [u8]| {
            r.read_exact(b)
                .context("the evaluation's log of the run: cannot read a temporary file")
        };
        let u64_at = |b: &[u8]| {
            let mut c = [0u8; 8];
            c.copy_from_slice(&b[..8]);
            u64::from_ne_bytes(c)
        };
        let mut step = KeyframeDepthEvents {
            t_cam_ns: 0,
            events: Vec::new(),
        };
        for _ in 0..steps {
            let mut h = [0u8; STEP_BYTES];
            read(&mut r, &mut h)?;
            step.t_cam_ns = u64_at(&h) as i64;
            let mut c = [0u8; 4];
            c.copy_from_slice(&h[8..]);
            step.events.clear();
            for _ in 0..u32::from_ne_bytes(c) {
                let mut b = [0u8; EVENT_BYTES];
                read(&mut r, &mut b)?;
                step.events.push(DepthEvent {
                    id: u64_at(&b),
                    kind: match b[8] {
                        0 => DepthEventKind::Associated,
                        1 => DepthEventKind::Rejected,
                        _ => DepthEventKind::Culled,
                    },
                    depth_m: f64::from_bits(u64_at(&b[9..])),
                });
            }
            f(&step);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use povins_core::math::quat_exp;

    /// What goes in comes out, the same bits, as many times as it is read.
    #[test]
    fn logs_read_back_exactly() {
        let poses: Vec<StampedPose> = (0..1000)
            .map(|k| StampedPose {
                t_ns: -5 + k * 4_999_999,
                p_wb: Vec3::new(k as f64 / 3.0, -1e-300, f64::MAX / (k + 1) as f64),
                q_wb: quat_exp(&Vec3::new(0.1 * k as f64, 1.0, -0.3)),
            })
            .collect();
        let mut log = PoseLog::default();
        for p in &poses {
            log.push(p);
        }
        log.flush();
        for _ in 0..2 {
            let back: Vec<StampedPose> = log.poses().unwrap().collect::<Result<_>>().unwrap();
            assert_eq!(back, poses);
        }
        let steps: Vec<KeyframeDepthEvents> = (0..50)
            .map(|k| KeyframeDepthEvents {
                t_cam_ns: 1_000_000_000 * k,
                events: (0..k as u64 % 7)
                    .map(|i| DepthEvent {
                        id: u64::MAX - i,
                        kind: [
                            DepthEventKind::Associated,
                            DepthEventKind::Rejected,
                            DepthEventKind::Culled,
                        ][i as usize % 3],
                        depth_m: 1.0 / (i + 1) as f64,
                    })
                    .collect(),
            })
            .collect();
        let mut events = EventLog::new();
        for s in &steps {
            events.push(s.t_cam_ns, &s.events);
        }
        let mut back = Vec::new();
        events.for_each(|s| back.push(s.clone())).unwrap();
        assert_eq!(back, steps);
        assert!(EventLog::default().for_each(|_| {}).is_err());
    }
}
