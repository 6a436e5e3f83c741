//! `report.md`: the machine, device, seeds, the command, and every figure, one section per part
//! of the report.

use std::fmt::Write as _;

use prm::Scene;

use super::editing::Editing;
use super::rig::{flicker, Frame};
use super::scale::{ScaleBudget, ScaleRow};
use super::sweeps::{Point, RuntimeSweep};
use super::{Args, Budget, Figures};

/// The whole report: the given level's parts and the scale section, each where it was
/// measured; `plots` says whether the PNGs were written (and are linked), `total` is the
/// report's run time in seconds.
pub fn markdown(
    a: &Args,
    b: &Budget,
    level: Option<(&Scene, &Figures)>,
    scale: Option<&[ScaleRow]>,
    device: &str,
    plots: bool,
    total: f64,
) -> String {
    let mut s = String::new();
    header(&mut s, a, device, total);
    if let Some((scene, f)) = level {
        level_facts(&mut s, b, scene, f);
        remake(&mut s, a, b);
        precompute_section(&mut s, &f.prm, plots);
        runtime_section(&mut s, b, f.prod, &f.runtime, plots);
        reference_section(&mut s, &f.reference);
        rig_section(&mut s, a, b, &f.frames, plots);
        placement_section(&mut s, b, f, plots);
        editing_section(&mut s, b, f.editing.as_ref(), plots);
        super::moving::section(&mut s, f, plots);
    }
    if let Some(rows) = scale {
        scale_section(&mut s, a, rows, plots);
    }
    s
}

fn pct(x: f64) -> String {
    format!("{:.2} %", x * 100.0)
}

fn signed_pct(x: f64) -> String {
    format!("{:+.2} %", x * 100.0)
}

/// An error with the ground truth's noise removed in quadrature, and the raw figure beside it;
/// an error no larger than the noise says so rather than reading 0 %: the ground truth cannot
/// tell it from nothing.
fn pct_clean(error: f64, noise: f64) -> String {
    if error <= noise {
        format!("within the noise ({} raw)", pct(error))
    } else {
        format!("{} ({} raw)", pct((error * error - noise * noise).sqrt()), pct(error))
    }
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{cpu}, {} threads used", rayon::current_num_threads())
}

/// Title, command, machine, device and seeds.
fn header(s: &mut String, a: &Args, device: &str, total: f64) {
    match &a.scene {
        Some(p) => {
            let _ = writeln!(s, "# Accuracy and cost: {}\n", p.display());
        }
        None => {
            let _ = writeln!(s, "# Accuracy and cost against the level's size\n");
        }
    }
    let _ = writeln!(s, "Made by `{}` in {:.0} s.\n", std::env::args().collect::<Vec<_>>().join(" "), total);
    let _ = writeln!(s, "- Machine: {}", machine());
    let _ = writeln!(s, "- GPU device: {device}");
    let _ = writeln!(
        s,
        "- Seeds: {} for every stage, every rig frame's ground truth included (common random numbers)",
        a.seed
    );
}

/// The level, its atlas and what the error is.
fn level_facts(s: &mut String, b: &Budget, scene: &Scene, f: &Figures) {
    let _ = writeln!(
        s,
        "- Level: {} triangles, {} lights; atlas {}²",
        scene.triangles.len(),
        scene.lights.len(),
        b.atlas
    );
    let _ = writeln!(
        s,
        "- Error: DESIGN.md §3 normalised luminance RMSE of the indirect irradiance over \
        covered texels against `prm ground-truth` at {} spp ({:.1} s), whose own noise is **{}**: an error \
        figure includes it (remove it in quadrature for the method's own).\n",
        b.gt_spp,
        f.gt_seconds,
        pct(f.gt_noise)
    );
}

/// How to re-make each figure alone with the CLI.
fn remake(s: &mut String, a: &Args, b: &Budget) {
    let _ = writeln!(
        s,
        "Each figure can be re-made alone: `prm ground-truth SCENE --spp {} --seed {} -o \
        gt.exr`, `prm precompute SCENE --entries N --paths M --clusters C --seed {} -o s.prm`, `prm evaluate \
        SCENE --prm s.prm [--top-k K] -o e.exr` (CPU twin) or `prm render ... --lightmap-out` (GPU), `prm \
        bake-reference SCENE --vpls P --cluster-size K --indirect-only -o r.exr`, then `prm compare X.exr \
        gt.exr`.\n",
        b.gt_spp, a.seed, a.seed
    );
}

/// Rows of label, time, error and bias.
fn budget_rows(s: &mut String, points: &[Point]) {
    for p in points {
        let _ =
            writeln!(s, "| {} | {:.2} s | {} | {:+.2} % |", p.label, p.seconds, pct(p.error), p.bias * 100.0);
    }
}

fn precompute_section(s: &mut String, prm: &[Point], plots: bool) {
    let _ = writeln!(s, "## PRM: precompute budget (all panes, exact weights)\n");
    if plots {
        let _ = writeln!(s, "![error against precompute time](precompute.png)\n");
    }
    let _ = writeln!(
        s,
        "| entries N, paths M, clusters C | precompute | error | bias |\n| --- | --- | --- | --- |"
    );
    budget_rows(s, prm);
}

fn runtime_section(s: &mut String, b: &Budget, prod: (u32, u32, u32), sweep: &RuntimeSweep, plots: bool) {
    let direct_ms = sweep.direct_ms;
    let _ = writeln!(
        s,
        "\n## PRM: runtime budget (N={} M={} C={}, the level's lights)\n",
        prod.0, prod.1, prod.2
    );
    if plots {
        let _ = writeln!(s, "![error against frame time](runtime.png)\n");
    }
    if direct_ms.is_finite() {
        let _ = writeln!(
            s,
            "Frame: {} px wide, shadow maps 1024², median of {} frames each recomposing \
            (lights still, so shadow maps are not re-rendered). Direct-only frame: **{:.2} ms**.\n",
            b.frame_width, b.frame_reps, direct_ms
        );
    } else {
        let _ = writeln!(
            s,
            "No GPU adapter: times are the CPU twin's lightmap (ray-traced entry visibility, \
            weights, selection, compose).\n"
        );
    }
    let _ = writeln!(
        s,
        "K picked at each vertex of the atlas tile grid (local, the runtime's default) or over \
        the whole map; groups stand in for \
        the clusters left out (a tile's, or the map's).\n\n\
        | top-K | frame (ms), local | error, local + groups | bias | error, map + groups | \
        bias | error, map alone | bias |\n| --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for ((p, g), q) in sweep.tile.iter().zip(&sweep.with).zip(&sweep.without) {
        let ratio = if direct_ms.is_finite() {
            format!(" ({:.2}x direct)", p.seconds * 1e3 / direct_ms)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "| {} | {:.2}{} | {} | {:+.2} % | {} | {:+.2} % | {} | {:+.2} % |",
            p.label,
            p.seconds * 1e3,
            ratio,
            pct(p.error),
            p.bias * 100.0,
            pct(g.error),
            g.bias * 100.0,
            pct(q.error),
            q.bias * 100.0
        );
    }
}

fn reference_section(s: &mut String, reference: &[Point]) {
    let _ = writeln!(s, "\n## Reference baker (virtual polygon lights)\n");
    let _ = writeln!(s, "| photons, VPLs per light | bake | error | bias |\n| --- | --- | --- | --- |");
    budget_rows(s, reference);
}

fn rig_section(s: &mut String, a: &Args, b: &Budget, frames: &[Frame], plots: bool) {
    let _ = writeln!(
        s,
        "\n## Moving-light rig ({} frames{})\n",
        frames.len(),
        a.rig.as_ref().map_or(
            ", the level's first light sweeping across the middle 40 % of its width".to_string(),
            |r| format!(", {}", r.display())
        )
    );
    if plots {
        let _ = writeln!(s, "![error and flicker per frame](rig.png)\n");
    }
    let _ = writeln!(
        s,
        "Ground truth per frame at {} spp; reference at {} photons. Flicker: RMS over texels \
        of the change of the (signed luminance) error from the previous frame, over the mean ground truth. \
        Every frame's ground truth has the same seed, so its noise is largely common to consecutive frames \
        and cancels in the change; \"lighting change\" is how much the ground truth itself moved.\n",
        b.rig_gt_spp, b.rig_reference.0
    );
    rig_table(s, frames);
}

/// Per frame: the ground truth's noise, each method's error and, from the second frame, its
/// flicker and the lighting change.
fn rig_table(s: &mut String, frames: &[Frame]) {
    let _ = writeln!(
        s,
        "| frame | GT noise | PRM top-32 | PRM all | reference | flicker top-32 | flicker \
        all | flicker reference | lighting change |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    let fl = flicker(frames);
    for (f, fr) in frames.iter().enumerate() {
        let flick = if f == 0 {
            "| - | - | - | - |".to_string()
        } else {
            let (v, floor) = fl[f - 1];
            format!("| {} | {} | {} | {} |", pct(v[0]), pct(v[1]), pct(v[2]), pct(floor))
        };
        let _ = writeln!(
            s,
            "| {f} | {} | {} | {} | {} {flick}",
            pct(fr.gt_noise),
            pct(fr.errors[0]),
            pct(fr.errors[1]),
            pct(fr.errors[2])
        );
    }
}

/// Error against the light's place: the torch rig's keyframes and the height sweep.
fn placement_section(s: &mut String, b: &Budget, f: &Figures, plots: bool) {
    let Some(path) = &f.torches else {
        let _ = writeln!(
            s,
            "\n## Light placement\n\nLeft out: no torch rig (`<level>_torches.json` or --torches)."
        );
        return;
    };
    let _ = writeln!(s, "\n## Light placement ({})\n", path.display());
    if plots {
        let _ = writeln!(s, "![error against the distance to the nearest surface](placement.png)\n");
    }
    let _ = writeln!(
        s,
        "Each placement measured as a rig frame: ground truth at {} spp (light paths for the lights' \
        hot spots), reference at {} photons. Errors with the ground truth's own noise removed in \
        quadrature (sqrt(error² - noise²)), the raw figure (the rig table's kind) in brackets; an error \
        no larger than the noise cannot be told from nothing at this many samples. Bias: the signed \
        mean difference over the ground truth's mean (its noise averages out of it). Targets (DESIGN.md §9): \
        5 cm or more from the nearest surface <= 8 % with |bias| <= 3 %, 15 cm from a corner <= 12 %, \
        mid-room <= 5 % (all panes), top-32 within 3 points.\n",
        b.rig_gt_spp, b.rig_reference.0
    );
    let _ = writeln!(
        s,
        "| placement | nearest surface | GT noise | PRM all | bias | PRM top-32 | bias | reference | bias |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for p in &f.placements {
        let noise = p.frame.gt_noise;
        let _ = writeln!(
            s,
            "| {} | {:.3} | {} | {} | {} | {} | {} | {} | {} |",
            p.label,
            p.distance,
            pct(noise),
            pct_clean(p.frame.errors[1], noise),
            signed_pct(p.frame.biases[1]),
            pct_clean(p.frame.errors[0], noise),
            signed_pct(p.frame.biases[0]),
            pct_clean(p.frame.errors[2], noise),
            signed_pct(p.frame.biases[2])
        );
    }
}

/// The halls at each size: what they cost, how right they are, and each figure per hall
/// against the one-hall level's.
fn scale_section(s: &mut String, a: &Args, rows: &[ScaleRow], plots: bool) {
    let b = ScaleBudget::new(a.quick, a.smoke);
    let _ =
        writeln!(s, "\n## Scale: the halls at {} halls\n", join(rows.iter().map(|r| r.rooms().to_string())));
    if plots {
        let _ = writeln!(s, "![cost and error against the number of halls](scale.png)\n");
    }
    let extra = if b.precompute_args.is_empty() {
        String::new()
    } else {
        format!(" {}", b.precompute_args.join(" "))
    };
    let _ = writeln!(
        s,
        "Each level is `prm_precompute::scenes::halls(NX, NZ, {}, {})` (the bundled `halls.glb` is 4 x 4), \
        written to `scale/halls_NXxNZ.glb` without lightmap UVs, and precomputed in its own process as a user \
        runs it: `prm precompute scale/halls_NXxNZ.glb --seed {}{extra} -o scale/halls_NXxNZ.prm` (the maps \
        are kept). Peak memory is that process's high-water mark. GPU memory is what the runtime allocates for \
        the map (`prm info --prm`). Errors against `prm ground-truth` at {} spp with its noise removed in \
        quadrature; top-32 is the default runtime selection (picked locally, groups for the rest), on the \
        device above. Frames: the level's camera at {} px wide, median of {}; the full frame recomposes every \
        time. Targets (issue 13): top-32 within 10 %; `.prm` at most the number of halls times one hall's; \
        precompute peak memory at most 2 GB and at most 2 x the `.prm`; time, memory and size per hall within \
        20 % of one hall's; frame ratio at most 1.10.\n",
        b.pillars.0, b.pillars.1, a.seed, b.gt_spp, b.frame_width, b.frame_reps
    );
    let mb = |x: u64| format!("{:.1} MB", x as f64 / 1e6);
    let _ = writeln!(
        s,
        "| halls | triangles | lights | texels (pages) | entries | clusters | precompute | peak memory | .prm | GPU \
        memory |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} ({} x {}²) | {} | {} | {:.1} s | {} | {} | {} |",
            r.rooms(),
            r.triangles,
            r.lights,
            r.texels,
            r.pages,
            r.page_size,
            r.entries,
            r.clusters,
            r.precompute_s,
            r.peak_bytes.map_or("unknown".into(), mb),
            mb(r.file_bytes),
            mb(r.gpu_bytes),
        );
    }
    let _ = writeln!(
        s,
        "\n| halls | GT noise | top-32 | all panes | top-32 bias | ground truth | direct frame | full frame | \
        ratio |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in rows {
        let frame = match r.frame_ms {
            Some((d, f)) => format!("{d:.2} ms | {f:.2} ms | {:.2}", f / d.max(1e-9)),
            None => "no GPU | no GPU | -".to_string(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:+.2} % | {:.1} s | {frame} |",
            r.rooms(),
            pct(r.gt_noise),
            pct(r.clean(r.top.0)),
            pct(r.clean(r.all.0)),
            r.top.1 * 100.0,
            r.gt_s
        );
    }
    let Some(first) = rows.first() else { return };
    let _ = writeln!(
        s,
        "\nPer hall, over the {}-hall level's (linear growth is 1.00):\n\n| halls | precompute | peak memory | .prm | \
        GPU memory | peak memory / .prm |\n| --- | --- | --- | --- | --- | --- |",
        first.rooms()
    );
    let ratio = |v: f64| if v.is_finite() { format!("{v:.2}") } else { "-".into() };
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            r.rooms(),
            ratio(r.per_hall(first, |r| r.precompute_s)),
            ratio(r.per_hall(first, ScaleRow::peak)),
            ratio(r.per_hall(first, |r| r.file_bytes as f64)),
            ratio(r.per_hall(first, |r| r.gpu_bytes as f64)),
            ratio(r.peak() / r.file_bytes as f64)
        );
    }
}

fn join(items: impl Iterator<Item = String>) -> String {
    let v: Vec<String> = items.collect();
    match v.len() {
        0 => String::new(),
        1 => v[0].clone(),
        n => format!("{} and {}", v[..n - 1].join(", "), v[n - 1]),
    }
}

/// The script of edits: the incremental baker against a full re-bake, and the PRM's `--update`
/// against a full precompute.
fn editing_section(s: &mut String, b: &Budget, e: Option<&Editing>, plots: bool) {
    let Some(e) = e else {
        let _ = writeln!(s, "\n## Editing\n\nLeft out: no edit script (`<level>_edits.json` or --edits).");
        return;
    };
    let _ = writeln!(s, "\n## Editing ({})\n", e.script.display());
    if plots && !e.rows.is_empty() {
        let _ = writeln!(s, "![error against the time since each edit](editing.png)\n");
    }
    let _ = writeln!(
        s,
        "The edits are applied one after the other. Incremental baker (`prm bake`): {} light paths, \
        {} texels, first bake {:.2} s. After each edit its lightmap is measured against the edited \
        level's ground truth ({} spp) as the updates go (the time the measuring takes is left out); \
        a full re-bake of the edited level with the same parameters shows the old lightmap until it \
        is done. *Within a re-bake's noise*: when the lightmap (direct + indirect) first came as \
        close to that re-bake as one bake's own noise (two seeds' bakes' distance over sqrt 2, in \
        brackets), issue 14's convergence; *all updates done* includes consolidation, which \
        exchanges corrections for the re-bake's own cells. Targets (issue 14), for one moved \
        object: 90 % of the invalid flux within 1 s, converged within 25 % of a full bake's time, \
        never further off than before the edit.\n",
        e.budget.paths, e.texels, e.bake_seconds, e.budget.gt_spp
    );
    let _ = writeln!(
        s,
        "| edit | VPLs changed | GT noise | error before | 90 % of invalid flux | no invalid light left | \
        within a re-bake's noise | all updates done | worst while updating | full re-bake |\n\
        | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in &e.rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.2} s | {:.2} s: {} | {:.2} s = {:.0} % of a re-bake ({}) | {:.2} s: {} | {} | {:.2} s: {} |",
            r.label,
            r.vpls_changed,
            pct(r.gt_noise),
            pct(r.error_before),
            r.seconds_90,
            r.seconds_valid,
            pct(r.error_valid),
            r.seconds_within_noise,
            100.0 * r.seconds_within_noise / r.rebake_seconds.max(1e-9),
            pct(r.fresh_noise),
            r.seconds_converged,
            pct(r.error_converged),
            pct(r.error_worst),
            r.rebake_seconds,
            pct(r.rebake_error),
        );
    }
    let (n, m, c) = b.prm[b.production];
    let _ = writeln!(
        s,
        "\nThe PRM (N={n} M={m} C={c}, atlas {}²): `prm precompute --cache` took {:.2} s; after each edit \
        `--update` of the last map against a full precompute of the edited level, both measured \
        with all panes and exact weights against the same ground truth, and against a full \
        precompute that keeps its cache (`--cache`, what an editing loop runs to go on updating; \
        its walks are traced). Target: an update after moving one object within 25 % of a full \
        precompute.\n",
        b.atlas, e.precompute_seconds
    );
    let _ = writeln!(
        s,
        "| edit | tiles hit | texels walked again | `--update` | full precompute | update / full | full with `--cache` | update / that | error, update | error, full |\n\
        | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in &e.rows {
        let u = &r.update;
        let _ = writeln!(
            s,
            "| {} | {} | {} of {} | {:.2} s | {:.2} s | {:.0} % | {:.2} s | {:.0} % | {} | {} |",
            r.label,
            match &u.refused {
                Some(why) => format!("refused ({why}): a full precompute"),
                None => format!("{} of {}", u.tiles_hit, u.tiles),
            },
            if u.refused.is_some() { e.texels } else { u.texels_walked },
            e.texels,
            u.seconds_update,
            u.seconds_full,
            100.0 * u.seconds_update / u.seconds_full.max(1e-9),
            u.seconds_full_cached,
            100.0 * u.seconds_update / u.seconds_full_cached.max(1e-9),
            pct(u.error_update),
            pct(u.error_full),
        );
    }
}
