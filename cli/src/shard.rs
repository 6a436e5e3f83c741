//! A precompute in parts (`prm_precompute::shard`): `prm precompute --prepare` writes the plan,
//! `prm precompute --shard I/N --plan PLAN` one part, `prm merge` the map.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use prm::{Bvh, Scene};
use prm_precompute::precompute::{Phase, PrecomputeParams};
use prm_precompute::shard::{self, Plan, ShardError};
use serde_json::json;

use crate::common::{cancel_flag, load_for_rays};
use crate::precompute::{peak_rss, with_threads, Args as PrecomputeArgs, PhaseBar};

/// The error a sharded step ends with: what failed, and that OUTPUT was not written.
fn failed(e: ShardError, output: &std::path::Path) -> anyhow::Error {
    match e {
        ShardError::Precompute(prm_precompute::precompute::PrecomputeError::Cancelled(_)) => {
            anyhow!("stopped by Ctrl-C; {} not written", output.display())
        }
        e => anyhow!("{e}; {} not written", output.display()),
    }
}

/// `prm precompute --prepare`: the plan of `scene` with parameters `p`, written to OUTPUT.
pub fn prepare(
    a: &PrecomputeArgs,
    (scene, bvh): (&Scene, &Bvh),
    p: &PrecomputeParams,
    start: Instant,
    progress: &(dyn Fn(Phase, usize, usize) + Sync),
    bar: &PhaseBar,
) -> Result<()> {
    let made = shard::plan(scene, bvh, p, progress, cancel_flag());
    bar.finish();
    let (mut plan, report) = made.map_err(|e| failed(e, &a.output))?;
    let bytes = plan.write(&a.output).map_err(|e| failed(e, &a.output))?;
    let v = json!({
        "plan": a.output.display().to_string(),
        "checksum": format!("{:016x}", plan.checksum),
        "bytes": bytes,
        "texels": plan.texels(),
        "entries": report.entries,
        "clusters": report.clusters,
        "seconds_plan": report.seconds_total,
        "seconds_wall": start.elapsed().as_secs_f64(),
        "peak_memory_bytes": peak_rss(),
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "{} -> {}: the plan of a precompute in parts ({} texels to share out, {} entries, {} clusters), \
             {:.1} MB, {:.2} s; next: prm precompute {} --shard I/N --plan {} -o PART for I = 0 .. N - 1, \
             then prm merge --plan {} PART... -o LEVEL.prm",
            a.scene.scene.display(),
            a.output.display(),
            plan.texels(),
            report.entries,
            report.clusters,
            bytes as f64 / 1e6,
            report.seconds_total,
            a.scene.scene.display(),
            a.output.display(),
            a.output.display()
        );
    }
    Ok(())
}

/// `prm precompute --shard I/N --plan PLAN`: the part, written to OUTPUT.
pub fn run_shard(a: &PrecomputeArgs, index: u32, count: u32) -> Result<()> {
    let start = Instant::now();
    let plan_path = a.plan.as_ref().ok_or_else(|| anyhow!("--shard needs --plan PLAN (from --prepare)"))?;
    let plan = Plan::read_walks(plan_path).map_err(|e| failed(e, &a.output))?;
    let scene = load_for_rays(&a.scene, a.json)?;
    let bvh = Bvh::build(&scene);
    let bar = PhaseBar::new(a.json);
    let on_progress = |phase: Phase, done: usize, total: usize| bar.update(phase, done, total);
    let ran = shard::run_shard(&scene, &bvh, &plan, index, count, &a.output, &on_progress, cancel_flag());
    bar.finish();
    let r = ran.map_err(|e| failed(e, &a.output))?;
    if a.json {
        let mut v = serde_json::to_value(&r)?;
        v["part"] = a.output.display().to_string().into();
        v["seconds_wall"] = start.elapsed().as_secs_f64().into();
        v["peak_memory_bytes"] = peak_rss().into();
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "shard {index}/{count} of {} -> {}: texels {}..{}, {:.1} MB, {:.2} s walking ({:.2} Mrays/s)",
            plan_path.display(),
            a.output.display(),
            r.texels.start,
            r.texels.end,
            r.bytes as f64 / 1e6,
            r.seconds_transport,
            r.rays as f64 / r.seconds_transport.max(1e-9) / 1e6
        );
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct MergeArgs {
    /// The plan the parts were walked from (`prm precompute --prepare`).
    #[arg(long)]
    plan: PathBuf,
    /// All N parts (`prm precompute --shard I/N`), in any order.
    #[arg(required = true)]
    parts: Vec<PathBuf>,
    /// Output .prm file: the same bytes as `prm precompute` with the plan's options.
    #[arg(short, long)]
    output: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

/// `prm merge`.
pub fn merge(a: MergeArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> =
        std::iter::once(&a.plan).chain(&a.parts).map(|p| p.as_path()).collect();
    crate::common::check_output_file(&a.output, &inputs)?;
    with_threads(a.threads, || {
        let start = Instant::now();
        let plan = Plan::read(&a.plan).map_err(|e| failed(e, &a.output))?;
        let bar = PhaseBar::new(a.json);
        let on_progress = |phase: Phase, done: usize, total: usize| bar.update(phase, done, total);
        let merged = shard::merge(plan, &a.parts, &on_progress, cancel_flag());
        bar.finish();
        let (prm, report) = merged.map_err(|e| failed(e, &a.output))?;
        if cancel_flag().load(std::sync::atomic::Ordering::Relaxed) {
            anyhow::bail!("stopped by Ctrl-C; {} not written", a.output.display());
        }
        let bytes = prm.write(&a.output).with_context(|| format!("writing {}", a.output.display()))?;
        let mut v = serde_json::to_value(&report)?;
        v["output"] = a.output.display().to_string().into();
        v["parts"] = a.parts.len().into();
        v["file_bytes"] = bytes.into();
        v["seconds_wall"] = start.elapsed().as_secs_f64().into();
        v["peak_memory_bytes"] = peak_rss().into();
        if a.json {
            println!("{}", serde_json::to_string_pretty(&v)?);
        } else {
            println!(
                "{} + {} parts -> {}: {} clusters, {} texels, {} tiles kept, {} dropped, {:.1} MB, {:.2} s",
                a.plan.display(),
                a.parts.len(),
                a.output.display(),
                report.clusters,
                report.texels,
                report.tiles_kept,
                report.tiles_dropped,
                bytes as f64 / 1e6,
                start.elapsed().as_secs_f64()
            );
        }
        Ok(())
    })
}
