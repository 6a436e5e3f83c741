//! glTF 2.0 (`.gltf` and `.glb`) into a world-space [`Scene`].
//!
//! What is read: meshes through the node hierarchy (matrix or TRS), triangle primitives,
//! normals (generated when absent), `baseColorFactor` x `baseColorTexture` as linear albedo,
//! `emissiveFactor` x `KHR_materials_emissive_strength`, `TEXCOORD_1` as lightmap UVs,
//! `KHR_lights_punctual` lights (units: [`crate::light`]) and perspective cameras.
//!
//! A node whose extras are `{"prm": {"movable": true}}` is a rigid object that may move at run
//! time ([`crate::scene::Movable`]): its subtree's triangles carry its object number. A movable
//! without geometry or inside another movable is an error naming it.
//!
//! Bad input is an error that names the file and the place (mesh, primitive, index): a missing
//! or unreadable file, a non-finite position, an out-of-range index, an albedo outside [0, 1],
//! negative or non-finite light intensity, overlapping lightmap UVs (unless allowed).
//! Zero-area triangles are dropped and counted in [`crate::scene::LoadReport`].

mod error;
mod lightmap;
mod lights;
mod material;
mod nodes;
mod primitive;
mod texture;

use std::path::Path;

pub use error::{Place, SceneError};
pub use texture::srgb_to_linear;

use crate::scene::{LoadReport, Material, Scene};

/// How to load a level.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// A primitive without `TEXCOORD_1` is an error instead of getting generated UVs.
    pub require_uv1: bool,
    /// Overlapping lightmap UVs are reported instead of being an error.
    pub allow_overlap: bool,
    /// Atlas resolution generated lightmap UVs are packed for (chart padding is 2 texels there);
    /// `None`: the layout [`crate::density::unwrap_layout`] gives the level at `texel_size`.
    pub unwrap_resolution: Option<u32>,
    /// World size in metres of a texel of generated UVs when `unwrap_resolution` is `None`.
    pub texel_size: f32,
    /// Side of a page of generated UVs when `unwrap_resolution` is `None` and the level needs
    /// more than one page at `texel_size` ([`crate::density::unwrap_layout`]).
    pub page_size: u32,
    /// Leave lightmap UVs alone: a primitive without `TEXCOORD_1` gets none generated (zeros)
    /// and the lightmap UVs are not checked. For a process that only traces rays through the
    /// level (a precompute's shard: its texels come from the plan), where generating them
    /// would cost seconds on a large level for nothing.
    pub skip_lightmap_uvs: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            require_uv1: false,
            allow_overlap: false,
            unwrap_resolution: Some(256),
            texel_size: crate::density::DEFAULT_TEXEL_SIZE,
            page_size: crate::density::DEFAULT_PAGE_SIZE,
            skip_lightmap_uvs: false,
        }
    }
}

/// Load a level file into a world-space scene.
pub fn load_scene(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Scene, SceneError> {
    let path = path.as_ref();
    regular_file(path, path)?;
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io { path: path.into(), source })?;
    // The gltf crate is not hardened against every malformed file; a panic inside it must
    // still reach the user as an error naming the file.
    let result =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load_from_bytes(path, &bytes, opts)));
    match result {
        Ok(r) => r,
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "the reader failed".into());
            Err(SceneError::Malformed { path: path.into(), what })
        }
    }
}

/// The steps of reading a file, in order; the first error stops it.
fn load_from_bytes(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<Scene, SceneError> {
    let (document, buffers) = parse(path, bytes)?;
    let mut scene = Scene { source: path.display().to_string(), ..Default::default() };
    let mut report = LoadReport::default();
    let (materials, texture_of) = material::read_materials(path, &document)?;
    scene.materials = materials;
    scene.textures = texture::read_textures(path, &document, &buffers, &texture_of)?;
    let default_material = scene.materials.len() as u32;
    scene.materials.push(Material::default());

    let reader = nodes::NodeReader { path, buffers: &buffers, texture_of: &texture_of, default_material };
    let mut prims = Vec::new();
    scene.node_names = document.nodes().map(|n| nodes::node_name(&n)).collect();
    nodes::walk(path, &document, &mut scene, |node, world, object, scene| {
        reader.read_node(node, world, object, &mut prims, scene, &mut report)
    })?;

    if report.non_triangle_primitives > 0 {
        report.notes.push(format!(
            "{} primitive(s) of points or lines left out: only triangles take part in the light",
            report.non_triangle_primitives
        ));
    }
    report.primitives_without_uv1 = lightmap::count_missing(path, &prims, opts)?;
    if prims.iter().all(|p| p.indices.is_empty()) {
        return Err(SceneError::NoGeometry { path: path.into() });
    }
    if opts.skip_lightmap_uvs {
        for p in prims.iter_mut().filter(|p| p.uv1.is_none()) {
            p.uv1 = Some(vec![glam::Vec2::ZERO; p.positions.len()]);
        }
    } else if report.primitives_without_uv1 > 0 {
        lightmap::generate(path, &mut prims, opts, &mut report)?;
    }
    primitive::join_primitives(path, prims, &mut scene, &mut report)?;
    if scene.triangles.is_empty() {
        return Err(SceneError::NoGeometry { path: path.into() });
    }
    for (k, m) in scene.movables.iter().enumerate() {
        if !scene.triangles.iter().any(|t| t.object == k as u32 + 1) {
            let what = "it has no geometry (no mesh with triangles in its subtree)".into();
            return Err(SceneError::Movable { path: path.into(), node: m.name.clone(), what });
        }
    }
    if !opts.skip_lightmap_uvs {
        lightmap::check(path, &scene, opts, &mut report)?;
    }
    scene.report = report;
    Ok(scene)
}

/// The glTF document and its buffers (a `.glb`'s own, or files beside `path`).
fn parse(path: &Path, bytes: &[u8]) -> Result<(gltf::Document, Vec<gltf::buffer::Data>), SceneError> {
    let gerr = |source| SceneError::Gltf { path: path.into(), source };
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice(bytes).map_err(gerr)?;
    let base = path.parent().unwrap_or(Path::new("."));
    let buffers = document.buffers().filter_map(|b| match b.source() {
        gltf::buffer::Source::Uri(u) => Some(u),
        gltf::buffer::Source::Bin => None,
    });
    let images = document.images().filter_map(|i| match i.source() {
        gltf::image::Source::Uri { uri, .. } => Some(uri),
        gltf::image::Source::View { .. } => None,
    });
    for uri in buffers.chain(images) {
        for file in uri_files(base, uri) {
            regular_file(path, &file)?;
        }
    }
    let buffers = gltf::import_buffers(&document, path.parent(), blob).map_err(gerr)?;
    Ok((document, buffers))
}

/// The files a buffer or image URI may name, as the gltf crate reads it: `file:` and
/// `file://` give a path as it stands, anything else is relative to `base` and percent-encoded
/// (both spellings are given where they differ); `data:` and other schemes name none.
fn uri_files(base: &Path, uri: &str) -> Vec<std::path::PathBuf> {
    let decoded = |s: &str| -> String {
        let b = s.as_bytes();
        let (mut out, mut i) = (Vec::with_capacity(b.len()), 0);
        while i < b.len() {
            let hex = b.get(i + 1..i + 3).and_then(|h| std::str::from_utf8(h).ok());
            match (b[i], hex.and_then(|h| u8::from_str_radix(h, 16).ok())) {
                (b'%', Some(v)) => {
                    out.push(v);
                    i += 3;
                }
                (c, _) => {
                    out.push(c);
                    i += 1;
                }
            }
        }
        String::from_utf8_lossy(&out).into_owned()
    };
    let (raw, relative) = if let Some(p) = uri.strip_prefix("file://") {
        (p, false)
    } else if let Some(p) = uri.strip_prefix("file:") {
        (p, false)
    } else if uri.starts_with("data:") || uri.contains("://") {
        return Vec::new();
    } else {
        (uri, true)
    };
    let mut files: Vec<std::path::PathBuf> = vec![raw.into(), decoded(raw).into()];
    if relative {
        files = files.into_iter().map(|f| base.join(f)).collect();
    }
    files.dedup();
    files
}

/// Refuse `file` (the level `path`, or a file it names) if it is there but is not a regular
/// file: reading a pipe or a device (/dev/zero) never ends. One that is not there is left to
/// the reader, which names it.
pub(super) fn regular_file(path: &Path, file: &Path) -> Result<(), SceneError> {
    match std::fs::metadata(file) {
        Ok(m) if !m.is_file() => Err(SceneError::Malformed {
            path: path.into(),
            what: format!("{} is not a regular file (a folder, pipe or device)", file.display()),
        }),
        _ => Ok(()),
    }
}
