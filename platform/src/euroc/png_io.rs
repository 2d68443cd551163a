//! 8-bit grayscale PNG files (EuRoC `cam0/data/*.png`).

use crate::error::IoError;
use std::path::Path;

fn corrupt(path: &Path, msg: String) -> IoError {
    IoError::Corrupt {
        file: path.into(),
        what: "png".into(),
        offset: 0,
        msg,
    }
}

/// Decodes an 8-bit grayscale PNG into `(width, height, row-major pixels)`.
pub fn read_mono8(path: &Path) -> Result<(u32, u32, Vec<u8>), IoError> {
    let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let dec = png::Decoder::new(std::io::BufReader::new(f));
    let mut rd = dec.read_info().map_err(|e| corrupt(path, e.to_string()))?;
    let mut buf = vec![0u8; rd.output_buffer_size()];
    let info = rd
        .next_frame(&mut buf)
        .map_err(|e| corrupt(path, e.to_string()))?;
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Eight {
        return Err(IoError::Invalid {
            path: path.into(),
            msg: format!(
                "image is {:?} {:?}, only 8-bit grayscale (mono8) is supported",
                info.color_type, info.bit_depth
            ),
        });
    }
    let (w, h) = (info.width as usize, info.height as usize);
    let mut px = Vec::with_capacity(w * h);
    for row in buf.chunks(info.line_size).take(h) {
        px.extend_from_slice(row.get(..w).unwrap_or(row));
    }
    if px.len() != w * h {
        return Err(corrupt(
            path,
            format!("decoded {} of {} pixels", px.len(), w * h),
        ));
    }
    Ok((info.width, info.height, px))
}

/// Encodes row-major mono8 pixels as an 8-bit grayscale PNG.
pub fn write_mono8(path: &Path, width: u32, height: u32, px: &[u8]) -> Result<(), IoError> {
    if px.len() as u64 != u64::from(width) * u64::from(height) {
        return Err(IoError::Invalid {
            path: path.into(),
            msg: format!("{} pixels for a {width}x{height} image", px.len()),
        });
    }
    let f = std::fs::File::create(path).map_err(|e| IoError::io(path, e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let err = |e: png::EncodingError| match e {
        png::EncodingError::IoError(io) => IoError::io(path, io),
        other => IoError::Invalid {
            path: path.into(),
            msg: other.to_string(),
        },
    };
    let mut w = enc.write_header().map_err(err)?;
    w.write_image_data(px).map_err(err)?;
    w.finish().map_err(err)
}
