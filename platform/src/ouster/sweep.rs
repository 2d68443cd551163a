//! Sweep assembly: lidar packets in arrival order to one [`LidarScan`] per frame id.

use super::metadata::{Metadata, XyzLut};
use super::packet::LidarPacket;
use crate::dataset::LidarScan;
use povins_core::lidar::LidarPoint;

/// What the assembler saw and dropped, summed over its life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Packets pushed.
    pub packets: u64,
    /// Sweeps emitted.
    pub sweeps: u64,
    /// Points emitted.
    pub points: u64,
    /// Valid columns whose pixels were used.
    pub columns: u64,
    /// Columns skipped because their status says invalid.
    pub invalid_columns: u64,
    /// Pixels of valid columns skipped because their range is 0 (no return).
    pub zero_range_points: u64,
    /// Columns of the window missing from an emitted frame (dropped packets, or a frame cut by
    /// the start or end of the stream).
    pub missing_columns: u64,
    /// Missing packets: `missing_columns` rounded up to whole packets, per frame.
    pub dropped_packets: u64,
    /// Packets of an earlier frame that arrived after a newer frame started (skipped).
    pub late_packets: u64,
    /// Columns received twice in one frame (the repeat is skipped).
    pub duplicate_columns: u64,
}

/// The frame being filled.
#[derive(Debug)]
struct Partial {
    frame_id: u32,
    seen: Vec<bool>,
    points: Vec<LidarPoint>,
    /// Earliest timestamp of a valid column, then of any column.
    t_valid_ns: Option<i64>,
    t_any_ns: i64,
}

/// What the last emitted sweep was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SweepInfo {
    /// Its frame id.
    pub frame_id: u32,
    /// Columns of the window it lacks.
    pub missing_columns: usize,
}

/// Assembles lidar packets (in arrival order) into sweeps, one per frame id.
///
/// A frame is emitted when a packet of a newer frame arrives (frame ids compared modulo 2^16,
/// 2^32 in the `FUSA` header, a difference below half of that being newer), and by
/// [`SweepAssembler::finish`]. Points are in the **sensor** frame (m), each timed by its
/// column's timestamp, in arrival order (column, then row); the sweep's `t_ns` is its earliest valid column's timestamp. Pixels with range 0 and
/// invalid columns are skipped and counted in [`Counts`]. The intensity is the signal photon
/// count, or the reflectivity in the low-data-rate profile (which has no signal).
#[derive(Debug)]
pub struct SweepAssembler {
    lut: XyzLut,
    meta: Metadata,
    use_reflectivity: bool,
    current: Option<Partial>,
    last: Option<SweepInfo>,
    counts: Counts,
    /// Consecutive late packets: past two frames' worth the sensor is taken to have restarted
    /// (frame ids start again after a re-init) and the late frame becomes the current one.
    late_run: usize,
}

impl SweepAssembler {
    /// An assembler for the packets described by `meta`.
    pub fn new(meta: &Metadata) -> Self {
        SweepAssembler {
            lut: XyzLut::new(meta),
            meta: meta.clone(),
            use_reflectivity: meta.profile == super::LidarProfile::LowDataRate,
            current: None,
            last: None,
            counts: Counts::default(),
            late_run: 0,
        }
    }

    /// Counts so far.
    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// The last emitted sweep's frame id and missing columns.
    pub fn last_sweep(&self) -> Option<SweepInfo> {
        self.last
    }

    /// Adds a packet; returns the previous frame's sweep when this packet starts a newer frame.
    pub fn push(&mut self, packet: &LidarPacket) -> Option<LidarScan> {
        self.counts.packets += 1;
        let mut emitted = None;
        if let Some(cur) = &self.current {
            let mask = self.meta.frame_id_mask();
            let ahead = packet.frame_id.wrapping_sub(cur.frame_id) & mask;
            let per_frame = self.meta.columns_per_frame / self.meta.columns_per_packet.max(1);
            if ahead > mask / 2 && self.late_run <= 2 * per_frame {
                self.counts.late_packets += 1;
                self.late_run += 1;
                return None;
            }
            self.late_run = 0;
            if ahead != 0 {
                emitted = self.take_current();
            }
        }
        let cols = self.meta.columns_per_frame;
        let cur = self.current.get_or_insert_with(|| Partial {
            frame_id: packet.frame_id,
            seen: vec![false; cols],
            points: Vec::new(),
            t_valid_ns: None,
            t_any_ns: i64::MAX,
        });
        for col in &packet.columns {
            let m = usize::from(col.measurement_id);
            let Some(seen) = cur.seen.get_mut(m) else {
                continue; // The decoder checks ids; a hand-made packet may not.
            };
            if *seen {
                self.counts.duplicate_columns += 1;
                continue;
            }
            *seen = true;
            cur.t_any_ns = cur.t_any_ns.min(col.t_ns);
            if !col.valid {
                self.counts.invalid_columns += 1;
                continue;
            }
            self.counts.columns += 1;
            cur.t_valid_ns = Some(cur.t_valid_ns.map_or(col.t_ns, |t| t.min(col.t_ns)));
            for (row, px) in col.pixels.iter().enumerate() {
                if px.range_mm == 0 {
                    self.counts.zero_range_points += 1;
                    continue;
                }
                let Some(p) = self.lut.point_m(m, row, px.range_mm) else {
                    continue;
                };
                let intensity = if self.use_reflectivity {
                    px.reflectivity
                } else {
                    px.signal
                };
                cur.points.push(LidarPoint {
                    t_ns: col.t_ns,
                    p_l: [p[0] as f32, p[1] as f32, p[2] as f32],
                    intensity: f32::from(intensity),
                });
            }
        }
        emitted
    }

    /// Emits the frame being filled, if any (call at the end of the stream).
    pub fn finish(&mut self) -> Option<LidarScan> {
        self.take_current()
    }

    fn take_current(&mut self) -> Option<LidarScan> {
        let cur = self.current.take()?;
        let missing = (0..self.meta.columns_per_frame)
            .filter(|&m| self.meta.in_window(m) && !cur.seen.get(m).copied().unwrap_or(false))
            .count();
        self.counts.missing_columns += missing as u64;
        self.counts.dropped_packets += missing.div_ceil(self.meta.columns_per_packet.max(1)) as u64;
        self.counts.sweeps += 1;
        self.counts.points += cur.points.len() as u64;
        self.last = Some(SweepInfo {
            frame_id: cur.frame_id,
            missing_columns: missing,
        });
        Some(LidarScan {
            t_ns: cur.t_valid_ns.unwrap_or(cur.t_any_ns),
            points: cur.points,
        })
    }
}
