//! `prm`: the one user-facing binary. Each subcommand lives in its own module.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod bake;
mod bake_reference;
mod bench;
mod bench_cssm;
mod bench_rays;
mod budget;
mod common;
mod compare;
mod evaluate;
mod export_panes;
mod gen_assets;
mod ground_truth;
mod info;
mod moving;
mod precompute;
mod render;
mod render_cssm;
mod report;
mod shard;
mod texels;
#[cfg(feature = "view")]
mod view;
#[cfg(feature = "view")]
mod view_edit;
mod visibility;

/// Precomputed radiance maps: indirect light for static levels under moving lights.
#[derive(Parser)]
#[command(name = "prm", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print triangle, light, texel and lightmap-UV facts about a level.
    Info(info::Args),
    /// Write the lightmap texel set (exit points) as EXR: P.x P.y P.z N.x N.y N.z mask.
    Texels(texels::Args),
    /// Regenerate the bundled scenes in assets/.
    GenAssets(gen_assets::Args),
    /// Measure ray-query throughput (closest hit and occlusion) on a level.
    BenchRays(bench_rays::Args),
    /// Path-trace the ground truth: direct and indirect irradiance per texel, or a camera view.
    GroundTruth(ground_truth::Args),
    /// The error of one lightmap or image against a reference (DESIGN.md §3 metric).
    Compare(compare::Args),
    /// Bake a level's precomputed radiance map (.prm), or (--prepare, --shard) a plan or a part
    /// of one baked in parts.
    Precompute(precompute::Args),
    /// Assemble a precompute baked in parts (--prepare, --shard) into the .prm one machine
    /// writes.
    Merge(shard::MergeArgs),
    /// Write a .prm's pane atlases as EXR pages.
    ExportPanes(export_panes::Args),
    /// Render frames under a (moving) light rig: direct light + the PRM's indirect lightmap
    /// (or, --mode cssm, hierarchical radiosity over precomputed visibility: moving objects).
    Render(render::Args),
    /// Precompute a level's visibility for moving objects (paper 003): a .vis file.
    Visibility(visibility::Args),
    /// The incremental many-light baker (paper 001): bake, then apply a script of edits and
    /// report how fast each converges.
    Bake(bake::Args),
    /// Bake the static reference lightmap with virtual polygon lights (paper 000).
    BakeReference(bake_reference::Args),
    /// Error against run time of every method, and flicker over a rig: report.md + plots.
    Report(report::Args),
    /// Frame time with and without indirect light, compose time and bytes, on the GPU.
    Bench(bench::Args),
    /// A window where the mouse moves a light, or (--edit) drags objects and lights while the
    /// incremental baker converges (built with `--features view`).
    #[cfg(feature = "view")]
    View(view::Args),
    /// The indirect lightmap a .prm gives for the level's lights (CPU, exact weights, all panes).
    Evaluate(evaluate::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{}", error_report(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// An error and its causes as the user reads them: the message, then each cause its parent's
/// message does not already end with. Most of the project's errors name their cause in their
/// own message ("chamber.glb: not a valid glTF 2.0 file: expected value at line 1"), and the
/// plain chain said it twice.
fn error_report(e: &anyhow::Error) -> String {
    let messages: Vec<String> = e.chain().map(|c| c.to_string()).collect();
    let causes: Vec<&String> = messages
        .windows(2)
        .filter(|pair| !pair[0].ends_with(pair[1].as_str()))
        .map(|pair| &pair[1])
        .collect();
    let mut out = format!("Error: {}", messages[0]);
    match causes.as_slice() {
        [] => {}
        [one] => out += &format!("\n\nCaused by:\n    {one}"),
        many => {
            out += "\n\nCaused by:";
            for (i, c) in many.iter().enumerate() {
                out += &format!("\n    {i}: {c}");
            }
        }
    }
    out
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Info(a) => info::run(a),
        Command::Texels(a) => texels::run(a),
        Command::GenAssets(a) => gen_assets::run(a),
        Command::BenchRays(a) => bench_rays::run(a),
        Command::GroundTruth(a) => ground_truth::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Precompute(a) => precompute::run(a),
        Command::Merge(a) => shard::merge(a),
        Command::ExportPanes(a) => export_panes::run(a),
        Command::Evaluate(a) => evaluate::run(a),
        Command::Bake(a) => bake::run(a),
        Command::BakeReference(a) => bake_reference::run(a),
        Command::Render(a) => render::run(a),
        Command::Visibility(a) => visibility::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Report(a) => report::run(a),
        #[cfg(feature = "view")]
        Command::View(a) => view::run(a),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use anyhow::Context;

    /// An error that names its cause in its message and gives it as its source too.
    #[derive(Debug)]
    struct Named {
        source: std::io::Error,
    }

    impl std::fmt::Display for Named {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "level.glb: cannot read file: {}", self.source)
        }
    }

    impl std::error::Error for Named {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.source)
        }
    }

    #[test]
    fn an_error_report_says_each_cause_once() {
        let io = || std::io::Error::new(std::io::ErrorKind::NotFound, "No such file or directory");
        // A cause the message already ends with is not said again.
        let e = anyhow::Error::new(Named { source: io() }).context("loading the level failed");
        assert_eq!(
            error_report(&e),
            "Error: loading the level failed\n\nCaused by:\n    level.glb: cannot read file: No such file or directory"
        );
        // Causes the message does not name are all kept, numbered.
        let e = Err::<(), _>(io()).context("reading the rig").context("rendering").unwrap_err();
        assert_eq!(
            error_report(&e),
            "Error: rendering\n\nCaused by:\n    0: reading the rig\n    1: No such file or directory"
        );
        assert_eq!(
            error_report(&anyhow::anyhow!("--rays 0 is out of range")),
            "Error: --rays 0 is out of range"
        );
    }
}
