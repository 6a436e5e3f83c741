//! Arguments and helpers shared by subcommands.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use prm::density::Atlas;
use prm::{load_scene, LoadOptions, Scene};

/// How to read the level.
#[derive(clap::Args, Clone, Debug)]
pub struct SceneArgs {
    /// The level: glTF 2.0, .gltf or .glb.
    pub scene: PathBuf,
    /// Fail when a primitive has no TEXCOORD_1 instead of generating lightmap UVs.
    #[arg(long)]
    pub require_uv1: bool,
    /// Accept overlapping lightmap UVs (surfaces then share texels, and lighting).
    #[arg(long)]
    pub allow_overlap: bool,
}

/// Check, before any work, that an output file can be made where it is asked for: its folder
/// exists and it is not itself a folder (a long bake must not end in "No such file").
pub fn check_output_file(path: &std::path::Path, inputs: &[&std::path::Path]) -> Result<()> {
    if path.is_dir() {
        bail!("{} is a folder: give the output a file name", path.display());
    }
    if let Some(folder) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !folder.is_dir() {
            bail!("the folder {} does not exist (for the output {})", folder.display(), path.display())
        }
    }
    if let Some(input) = inputs.iter().find(|i| same_file(path, i)) {
        bail!(
            "the output {} is the input {}: writing it would destroy what it is made from",
            path.display(),
            input.display()
        );
    }
    Ok(())
}

/// Whether `a` and `b` name one file: by another spelling (`./a.glb`), through a symbolic
/// link, or (on unix) as two hard links to it. Paths that are not there yet are compared by
/// their resolved folder and name.
pub fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return (x.dev(), x.ino()) == (y.dev(), y.ino());
        }
    }
    let resolved = |p: &std::path::Path| -> Option<PathBuf> {
        if let Ok(p) = p.canonicalize() {
            return Some(p);
        }
        let folder = p.parent().filter(|f| !f.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
        Some(folder.canonicalize().ok()?.join(p.file_name()?))
    };
    matches!((resolved(a), resolved(b)), (Some(x), Some(y)) if x == y)
}

/// An output folder this run writes into. If the run made it and then fails, it goes again
/// with what was written into it (no half-written results); one that was there before is
/// left as it is. [`OutputFolder::keep`] once the run has succeeded.
pub struct OutputFolder {
    path: std::path::PathBuf,
    made: bool,
}

impl OutputFolder {
    pub fn create(path: &std::path::Path) -> Result<OutputFolder> {
        let creating = || format!("creating {}", path.display());
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).with_context(creating)?;
        }
        // Made here only if this call made it: a folder that is there (`out/..`, `.`, another
        // run's made a moment ago) is never this run's to remove.
        let made = match std::fs::create_dir(path) {
            Ok(()) => true,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && path.is_dir() => false,
            Err(e) => return Err(e).with_context(creating),
        };
        Ok(OutputFolder { path: path.to_path_buf(), made })
    }

    /// The run succeeded: the folder stays.
    pub fn keep(mut self) {
        self.made = false;
    }
}

impl Drop for OutputFolder {
    fn drop(&mut self) {
        if self.made {
            // Best effort: the run's own error is the one to report.
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

/// Largest accepted atlas side: 16384^2 texels is already a 4 GiB texel set.
pub const MAX_ATLAS: u32 = 16384;

/// Check an atlas size given on the command line.
pub fn check_atlas(atlas: u32) -> Result<()> {
    if atlas == 0 || atlas > MAX_ATLAS {
        bail!("--atlas {atlas} is out of range: use 1 to {MAX_ATLAS}");
    }
    Ok(())
}

/// The lightmap's size: given in texels, or from a texel size in metres.
#[derive(clap::Args, Clone, Debug)]
pub struct AtlasArgs {
    /// Atlas width and height in texels, one page (default: what --texel-size gives the
    /// level's surface, at least 256).
    #[arg(long)]
    pub atlas: Option<u32>,
    /// World size of a lightmap texel in metres, when --atlas is not given.
    #[arg(long, default_value_t = prm::density::DEFAULT_TEXEL_SIZE)]
    pub texel_size: f32,
    /// Side of a lightmap page in texels, for a level without lightmap UVs that needs more than
    /// one page at --texel-size (a multiple of 16, 64 to 8192).
    #[arg(long, default_value_t = prm::density::DEFAULT_PAGE_SIZE)]
    pub page_size: u32,
}

impl AtlasArgs {
    /// The level loaded for this lightmap size, and its atlas.
    pub fn load(&self, args: &SceneArgs, quiet: bool) -> Result<(Scene, Atlas)> {
        if let Some(atlas) = self.atlas {
            check_atlas(atlas)?;
            return Ok((load(args, atlas, quiet)?, Atlas::single(atlas)));
        }
        let bad = |e: String| anyhow::anyhow!("bad parameter: {e}");
        prm::density::check_texel_size(self.texel_size).map_err(bad)?;
        prm::density::check_page_size(self.page_size).map_err(bad)?;
        let scene = load_with(args, None, self.texel_size, self.page_size, quiet)?;
        let atlas = prm::density::atlas(&scene, self.texel_size).map_err(anyhow::Error::msg)?;
        Ok((scene, atlas))
    }
}

/// Load the level, printing what the loader had to fix or generate.
pub fn load(args: &SceneArgs, atlas: u32, quiet: bool) -> Result<Scene> {
    load_with(args, Some(atlas), prm::density::DEFAULT_TEXEL_SIZE, prm::density::DEFAULT_PAGE_SIZE, quiet)
}

/// Load the level as a map with this header was baked for it: generated UVs in the map's
/// pages at its texel size, or packed for its one page.
pub fn load_for(args: &SceneArgs, header: &prm::prm_file::Header, quiet: bool) -> Result<Scene> {
    if header.pages > 1 || header.page_texel_size > 0.0 {
        load_with(args, None, header.page_texel_size, header.atlas_width, quiet)
    } else {
        load(args, header.atlas_width, quiet)
    }
}

/// The level for a process that only traces rays through it (a precompute's shard): its
/// lightmap UVs neither generated nor checked ([`LoadOptions::skip_lightmap_uvs`]).
pub fn load_for_rays(args: &SceneArgs, quiet: bool) -> Result<Scene> {
    let opts = LoadOptions {
        require_uv1: args.require_uv1,
        allow_overlap: args.allow_overlap,
        skip_lightmap_uvs: true,
        ..Default::default()
    };
    let scene = load_scene(&args.scene, &opts).with_context(|| "loading the level failed")?;
    if !quiet && scene.report.degenerate_dropped > 0 {
        eprintln!("note: {} zero-area triangle(s) dropped", scene.report.degenerate_dropped);
    }
    Ok(scene)
}

/// [`load`] with generated UVs packed for `atlas`, or for what `texel_size` gives the level in
/// pages of `page_size`.
fn load_with(
    args: &SceneArgs,
    atlas: Option<u32>,
    texel_size: f32,
    page_size: u32,
    quiet: bool,
) -> Result<Scene> {
    let opts = LoadOptions {
        require_uv1: args.require_uv1,
        allow_overlap: args.allow_overlap,
        unwrap_resolution: atlas.map(|a| a.clamp(16, prm::density::MAX_DENSITY_ATLAS)),
        texel_size,
        page_size,
        skip_lightmap_uvs: false,
    };
    let scene = load_scene(&args.scene, &opts).with_context(|| "loading the level failed")?;
    if !quiet {
        for note in &scene.report.notes {
            eprintln!("note: {note}");
        }
        if scene.report.degenerate_dropped > 0 {
            eprintln!("note: {} zero-area triangle(s) dropped", scene.report.degenerate_dropped);
        }
    }
    Ok(scene)
}

/// The process-wide Ctrl-C flag: the first Ctrl-C sets it and long stages stop at their next
/// chunk, leaving no output file; a second Ctrl-C exits at once.
pub fn cancel_flag() -> &'static std::sync::atomic::AtomicBool {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::OnceLock;
    static FLAG: AtomicBool = AtomicBool::new(false);
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        let _ = ctrlc::set_handler(|| {
            if FLAG.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
            eprintln!("\nstopping (Ctrl-C again to quit at once); no output will be written");
        });
    });
    &FLAG
}

/// A progress bar with rate and ETA on stderr.
pub fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    let style =
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {per_sec} ETA {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> ");
    bar.set_style(style);
    bar.set_message(what.to_string());
    bar
}

/// Which lights to use: the level's, or a rig's frame.
#[derive(clap::Args, Clone, Debug)]
pub struct RigArgs {
    /// Light rig (JSON, see README); without one the level's glTF lights are used.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// Frame of the rig to use.
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
    /// Frames the rig's duration is divided into.
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
}

impl RigArgs {
    /// The rig (the level's lights when none is given).
    pub fn rig(&self, scene: &Scene) -> Result<prm::rig::Rig> {
        load_rig(self.rig.as_deref(), scene)
    }

    /// The lights of the chosen frame.
    pub fn lights(&self, scene: &Scene) -> Result<Vec<prm::Light>> {
        if self.frames == 0 || self.frame >= self.frames {
            bail!("--frame {} must be below --frames {}", self.frame, self.frames);
        }
        Ok(self.rig(scene)?.frame(self.frame, self.frames))
    }
}

/// A rig file read against the level's lights, or the level's lights unmoving.
pub fn load_rig(path: Option<&std::path::Path>, scene: &Scene) -> Result<prm::rig::Rig> {
    match path {
        Some(p) => Ok(prm::rig::Rig::load(p, &scene.lights)?),
        None => Ok(prm::rig::Rig::from_lights(&scene.lights)),
    }
}

/// A level and its `.prm`: what every command that lights a level from its map reads.
#[derive(clap::Args, Clone, Debug)]
pub struct MapArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The level's .prm.
    #[arg(long)]
    pub prm: PathBuf,
}

impl MapArgs {
    /// The level and its map, refused if the map was baked for another level.
    pub fn load(&self) -> Result<(Scene, prm::prm_file::Prm)> {
        load_with_prm(&self.scene, &self.prm)
    }
}

/// Where the runtime's pane budget applies (`prm_runtime::Budget`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BudgetArg {
    /// At each vertex of the atlas tile grid, the K panes that bring the tiles around it the
    /// most light, blended over each tile from its corners.
    Local,
    /// The K panes that bring the whole map the most light, everywhere.
    Global,
}

impl From<BudgetArg> for prm_runtime::Budget {
    fn from(b: BudgetArg) -> Self {
        match b {
            BudgetArg::Local => prm_runtime::Budget::Local,
            BudgetArg::Global => prm_runtime::Budget::Global,
        }
    }
}

/// How many panes the runtime composes per frame.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct ComposeArgs {
    /// Panes composed per frame: the strongest by luminance(weight) x energy.
    #[arg(long, default_value_t = 32)]
    pub top_k: usize,
    /// Where --top-k applies: local (picked at each vertex of the atlas tile grid), or one
    /// list for the whole map.
    #[arg(long, value_enum, default_value_t = BudgetArg::Local)]
    pub budget: BudgetArg,
    /// Drop the left-out clusters' light instead of composing their groups' panes for it.
    #[arg(long)]
    pub no_residual: bool,
    /// GPU memory for the map's tables and the shadow maps, in MB (1e6 bytes): beyond it,
    /// atlas tiles out of the camera's view go first (farthest first), then the shadow maps
    /// halve, then tiles in view; what went is printed (default: no limit).
    #[arg(long)]
    pub gpu_budget: Option<f64>,
    /// Probe every light's shadow maps at every entry cell, even where the maps' blocks show
    /// the light hidden from the whole cell (a side-by-side measure of that culling: the
    /// lightmap is the same).
    #[arg(long)]
    pub no_light_culling: bool,
    /// Compose every atlas tile at every update, even those no changed pane or near-field sum
    /// reaches (a side-by-side measure of composing only the changed tiles: the lightmap is
    /// the same).
    #[arg(long)]
    pub recompose_all: bool,
    /// How far an atlas tile's light from its panes, or a near-field sum in it, may move (a
    /// share of the tile's light) and still leave the tile as it is (0: only the same bits do).
    #[arg(long, default_value_t = 0.0)]
    pub recompose_tolerance: f32,
    /// Tiles per side of a directional light's shadow map at most (1 to 16; 1: one map over
    /// the whole level). A tile covers at most 4 m of the level (a room 8 m across gets 3 x 3),
    /// up to this many a side; a wider level's tiles are wider.
    #[arg(long, default_value_t = prm_runtime::memory::SUN_TILES_MAX)]
    pub sun_tiles: u32,
}

impl ComposeArgs {
    /// The runtime's parameters with these, refused as the GPU runtime would (the CPU twin
    /// would take them silently).
    pub fn runtime(&self, shadow_size: u32) -> Result<prm_runtime::RuntimeParams> {
        if self.top_k == 0 {
            bail!("--top-k must be at least 1");
        }
        let p = prm_runtime::RuntimeParams {
            top_k: self.top_k,
            budget: self.budget.into(),
            shadow_size,
            residual: !self.no_residual,
            cull_hidden_lights: !self.no_light_culling,
            recompose_changed_only: !self.recompose_all,
            recompose_tolerance: self.recompose_tolerance,
            sun_tiles: self.sun_tiles,
        };
        p.check().map_err(|e| anyhow::anyhow!("bad parameter: {e}"))?;
        Ok(p)
    }
}

/// A `.prm` and the level it must have been baked for (loaded at the map's atlas size).
pub fn load_with_prm(args: &SceneArgs, prm_path: &std::path::Path) -> Result<(Scene, prm::prm_file::Prm)> {
    let map = prm::prm_file::Prm::read(prm_path, None).with_context(|| "reading the radiance map failed")?;
    let scene = load_for(args, map.header(), false)?;
    map.check_scene(prm_path, &scene)?;
    Ok((scene, map))
}

/// The glTF node names of the level file, by node index (empty if it does not parse: the
/// loader has already said why).
#[cfg(feature = "view")]
pub fn node_names(level: &std::path::Path) -> Vec<Option<String>> {
    gltf::Gltf::open(level)
        .map(|g| g.nodes().map(|n| n.name().map(str::to_string)).collect())
        .unwrap_or_default()
}

/// Warn (on stderr) of every sphere light that reaches into the level's geometry
/// ([`prm::Bvh::geometry_inside_sphere`]): the bakers give the surfaces inside it its surface
/// brightness.
pub fn warn_spheres_in_geometry(scene: &Scene, bvh: &prm::Bvh) {
    for l in &scene.lights {
        if let (Some(t), prm::light::Aperture::Sphere { radius }) =
            (bvh.geometry_inside_sphere(l), &l.aperture)
        {
            eprintln!(
                "warning: sphere light \"{}\" (radius {radius:.4} m) has geometry {t:.3} m from its centre, inside \
                 it: the surfaces there get its surface brightness; a smaller radius or a light moved off the \
                 surface avoids it",
                l.name
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_file_is_known_by_any_of_its_names() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.glb"), dir.path().join("b.glb"));
        std::fs::write(&a, b"level").unwrap();
        std::fs::write(&b, b"level").unwrap();
        assert!(same_file(&a, &dir.path().join(".").join("a.glb")));
        assert!(!same_file(&a, &b), "two files of the same bytes are two files");
        // Not there yet: by folder and name.
        let x = dir.path().join("x.exr");
        assert!(same_file(&x, &dir.path().join(".").join("x.exr")));
        assert!(!same_file(&x, &a));
        #[cfg(unix)]
        {
            let link = dir.path().join("link.glb");
            std::fs::hard_link(&a, &link).unwrap();
            assert!(same_file(&link, &a), "a hard link is the file");
            assert!(check_output_file(&link, &[&a]).unwrap_err().to_string().contains("is the input"));
        }
        assert!(check_output_file(&b, &[&a]).is_ok());
    }
}
