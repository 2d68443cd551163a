//! Compressed camera images (JPEG, PNG) decoded to 8-bit grayscale, as `sensor_msgs/msg/
//! CompressedImage` carries them.
//!
//! The codec is recognised by the payload's signature (PNG `89 50 4E 47 0D 0A 1A 0A`, JPEG
//! `FF D8`), so a wrong or free-form `format` string (`jpeg`, `png`, `bgr8; jpeg compressed bgr8`,
//! ...) does not matter; a payload that is neither is rejected naming the format. Colour is
//! converted to luma with OpenCV's BT.601 integer weights (`(4899 R + 9617 G + 1868 B + 8192) >>
//! 14`, as `cv::cvtColor(..., COLOR_RGB2GRAY)`), alpha is dropped, 16-bit samples keep their high
//! byte, CMYK is converted through RGB. An image wider or taller than the largest the front end
//! takes ([`LARGEST_IMAGE`], 1920x1200) is refused from its header, before decoding: no odometry
//! povins builds could use it, and a corrupt 1.6 kB JPEG declaring 10,256 x 4,108 px took 2.6 s to
//! decode in full (the image fuzz target's corpus; a size within the old 8192 px, 64 Mpx limits,
//! such as 8000 x 8000, still took 2.5 s). Decoders are well-kept crates (`jpeg-decoder`, `png`);
//! a panic inside one is caught and reported as an error, so corrupt input never takes the
//! process down.

pub use crate::odometry::LARGEST_IMAGE;

/// Largest image accepted, pixels: [`LARGEST_IMAGE`]'s (2.3 Mpx).
pub const MAX_PIXELS: u64 = LARGEST_IMAGE.0 as u64 * LARGEST_IMAGE.1 as u64;

/// A decoded grayscale image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mono8 {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Row-major pixels.
    pub pixels: Vec<u8>,
}

/// Luma of an RGB pixel (OpenCV's BT.601 fixed-point weights).
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((4899 * u32::from(r) + 9617 * u32::from(g) + 1868 * u32::from(b) + 8192) >> 14) as u8
}

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A];

/// Decodes a JPEG or PNG payload to mono8; the error says what is wrong (codec and reason).
pub fn decode_mono8(format: &str, data: &[u8]) -> Result<Mono8, String> {
    let result = std::panic::catch_unwind(|| {
        if data.starts_with(&PNG_SIGNATURE) {
            decode_png(data).map_err(|e| format!("PNG: {e}"))
        } else if data.starts_with(&[0xFF, 0xD8]) {
            decode_jpeg(data).map_err(|e| format!("JPEG: {e}"))
        } else if data.is_empty() {
            Err(format!("empty image payload (format {format:?})"))
        } else {
            Err(format!(
                "payload of {} bytes is neither JPEG nor PNG (format {format:?}, starts {:02x?})",
                data.len(),
                &data[..data.len().min(4)]
            ))
        }
    });
    result.unwrap_or_else(|_| Err("decoder panicked on a corrupt payload".into()))
}

/// Refuses an empty image or one larger than [`LARGEST_IMAGE`] (see the module docs), before any
/// pixel is decoded or converted; the error names the size and the limit.
pub(crate) fn check_size(w: u32, h: u32) -> Result<(), String> {
    if w == 0 || h == 0 {
        return Err(format!("{w}x{h} image is empty"));
    }
    let (max_w, max_h) = LARGEST_IMAGE;
    if w > max_w || h > max_h {
        return Err(format!(
            "{w}x{h} image is larger than the front end's largest capacity ({max_w}x{max_h})"
        ));
    }
    Ok(())
}

fn decode_png(data: &[u8]) -> Result<Mono8, String> {
    let mut dec = png::Decoder::new(std::io::Cursor::new(data));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut rd = dec.read_info().map_err(|e| e.to_string())?;
    let (w, h) = (rd.info().width, rd.info().height);
    check_size(w, h)?;
    let mut buf = vec![0u8; rd.output_buffer_size()];
    let info = rd.next_frame(&mut buf).map_err(|e| e.to_string())?;
    let ch = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err("palette was not expanded".into()),
    };
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!(
            "unexpected bit depth {:?} after expansion",
            info.bit_depth
        ));
    }
    let (wu, hu) = (w as usize, h as usize);
    let mut px = Vec::with_capacity(wu * hu);
    for row in buf.chunks(info.line_size).take(hu) {
        let row = row.get(..wu * ch).ok_or("short row")?;
        match ch {
            1 => px.extend_from_slice(row),
            2 => px.extend(row.chunks_exact(2).map(|p| p[0])),
            _ => px.extend(row.chunks_exact(ch).map(|p| luma(p[0], p[1], p[2]))),
        }
    }
    if px.len() != wu * hu {
        return Err(format!("decoded {} of {} pixels", px.len(), wu * hu));
    }
    Ok(Mono8 {
        width: w,
        height: h,
        pixels: px,
    })
}

fn decode_jpeg(data: &[u8]) -> Result<Mono8, String> {
    let mut dec = jpeg_decoder::Decoder::new(std::io::Cursor::new(data));
    dec.read_info().map_err(|e| e.to_string())?;
    let info = dec.info().ok_or("no frame header")?;
    let (w, h) = (u32::from(info.width), u32::from(info.height));
    check_size(w, h)?;
    dec.set_max_decoding_buffer_size((MAX_PIXELS * 4) as usize);
    let raw = dec.decode().map_err(|e| e.to_string())?;
    let n = w as usize * h as usize;
    let px: Vec<u8> = match info.pixel_format {
        jpeg_decoder::PixelFormat::L8 => raw,
        // Big-endian 16-bit samples: keep the high byte.
        jpeg_decoder::PixelFormat::L16 => raw.chunks_exact(2).map(|p| p[0]).collect(),
        jpeg_decoder::PixelFormat::RGB24 => raw
            .chunks_exact(3)
            .map(|p| luma(p[0], p[1], p[2]))
            .collect(),
        jpeg_decoder::PixelFormat::CMYK32 => raw
            .chunks_exact(4)
            .map(|p| {
                let k = 255 - u32::from(p[3]);
                let c = |v: u8| ((255 - u32::from(v)) * k / 255) as u8;
                luma(c(p[0]), c(p[1]), c(p[2]))
            })
            .collect(),
    };
    if px.len() != n {
        return Err(format!("decoded {} of {n} pixels", px.len()));
    }
    Ok(Mono8 {
        width: w,
        height: h,
        pixels: px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_bytes(w: u32, h: u32, color: png::ColorType, px: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(color);
            enc.set_depth(png::BitDepth::Eight);
            let mut wr = enc.write_header().unwrap();
            wr.write_image_data(px).unwrap();
        }
        out
    }

    fn jpeg_bytes(w: u32, h: u32, color: image::ColorType, px: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
            .encode(px, w, h, color)
            .unwrap();
        out
    }

    fn gradient(w: u32, h: u32) -> Vec<u8> {
        (0..w * h).map(|i| ((i % w) * 255 / w) as u8).collect()
    }

    #[test]
    fn png_gray_and_colour_decode_to_luma() {
        let g = gradient(40, 30);
        let m = decode_mono8("png", &png_bytes(40, 30, png::ColorType::Grayscale, &g)).unwrap();
        assert_eq!((m.width, m.height), (40, 30));
        assert_eq!(m.pixels, g);
        let rgb: Vec<u8> = g.iter().flat_map(|&v| [v, 255 - v, 40]).collect();
        let m = decode_mono8(
            "rgb8; png compressed rgb8",
            &png_bytes(40, 30, png::ColorType::Rgb, &rgb),
        )
        .unwrap();
        let want: Vec<u8> = g.iter().map(|&v| luma(v, 255 - v, 40)).collect();
        assert_eq!(m.pixels, want);
        let rgba: Vec<u8> = g.iter().flat_map(|&v| [v, v, v, 7]).collect();
        let m = decode_mono8("png", &png_bytes(40, 30, png::ColorType::Rgba, &rgba)).unwrap();
        // Equal channels give the value back (weights sum to 2^14).
        assert_eq!(m.pixels, g);
    }

    #[test]
    fn jpeg_gray_and_colour_decode_close_to_the_source() {
        let g = gradient(64, 48);
        let m = decode_mono8("jpeg", &jpeg_bytes(64, 48, image::ColorType::L8, &g)).unwrap();
        assert_eq!((m.width, m.height), (64, 48));
        let err = m
            .pixels
            .iter()
            .zip(&g)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(err <= 6, "gray JPEG error {err}");
        let rgb: Vec<u8> = g.iter().flat_map(|&v| [v, v, v]).collect();
        let m = decode_mono8(
            "bgr8; jpeg compressed bgr8",
            &jpeg_bytes(64, 48, image::ColorType::Rgb8, &rgb),
        )
        .unwrap();
        let err = m
            .pixels
            .iter()
            .zip(&g)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(err <= 8, "colour JPEG error {err}");
    }

    #[test]
    fn corrupt_payloads_are_errors_that_say_why() {
        let g = gradient(64, 48);
        let good = [
            png_bytes(64, 48, png::ColorType::Grayscale, &g),
            jpeg_bytes(64, 48, image::ColorType::L8, &g),
        ];
        for (k, bytes) in good.iter().enumerate() {
            let codec = if k == 0 { "PNG" } else { "JPEG" };
            // Every truncation fails (or, for JPEG, may decode the part present) without a panic.
            for cut in (0..bytes.len()).step_by(7) {
                match decode_mono8("x", &bytes[..cut]) {
                    Ok(m) => assert_eq!(m.pixels.len(), 64 * 48),
                    Err(e) => assert!(
                        cut < 2 || e.starts_with(codec) || e.contains("neither"),
                        "{e}"
                    ),
                }
            }
            // Garbage after the signature.
            let mut bad = bytes[..8].to_vec();
            bad.extend((0..500u32).map(|i| (i * 7919 % 251) as u8));
            let e = decode_mono8("x", &bad).unwrap_err();
            assert!(e.starts_with(codec), "{e}");
            // Random byte flips never panic.
            let mut s = 0x1234_5678u32;
            for _ in 0..300 {
                let mut c = bytes.clone();
                for _ in 0..3 {
                    s ^= s << 13;
                    s ^= s >> 17;
                    s ^= s << 5;
                    let i = s as usize % c.len();
                    c[i] ^= 1 << (s % 8);
                }
                let _ = decode_mono8("x", &c);
            }
        }
        let e = decode_mono8("tiff", b"II*\0rest").unwrap_err();
        assert!(
            e.contains("neither JPEG nor PNG") && e.contains("tiff"),
            "{e}"
        );
        assert!(decode_mono8("png", &[]).unwrap_err().contains("empty"));
        // A huge declared size is refused before decoding.
        let mut big = png_bytes(1, 1, png::ColorType::Grayscale, &[0]);
        big[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        big[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        assert!(decode_mono8("png", &big).is_err());
        // A side over the front end's largest capacity is refused before decoding, naming the
        // size and the limit; the limit itself is decoded, in either codec.
        let gray = |w: u32, h: u32| vec![7; w as usize * h as usize];
        let png_of = |w, h| png_bytes(w, h, png::ColorType::Grayscale, &gray(w, h));
        for (w, h) in [(1921, 1), (1, 1201), (8192, 1)] {
            let e = decode_mono8("png", &png_of(w, h)).unwrap_err();
            assert!(
                e.contains(&format!("{w}x{h}")) && e.contains("1920x1200"),
                "{e}"
            );
        }
        let m = decode_mono8("png", &png_of(1920, 1200)).unwrap();
        assert_eq!(
            (m.width, m.height, m.pixels.len()),
            (1920, 1200, 1920 * 1200)
        );
        let jpeg_of = |w, h| jpeg_bytes(w, h, image::ColorType::L8, &gray(w, h));
        let e = decode_mono8("jpeg", &jpeg_of(1921, 8)).unwrap_err();
        assert!(e.contains("1921x8") && e.contains("1920x1200"), "{e}");
        let m = decode_mono8("jpeg", &jpeg_of(1920, 1200)).unwrap();
        assert_eq!((m.width, m.height), (1920, 1200));
    }
}
