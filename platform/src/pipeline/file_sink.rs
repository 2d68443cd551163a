//! A file written by a thread of its own while the run goes on ([`FileSink`]): the sink's calls
//! on the IMU thread copy each output into a lock-free queue (allocated when the sink is made;
//! full: dropped and counted) and return; the writer thread writes what the queue holds, flushes
//! at least every [`FileOptions::flush_period`] (so a killed process leaves a file complete up to
//! its last flush), and at [`FileSink::stop`] writes the rest and closes the file. The format is
//! a [`StampedWriter`]: [`super::TumSink`] and [`super::McapSink`] are the two.

use super::sink::{PoseOut, Sink, Stamped};
use crate::error::IoError;
use crate::trajectory::{write_tum_header, write_tum_row, StampedPose};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often the writer thread looks at the queue.
const POLL: Duration = Duration::from_millis(20);

/// A file format the writer thread writes outputs in.
pub trait StampedWriter: Send + 'static {
    /// Writes one output (a format may skip the kinds it does not hold).
    fn write(&mut self, item: &Stamped) -> Result<(), IoError>;
    /// Hands everything written so far to the operating system, complete.
    fn flush(&mut self) -> Result<(), IoError>;
    /// Writes what closes the file, and closes it.
    fn finish(self: Box<Self>) -> Result<(), IoError>;
}

/// How a [`FileSink`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileOptions {
    /// Longest time between two flushes of the file.
    pub flush_period: Duration,
    /// Outputs the queue to the writer thread holds.
    pub queue: usize,
}

impl Default for FileOptions {
    /// Flushed every second, a queue of 65,536 outputs (5 minutes of 200 Hz poses, 4 MiB).
    fn default() -> Self {
        FileOptions {
            flush_period: Duration::from_secs(1),
            queue: 1 << 16,
        }
    }
}

/// What a [`FileSink`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FileCounts {
    /// Poses written.
    pub poses: u64,
    /// Keyframe states written.
    pub keyframes: u64,
    /// Outputs not written: the queue was full, or the writing had stopped at an error.
    pub dropped_queue: u64,
    /// Flushes of the file during the run (not counting the end).
    pub flushes: u64,
}

#[derive(Debug, Default)]
struct Shared {
    stop: AtomicBool,
    poses: AtomicU64,
    keyframes: AtomicU64,
    flushes: AtomicU64,
}

/// The queue and the writer thread of one file (see the module doc).
#[derive(Debug)]
pub struct FileSink {
    path: PathBuf,
    tx: rtrb::Producer<Stamped>,
    shared: Arc<Shared>,
    dropped: u64,
    writer: Option<JoinHandle<Result<(), IoError>>>,
}

impl FileSink {
    /// Starts the writer thread `name` writing `file` (already created at `path`).
    pub fn spawn(
        name: &str,
        path: &Path,
        file: Box<dyn StampedWriter>,
        opts: FileOptions,
    ) -> Result<Self, IoError> {
        if opts.flush_period.is_zero() || opts.queue == 0 {
            return Err(IoError::Invalid {
                path: path.into(),
                msg: format!(
                    "output options {opts:?}: the flush period and the queue must be above 0"
                ),
            });
        }
        let shared = Arc::new(Shared::default());
        let (tx, rx) = rtrb::RingBuffer::new(opts.queue);
        let s = shared.clone();
        let writer = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || write_loop(file, rx, &s, opts.flush_period))
            .map_err(|e| IoError::io(path, e))?;
        Ok(FileSink {
            path: path.into(),
            tx,
            shared,
            dropped: 0,
            writer: Some(writer),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Queues one output (the IMU thread: no allocation, no wait).
    pub fn push(&mut self, item: Stamped) {
        if self.tx.push(item).is_err() {
            self.dropped += 1;
        }
    }

    /// The counts so far (complete after [`Self::stop`]).
    pub fn counts(&self) -> FileCounts {
        FileCounts {
            poses: self.shared.poses.load(Ordering::Relaxed),
            keyframes: self.shared.keyframes.load(Ordering::Relaxed),
            dropped_queue: self.dropped,
            flushes: self.shared.flushes.load(Ordering::Relaxed),
        }
    }

    /// Stops the writer thread after it has written what is queued and closed the file; its
    /// result (the first error, naming the file). Later calls return `Ok`.
    pub fn stop(&mut self) -> Result<(), IoError> {
        self.shared.stop.store(true, Ordering::Release);
        let Some(h) = self.writer.take() else {
            return Ok(());
        };
        h.thread().unpark();
        match h.join() {
            Ok(r) => r,
            Err(_) => Err(IoError::Invalid {
                path: self.path.clone(),
                msg: "the writer thread panicked".into(),
            }),
        }
    }
}

impl Drop for FileSink {
    /// Without [`FileSink::stop`], the file is still completed (errors are lost).
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

/// The writer thread: writes what the queue holds, flushes every `period`, and at the stop
/// writes the rest and closes the file.
fn write_loop(
    mut file: Box<dyn StampedWriter>,
    mut rx: rtrb::Consumer<Stamped>,
    shared: &Shared,
    period: Duration,
) -> Result<(), IoError> {
    let mut last_flush = Instant::now();
    let mut unflushed = false;
    loop {
        // Read before draining: whatever was pushed before the stop is written.
        let stop = shared.stop.load(Ordering::Acquire);
        while let Ok(item) = rx.pop() {
            file.write(&item)?;
            let n = match item {
                Stamped::Pose(_) => &shared.poses,
                Stamped::Keyframe(_) => &shared.keyframes,
            };
            n.fetch_add(1, Ordering::Relaxed);
            unflushed = true;
        }
        if stop {
            return file.finish();
        }
        let since = last_flush.elapsed();
        if since >= period {
            if unflushed {
                file.flush()?;
                shared.flushes.fetch_add(1, Ordering::Relaxed);
                unflushed = false;
            }
            last_flush = Instant::now();
            continue;
        }
        std::thread::park_timeout(POLL.min(period - since));
    }
}

/// The IMU-rate poses as a TUM trajectory file ([`crate::trajectory::write_tum`]'s format, row
/// by row), written by a [`FileSink`] thread during the run.
#[derive(Debug)]
pub struct TumSink {
    file: FileSink,
}

impl TumSink {
    /// Creates `path` (its header written) and starts the writer thread.
    pub fn create(path: impl Into<PathBuf>, opts: FileOptions) -> Result<Self, IoError> {
        let path = path.into();
        let f = File::create(&path).map_err(|e| IoError::io(&path, e))?;
        let mut w = BufWriter::with_capacity(1 << 16, f);
        write_tum_header(&mut w).map_err(|e| IoError::io(&path, e))?;
        let writer = TumWriter {
            path: path.clone(),
            w,
        };
        Ok(TumSink {
            file: FileSink::spawn("tum-writer", &path, Box::new(writer), opts)?,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        self.file.path()
    }

    /// The counts so far (complete after [`Sink::finish`]).
    pub fn counts(&self) -> FileCounts {
        self.file.counts()
    }
}

impl Sink for TumSink {
    fn pose(&mut self, p: &PoseOut) {
        self.file.push(Stamped::Pose(StampedPose::from(&p.nav)));
    }

    fn finish(&mut self) -> Result<(), IoError> {
        self.file.stop()
    }
}

struct TumWriter {
    path: PathBuf,
    w: BufWriter<File>,
}

impl StampedWriter for TumWriter {
    fn write(&mut self, item: &Stamped) -> Result<(), IoError> {
        match item {
            Stamped::Pose(p) => {
                write_tum_row(&mut self.w, p).map_err(|e| IoError::io(&self.path, e))
            }
            Stamped::Keyframe(_) => Ok(()),
        }
    }

    fn flush(&mut self) -> Result<(), IoError> {
        self.w.flush().map_err(|e| IoError::io(&self.path, e))
    }

    fn finish(mut self: Box<Self>) -> Result<(), IoError> {
        self.flush()
    }
}
