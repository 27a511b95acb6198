//! The report's figures: both sweeps with the paper's fit and the full-model
//! curve, and their residuals, as SVG (plotters' SVG backend; no fonts needed).
//! The series are computed by pure functions so tests can check them apart
//! from the drawing.

use plotters::prelude::*;
use sim::recording::{Phase, Recording};

use crate::fit::{Calibration, ModelParams, predict};

use super::ReportError;

/// Points on the paper's fitted curve.
const CURVE_POINTS: usize = 120;
/// Figure size, px.
const SIZE: (u32, u32) = (900, 640);
/// Height of the main panel; the residual panel takes the rest.
const MAIN_HEIGHT: u32 = 420;

/// The series of one sweep's figure.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SweepPlot {
    /// Measured points: (gamma1, gamma2) mm for the normal sweep,
    /// (theta1, theta2) degrees for torsion.
    pub points: Vec<(f64, f64)>,
    /// The paper's reduced relation (Eq. 22 or Eq. 38) over the data's range.
    pub paper: Vec<(f64, f64)>,
    /// The full-model fit's prediction at each measured position, ordered along x.
    pub full: Vec<(f64, f64)>,
    /// Residuals of the paper's fit, observed minus fitted y (µm for the
    /// normal sweep, degrees for torsion), against measured x.
    pub paper_residuals: Vec<(f64, f64)>,
    /// Residuals of the full-model fit in the quantity it fits (gamma1 in µm,
    /// theta1 in degrees), against measured x.
    pub full_residuals: Vec<(f64, f64)>,
}

fn full_params(cal: &Calibration) -> ModelParams {
    cal.full.params()
}

fn sorted_by_x(mut v: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    v.retain(|p| p.0.is_finite() && p.1.is_finite());
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.dedup_by(|a, b| a.0 == b.0);
    v
}

fn x_range(points: &[(f64, f64)]) -> (f64, f64) {
    let lo = points.iter().map(|p| p.0).fold(f64::INFINITY, f64::min).min(0.0);
    let hi = points.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    (lo, if hi.is_finite() { hi } else { 1.0 })
}

/// Normal sweep: gamma2 = stage - gamma1 against gamma1, with Eq. 22
/// (gamma2 = H1 gamma1 + H2 gamma1^1.5) and the full model.
pub fn normal_plot(rec: &Recording, cal: &Calibration) -> Result<SweepPlot, ReportError> {
    let pred = predict(rec, &full_params(cal))?;
    let (h1, h2) = (cal.paper.h1, cal.paper.h2);
    let [wlo, whi] = cal.paper.window_mm;
    let mut p = SweepPlot::default();
    let mut full = Vec::new();
    for (s, q) in rec.samples.iter().zip(&pred) {
        if s.phase != Phase::Normal {
            continue;
        }
        let (g1, g2) = (s.gamma1_mm, s.stage_mm - s.gamma1_mm);
        p.points.push((g1, g2));
        full.push((q.gamma1_mm, s.stage_mm - q.gamma1_mm));
        if (wlo..=whi).contains(&g1) {
            p.paper_residuals.push((g1, (g2 - (h1 * g1 + h2 * g1.powf(1.5))) * 1e3));
        }
        if g1 != 0.0 {
            p.full_residuals.push((g1, (g1 - q.gamma1_mm) * 1e3));
        }
    }
    p.full = sorted_by_x(full);
    let (_, hi) = x_range(&p.points);
    p.paper = (0..=CURVE_POINTS)
        .map(|i| {
            let x = hi.max(0.0) * i as f64 / CURVE_POINTS as f64;
            (x, h1 * x + h2 * x.powf(1.5))
        })
        .collect();
    Ok(p)
}

/// Torsion sweep: theta2 = rot - theta1 against theta1, with Eq. 38
/// (theta2 = H3 theta1) and the full model.
pub fn torsion_plot(rec: &Recording, cal: &Calibration) -> Result<SweepPlot, ReportError> {
    let pred = predict(rec, &full_params(cal))?;
    let h3 = cal.paper.h3;
    let mut p = SweepPlot::default();
    let mut full = Vec::new();
    for (s, q) in rec.samples.iter().zip(&pred) {
        if s.phase != Phase::Torsion {
            continue;
        }
        let (t1, t2) = (s.theta1_deg, s.rot_deg - s.theta1_deg);
        p.points.push((t1, t2));
        full.push((q.theta1_deg, s.rot_deg - q.theta1_deg));
        p.paper_residuals.push((t1, t2 - h3 * t1));
        p.full_residuals.push((t1, t1 - q.theta1_deg));
    }
    p.full = sorted_by_x(full);
    let (lo, hi) = x_range(&p.points);
    p.paper = (0..=CURVE_POINTS)
        .map(|i| {
            let x = lo + (hi - lo) * i as f64 / CURVE_POINTS as f64;
            (x, h3 * x)
        })
        .collect();
    Ok(p)
}

/// Labels of one figure.
pub struct PlotText<'a> {
    pub title: &'a str,
    pub x: &'a str,
    pub y: &'a str,
    pub residual_y: &'a str,
    pub paper: &'a str,
    pub full: &'a str,
}

fn range_of<'a>(series: impl IntoIterator<Item = &'a [(f64, f64)]>, axis: fn(&(f64, f64)) -> f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for s in series {
        for v in s.iter().map(axis).filter(|v| v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 * lo.abs().max(1e-3) };
    (lo - pad, hi + pad)
}

const DATA: RGBColor = RGBColor(31, 119, 180);
const PAPER: RGBColor = RGBColor(214, 39, 40);
const FULL: RGBColor = RGBColor(44, 160, 44);

/// Render one sweep's figure (main panel and residual panel) to an SVG string.
pub fn render_svg(data: &SweepPlot, text: &PlotText<'_>) -> Result<String, ReportError> {
    let mut svg = String::new();
    draw(&mut svg, data, text).map_err(|e| ReportError::Plot { what: text.title.to_string(), message: e })?;
    Ok(svg)
}

fn draw(svg: &mut String, data: &SweepPlot, text: &PlotText<'_>) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    let root = SVGBackend::with_string(svg, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(e)?;
    let (top, bottom) = root.split_vertically(MAIN_HEIGHT);

    let all: [&[(f64, f64)]; 3] = [&data.points, &data.paper, &data.full];
    let (x0, x1) = range_of(all, |p| p.0);
    let (y0, y1) = range_of(all, |p| p.1);
    let mut chart = ChartBuilder::on(&top)
        .caption(text.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    chart.configure_mesh().x_desc(text.x).y_desc(text.y).draw().map_err(e)?;
    chart
        .draw_series(data.points.iter().map(|&(x, y)| Circle::new((x, y), 2, DATA.filled())))
        .map_err(e)?
        .label("measured")
        .legend(|(x, y)| Circle::new((x + 10, y), 3, DATA.filled()));
    chart
        .draw_series(LineSeries::new(data.paper.iter().copied(), PAPER.stroke_width(2)))
        .map_err(e)?
        .label(text.paper)
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], PAPER.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(data.full.iter().copied(), FULL.stroke_width(2)))
        .map_err(e)?
        .label(text.full)
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], FULL.stroke_width(2)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;

    let res: [&[(f64, f64)]; 2] = [&data.paper_residuals, &data.full_residuals];
    let (ry0, ry1) = range_of(res, |p| p.1);
    let (ry0, ry1) = (ry0.min(0.0), ry1.max(0.0));
    let mut rc = ChartBuilder::on(&bottom)
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, ry0..ry1)
        .map_err(e)?;
    rc.configure_mesh().x_desc(text.x).y_desc(text.residual_y).draw().map_err(e)?;
    rc.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.mix(0.5))).map_err(e)?;
    rc.draw_series(data.paper_residuals.iter().map(|&(x, y)| Cross::new((x, y), 3, PAPER)))
        .map_err(e)?
        .label(format!("{} residual", text.paper))
        .legend(|(x, y)| Cross::new((x + 10, y), 3, PAPER));
    rc.draw_series(data.full_residuals.iter().map(|&(x, y)| TriangleMarker::new((x, y), 3, FULL)))
        .map_err(e)?
        .label(format!("{} residual", text.full))
        .legend(|(x, y)| TriangleMarker::new((x + 10, y), 3, FULL));
    rc.configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

pub const NORMAL_TEXT: PlotText<'static> = PlotText {
    title: "Normal sweep: gamma2 vs gamma1",
    x: "gamma1 (mm)",
    y: "gamma2 = stage - gamma1 (mm)",
    residual_y: "residual (µm)",
    paper: "paper fit (Eq. 22)",
    full: "full model",
};

pub const TORSION_TEXT: PlotText<'static> = PlotText {
    title: "Torsion sweep: theta2 vs theta1",
    x: "theta1 (deg)",
    y: "theta2 = rot - theta1 (deg)",
    residual_y: "residual (deg)",
    paper: "paper fit (Eq. 38)",
    full: "full model",
};
