//! Camera images as sources deliver them ([`ImageData`]: undecoded until the consumer needs the
//! pixels) and their decoding to 8-bit grayscale ([`decode`]: PNG and JPEG through
//! [`crate::image_codec`], colour converted to luma there).

use std::borrow::Cow;
use std::path::PathBuf;

/// One camera image as a source delivers it.
#[derive(Debug, Clone, PartialEq)]
pub enum ImageData {
    /// Row-major 8-bit grayscale pixels.
    Mono8 {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// `width * height` bytes.
        pixels: Vec<u8>,
    },
    /// A PNG or JPEG payload.
    Encoded(Vec<u8>),
    /// A PNG or JPEG file (a dataset folder).
    File(PathBuf),
}

/// Decodes an image to `(width, height, mono8 pixels)`; the error says why it cannot be used.
pub fn decode(data: &ImageData) -> Result<(usize, usize, Cow<'_, [u8]>), String> {
    let owned =
        |m: crate::image_codec::Mono8| (m.width as usize, m.height as usize, Cow::Owned(m.pixels));
    match data {
        ImageData::Mono8 {
            width,
            height,
            pixels,
        } => {
            if width.checked_mul(*height) == Some(pixels.len()) {
                Ok((*width, *height, Cow::Borrowed(&pixels[..])))
            } else {
                Err(format!(
                    "{} bytes for {width}x{height} pixels",
                    pixels.len()
                ))
            }
        }
        ImageData::Encoded(bytes) => crate::image_codec::decode_mono8("image", bytes).map(owned),
        ImageData::File(path) => std::fs::read(path)
            .map_err(|e| format!("{}: {e}", path.display()))
            .and_then(|bytes| {
                crate::image_codec::decode_mono8("file", &bytes)
                    .map(owned)
                    .map_err(|e| format!("{}: {e}", path.display()))
            }),
    }
}

/// The image decoded in place to [`ImageData::Mono8`] (unchanged when it already is, or when
/// it cannot be decoded: [`decode`] then gives the reason again to whoever uses it).
pub fn decoded(data: ImageData) -> ImageData {
    if matches!(data, ImageData::Mono8 { .. }) {
        return data;
    }
    match decode(&data) {
        Ok((width, height, pixels)) => ImageData::Mono8 {
            width,
            height,
            pixels: pixels.into_owned(),
        },
        Err(_) => data,
    }
}
