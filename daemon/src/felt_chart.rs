//! `classify --felt-svg`: the share of presses whose wheel rests at the
//! right fabric's sample, against time since contact, one line per motion
//! policy (docs/studies/2026-12-04-felt-latency.md).

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use telextiles_session::felt::FeltTally;
use telextiles_session::MotionPolicy;

/// Time axis of the chart, ms after contact.
pub const SPAN_MS: f64 = 1200.0;

/// Draw the chart of `policies` (with what each did) to `path`, titled
/// with `title`.
pub fn draw(path: &Path, title: &str, policies: &[(MotionPolicy, FeltTally)]) -> Result<()> {
    let e = |x: &dyn std::fmt::Display| anyhow!("cannot draw {}: {x}", path.display());
    let root = SVGBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..SPAN_MS, 0.0..100.0)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("time since contact on the sending sensor, ms")
        .y_desc("% of presses at rest at the right sample")
        .draw()
        .map_err(|x| e(&x))?;
    for (i, (policy, tally)) in policies.iter().enumerate() {
        let pts: Vec<(f64, f64)> = (0..=(SPAN_MS / 5.0) as usize)
            .filter_map(|k| {
                let t = k as f64 * 5.0;
                tally.right_at_rest_by(t).map(|y| (t, y))
            })
            .collect();
        let s = tally.summary();
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(2)))
            .map_err(|x| e(&x))?
            .label(format!(
                "{policy}: p50 {:.0} ms, p90 {:.0} ms",
                s.felt_p50_ms, s.felt_p90_ms
            ))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
