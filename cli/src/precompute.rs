//! `prm precompute`: bake a level's precomputed radiance map into a `.prm` file.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use prm::prm_file::Prm;
use prm::Bvh;
use prm_precompute::precompute::{
    precompute_with, Baked, Density, Phase, PrecomputeError, PrecomputeParams, Reuse,
};
use prm_precompute::transport::Estimator;
use prm_precompute::update::UpdateCache;
use serde_json::json;

use crate::common::{cancel_flag, progress_bar, AtlasArgs, SceneArgs};

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Preset {
    Preview,
    Production,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum EstimatorArg {
    /// Texel-side walks credited to the cluster whose region they hit (default).
    Gather,
    /// Paper 004's virtual point lights with a clamped 1/r².
    Scatter,
    /// Gather walks plus one entry per cluster, first bounce combined by MIS.
    Mis,
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output .prm file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Parameter preset; the options below override it.
    #[arg(long, value_enum, default_value = "production", conflicts_with = "shard")]
    preset: Preset,
    /// Entry points N (default: the preset's entries per m^2 of surface, at least its count).
    #[arg(long)]
    entries: Option<u32>,
    /// Light paths: per texel (gather) or per entry (scatter).
    #[arg(long)]
    paths: Option<u32>,
    /// Clusters C, one pane each (default: one per 16 entries, at least the preset's count).
    #[arg(long)]
    clusters: Option<u32>,
    #[command(flatten)]
    lightmap: AtlasArgs,
    /// Random seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Pane estimator.
    #[arg(long, value_enum)]
    estimator: Option<EstimatorArg>,
    /// Scatter only: 1/r² is clamped below (clamp x entry spacing)².
    #[arg(long, default_value_t = 0.5, conflicts_with = "shard")]
    clamp: f32,
    /// Pane tile side in texels.
    #[arg(long)]
    tile_size: Option<u32>,
    /// Reach of the near-field links in entry spacings (0: none; default 2.5).
    #[arg(long)]
    near_radius: Option<f32>,
    /// Reach of the near field's echo (its second and third bounce) in entry spacings (0: none;
    /// default 1).
    #[arg(long)]
    echo_radius: Option<f32>,
    /// Leave out the far field (the first bounce of light uneven over a cluster, carried past
    /// the near links to the whole level; on by default).
    #[arg(long)]
    no_far_field: bool,
    /// Walks credit each cluster their next hit lands in, instead of reading the clusters'
    /// first bounce at each vertex from a table (the table is on by default; it needs the far
    /// field and the near links).
    #[arg(long)]
    no_next_bounce: bool,
    /// Leave each pane's power as the walks made it, instead of scaling it to the power its
    /// cells send to the level over every bounce (by their bounce gains; on by default).
    #[arg(long)]
    no_power_match: bool,
    /// Entries farther apart than this, in entry spacings, exchange no far-field light (its
    /// visibility then grows with the level, not its square; default 48, about 26 m at the
    /// production density).
    #[arg(long)]
    far_radius: Option<f32>,
    /// The next-bounce table keeps its weak elements by Russian roulette: those under the
    /// first bounce an albedo-1 cluster facing a cell head-on gives at this many entry
    /// spacings (default 32; 0: every element kept, the walks about 20 % slower).
    #[arg(long)]
    next_cutoff: Option<f32>,
    /// Reach of the geometry-guided pane smoothing in entry spacings (0: none; default 1)
    #[arg(long)]
    smooth: Option<f32>,
    /// Groups of clusters whose summed panes stand in for the clusters a top-K runtime leaves
    /// out (0: none; default: one per 16 clusters, at least 16).
    #[arg(long)]
    groups: Option<u32>,
    /// Relative energy of a pane its dropped tiles may hold.
    #[arg(long)]
    drop_threshold: Option<f64>,
    /// Cap on the walks' bounces (1: the panes hold the first bounce only, as
    /// `prm ground-truth --max-bounces 1` does; default: none but Russian roulette).
    #[arg(long)]
    max_bounces: Option<u32>,
    /// Also write the update cache OUTPUT.cache that a later `--update` needs (where each
    /// atlas tile's walks went, and every pane tile before the drop rule; about the size of
    /// the .prm). Gather estimator only.
    #[arg(long)]
    cache: bool,
    /// Update OLD.prm after an edit of the level: walk again only the texels whose panes the
    /// edit can change (OLD.prm.cache, from `--cache` or an earlier update, says which), keep
    /// OLD's clusters, and write OUTPUT and OUTPUT.cache. Give the same options as OLD's bake.
    /// Where that is impossible (triangles added, another entry count, other options) it
    /// says why and runs a full precompute.
    #[arg(long, value_name = "OLD.prm")]
    update: Option<PathBuf>,
    /// Write the plan of a precompute in parts to OUTPUT instead of a map: everything before
    /// the walks, made once for all shards (`--shard`) and the merge (`prm merge`).
    #[arg(long, conflicts_with_all = ["shard", "cache", "update"])]
    prepare: bool,
    /// Walk shard I of N (0 <= I < N) of the plan given with --plan and write its part to
    /// OUTPUT; `prm merge` makes the map from the plan and all N parts, the same bytes as one
    /// machine's precompute. The parameters are the plan's (a parameter given here is an
    /// error; --texel-size and --page-size are not used).
    #[arg(long, value_name = "I/N", requires = "plan", conflicts_with_all = ["cache", "update"])]
    shard: Option<String>,
    /// The plan (from --prepare) a --shard walks a part of.
    #[arg(long, value_name = "PLAN", requires = "shard")]
    pub plan: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> Result<()> {
    crate::common::check_output_file(&a.output, &[&a.scene.scene])?;
    if let Some(shard) = &a.shard {
        let given = [
            ("--entries", a.entries.is_some()),
            ("--paths", a.paths.is_some()),
            ("--clusters", a.clusters.is_some()),
            ("--atlas", a.lightmap.atlas.is_some()),
            ("--seed", a.seed.is_some()),
            ("--estimator", a.estimator.is_some()),
            ("--tile-size", a.tile_size.is_some()),
            ("--near-radius", a.near_radius.is_some()),
            ("--echo-radius", a.echo_radius.is_some()),
            ("--no-far-field", a.no_far_field),
            ("--no-next-bounce", a.no_next_bounce),
            ("--no-power-match", a.no_power_match),
            ("--far-radius", a.far_radius.is_some()),
            ("--next-cutoff", a.next_cutoff.is_some()),
            ("--smooth", a.smooth.is_some()),
            ("--groups", a.groups.is_some()),
            ("--drop-threshold", a.drop_threshold.is_some()),
            ("--max-bounces", a.max_bounces.is_some()),
        ];
        if let Some((name, _)) = given.iter().find(|g| g.1) {
            bail!("{name} with --shard: a shard's parameters are its plan's; give them to --prepare");
        }
        let (index, count) = parse_shard(shard)?;
        return with_threads(a.threads, || crate::shard::run_shard(&a, index, count));
    }
    let mut p = a.preset.params();
    p.paths = a.paths.unwrap_or(p.paths);
    p.seed = a.seed.unwrap_or(p.seed);
    p.drop_threshold = a.drop_threshold.unwrap_or(p.drop_threshold);
    p.smooth_radius = a.smooth.unwrap_or(p.smooth_radius);
    p.near_radius = a.near_radius.unwrap_or(p.near_radius);
    p.echo_radius = a.echo_radius.unwrap_or(p.echo_radius);
    p.far_field &= !a.no_far_field;
    p.next_bounce &= !a.no_next_bounce;
    p.match_power &= !a.no_power_match;
    p.far_radius = a.far_radius.unwrap_or(p.far_radius);
    p.next_cutoff = a.next_cutoff.unwrap_or(p.next_cutoff);
    p.max_bounces = a.max_bounces.unwrap_or(p.max_bounces);
    p.tile_size = a.tile_size.unwrap_or(p.tile_size);
    if let Some(e) = a.estimator {
        p.estimator = match e {
            EstimatorArg::Gather => Estimator::Gather,
            EstimatorArg::Scatter => Estimator::Scatter { clamp: a.clamp },
            EstimatorArg::Mis => Estimator::Mis,
        };
    }
    // Everything but the level-dependent counts, checked before the level is read.
    p.validate().map_err(|e| anyhow!("bad parameter: {e}"))?;
    with_threads(a.threads, || bake(&a, p))
}

/// `f` on a pool of `threads` worker threads (None: all cores).
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> Result<T> + Send) -> Result<T> {
    if let Some(t @ (0 | 1025..)) = threads {
        bail!("--threads {t} is out of range (1 to 1024; leave it out for all cores)");
    }
    let threads = threads.unwrap_or(0);
    let pool =
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("starting worker threads")?;
    pool.install(f)
}

/// `I/N` of `--shard`: shard I of N, 0 <= I < N.
fn parse_shard(s: &str) -> Result<(u32, u32)> {
    let bad = || {
        anyhow!(
            "--shard {s}: give I/N, shard I of N with 0 <= I < N <= {}",
            prm_precompute::shard::MAX_SHARDS
        )
    };
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (i, n): (u32, u32) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
    if n == 0 || n > prm_precompute::shard::MAX_SHARDS || i >= n {
        return Err(bad());
    }
    Ok((i, n))
}

impl Preset {
    /// The preset's parameters, its counts the floor of what its density gives a level.
    pub fn params(self) -> PrecomputeParams {
        match self {
            Preset::Preview => PrecomputeParams::preview(),
            Preset::Production => PrecomputeParams::production(),
        }
    }

    /// What the preset means per square metre.
    pub fn density(self) -> Density {
        match self {
            Preset::Preview => Density::PREVIEW,
            Preset::Production => Density::PRODUCTION,
        }
    }
}

fn bake(a: &Args, mut p: PrecomputeParams) -> Result<()> {
    let start = Instant::now();
    // An update reads OLD and its cache while the level loads: both are mostly one thread's
    // work (1.9 s and 0.9 s on the 16 chambers).
    let (loaded, old) = std::thread::scope(|s| {
        let old =
            a.update.as_deref().filter(|_| !a.prepare).map(|path| s.spawn(|| read_old(path, &a.output)));
        (a.lightmap.load(&a.scene, a.json), old.map(|h| h.join()))
    });
    let (scene, atlas) = loaded?;
    let old = match old {
        Some(Ok(read)) => Some(read?),
        Some(Err(_)) => bail!("reading the old map failed; {} not written", a.output.display()),
        None => None,
    };
    p.atlas = atlas;
    let area = scene.total_area();
    p.fit_to_area(&a.preset.density(), area, [a.entries, a.clusters, a.groups]);
    p.validate().map_err(|e| anyhow!("bad parameter: {e}"))?;
    // The bake takes at most one cluster an entry and one group a cluster; a count asked for
    // beyond that is refused rather than cut without a word.
    let from = |given: Option<u32>| {
        if given.is_some() {
            ""
        } else {
            ", from the level's area at the preset's density"
        }
    };
    if let Some(c) = a.clusters.filter(|&c| c > p.entries) {
        bail!(
            "--clusters {c} is more than the entries ({}{}): a cluster needs an entry",
            p.entries,
            from(a.entries)
        );
    }
    if let Some(g) = a.groups.filter(|&g| g > p.clusters) {
        bail!(
            "--groups {g} is more than the clusters ({}{}): a group needs a cluster",
            p.clusters,
            from(a.clusters)
        );
    }
    let p = &p;
    let bvh = Bvh::build(&scene);
    let cancel = cancel_flag();
    let bar = PhaseBar::new(a.json);
    let on_progress = |phase: Phase, done: usize, total: usize| bar.update(phase, done, total);
    if a.prepare {
        return crate::shard::prepare(a, (&scene, &bvh), p, start, &on_progress, &bar);
    }
    let keep_cache = a.cache || a.update.is_some();
    // Said before the bake, and as what was asked for: the bake would refuse it as an update.
    if keep_cache && p.estimator != Estimator::Gather {
        bail!(
            "{} needs the gather estimator (this bake: {})",
            if a.update.is_some() { "--update" } else { "--cache" },
            p.estimator
        );
    }
    // Given, not lent: the update lets each go once it is done with it.
    let reuse = match old {
        Some((prm, cache)) => Reuse::Update { cache: cache.into(), old: prm.into() },
        None => Reuse::Nothing,
    };
    let mut result = precompute_with(&scene, &bvh, p, reuse, keep_cache, &on_progress, cancel);
    let mut refused = None;
    if let Err(PrecomputeError::Refused(r)) = &result {
        if a.update.is_some() {
            // The update cannot reuse OLD: say why and bake it whole.
            if !a.json {
                eprintln!("cannot update: {r}; running a full precompute");
            }
            refused = Some(r.to_string());
            result = precompute_with(&scene, &bvh, p, Reuse::Nothing, true, &on_progress, cancel);
        }
    }
    bar.finish();
    let Baked { prm, report, cache } = result.map_err(|e| match e {
        PrecomputeError::Cancelled(_) => anyhow!("stopped by Ctrl-C; {} not written", a.output.display()),
        e => anyhow!("{e}; {} not written", a.output.display()),
    })?;
    let t = Instant::now();
    if cancel.load(std::sync::atomic::Ordering::Relaxed) {
        bail!("stopped by Ctrl-C; {} not written", a.output.display());
    }
    let file_bytes = prm.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
    let cache_path = cache_path(&a.output);
    if let Some(cache) = &cache {
        cache.write(&cache_path, &prm).with_context(|| format!("writing {}", cache_path.display()))?;
    }
    let write_s = t.elapsed().as_secs_f64();
    let mut v = serde_json::to_value(&report)?;
    v["scene"] = a.scene.scene.display().to_string().into();
    v["output"] = a.output.display().to_string().into();
    v["file_bytes"] = file_bytes.into();
    v["seconds_write"] = write_s.into();
    v["seconds_wall"] = start.elapsed().as_secs_f64().into();
    v["peak_memory_bytes"] = peak_rss().map_or(serde_json::Value::Null, |b| b.into());
    v["density"] = json!({
        "surface_area_m2": area,
        "atlas": p.atlas.side,
        "pages": p.atlas.pages,
        "texel_size_m": (area / (report.texels.max(1) as f64)).sqrt(),
        "entries_per_m2": report.entries as f64 / area.max(1e-12),
        "entries_per_cluster": report.entries as f64 / report.clusters.max(1) as f64,
        "groups": p.groups,
        "atlas_from": if a.lightmap.atlas.is_some() { "--atlas" } else { "--texel-size" },
    });
    if let Some(path) = &a.update {
        v["update"] = json!({
            "old": path.display().to_string(),
            "refused": refused,
            "tiles": prm.header().atlas().width().div_ceil(p.tile_size) as u64
                * prm.header().atlas().height().div_ceil(p.tile_size) as u64,
            "tiles_hit": report.update_tiles_hit,
            "tiles_encoded": report.update_tiles_encoded,
            "texels_walked": report.update_texels_walked,
            "rooms_touched": report.update_rooms_touched,
            "entries_settled": report.update_entries_settled,
            "far_pairs_kept": report.update_far_pairs_kept,
            "near_texels_kept": report.update_near_texels_kept,
            "rows_made": report.update_rows_made,
        });
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} -> {}: {} entries ({} inside solids left out), {} clusters, {} texels, {} ({}), {:.2} s \
                (transport {:.2} s, {:.2} Mrays/s), {} tiles kept, {} dropped ({:.3} % of energy), {:.1} MB",
            a.scene.scene.display(),
            a.output.display(),
            report.entries,
            report.entries_enclosed,
            report.clusters,
            report.texels,
            report.estimator,
            json!(report.paths),
            report.seconds_total,
            report.seconds_transport,
            report.rays_per_second / 1e6,
            report.tiles_kept,
            report.tiles_dropped,
            100.0 * report.dropped_energy,
            file_bytes as f64 / 1e6
        );
        let d = &v["density"];
        println!(
            "  density: {:.0} m^2 of surface, atlas {} (from {}), {:.3} m texels, {:.2} entries per m^2, \
                {:.1} entries per cluster, {} groups",
            area,
            p.atlas,
            d["atlas_from"].as_str().unwrap_or(""),
            d["texel_size_m"].as_f64().unwrap_or(0.0),
            d["entries_per_m2"].as_f64().unwrap_or(0.0),
            d["entries_per_cluster"].as_f64().unwrap_or(0.0),
            p.groups
        );
        if a.update.is_some() && refused.is_none() {
            let u = &v["update"];
            println!(
                "  update of {}: the edit reached {} room(s) and {} of {} atlas tiles; {} encoded again, {} \
                    of {} texels walked again ({:.1} %), the rest from {}",
                a.update.as_ref().map_or(String::new(), |p| p.display().to_string()),
                report.update_rooms_touched,
                report.update_tiles_hit,
                u["tiles"],
                report.update_tiles_encoded,
                report.update_texels_walked,
                report.texels,
                100.0 * report.update_texels_walked as f64 / report.texels.max(1) as f64,
                cache_path_of(a.update.as_deref()).display()
            );
        }
        if cache.is_some() {
            println!("  update cache: {}", cache_path.display());
        }
        if report.walks_truncated > 0 || report.unowned_vertices > 0 {
            println!(
                "  note: {} walks cut at the bounce cap, {} path vertices with no owning entry (their \
                light is lost)",
                report.walks_truncated, report.unowned_vertices
            );
        }
    }
    Ok(())
}

/// The progress bar of a precompute's phases (hidden with `--json`).
pub struct PhaseBar {
    bar: Mutex<indicatif::ProgressBar>,
    hidden: bool,
}

impl PhaseBar {
    pub fn new(hidden: bool) -> PhaseBar {
        let bar = progress_bar(1, "texels");
        if hidden {
            bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        PhaseBar { bar: Mutex::new(bar), hidden }
    }

    /// `done` of `total` in `phase`.
    pub fn update(&self, phase: Phase, done: usize, total: usize) {
        let Ok(b) = self.bar.lock() else { return };
        if self.hidden {
            b.set_draw_target(indicatif::ProgressDrawTarget::hidden());
        }
        let name = match phase {
            Phase::Texels => "texels",
            Phase::Entries => "entries",
            Phase::Clustering => "clustering",
            Phase::Transport => "transport",
            Phase::Panes => "panes",
        };
        if b.message() != name {
            b.set_message(name);
            b.set_length(total as u64);
            b.reset_eta();
        }
        b.set_position(done as u64);
    }

    pub fn finish(&self) {
        if let Ok(b) = self.bar.lock() {
            b.finish_and_clear();
        }
    }
}

/// The update cache beside a `.prm`: its name with `.cache` added.
pub fn cache_path(prm: &std::path::Path) -> PathBuf {
    let mut name = prm.as_os_str().to_owned();
    name.push(".cache");
    PathBuf::from(name)
}

fn cache_path_of(prm: Option<&std::path::Path>) -> PathBuf {
    prm.map(cache_path).unwrap_or_default()
}

/// OLD.prm and its update cache, or an error that says which is missing or damaged.
fn read_old(path: &std::path::Path, output: &std::path::Path) -> Result<(Prm, UpdateCache)> {
    let prm = Prm::read(path, None).map_err(|e| anyhow!("{e}; {} not written", output.display()))?;
    let cache_file = cache_path(path);
    if !cache_file.exists() {
        bail!(
            "{} has no update cache ({} is missing): bake it with --cache first; {} not written",
            path.display(),
            cache_file.display(),
            output.display()
        );
    }
    let cache =
        UpdateCache::read(&cache_file, &prm).map_err(|e| anyhow!("{e}; {} not written", output.display()))?;
    Ok((prm, cache))
}

/// Peak resident memory of this process, from /proc (Linux); `None` elsewhere.
pub fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
