//! A borrowed 8-bit grayscale image.

use crate::Error;

/// Largest accepted image side, px. Keeps every pixel index, fixed-point product and the
/// occupancy mask in range (and is far above any camera this estimator serves).
pub const MAX_IMAGE_SIDE: usize = 8192;

/// A borrowed 8-bit grayscale image: `height` rows of `width` pixels, row `y` starting at byte
/// `y * stride` of `data`. Pixel `(u, v)` is column `u`, row `v` (pixel centres at integers, as in
/// [`crate::camera`]).
///
/// The constructor checks the geometry once, so every row of a valid view is in `data`.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
    stride: usize,
}

impl<'a> ImageView<'a> {
    /// A view of `data` as `width` x `height` pixels with rows `stride` bytes apart.
    ///
    /// Errors: [`Error::DimensionMismatch`] for a zero width or height, a side above
    /// [`MAX_IMAGE_SIDE`], `stride < width`, or `data` shorter than
    /// `stride * (height - 1) + width` bytes (the last row needs no padding).
    pub fn new(data: &'a [u8], width: usize, height: usize, stride: usize) -> Result<Self, Error> {
        if width == 0
            || height == 0
            || width > MAX_IMAGE_SIDE
            || height > MAX_IMAGE_SIDE
            || stride < width
        {
            return Err(Error::DimensionMismatch);
        }
        let need = stride
            .checked_mul(height - 1)
            .and_then(|n| n.checked_add(width))
            .ok_or(Error::DimensionMismatch)?;
        if data.len() < need {
            return Err(Error::DimensionMismatch);
        }
        Ok(ImageView {
            data,
            width,
            height,
            stride,
        })
    }

    /// Width, px.
    #[inline]
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    #[inline]
    pub fn height(&self) -> usize {
        self.height
    }

    /// Bytes from one row to the next.
    #[inline]
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The underlying bytes (at least `stride * (height - 1) + width`).
    #[inline]
    pub fn data(&self) -> &'a [u8] {
        self.data
    }

    /// Row `y` (`width` bytes), or an empty slice when `y >= height`.
    #[inline]
    pub fn row(&self, y: usize) -> &'a [u8] {
        if y >= self.height {
            return &[];
        }
        let start = y * self.stride;
        self.data.get(start..start + self.width).unwrap_or(&[])
    }

    /// Pixel `(x, y)`, or `None` outside the image.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Option<u8> {
        if x >= self.width {
            return None;
        }
        self.row(y).get(x).copied()
    }

    /// Row `y` from column `x0` for `len` pixels, or `None` if that span leaves the image.
    #[inline]
    pub(crate) fn span(&self, x0: usize, y: usize, len: usize) -> Option<&'a [u8]> {
        self.row(y).get(x0..x0.checked_add(len)?)
    }

    /// Pixel at `(x, y)` with coordinates clamped into the image (border replication).
    #[inline]
    pub fn clamped(&self, x: isize, y: isize) -> u8 {
        let xc = x.clamp(0, self.width as isize - 1) as usize;
        let yc = y.clamp(0, self.height as isize - 1) as usize;
        self.get(xc, yc).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_geometry() {
        let buf = [0u8; 100];
        assert_eq!(
            ImageView::new(&buf, 0, 10, 10).unwrap_err(),
            Error::DimensionMismatch
        );
        assert_eq!(
            ImageView::new(&buf, 10, 0, 10).unwrap_err(),
            Error::DimensionMismatch
        );
        assert_eq!(
            ImageView::new(&buf, 10, 10, 9).unwrap_err(),
            Error::DimensionMismatch
        );
        assert_eq!(
            ImageView::new(&buf, 10, 11, 10).unwrap_err(),
            Error::DimensionMismatch
        );
        assert_eq!(
            ImageView::new(&buf, 9000, 1, 9000).unwrap_err(),
            Error::DimensionMismatch
        );
        assert_eq!(
            ImageView::new(&buf, 1, 2, usize::MAX).unwrap_err(),
            Error::DimensionMismatch
        );
        // The last row needs no padding: 9 rows of stride 11 plus 10 bytes = 109 > 100.
        assert!(ImageView::new(&buf, 10, 10, 11).is_err());
        assert!(ImageView::new(&buf, 10, 9, 11).is_ok());
        assert!(ImageView::new(&buf, 10, 10, 10).is_ok());
    }

    #[test]
    fn rows_and_pixels() {
        let mut buf = [0u8; 12];
        for (i, b) in buf.iter_mut().enumerate() {
            *b = i as u8;
        }
        let v = ImageView::new(&buf, 3, 3, 4).unwrap();
        assert_eq!(v.row(1), &[4, 5, 6]);
        assert_eq!(v.row(3), &[] as &[u8]);
        assert_eq!(v.get(2, 2), Some(10));
        assert_eq!(v.get(3, 0), None);
        assert_eq!(v.clamped(-5, 7), 8);
        assert_eq!(v.span(1, 2, 2), Some(&[9u8, 10][..]));
        assert_eq!(v.span(2, 2, 2), None);
    }
}
