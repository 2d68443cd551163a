//! Pictures of the image front end's work: a camera frame with its tracks drawn (PNG), and the
//! histogram of track lengths (SVG or PNG by extension).

use crate::plot::{register_font, FONT};
use anyhow::{bail, Context, Result};
use plotters::prelude::*;
use std::path::Path;

/// Colour of a track by its age (frames tracked): new, young, established, old.
pub fn age_color(age: usize) -> RGBColor {
    match age {
        0 => RGBColor(0, 200, 255),
        1..=4 => RGBColor(255, 220, 0),
        5..=19 => RGBColor(40, 230, 40),
        _ => RGBColor(255, 60, 200),
    }
}

/// One track in a picture: its positions, oldest first, the last one in the drawn frame.
#[derive(Debug, Clone, PartialEq)]
pub struct DrawnTrack {
    /// Positions (raw pixels), oldest first.
    pub trail: Vec<[f64; 2]>,
    /// Frames tracked so far (0: detected in this frame).
    pub age: usize,
}

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow::anyhow!("{e}")
}

/// Draws the `w` x `h` mono8 image `px` with `tracks` (trail and a circle at the current
/// position, coloured by age) and a caption into a PNG at `path`.
pub fn draw_frame(
    path: &Path,
    w: usize,
    h: usize,
    px: &[u8],
    tracks: &[DrawnTrack],
    caption: &str,
) -> Result<()> {
    if px.len() < w * h || w == 0 || h == 0 {
        bail!("{}: {w}x{h} image with {} bytes", path.display(), px.len());
    }
    register_font()?;
    // Twice the size so the tracks stay readable.
    const S: f64 = 2.0;
    let (wo, ho) = ((w as f64 * S) as u32, (h as f64 * S) as u32);
    let root = BitMapBackend::new(path, (wo, ho)).into_drawing_area();
    for y in 0..ho {
        for x in 0..wo {
            let g = px[(y as usize / 2) * w + x as usize / 2];
            root.draw_pixel((x as i32, y as i32), &RGBColor(g, g, g))
                .map_err(err)?;
        }
    }
    let at = |p: &[f64; 2]| ((p[0] * S + 0.5) as i32, (p[1] * S + 0.5) as i32);
    for t in tracks {
        let c = age_color(t.age);
        if t.trail.len() >= 2 {
            root.draw(&PathElement::new(
                t.trail.iter().map(at).collect::<Vec<_>>(),
                c.stroke_width(2),
            ))
            .map_err(err)?;
        }
        if let Some(p) = t.trail.last() {
            root.draw(&Circle::new(at(p), 4, c.stroke_width(2)))
                .map_err(err)?;
        }
    }
    let style = (FONT, 22).into_font().color(&WHITE);
    root.draw(&Rectangle::new(
        [(0, 0), (wo as i32, 58)],
        RGBColor(0, 0, 0).mix(0.6).filled(),
    ))
    .map_err(err)?;
    root.draw(&Text::new(caption.to_string(), (8, 4), style))
        .map_err(err)?;
    let legend = [
        ("new", age_color(0)),
        ("tracked 1-4 frames", age_color(1)),
        ("5-19 frames", age_color(5)),
        (">= 20 frames", age_color(20)),
    ];
    let mut x = 14;
    for (name, c) in legend {
        root.draw(&Circle::new((x, 43), 5, c.filled()))
            .map_err(err)?;
        root.draw(&Text::new(
            name,
            (x + 10, 32),
            (FONT, 20).into_font().color(&WHITE),
        ))
        .map_err(err)?;
        x += 210;
    }
    root.present()
        .map_err(err)
        .with_context(|| format!("writing {}", path.display()))
}

/// Draws the histogram of `lengths` (observations per track) into `path` (`.svg` or `.png`).
pub fn draw_length_histogram(path: &Path, lengths: &[usize], title: &str) -> Result<()> {
    register_font()?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let size = (1000, 600);
    match ext.as_deref() {
        Some("svg") => histogram(
            SVGBackend::new(path, size).into_drawing_area(),
            lengths,
            title,
        ),
        Some("png") => histogram(
            BitMapBackend::new(path, size).into_drawing_area(),
            lengths,
            title,
        ),
        _ => bail!("{}: the output must end in .svg or .png", path.display()),
    }
    .with_context(|| format!("writing {}", path.display()))
}

fn histogram<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    lengths: &[usize],
    title: &str,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(err)?;
    // Lengths above the cap share the last bin.
    const CAP: usize = 60;
    let mut bins = vec![0usize; CAP + 1];
    for &l in lengths {
        bins[l.min(CAP)] += 1;
    }
    let top = bins.iter().copied().max().unwrap_or(1).max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0usize..CAP + 1, 0usize..top + top / 10 + 1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(format!(
            "track length, frames (observations; the last bin is >= {CAP})"
        ))
        .y_desc("tracks")
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 18))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(
            bins.iter()
                .enumerate()
                .filter(|(_, &n)| n > 0)
                .map(|(l, &n)| {
                    Rectangle::new([(l, 0), (l + 1, n)], RGBColor(31, 119, 180).filled())
                }),
        )
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}
