//! Residual plots before / after correction as SVG (plotters' SVG backend).
//! Four panels: gamma1 residual (µm) and theta1 residual (degrees) against
//! sample time, before and after, with the ±2 sigma noise band.

use std::path::{Path, PathBuf};

use plotters::drawing::DrawingAreaErrorKind;
use plotters::prelude::*;

use super::Diagnosis;

/// Why the residual plot was not written, with the cause.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("plot {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("plot {path}: {source}")]
    Draw {
        path: PathBuf,
        #[source]
        source: DrawingAreaErrorKind<std::io::Error>,
    },
}

type Series = Vec<(f64, f64)>;

fn series(d: &Diagnosis) -> [Series; 4] {
    let mut out: [Series; 4] = Default::default();
    for r in &d.residuals {
        if let Some(v) = r.gamma1_before_mm {
            out[0].push((r.t_s, v * 1e3));
        }
        if let Some(v) = r.gamma1_after_mm {
            out[1].push((r.t_s, v * 1e3));
        }
        if let Some(v) = r.theta1_before_deg {
            out[2].push((r.t_s, v));
        }
        if let Some(v) = r.theta1_after_deg {
            out[3].push((r.t_s, v));
        }
    }
    out
}

fn span(s: &[&Series], band: f64) -> (f64, f64, f64, f64) {
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = (-2.5 * band, 2.5 * band);
    for p in s.iter().flat_map(|v| v.iter()) {
        x = (x.0.min(p.0), x.1.max(p.0));
        y = (y.0.min(p.1), y.1.max(p.1));
    }
    if !x.0.is_finite() {
        x = (0.0, 1.0);
    }
    let pad = 0.05 * (y.1 - y.0).max(1e-9);
    (x.0, x.1.max(x.0 + 1e-9), y.0 - pad, y.1 + pad)
}

/// Write `residuals.svg` into `dir` (created if missing); returns its path.
pub fn write_residual_plot(d: &Diagnosis, dir: &Path) -> Result<PathBuf, PlotError> {
    let path = dir.join("residuals.svg");
    let err = |source| PlotError::Draw { path: path.clone(), source };
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Io { path: path.clone(), source })?;
    let s = series(d);
    let target = path.clone();
    let root = SVGBackend::new(&target, (1000, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let panels = root.split_evenly((2, 2));
    let title = |k: usize| match k {
        0 => "gamma1 residual, baseline (um)",
        1 => "gamma1 residual, corrected (um)",
        2 => "theta1 residual, baseline (deg)",
        _ => "theta1 residual, corrected (deg)",
    };
    let g = span(&[&s[0], &s[1]], d.noise.normal_um);
    let t = span(&[&s[2], &s[3]], d.noise.torsion_deg);
    for (k, area) in panels.iter().enumerate() {
        let (x0, x1, y0, y1) = if k < 2 { g } else { t };
        let band = if k < 2 { d.noise.normal_um } else { d.noise.torsion_deg };
        let mut chart = ChartBuilder::on(area)
            .caption(title(k), ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(48)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(err)?;
        chart.configure_mesh().x_desc("t (s)").light_line_style(WHITE).draw().map_err(err)?;
        for b in [-2.0 * band, 2.0 * band] {
            chart
                .draw_series(LineSeries::new([(x0, b), (x1, b)], RGBColor(150, 150, 150).stroke_width(1)))
                .map_err(err)?;
        }
        let color = if k % 2 == 0 { RED } else { BLUE };
        chart.draw_series(s[k].iter().map(|&p| Circle::new(p, 2, color.filled()))).map_err(err)?;
    }
    root.present().map_err(err)?;
    drop(root);
    Ok(path)
}
