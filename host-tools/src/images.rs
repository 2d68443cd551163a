//! Camera images decoded lazily, in order, on a helper thread: a replay never holds more than
//! [`PREFETCH`] decoded images beyond the ones already in the dataset.
//!
//! EuRoC folders list their images by path ([`ImageFrame::path`]); each file is read and decoded
//! here (8-bit grayscale or colour PNG, or JPEG, converted to luma by
//! [`povins_platform::image_codec::decode_mono8`]). Images already decoded by the reader (MCAP)
//! are lent as they are. A file that cannot be read or decoded yields an error message for that
//! frame, never a panic.

use povins_platform::dataset::ImageFrame;
use std::borrow::Cow;
use std::time::Instant;

/// Decoded images queued ahead of the consumer.
pub const PREFETCH: usize = 8;

/// One camera image, ready for the front end.
#[derive(Debug, Clone)]
pub struct LoadedImage<'a> {
    /// Index in the slice given to [`with_images`].
    pub index: usize,
    /// Image time (camera clock), ns.
    pub t_ns: i64,
    /// `(width, height, row-major mono8 pixels)`, or why the image could not be read.
    pub pixels: Result<(usize, usize, Cow<'a, [u8]>), String>,
    /// Time spent reading and decoding it (on the helper thread), s.
    pub decode_s: f64,
}

/// Reads and decodes one image (see the module docs).
pub fn load(index: usize, im: &ImageFrame) -> LoadedImage<'_> {
    let t0 = Instant::now();
    let pixels = if !im.mono8.is_empty() {
        let n = im.width as usize * im.height as usize;
        if im.mono8.len() == n {
            Ok((
                im.width as usize,
                im.height as usize,
                Cow::Borrowed(&im.mono8[..]),
            ))
        } else {
            Err(format!(
                "image at {} ns has {} bytes for {}x{} pixels",
                im.t_ns,
                im.mono8.len(),
                im.width,
                im.height
            ))
        }
    } else if let Some(p) = &im.path {
        match std::fs::read(p) {
            Ok(bytes) => povins_platform::image_codec::decode_mono8("file", &bytes)
                .map(|m| (m.width as usize, m.height as usize, Cow::Owned(m.pixels)))
                .map_err(|e| format!("{}: {e}", p.display())),
            Err(e) => Err(format!("{}: {e}", p.display())),
        }
    } else {
        Err(format!(
            "image at {} ns has neither pixels nor a file",
            im.t_ns
        ))
    };
    LoadedImage {
        index,
        t_ns: im.t_ns,
        pixels,
        decode_s: t0.elapsed().as_secs_f64(),
    }
}

/// Runs `f` with an iterator over `images` decoded in order on a helper thread, at most
/// [`PREFETCH`] ahead. Stopping early is fine (the helper stops when the iterator is dropped).
pub fn with_images<'a, R>(
    images: &'a [ImageFrame],
    f: impl FnOnce(&mut dyn Iterator<Item = LoadedImage<'a>>) -> R,
) -> R {
    std::thread::scope(|s| {
        let (tx, rx) = std::sync::mpsc::sync_channel(PREFETCH);
        s.spawn(move || {
            for (k, im) in images.iter().enumerate() {
                if tx.send(load(k, im)).is_err() {
                    break;
                }
            }
        });
        let mut it = rx.into_iter();
        f(&mut it)
    })
}
