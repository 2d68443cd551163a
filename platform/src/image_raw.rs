//! Raw `sensor_msgs/Image` pixels (ROS 1 and ROS 2 alike) converted to 8-bit gray, one
//! documented way per encoding:
//!
//! - `mono8`, `8UC1`: as is.
//! - `mono16`: the high byte of each sample (`is_bigendian` says the byte order).
//! - `rgb8`, `bgr8`, `rgba8`, `bgra8`: luma with OpenCV's BT.601 integer weights
//!   ([`crate::image_codec::luma`], the same as for colour JPEG/PNG), alpha dropped.
//! - Bayer `bayer_rggb8`, `bayer_bggr8`, `bayer_gbrg8`, `bayer_grbg8`: each pixel takes the luma
//!   of its 2x2 cell (cells start at even rows and columns; R, B and the mean of the two G;
//!   width and height must be even). Half the resolution in detail, no demosaicing artefacts.
//! - YUV 4:2:2: `yuv422` / `uyvy` (byte order U Y0 V Y1, ROS's `yuv422`) and `yuv422_yuy2` /
//!   `yuyv` (Y0 U Y1 V): the Y samples (width must be even).
//!
//! Rows are read at `step` bytes apart; `step` below the row's bytes, or data shorter than
//! `step * height`, is refused naming the sizes.

use crate::image_codec::luma;

/// Largest image accepted, pixels (as for compressed images: no side over
/// [`crate::image_codec::LARGEST_IMAGE`]).
pub use crate::image_codec::MAX_PIXELS;

/// Pixels of `width x height` gray bytes from a raw image (see the module docs).
pub fn mono8_from_raw(
    encoding: &str,
    width: u32,
    height: u32,
    step: u32,
    is_bigendian: bool,
    data: &[u8],
) -> Result<Vec<u8>, String> {
    let (w, h, step) = (width as usize, height as usize, step as usize);
    crate::image_codec::check_size(width, height)?;
    let bpp = match encoding {
        "mono8" | "8UC1" | "bayer_rggb8" | "bayer_bggr8" | "bayer_gbrg8" | "bayer_grbg8" => 1,
        "mono16" | "yuv422" | "uyvy" | "yuv422_yuy2" | "yuyv" => 2,
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        other => {
            return Err(format!(
                "encoding {other:?} is not supported (mono8, mono16, rgb8, bgr8, rgba8, bgra8, \
                 bayer_rggb8/bggr8/gbrg8/grbg8, yuv422/uyvy, yuv422_yuy2/yuyv)"
            ))
        }
    };
    if step < w * bpp {
        return Err(format!(
            "step {step} is smaller than a {encoding} row of {w} px ({} bytes)",
            w * bpp
        ));
    }
    if data.len() < step * (h - 1) + w * bpp {
        return Err(format!(
            "{} bytes of data for {h} rows of step {step} ({} needed)",
            data.len(),
            step * (h - 1) + w * bpp
        ));
    }
    let row = |r: usize| &data[r * step..r * step + w * bpp];
    let mut px = Vec::with_capacity(w * h);
    match encoding {
        "mono8" | "8UC1" => (0..h).for_each(|r| px.extend_from_slice(row(r))),
        "mono16" => {
            let hi = usize::from(!is_bigendian);
            (0..h).for_each(|r| px.extend(row(r).chunks_exact(2).map(|p| p[hi])));
        }
        "rgb8" | "rgba8" => (0..h).for_each(|r| {
            px.extend(row(r).chunks_exact(bpp).map(|p| luma(p[0], p[1], p[2])));
        }),
        "bgr8" | "bgra8" => (0..h).for_each(|r| {
            px.extend(row(r).chunks_exact(bpp).map(|p| luma(p[2], p[1], p[0])));
        }),
        "yuv422" | "uyvy" | "yuv422_yuy2" | "yuyv" => {
            if !w.is_multiple_of(2) {
                return Err(format!("{encoding} needs an even width, not {w}"));
            }
            let y = usize::from(matches!(encoding, "yuv422" | "uyvy"));
            (0..h).for_each(|r| px.extend(row(r).iter().skip(y).step_by(2)));
        }
        _ => bayer(encoding, w, h, &row, &mut px)?,
    }
    Ok(px)
}

/// Bayer mosaics: each pixel the luma of its 2x2 cell.
fn bayer<'a>(
    encoding: &str,
    w: usize,
    h: usize,
    row: &impl Fn(usize) -> &'a [u8],
    px: &mut Vec<u8>,
) -> Result<(), String> {
    if !w.is_multiple_of(2) || !h.is_multiple_of(2) {
        return Err(format!(
            "{encoding} needs an even width and height, not {w}x{h}"
        ));
    }
    // Positions of R and B in the cell as (row, column); G are the other two.
    let (r_at, b_at) = match encoding {
        "bayer_rggb8" => ((0, 0), (1, 1)),
        "bayer_bggr8" => ((1, 1), (0, 0)),
        "bayer_gbrg8" => ((1, 0), (0, 1)),
        _ => ((0, 1), (1, 0)), // bayer_grbg8
    };
    let mut cells = vec![0u8; w / 2];
    for cy in 0..h / 2 {
        let rows = [row(2 * cy), row(2 * cy + 1)];
        for (cx, cell) in cells.iter_mut().enumerate() {
            let at = |(r, c): (usize, usize)| rows[r][2 * cx + c];
            let (gr, gc) = if r_at.0 == r_at.1 { (0, 1) } else { (0, 0) };
            let g = (u16::from(at((gr, gc))) + u16::from(at((1 - gr, 1 - gc)))).div_ceil(2);
            *cell = luma(at(r_at), g as u8, at(b_at));
        }
        for _ in 0..2 {
            px.extend(cells.iter().flat_map(|&v| [v, v]));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_encoding_gives_the_documented_gray() {
        // 4x2 image; gray levels g per pixel.
        let g: Vec<u8> = vec![10, 20, 30, 40, 50, 60, 70, 80];
        let step = |bpp: usize| (4 * bpp + 3) as u32; // padded rows
        let build = |bpp: usize, f: &dyn Fn(u8) -> Vec<u8>| {
            let mut d = Vec::new();
            for r in 0..2 {
                for &v in &g[4 * r..4 * r + 4] {
                    d.extend(f(v));
                }
                d.extend([0xEE; 3]);
            }
            (step(bpp), d)
        };
        for (enc, bpp, f) in [
            ("mono8", 1, &(|v| vec![v]) as &dyn Fn(u8) -> Vec<u8>),
            ("rgb8", 3, &|v| vec![v, v, v]),
            ("bgra8", 4, &|v| vec![v, v, v, 255]),
            ("mono16", 2, &|v| vec![0x55, v]),
        ] {
            let (s, d) = build(bpp, f);
            assert_eq!(mono8_from_raw(enc, 4, 2, s, false, &d).unwrap(), g, "{enc}");
        }
        let (s, d) = build(2, &|v| vec![v, 0x55]);
        assert_eq!(mono8_from_raw("mono16", 4, 2, s, true, &d).unwrap(), g);
        // Colour order: pure red in rgb8 is pure blue in bgr8.
        let red = mono8_from_raw("rgb8", 1, 1, 3, false, &[255, 0, 0]).unwrap();
        assert_eq!(red, vec![luma(255, 0, 0)]);
        assert_eq!(
            mono8_from_raw("bgr8", 1, 1, 3, false, &[255, 0, 0]).unwrap(),
            vec![luma(0, 0, 255)]
        );
        // YUV: the Y samples.
        let uyvy = [1, 10, 2, 20, 3, 30, 4, 40];
        assert_eq!(
            mono8_from_raw("uyvy", 4, 1, 8, false, &uyvy).unwrap(),
            vec![10, 20, 30, 40]
        );
        let yuyv = [10, 1, 20, 2, 30, 3, 40, 4];
        assert_eq!(
            mono8_from_raw("yuv422_yuy2", 4, 1, 8, false, &yuyv).unwrap(),
            vec![10, 20, 30, 40]
        );
        // Bayer: R=200, G=100 and 50, B=0 in every layout.
        for (enc, cell) in [
            ("bayer_rggb8", [200, 100, 50, 0]),
            ("bayer_bggr8", [0, 100, 50, 200]),
            ("bayer_gbrg8", [100, 0, 200, 50]),
            ("bayer_grbg8", [100, 200, 0, 50]),
        ] {
            let d = [cell[0], cell[1], cell[2], cell[3]];
            let want = luma(200, 75, 0);
            assert_eq!(
                mono8_from_raw(enc, 2, 2, 2, false, &d).unwrap(),
                vec![want; 4],
                "{enc}"
            );
        }
    }

    #[test]
    fn bad_sizes_and_encodings_are_refused() {
        let e = mono8_from_raw("rgb8", 4, 2, 8, false, &[0; 100]).unwrap_err();
        assert!(e.contains("step 8"), "{e}");
        let e = mono8_from_raw("mono8", 4, 2, 4, false, &[0; 7]).unwrap_err();
        assert!(e.contains("7 bytes"), "{e}");
        let e = mono8_from_raw("32FC1", 4, 2, 16, false, &[0; 32]).unwrap_err();
        assert!(e.contains("not supported"), "{e}");
        assert!(mono8_from_raw("bayer_rggb8", 3, 2, 3, false, &[0; 6]).is_err());
        assert!(mono8_from_raw("mono8", 0, 2, 0, false, &[]).is_err());
    }
}
