//! `history SENSOR --plot out.svg`: E1 and nu1 over time with their 95 %
//! intervals, alarms marked, and the trend line when there is one.

use plotters::prelude::*;

use crate::CalibrationRecord;
use crate::change::{Assessment, Quantity, Trend};

const SIZE: (u32, u32) = (900, 700);

/// One panel's series: (days since the first calibration, value, interval, alarm).
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub label: &'static str,
    pub points: Vec<(f64, f64, Option<[f64; 2]>, bool)>,
    /// Trend line end points, when there is a trend.
    pub trend: Option<[(f64, f64); 2]>,
}

/// The series of both panels (pure, so they can be checked apart from drawing).
pub fn panels(series: &[&CalibrationRecord], assessed: &[Assessment], trends: [Option<&Trend>; 2]) -> [Panel; 2] {
    let t0 = series.first().map_or(0.0, |r| r.time_unix_s);
    let day = |r: &CalibrationRecord| (r.time_unix_s - t0) / 86_400.0;
    let panel = |q: Quantity, trend: Option<&Trend>| {
        let points: Vec<_> = series
            .iter()
            .zip(assessed)
            .map(|(r, a)| {
                let (x, ci, v) = match q {
                    Quantity::E1 => (r.e1_mpa, r.e1_ci95, &a.e1),
                    Quantity::Nu1 => (r.nu1, r.nu1_ci95, &a.nu1),
                };
                (day(r), x, ci, v.as_ref().is_some_and(|v| v.alarm))
            })
            .collect();
        let trend_line = trend.and_then(|t| {
            // The line through the weighted data: anchored at the points' mean.
            let n = points.len() as f64;
            let (md, mx) = points.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
            let per_day = t.rate_per_month / (crate::change::MONTH_S / 86_400.0);
            let last = points.last()?.0;
            Some([(0.0, mx - per_day * md), (last, mx + per_day * (last - md))])
        });
        Panel { label: q.label(), points, trend: trend_line }
    };
    [panel(Quantity::E1, trends[0]), panel(Quantity::Nu1, trends[1])]
}

/// Render both panels to an SVG string.
pub fn render_svg(sensor: &str, panels: &[Panel; 2]) -> Result<String, String> {
    let mut svg = String::new();
    {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let root = root.titled(&format!("Calibration history of {sensor}"), ("sans-serif", 22)).map_err(e)?;
        let areas = root.split_evenly((2, 1));
        for (area, p) in areas.iter().zip(panels) {
            let lo = |pt: &(f64, f64, Option<[f64; 2]>, bool)| pt.2.map_or(pt.1, |c| c[0]);
            let hi = |pt: &(f64, f64, Option<[f64; 2]>, bool)| pt.2.map_or(pt.1, |c| c[1]);
            let y0 = p.points.iter().map(lo).fold(f64::INFINITY, f64::min);
            let y1 = p.points.iter().map(hi).fold(f64::NEG_INFINITY, f64::max);
            let x1 = p.points.iter().map(|q| q.0).fold(0.0, f64::max);
            let pad = ((y1 - y0) * 0.1).max(1e-6 * y1.abs().max(1e-9));
            let (y0, y1) = if y0.is_finite() { (y0 - pad, y1 + pad) } else { (0.0, 1.0) };
            let mut chart = ChartBuilder::on(area)
                .margin(12)
                .x_label_area_size(36)
                .y_label_area_size(72)
                .build_cartesian_2d(-0.02 * x1.max(1.0)..x1.max(1.0) * 1.02, y0..y1)
                .map_err(e)?;
            chart.configure_mesh().x_desc("days since the first calibration").y_desc(p.label).draw().map_err(e)?;
            let color = |alarm: bool| if alarm { RED } else { BLUE };
            chart
                .draw_series(p.points.iter().filter_map(|&(d, _, ci, alarm)| {
                    ci.map(|[l, h]| PathElement::new(vec![(d, l), (d, h)], color(alarm).stroke_width(1)))
                }))
                .map_err(e)?;
            chart
                .draw_series(p.points.iter().map(|&(d, x, _, alarm)| Circle::new((d, x), 3, color(alarm).filled())))
                .map_err(e)?;
            if let Some([a, b]) = p.trend {
                chart.draw_series(LineSeries::new([a, b], BLACK.mix(0.6).stroke_width(2))).map_err(e)?;
            }
        }
        root.present().map_err(e)?;
    }
    Ok(svg)
}
