//! The plots of a run, each written as SVG and PNG with the embedded DejaVu font.
//!
//! One module per figure; each implements [`Figure`], drawn once per backend
//! by [`save`].

pub mod comparison;
pub mod distances;
pub mod map;
pub mod rse_theta;
pub mod style;
pub mod theta;

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::SimError;

/// A drawing failure, as text (backends have different error types).
#[derive(Debug)]
pub struct PlotError(pub String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        PlotError(e.to_string())
    }
}

/// Result of drawing on a backend.
pub type PlotResult = Result<(), PlotError>;

/// A figure that can be drawn on any plotters backend.
pub trait Figure {
    /// Size of the image (px).
    fn size(&self) -> (u32, u32);
    /// Draw the whole figure on `root` (already filled white).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> PlotResult;
}

/// Draw `figure` into `out_dir/stem.svg` and `out_dir/stem.png`; returns both paths.
pub fn save(figure: &impl Figure, out_dir: &Path, stem: &str) -> Result<[PathBuf; 2], SimError> {
    let svg_path = out_dir.join(format!("{stem}.svg"));
    let png_path = out_dir.join(format!("{stem}.png"));
    style::ensure_fonts().map_err(|message| SimError::Plot { path: svg_path.clone(), message })?;

    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, figure.size()).into_drawing_area();
        draw_on(figure, &root).map_err(|e| SimError::Plot { path: svg_path.clone(), message: e.0 })?;
    }
    std::fs::write(&svg_path, svg).map_err(|e| SimError::file(&svg_path, e))?;

    {
        let root = BitMapBackend::new(&png_path, figure.size()).into_drawing_area();
        draw_on(figure, &root).map_err(|e| SimError::Plot { path: png_path.clone(), message: e.0 })?;
    }
    Ok([svg_path, png_path])
}

fn draw_on<DB: DrawingBackend>(figure: &impl Figure, root: &DrawingArea<DB, Shift>) -> PlotResult {
    root.fill(&WHITE)?;
    figure.draw(root)?;
    root.present()?;
    Ok(())
}

/// Draw `text` centred in `area` (for figures without data).
pub fn note_centred<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, text: &str) -> PlotResult {
    let (w, h) = area.dim_in_pixel();
    let style = style::axis_desc_style().pos(plotters::style::text_anchor::Pos::new(
        plotters::style::text_anchor::HPos::Center,
        plotters::style::text_anchor::VPos::Center,
    ));
    area.draw_text(text, &style, (w as i32 / 2, h as i32 / 2))?;
    Ok(())
}
