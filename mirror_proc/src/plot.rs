//! The learning-curve figure (like the paper's Figure 4), drawn with `plotters` as SVG.

use std::path::Path;

use plotters::prelude::*;

use crate::calibrate::Method;
use crate::experiment::{ExperimentResult, Summary};

/// Errors of plot drawing.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot draw the plot: {message}")]
pub struct PlotError {
    path: String,
    message: String,
}

/// Picks one figure out of a summary row.
type Metric = fn(&Summary) -> Option<f64>;

const METHOD_COLOURS: [RGBColor; 3] = [
    RGBColor(200, 40, 40),
    RGBColor(30, 90, 200),
    RGBColor(20, 150, 60),
];

/// Writes the learning curves (error vs training poses) as SVG: median 3D
/// error on the left, mean 2D error on the right; solid lines through the mirror, dashed
/// lines for direct views; oracle and noise floor as horizontal references.
pub fn learning_curves(result: &ExperimentResult, path: &Path) -> Result<(), PlotError> {
    let fail = |e: &dyn std::fmt::Display| PlotError {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let is_svg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if !is_svg {
        return Err(fail(&"only .svg output is supported"));
    }
    let root = SVGBackend::new(path, (1280, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let root = root
        .titled(
            &format!(
                "Mirror calibration learning curves, preset {} (mean over {} mirror placements)",
                result.preset,
                result.mirrors.len()
            ),
            ("sans-serif", 20),
        )
        .map_err(|e| fail(&e))?;
    let panels = root.split_evenly((1, 2));
    let metrics: [(&str, Metric, Metric); 2] = [
        // Medians for 3D: a single sample whose mirror rays nearly miss each
        // other (paper method) sends the mean to 1e10 mm and hides the curves.
        (
            "median 3D error, mm",
            |s| s.mirror_3d_mm_median,
            |s| s.direct_3d_mm_median,
        ),
        ("mean 2D error, px", |s| s.mirror_2d_px, |s| s.direct_2d_px),
    ];
    let max_size = result.sizes.iter().copied().max().unwrap_or(1).max(2) as f64;
    let min_size = result.sizes.iter().copied().min().unwrap_or(1) as f64;
    for (panel, (label, mirror, direct)) in panels.iter().zip(metrics) {
        let values: Vec<f64> = result
            .summary
            .iter()
            .flat_map(|s| [mirror(s), direct(s)])
            .flatten()
            .filter(|v| *v > 0.0 && v.is_finite())
            .collect();
        let lo = values
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
            .max(1e-3)
            * 0.8;
        let hi = values.iter().copied().fold(0.0, f64::max).max(lo * 2.0) * 1.25;
        let mut chart = ChartBuilder::on(panel)
            .margin(16)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(min_size..max_size, (lo..hi).log_scale())
            .map_err(|e| fail(&e))?;
        chart
            .configure_mesh()
            .x_desc("training poses")
            .y_desc(label)
            .draw()
            .map_err(|e| fail(&e))?;
        let curve = |method: &str, f: fn(&Summary) -> Option<f64>| -> Vec<(f64, f64)> {
            result
                .sizes
                .iter()
                .filter_map(|&n| {
                    result
                        .summary_for(method, n)
                        .and_then(f)
                        .map(|v| (n as f64, v))
                })
                .collect()
        };
        for (method, colour) in Method::ALL.iter().zip(METHOD_COLOURS) {
            chart
                .draw_series(LineSeries::new(
                    curve(method.as_str(), mirror),
                    colour.stroke_width(2),
                ))
                .map_err(|e| fail(&e))?
                .label(format!("{method}, mirror"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
        }
        // Direct views: paper and joint share the nominal arm model; joint+kinematics corrects it.
        for (method, colour, name) in [
            (Method::Joint, RGBColor(90, 90, 90), "nominal model, direct"),
            (
                Method::JointKinematics,
                METHOD_COLOURS[2],
                "joint+kinematics, direct",
            ),
        ] {
            chart
                .draw_series(DashedLineSeries::new(
                    curve(method.as_str(), direct),
                    6,
                    4,
                    colour.stroke_width(2),
                ))
                .map_err(|e| fail(&e))?
                .label(name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(1))
                });
        }
        for (name, colour) in [("oracle", BLACK), ("noise floor", RGBColor(150, 150, 150))] {
            if let Some(v) = result.summary_for(name, 0).and_then(mirror) {
                chart
                    .draw_series(DashedLineSeries::new(
                        vec![(min_size, v), (max_size, v)],
                        2,
                        3,
                        colour.stroke_width(2),
                    ))
                    .map_err(|e| fail(&e))?
                    .label(format!("{name}, mirror"))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                    });
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| fail(&e))?;
    }
    root.present().map_err(|e| fail(&e))?;
    Ok(())
}
