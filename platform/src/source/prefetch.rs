//! [`Prefetch`]: a source read on a helper thread, its images decoded there, at most
//! [`PREFETCH_EVENTS`] events ahead of the consumer. The events and their order are the inner
//! source's; only the decoding moves off the consumer's thread (each image's time for it is in
//! [`SensorEvent::Image`]'s `prepared_ns`).

use super::{SensorEvent, Source};
use crate::error::IoError;
use crate::images::decoded;
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::Instant;

/// Events read ahead (about 6 images of a 20 Hz camera beside a 200 Hz IMU).
pub const PREFETCH_EVENTS: usize = 64;

type Item = Result<Option<SensorEvent>, IoError>;

/// A source read ahead on a helper thread (see the module docs). Made by [`Prefetch::run`],
/// which owns the thread's scope.
pub struct Prefetch {
    rx: Receiver<Item>,
    realtime: bool,
    done: bool,
}

impl Prefetch {
    /// Runs `f` with `inner` read ahead on a helper thread (stopped when `f` returns, also
    /// early); returns `f`'s result and the inner source (its figures).
    pub fn run<S, R>(inner: S, f: impl FnOnce(&mut Prefetch) -> R) -> (R, S)
    where
        S: Source + Send,
    {
        let realtime = inner.is_realtime();
        std::thread::scope(|sc| {
            let (tx, rx) = sync_channel::<Item>(PREFETCH_EVENTS);
            let helper = sc.spawn(move || {
                let mut inner = inner;
                loop {
                    let item = inner.next().map(|ev| ev.map(prepare));
                    let end = !matches!(item, Ok(Some(_)));
                    if tx.send(item).is_err() || end {
                        break;
                    }
                }
                inner
            });
            let mut p = Prefetch {
                rx,
                realtime,
                done: false,
            };
            let r = f(&mut p);
            // Dropping the receiver stops the helper at its next send.
            drop(p);
            let inner = helper
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (r, inner)
        })
    }
}

/// Decodes an image event's pixels, timing it.
fn prepare(ev: SensorEvent) -> SensorEvent {
    match ev {
        SensorEvent::Image {
            t_cam_ns,
            data,
            prepared_ns,
        } => {
            let t0 = Instant::now();
            let data = decoded(data);
            let ns = u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX);
            SensorEvent::Image {
                t_cam_ns,
                data,
                prepared_ns: prepared_ns.saturating_add(ns),
            }
        }
        ev => ev,
    }
}

impl Source for Prefetch {
    fn next(&mut self) -> Result<Option<SensorEvent>, IoError> {
        if self.done {
            return Ok(None);
        }
        match self.rx.recv() {
            Ok(item) => {
                self.done = !matches!(item, Ok(Some(_)));
                item
            }
            Err(_) => {
                self.done = true;
                Ok(None)
            }
        }
    }

    fn is_realtime(&self) -> bool {
        self.realtime
    }
}
