//! The stability suite's charts and failure points (accuracy and flips per
//! factor level, coverage, decision time), and the plain line chart the
//! idle and timing studies draw with.

use crate::decision_curve::DecisionCurve;
use crate::stability::*;
use anyhow::{anyhow, Result};

/// The coverage factors' chart: top-1 per press against index presses per
/// textile (log scale), one panel per factor (jig, hand-held queries), one
/// colour per method, one line style per index (nearest frame: solid;
/// textile centroids, `index build --sim`: dotted; centroids and press
/// means, `index build --presses`: dashed). Nothing is written when the
/// report has no coverage factor.
pub fn coverage_chart(
    report: &StabilityReport,
    names: &[String],
    svg: &std::path::Path,
) -> Result<bool> {
    use plotters::prelude::*;
    let e = |x: Box<dyn std::error::Error + '_>| anyhow!("chart: {x}");
    let factors: Vec<Factor> = report
        .config
        .factors
        .iter()
        .copied()
        .filter(Factor::is_coverage)
        .collect();
    if factors.is_empty() {
        return Ok(false);
    }
    let methods: Vec<&MethodStability> = report
        .methods
        .iter()
        .filter(|m| names.contains(&m.name))
        .collect();
    let root = SVGBackend::new(svg, (1200, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
    let panels = root.split_evenly((1, factors.len()));
    for (pi, (panel, f)) in panels.iter().zip(&factors).enumerate() {
        let hi = f.levels(report.config.quick).last().copied().unwrap_or(2.0);
        let mut c = ChartBuilder::on(panel)
            .caption(
                format!("Top-1 per press: {}", f.label()),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(45)
            .build_cartesian_2d((0.9f64..hi * 1.1).log_scale(), 0.0..100.0)
            .map_err(|x| e(Box::new(x)))?;
        c.configure_mesh()
            .x_desc("index presses per textile")
            .y_desc("top-1 per press, %")
            .x_labels(6)
            .y_labels(6)
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        c.draw_series(LineSeries::new(
            [(0.9, 90.0), (hi * 1.1, 90.0)],
            RED.mix(0.5).stroke_width(1),
        ))
        .map_err(|x| e(Box::new(x)))?;
        for (mi, m) in methods.iter().enumerate() {
            let Some(curve) = m.curves.iter().find(|c| c.factor == *f) else {
                continue;
            };
            let color = Palette99::pick(mi).to_rgba();
            let kinds: [(&str, LevelFigure); 3] = [
                ("nearest frame", |l| Some(l.press_top1)),
                ("centroids (--sim)", |l| l.press_top1_centroid),
                ("centroids + presses (--presses)", |l| {
                    l.press_top1_exemplars
                }),
            ];
            for (ki, (kind, get)) in kinds.into_iter().enumerate() {
                let pts: Vec<(f64, f64)> = curve
                    .levels
                    .iter()
                    .filter_map(|l| get(l).map(|v| (l.value, 100.0 * v)))
                    .collect();
                c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                    .map_err(|x| e(Box::new(x)))?;
                let label = format!("{}, {kind}", m.name);
                let s = match ki {
                    0 => c.draw_series(LineSeries::new(pts, color.stroke_width(2))),
                    1 => c.draw_series(DashedLineSeries::new(pts, 2, 4, color.stroke_width(2))),
                    _ => c.draw_series(DashedLineSeries::new(pts, 8, 4, color.stroke_width(2))),
                }
                .map_err(|x| e(Box::new(x)))?;
                if pi == 0 {
                    // The legend draws the line's own pattern: three
                    // segments of `len` px, 6 px apart.
                    let len = [6, 2, 5][ki];
                    s.label(label).legend(move |(x, y)| {
                        let style = color.stroke_width(2);
                        let seg = |a: i32| PathElement::new(vec![(a, 0), (a + len, 0)], style);
                        EmptyElement::at((x, y)) + seg(0) + seg(6) + seg(12)
                    });
                }
            }
        }
        if pi == 0 {
            c.configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 11))
                .position(SeriesLabelPosition::LowerRight)
                .draw()
                .map_err(|x| e(Box::new(x)))?;
        }
    }
    root.present().map_err(|x| e(Box::new(x)))?;
    Ok(true)
}

/// Where a method's press accuracy first drops below `threshold` as the
/// factor moves away from its nominal level (both directions for force
/// and LED gain; rotation by the absolute angle). Text for the table.
pub fn failure_point(curve: &FactorCurve, threshold: f64) -> String {
    let f = curve.factor;
    let lv = &curve.levels;
    let fails = |s: &LevelScore| s.press_top1 < threshold;
    let unit = match f {
        Factor::Rotation | Factor::Tilt => "°",
        Factor::Force => " N",
        Factor::Noise => " DN",
        Factor::StaleBackground => " px",
        Factor::Spot => " mm",
        _ => "",
    };
    match f {
        Factor::Coverage | Factor::CoverageHand => {
            let best = lv
                .iter()
                .max_by(|a, b| a.press_top1.total_cmp(&b.press_top1));
            match (lv.iter().find(|s| !fails(s)), best) {
                (Some(s), _) => format!("reaches it at {} presses", s.value),
                (None, Some(b)) => format!(
                    "never (best {:.0}% at {} presses)",
                    100.0 * b.press_top1,
                    b.value
                ),
                (None, None) => "-".into(),
            }
        }
        Factor::Unseen => {
            let s = &lv[0];
            format!(
                "{:.0}% in attribute top-10, median rank {}",
                100.0 * s.press_top1,
                s.attr_rank_median.map_or("-".into(), |r| format!("{r:.0}"))
            )
        }
        Factor::HandHeld | Factor::SensorSwap | Factor::SensorPool => {
            let bad: Vec<String> = lv
                .iter()
                .filter(|s| fails(s))
                .map(|s| format!("{}", s.value))
                .collect();
            let what = if f == Factor::HandHeld {
                "people"
            } else {
                "units"
            };
            if bad.is_empty() {
                format!("none of {} {what}", lv.len())
            } else {
                format!("{} of {} {what} ({})", bad.len(), lv.len(), bad.join(", "))
            }
        }
        _ => {
            let nominal = f.nominal();
            let dev = |v: f64| {
                if f == Factor::Rotation {
                    let a = v.rem_euclid(360.0);
                    a.min(360.0 - a)
                } else {
                    (v - nominal).abs()
                }
            };
            if let Some(n) = lv.iter().find(|s| dev(s.value) < 1e-9) {
                if fails(n) {
                    return format!("below at nominal ({:.0}%)", 100.0 * n.press_top1);
                }
            }
            let side = |below: bool| -> Option<f64> {
                let mut v: Vec<&LevelScore> = lv
                    .iter()
                    .filter(|s| {
                        let d = s.value - nominal;
                        f == Factor::Rotation || (if below { d < 0.0 } else { d > 0.0 })
                    })
                    .collect();
                v.sort_by(|a, b| dev(a.value).total_cmp(&dev(b.value)));
                v.into_iter().find(|s| fails(s)).map(|s| s.value)
            };
            match f {
                Factor::Force | Factor::LedDrift => {
                    let lo = side(true).map_or("-".into(), |v| format!("≤ {v}{unit}"));
                    let hi = side(false).map_or("-".into(), |v| format!("≥ {v}{unit}"));
                    if lo == "-" && hi == "-" {
                        "never".into()
                    } else {
                        format!("{lo} / {hi}")
                    }
                }
                Factor::Rotation => side(false).map_or("never".into(), |v| {
                    let a = v.rem_euclid(360.0);
                    format!("{:.0}{unit}", a.min(360.0 - a))
                }),
                _ => side(false).map_or("never".into(), |v| format!("{v}{unit}")),
            }
        }
    }
}

/// Charts: accuracy per factor (one panel each) and flip rate per factor,
/// for the named methods.
pub fn charts(
    report: &StabilityReport,
    names: &[String],
    accuracy_svg: &std::path::Path,
    flips_svg: &std::path::Path,
) -> Result<()> {
    use plotters::prelude::*;
    let e = |x: Box<dyn std::error::Error + '_>| anyhow!("chart: {x}");
    let methods: Vec<&MethodStability> = report
        .methods
        .iter()
        .filter(|m| names.contains(&m.name))
        .collect();
    let factors: Vec<Factor> = report
        .config
        .factors
        .iter()
        .copied()
        .filter(|f| *f != Factor::Unseen)
        .collect();
    for (svg, flips) in [(accuracy_svg, false), (flips_svg, true)] {
        let root = SVGBackend::new(svg, (1750, 760)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
        let (title, body) = root.split_vertically(40);
        title
            .draw(&Text::new(
                if flips {
                    "Decision flip rate between consecutive frames (60 fps) as one condition changes"
                } else {
                    "Top-1 per press as one condition changes (index: person 0, sensor 0, jig, 0°, 4 N)"
                },
                (20, 12),
                ("sans-serif", 20),
            ))
            .map_err(|x| e(Box::new(x)))?;
        let panels = body.split_evenly((2, 5));
        for (pi, (panel, f)) in panels.iter().zip(&factors).enumerate() {
            let levels: Vec<f64> = methods
                .first()
                .and_then(|m| m.curves.iter().find(|c| c.factor == *f))
                .map(|c| c.levels.iter().map(|l| l.value).collect())
                .unwrap_or_default();
            if levels.is_empty() {
                continue;
            }
            let (lo, hi) = levels
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let hi = if hi > lo { hi } else { lo + 1.0 };
            let mut c = ChartBuilder::on(panel)
                .margin(8)
                .x_label_area_size(35)
                .y_label_area_size(40)
                .build_cartesian_2d(lo..hi, 0.0..100.0)
                .map_err(|x| e(Box::new(x)))?;
            c.configure_mesh()
                .x_desc(f.label())
                .y_desc(if flips { "flips, %" } else { "top-1, %" })
                .x_labels(6)
                .y_labels(6)
                .draw()
                .map_err(|x| e(Box::new(x)))?;
            if !flips {
                c.draw_series(LineSeries::new(
                    [(lo, 90.0), (hi, 90.0)],
                    RED.mix(0.5).stroke_width(1),
                ))
                .map_err(|x| e(Box::new(x)))?;
            }
            for (mi, m) in methods.iter().enumerate() {
                let Some(curve) = m.curves.iter().find(|c| c.factor == *f) else {
                    continue;
                };
                let color = Palette99::pick(mi).to_rgba();
                let pts: Vec<(f64, f64)> = curve
                    .levels
                    .iter()
                    .map(|l| {
                        (
                            l.value,
                            100.0 * if flips { l.flip_rate } else { l.press_top1 },
                        )
                    })
                    .collect();
                c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                    .map_err(|x| e(Box::new(x)))?;
                let s = c
                    .draw_series(LineSeries::new(pts, color.stroke_width(2)))
                    .map_err(|x| e(Box::new(x)))?;
                if pi == 0 {
                    s.label(m.name.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                    });
                }
            }
            if pi == 0 {
                c.configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 11))
                    .position(SeriesLabelPosition::LowerLeft)
                    .draw()
                    .map_err(|x| e(Box::new(x)))?;
            }
        }
        root.present().map_err(|x| e(Box::new(x)))?;
    }
    Ok(())
}

/// Accuracy against ms since first contact, one line per method.
pub fn decision_chart(curves: &[DecisionCurve], svg: &std::path::Path) -> Result<()> {
    let n = curves
        .iter()
        .map(|c| c.top1.len())
        .max()
        .unwrap_or(1)
        .max(2);
    let ms = |k: usize| k as f64 * 1000.0 / 60.0;
    let series: Vec<Line> = curves
        .iter()
        .map(|cv| Line {
            label: cv.name.clone(),
            points: cv.top1.iter().map(|&(k, a)| (ms(k), 100.0 * a)).collect(),
            width: 2,
        })
        .collect();
    line_chart(
        svg,
        "Accuracy against time since first contact (held-out people, running mean)",
        (
            "ms since the first contact frame (frames aggregated x 16.7 ms)",
            "top-1 per press, %",
        ),
        ms(1)..ms(n),
        &series,
    )
}

/// One line of [`line_chart`].
pub struct Line {
    pub label: String,
    /// (x, y in %).
    pub points: Vec<(f64, f64)>,
    pub width: u32,
}

/// A percentage (0..100) against `x`, one line per series, legend at the
/// lower right: the time charts of the study and of `decider-timing`.
pub fn line_chart(
    svg: &std::path::Path,
    caption: &str,
    (x_desc, y_desc): (&str, &str),
    x: std::ops::Range<f64>,
    series: &[Line],
) -> Result<()> {
    use plotters::prelude::*;
    let e = |x: Box<dyn std::error::Error + '_>| anyhow!("chart: {x}");
    let root = SVGBackend::new(svg, (1000, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
    let mut c = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x, 0.0..100.0)
        .map_err(|x| e(Box::new(x)))?;
    c.configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()
        .map_err(|x| e(Box::new(x)))?;
    for (i, l) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let w = l.width;
        c.draw_series(LineSeries::new(
            l.points.iter().copied(),
            color.stroke_width(w),
        ))
        .map_err(|x| e(Box::new(x)))?
        .label(l.label.clone())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(w)));
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|x| e(Box::new(x)))?;
    root.present().map_err(|x| e(Box::new(x)))?;
    Ok(())
}
