//! Rendering every camera frame of a simulated sequence on worker threads.

use super::truth::camera_frames;
use super::{RenderOptions, Renderer};
use crate::sim::{Progress, SimOutput};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Receives each rendered frame: `(frame index, stamp ns, mono8 pixels)`, called from the worker
/// threads in any order.
pub type Sink<'a> = &'a (dyn Fn(usize, i64, Vec<u8>) -> anyhow::Result<()> + Sync);

/// CPU time of the calling thread, s (Linux `/proc/thread-self/schedstat`; `None` elsewhere).
pub fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = s.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

/// Timing of a sequence render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SequenceStats {
    /// Frames rendered.
    pub frames: usize,
    /// Worker threads.
    pub threads: usize,
    /// Wall time, s (ray table included).
    pub wall_s: f64,
    /// Mean time a worker spends rendering a frame (the sink excluded), ms: thread CPU time
    /// where the OS reports it (so other load on the machine does not count), else wall time.
    pub ms_per_frame: f64,
}

/// Renders the camera frames of `out` (one image per frame of `dataset.features`) with `threads`
/// workers (0 = all cores). Pixels depend only on the seed, the options and the frame, never on
/// the thread count or the order of completion.
pub fn render_sequence(
    out: &SimOutput,
    opts: &RenderOptions,
    seed: u64,
    threads: usize,
    progress: Progress<'_>,
    sink: Sink<'_>,
) -> anyhow::Result<SequenceStats> {
    opts.check()?;
    let start = Instant::now();
    let c = &out.dataset.calib;
    let renderer = Renderer::new(&out.world, c.camera, &c.t_bc);
    let frames = camera_frames(out);
    let threads = if threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        threads
    }
    .clamp(1, 64);
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let first_err: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let busy_s = Mutex::new(0.0f64);
    std::thread::scope(|sc| {
        for _ in 0..threads {
            sc.spawn(|| {
                let mut busy = 0.0;
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    if k >= frames.len() || failed.load(Ordering::Relaxed) {
                        break;
                    }
                    let (stamp, t) = frames[k];
                    let (t0, c0) = (Instant::now(), thread_cpu_s());
                    let px = renderer.render_frame(
                        &out.trajectory,
                        t,
                        (out.frames.first + k) as u64,
                        seed,
                        opts,
                    );
                    busy += match (c0, thread_cpu_s()) {
                        (Some(a), Some(b)) => b - a,
                        _ => t0.elapsed().as_secs_f64(),
                    };
                    if let Err(e) = sink(k, stamp, px) {
                        failed.store(true, Ordering::Relaxed);
                        if let Ok(mut slot) = first_err.lock() {
                            slot.get_or_insert(e);
                        }
                        break;
                    }
                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                    progress("images", d, frames.len());
                }
                if let Ok(mut b) = busy_s.lock() {
                    *b += busy;
                }
            });
        }
    });
    if let Some(e) = first_err.into_inner().ok().flatten() {
        return Err(e);
    }
    let n = frames.len();
    Ok(SequenceStats {
        frames: n,
        threads,
        wall_s: start.elapsed().as_secs_f64(),
        ms_per_frame: busy_s.into_inner().unwrap_or(0.0) * 1e3 / n.max(1) as f64,
    })
}
