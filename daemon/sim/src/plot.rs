//! What the project's PNG plots share (`op3dsg bench perf`'s fusion curve, `bench quality`'s
//! curves): DejaVu Sans embedded in the binary, a line with dots per series, a framed legend,
//! and writing the buffer as a PNG.

use std::path::Path;

use anyhow::{Context as _, anyhow};

/// An error of plotters, naming what was being drawn.
pub(crate) fn plot_err(what: &str, e: impl std::fmt::Debug) -> anyhow::Error {
    anyhow!("drawing the plot ({what}): {e:?}")
}

/// One labelled series of the project's plots: a line of width 2 through `line` with a dot on
/// every point, in `colour`, named `label` in the legend.
pub(crate) fn draw_line_with_points<'a, DB, CT>(
    chart: &mut plotters::chart::ChartContext<'a, DB, CT>,
    line: Vec<(f64, f64)>,
    colour: plotters::style::RGBColor,
    label: String,
) -> anyhow::Result<()>
where
    DB: plotters::prelude::DrawingBackend + 'a,
    CT: plotters::coord::CoordTranslate<From = (f64, f64)>,
{
    use plotters::prelude::*;
    chart
        .draw_series(LineSeries::new(line.clone(), colour.stroke_width(2)))
        .map_err(|e| plot_err(&label, e))?
        .label(label.clone())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(2)));
    chart
        .draw_series(line.into_iter().map(|(x, y)| Circle::new((x, y), 4, colour.filled())))
        .map_err(|e| plot_err(&label, e))?;
    Ok(())
}

/// The legend of the project's plots: framed, on a white background, at `position`.
pub(crate) fn draw_legend<'a, DB, CT>(
    chart: &mut plotters::chart::ChartContext<'a, DB, CT>,
    position: plotters::chart::SeriesLabelPosition,
    font_size: u32,
) -> anyhow::Result<()>
where
    DB: plotters::prelude::DrawingBackend + 'a,
    CT: plotters::coord::CoordTranslate,
{
    use plotters::prelude::*;
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", font_size))
        .draw()
        .map_err(|e| plot_err("legend", e))
}

/// Registers DejaVu Sans (embedded by the `dejavu` crate) as plotters' `sans-serif`, once.
pub(crate) fn register_font() -> anyhow::Result<()> {
    use plotters::style::FontStyle;
    static FONT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let registered = *FONT.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if registered { Ok(()) } else { Err(anyhow!("the embedded DejaVu Sans font could not be loaded")) }
}

/// Writes an RGB8 plot buffer of `size` as a PNG at `path` (`what` names it in the error).
pub(crate) fn save_png(buffer: Vec<u8>, size: (u32, u32), path: &Path, what: &str) -> anyhow::Result<()> {
    let image = image::RgbImage::from_raw(size.0, size.1, buffer).ok_or_else(|| anyhow!("{what} buffer size"))?;
    image
        .save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("writing the {what} {}", path.display()))
}
