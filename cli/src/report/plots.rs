//! The report's PNG plots, made with `plotters`: error against precompute time, against frame
//! time, per frame of the rig with its flicker, and per edit against the time since it. Labels need a TrueType font (DejaVu,
//! Liberation or Noto, as Debian's `fonts-dejavu-core` installs).

use std::ops::Range;
use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::rig::{flicker, Frame};
use super::scale::ScaleRow;
use super::sweeps::{Point, RuntimeSweep};
use super::Figures;

/// Writes precompute.png, runtime.png, rig.png and placement.png for the level's parts, and
/// scale.png for the scale section, into `output`; false (and a note) when no font is found, so
/// no plots are made.
pub fn write_plots(
    output: &Path,
    f: Option<&Figures>,
    scale: Option<&[ScaleRow]>,
    gpu: bool,
) -> Result<bool> {
    if !register_font() {
        eprintln!(
            "note: no TrueType font found (install fonts-dejavu-core); report.md written without plots"
        );
        return Ok(false);
    }
    if let Some(f) = f {
        plot_precompute(&output.join("precompute.png"), &f.prm, &f.reference)?;
        plot_runtime(&output.join("runtime.png"), &f.runtime, gpu)?;
        plot_rig(&output.join("rig.png"), &f.frames)?;
        if !f.placements.is_empty() {
            plot_placement(&output.join("placement.png"), &f.placements)?;
        }
        if let Some(e) = f.editing.as_ref().filter(|e| !e.rows.is_empty()) {
            plot_editing(&output.join("editing.png"), e)?;
        }
        if let Some(m) = f.moving.as_ref().filter(|m| !m.rows.is_empty()) {
            super::moving::plot(&output.join("moving.png"), m)?;
        }
    }
    if let Some(rows) = scale.filter(|r| !r.is_empty()) {
        plot_scale(&output.join("scale.png"), rows)?;
    }
    Ok(true)
}

/// Registers the first TrueType font found as plotters' "sans-serif".
fn register_font() -> bool {
    let candidates = [
        "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        "/usr/share/fonts/truetype/noto/NotoSans-Regular.ttf",
        "/usr/share/fonts/TTF/DejaVuSans.ttf",
        "/Library/Fonts/Arial.ttf",
        "C:\\Windows\\Fonts\\arial.ttf",
    ];
    for c in candidates {
        if let Ok(bytes) = std::fs::read(c) {
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                return true;
            }
        }
    }
    false
}

const PRM_COLOUR: RGBColor = RGBColor(31, 119, 180);
const REF_COLOUR: RGBColor = RGBColor(214, 39, 40);
const PLAIN_COLOUR: RGBColor = RGBColor(150, 150, 150);
const ALL_COLOUR: RGBColor = RGBColor(44, 160, 44);

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing a plot: {e}")
}

/// The series labels in a framed, half-transparent box (every plot's legend).
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<()> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)
}

fn bounds(points: &[&Point], f: impl Fn(&Point) -> f64) -> (f64, f64) {
    let v: Vec<f64> = points.iter().map(|p| f(p)).filter(|x| x.is_finite() && *x > 0.0).collect();
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(0.0, f64::max);
    if lo.is_finite() && hi > 0.0 {
        (lo, hi)
    } else {
        (1e-3, 1.0)
    }
}

fn plot_precompute(path: &Path, prm: &[Point], reference: &[Point]) -> Result<()> {
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let all: Vec<&Point> = prm.iter().chain(reference).collect();
    let (t0, t1) = bounds(&all, |p| p.seconds);
    let e1 = all.iter().map(|p| p.error * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max) * 1.15 + 0.5;
    let mut chart = ChartBuilder::on(&root)
        .caption("Indirect error against precompute / bake time", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((t0 * 0.7..t1 * 1.4).log_scale(), 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("time (s, log)")
        .y_desc("error vs ground truth (%)")
        .draw()
        .map_err(plot_err)?;
    for (points, colour, name) in [
        (prm, PRM_COLOUR, "PRM, all panes (entries N, paths M, clusters C)"),
        (reference, REF_COLOUR, "reference baker (photons, VPLs per light)"),
    ] {
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (p.seconds, p.error * 100.0)),
                colour.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart
            .draw_series(points.iter().map(|p| Circle::new((p.seconds, p.error * 100.0), 4, colour.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(points.iter().map(|p| {
                Text::new(
                    p.label.clone(),
                    (p.seconds, p.error * 100.0 + e1 * 0.02),
                    ("sans-serif", 12).into_font().color(&colour),
                )
            }))
            .map_err(plot_err)?;
    }
    legend(&mut chart)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// The runtime plot's time axis (ms, the direct-only frame time included) and its top error (%).
fn runtime_axes(sweep: &RuntimeSweep) -> (Range<f64>, f64) {
    let direct_ms = sweep.direct_ms;
    let all: Vec<&Point> = sweep.tile.iter().chain(&sweep.with).chain(&sweep.without).collect();
    let (t0, t1) = bounds(&all, |p| p.seconds * 1e3);
    let (t0, t1) = if direct_ms.is_finite() { (t0.min(direct_ms), t1.max(direct_ms)) } else { (t0, t1) };
    let e1 = (all.iter().map(|p| p.error * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max) * 1.1 + 0.5)
        .min(120.0);
    let pad = (t1 - t0).max(t1 * 0.05);
    ((t0 - pad * 0.2).max(0.0)..t1 + pad * 0.2, e1)
}

fn plot_runtime(path: &Path, sweep: &RuntimeSweep, gpu: bool) -> Result<()> {
    let (tile, with, without) = (&sweep.tile[..], &sweep.with[..], &sweep.without[..]);
    let direct_ms = sweep.direct_ms;
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let ms = |p: &Point| p.seconds * 1e3;
    let (x_range, e1) = runtime_axes(sweep);
    let caption = if gpu {
        "Indirect error against frame time (GPU runtime, top-K)"
    } else {
        "Indirect error against lightmap time (CPU twin, top-K)"
    };
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range, 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(if gpu { "full frame time (ms, median)" } else { "lightmap time (ms)" })
        .y_desc("error vs ground truth (%)")
        .draw()
        .map_err(plot_err)?;
    for (points, colour, name) in [
        (tile, PRM_COLOUR, "K picked locally + groups (default)"),
        (with, ALL_COLOUR, "K over the map + groups"),
        (without, PLAIN_COLOUR, "K over the map alone"),
    ] {
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (ms(p), p.error * 100.0)),
                colour.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart
            .draw_series(points.iter().map(|p| Circle::new((ms(p), p.error * 100.0), 4, colour.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(points.iter().map(|p| {
                Text::new(
                    format!("K={}", p.label),
                    (ms(p), (p.error * 100.0 + e1 * 0.02).min(e1 * 0.97)),
                    ("sans-serif", 12).into_font().color(&colour),
                )
            }))
            .map_err(plot_err)?;
    }
    if direct_ms.is_finite() {
        chart
            .draw_series(LineSeries::new([(direct_ms, 0.0), (direct_ms, e1)], BLACK.stroke_width(1)))
            .map_err(plot_err)?
            .label("direct-only frame")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    }
    legend(&mut chart)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

fn plot_rig(path: &Path, frames: &[Frame]) -> Result<()> {
    let root = BitMapBackend::new(path, (900, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (top, bottom) = root.split_vertically(450);
    plot_rig_errors(&top, frames)?;
    plot_rig_flicker(&bottom, frames)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

const RIG_NAMES: [&str; 3] = ["PRM top-32 + groups", "PRM all panes", "reference baker"];
const RIG_COLOURS: [RGBColor; 3] = [PRM_COLOUR, ALL_COLOUR, REF_COLOUR];

/// The rig plot's upper half: each method's error per frame, and the ground truth's own noise.
fn plot_rig_errors(area: &DrawingArea<BitMapBackend, Shift>, frames: &[Frame]) -> Result<()> {
    let n = frames.len().max(2) as f64;
    let e1 =
        frames.iter().flat_map(|f| f.errors).map(|e| e * 100.0).filter(|e| e.is_finite()).fold(0.0, f64::max)
            * 1.15
            + 0.5;
    let mut chart = ChartBuilder::on(area)
        .caption("Error per frame of the moving-light rig", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.2..n - 0.8, 0.0..e1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(frames.len())
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("frame")
        .y_desc("error (%)")
        .draw()
        .map_err(plot_err)?;
    for m in 0..3 {
        let c = RIG_COLOURS[m];
        chart
            .draw_series(LineSeries::new(
                frames.iter().enumerate().map(|(f, fr)| (f as f64, fr.errors[m] * 100.0)),
                c.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label(RIG_NAMES[m])
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .draw_series(LineSeries::new(
            frames.iter().enumerate().map(|(f, fr)| (f as f64, fr.gt_noise * 100.0)),
            BLACK.stroke_width(1),
        ))
        .map_err(plot_err)?
        .label("ground truth's own noise (error plot); lighting change (flicker plot)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(1)));
    legend(&mut chart)?;
    Ok(())
}

/// The rig plot's lower half: each method's flicker per transition, and the lighting change.
fn plot_rig_flicker(area: &DrawingArea<BitMapBackend, Shift>, frames: &[Frame]) -> Result<()> {
    let n = frames.len().max(2) as f64;
    let flick = flicker(frames);
    let f1 = flick
        .iter()
        .flat_map(|(v, floor)| v.iter().copied().chain([*floor]))
        .map(|e| e * 100.0)
        .filter(|e| e.is_finite())
        .fold(0.0, f64::max)
        * 1.15
        + 0.5;
    let mut chart = ChartBuilder::on(area)
        .caption("Flicker: RMS change of the error image between frames", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.8..n - 0.8, 0.0..f1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(frames.len())
        .x_label_formatter(&|x| format!("{x:.0}"))
        .x_desc("frame (change from the previous)")
        .y_desc("flicker (% of mean)")
        .draw()
        .map_err(plot_err)?;
    for m in 0..3 {
        chart
            .draw_series(LineSeries::new(
                flick.iter().enumerate().map(|(f, (v, _))| ((f + 1) as f64, v[m] * 100.0)),
                RIG_COLOURS[m].stroke_width(2),
            ))
            .map_err(plot_err)?;
    }
    chart
        .draw_series(LineSeries::new(
            flick.iter().enumerate().map(|(f, (_, floor))| ((f + 1) as f64, floor * 100.0)),
            BLACK.stroke_width(1),
        ))
        .map_err(plot_err)?;
    Ok(())
}

/// Error (noise removed, left) and bias (right) against the distance to the nearest surface,
/// log scale: lines for the height sweep, dots for the torch rig's keyframes.
fn plot_placement(path: &Path, placements: &[super::placement::Placement]) -> Result<()> {
    let root = BitMapBackend::new(path, (1200, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (left, right) = root.split_horizontally(600);
    let clean = |p: &super::placement::Placement, m: usize| {
        (p.frame.errors[m].powi(2) - p.frame.gt_noise.powi(2)).max(0.0).sqrt() * 100.0
    };
    let bias = |p: &super::placement::Placement, m: usize| p.frame.biases[m] * 100.0;
    let top = placements.iter().flat_map(|p| (0..3).map(move |m| clean(p, m))).fold(0.0, f64::max);
    placement_panel(
        &left,
        placements,
        "Error",
        "error, ground-truth noise removed (%)",
        0.0..top * 1.15 + 0.5,
        &clean,
    )?;
    let reach = placements.iter().flat_map(|p| (0..3).map(move |m| bias(p, m).abs())).fold(0.0, f64::max);
    let span = reach * 1.15 + 0.5;
    placement_panel(&right, placements, "Bias", "bias (%)", -span..span, &bias)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// One panel of [`plot_placement`]: `value(placement, method)` against the distance.
fn placement_panel(
    area: &DrawingArea<BitMapBackend, Shift>,
    placements: &[super::placement::Placement],
    what: &str,
    y_desc: &str,
    y: Range<f64>,
    value: &dyn Fn(&super::placement::Placement, usize) -> f64,
) -> Result<()> {
    let d = |p: &super::placement::Placement| (p.distance as f64).max(1e-3);
    let (lo, hi) = placements.iter().map(d).fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{what} against the light's distance to the nearest surface"), ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((lo * 0.8..hi * 1.25).log_scale(), y)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("distance to the nearest surface (scene units, log)")
        .y_desc(y_desc)
        .draw()
        .map_err(plot_err)?;
    let mut sweep: Vec<&super::placement::Placement> = placements.iter().filter(|p| p.sweep).collect();
    sweep.sort_by(|a, b| a.distance.total_cmp(&b.distance));
    for m in 0..3 {
        let c = RIG_COLOURS[m];
        chart
            .draw_series(LineSeries::new(sweep.iter().map(|p| (d(p), value(p, m))), c.stroke_width(2)))
            .map_err(plot_err)?
            .label(RIG_NAMES[m])
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart
            .draw_series(
                placements
                    .iter()
                    .filter(|p| !p.sweep)
                    .map(|p| Circle::new((d(p), value(p, m)), 4, c.filled())),
            )
            .map_err(plot_err)?;
    }
    legend(&mut chart)?;
    Ok(())
}

/// A scale plot's series: its name, colour and figure of a level size.
type ScaleSeries = (&'static str, RGBColor, fn(&ScaleRow) -> f64);

/// Left: precompute time, peak memory, `.prm` size and GPU memory per hall over the first
/// level's (linear growth is a flat line at 1). Right: the errors, noise removed.
fn plot_scale(path: &Path, rows: &[ScaleRow]) -> Result<()> {
    let root = BitMapBackend::new(path, (1100, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (left, right) = root.split_horizontally(550);
    let first = &rows[0];
    let cost: [ScaleSeries; 4] = [
        ("precompute time", PRM_COLOUR, |r| r.precompute_s),
        ("peak memory", ALL_COLOUR, ScaleRow::peak),
        (".prm size", REF_COLOUR, |r| r.file_bytes as f64),
        ("GPU memory", BLACK, |r| r.gpu_bytes as f64),
    ];
    let per_hall: Vec<(&str, RGBColor, Vec<f64>)> = cost
        .iter()
        .map(|&(name, c, f)| (name, c, rows.iter().map(|r| r.per_hall(first, f)).collect()))
        .collect();
    let caption = "Cost per hall, over one level's";
    scale_panel(&left, rows, caption, "per hall / first level's per hall", 1.5, &per_hall)?;
    let errors: [ScaleSeries; 2] = [
        ("PRM top-32 + groups", PRM_COLOUR, |r| r.clean(r.top.0)),
        ("PRM all panes", ALL_COLOUR, |r| r.clean(r.all.0)),
    ];
    let percent: Vec<(&str, RGBColor, Vec<f64>)> =
        errors.iter().map(|&(name, c, f)| (name, c, rows.iter().map(|r| f(r) * 100.0).collect())).collect();
    let caption = "Error against the number of halls";
    scale_panel(&right, rows, caption, "error, ground-truth noise removed (%)", 0.5, &percent)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// One panel of the scale plot: a column per level size, labelled with its halls, and each
/// series (its values per size; non-finite ones left out) as a line with a dot per size. The
/// y axis runs from 0 to above the largest value and `y_min_top`.
fn scale_panel(
    area: &DrawingArea<BitMapBackend, Shift>,
    rows: &[ScaleRow],
    caption: &str,
    y_desc: &str,
    y_min_top: f64,
    series: &[(&str, RGBColor, Vec<f64>)],
) -> Result<()> {
    let halls: Vec<String> = rows.iter().map(|r| r.rooms().to_string()).collect();
    let label = |x: &f64| {
        let k = x.round();
        match (k - x).abs() < 1e-6 && k >= 0.0 {
            true => halls.get(k as usize).cloned().unwrap_or_default(),
            false => String::new(),
        }
    };
    let top =
        series.iter().flat_map(|s| s.2.iter()).filter(|v| v.is_finite()).fold(y_min_top, |a, &v| a.max(v));
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-0.3..rows.len() as f64 - 0.7, 0.0..top * 1.15)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(rows.len())
        .x_label_formatter(&label)
        .x_desc("halls")
        .y_desc(y_desc)
        .draw()
        .map_err(plot_err)?;
    for &(name, c, ref values) in series {
        let points: Vec<(f64, f64)> =
            values.iter().enumerate().map(|(k, &v)| (k as f64, v)).filter(|p| p.1.is_finite()).collect();
        chart
            .draw_series(LineSeries::new(points.clone(), c.stroke_width(2)))
            .map_err(plot_err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(points.into_iter().map(|p| Circle::new(p, 4, c.filled()))).map_err(plot_err)?;
    }
    legend(&mut chart)
}

/// One panel per edit: the incremental baker's error against the time since the edit (log),
/// beside a full re-bake (the old lightmap until it is done, then its own), over the ground
/// truth's noise.
fn plot_editing(path: &Path, e: &super::editing::Editing) -> Result<()> {
    let n = e.rows.len().max(1);
    let root = BitMapBackend::new(path, (460 * n as u32, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    for (area, row) in root.split_evenly((1, n)).iter().zip(&e.rows) {
        let t0 = 0.01;
        let t1 = row.rebake_seconds.max(row.seconds_converged).max(t0 * 10.0) * 1.5;
        let top =
            row.curve.iter().map(|p| p.1).chain([row.error_before, row.rebake_error]).fold(0.0, f64::max);
        let top = (top * 100.0 * 1.15).max(1.0);
        let caption: String = row.label.chars().take(48).collect();
        let mut chart = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d((t0..t1).log_scale(), 0.0..top)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("seconds since the edit (log)")
            .y_desc("error against the ground truth (%)")
            .draw()
            .map_err(plot_err)?;
        // The lightmap shown at a time is the last one measured: a staircase.
        let mut inc: Vec<(f64, f64)> = Vec::new();
        for &(t, err) in &row.curve {
            if let Some(&(_, last)) = inc.last() {
                inc.push((t.max(t0), last));
            }
            inc.push((t.max(t0), err * 100.0));
        }
        chart
            .draw_series(LineSeries::new(inc, PRM_COLOUR.stroke_width(2)))
            .map_err(plot_err)?
            .label("incremental baker")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], PRM_COLOUR.stroke_width(2)));
        let tb = row.rebake_seconds.max(t0);
        let rebake = vec![
            (t0, row.error_before * 100.0),
            (tb, row.error_before * 100.0),
            (tb, row.rebake_error * 100.0),
            (t1, row.rebake_error * 100.0),
        ];
        chart
            .draw_series(LineSeries::new(rebake, REF_COLOUR.stroke_width(2)))
            .map_err(plot_err)?
            .label("full re-bake")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], REF_COLOUR.stroke_width(2)));
        let noise = row.gt_noise * 100.0;
        chart
            .draw_series(DashedLineSeries::new(
                [(t0, noise), (t1, noise)],
                6,
                4,
                PLAIN_COLOUR.stroke_width(1),
            ))
            .map_err(plot_err)?
            .label("ground truth's noise")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], PLAIN_COLOUR.stroke_width(1)));
        legend(&mut chart)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}
