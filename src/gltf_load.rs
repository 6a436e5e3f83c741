//! glTF 2.0 (`.gltf` and `.glb`) into a world-space [`Scene`].
//!
//! What is read: meshes through the node hierarchy (matrix or TRS), triangle primitives,
//! normals (generated when absent), `baseColorFactor` x `baseColorTexture` as linear albedo,
//! `emissiveFactor` x `KHR_materials_emissive_strength`, `TEXCOORD_1` as lightmap UVs,
//! `KHR_lights_punctual` lights (units: [`crate::light`]) and perspective cameras.
//!
//! Bad input is an error that names the file and the place (mesh, primitive, index): a missing
//! or unreadable file, a non-finite position, an out-of-range index, an albedo outside [0, 1],
//! negative or non-finite light intensity, overlapping lightmap UVs (unless allowed).
//! Zero-area triangles are dropped and counted in [`crate::scene::LoadReport`].

use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Vec2, Vec3};
use gltf::khr_lights_punctual::Kind;

use crate::light::{Light, LightKind};
use crate::scene::{Camera, LoadReport, Material, Scene, Texture, Triangle};
use crate::uv;

/// How to load a level.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// A primitive without `TEXCOORD_1` is an error instead of getting generated UVs.
    pub require_uv1: bool,
    /// Overlapping lightmap UVs are reported instead of being an error.
    pub allow_overlap: bool,
    /// Atlas resolution generated lightmap UVs are packed for (chart padding is 2 texels there).
    pub unwrap_resolution: u32,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { require_uv1: false, allow_overlap: false, unwrap_resolution: 256 }
    }
}

/// Where in the file a problem is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Place {
    pub mesh: usize,
    pub mesh_name: String,
    pub primitive: usize,
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "mesh {} ('{}') primitive {}", self.mesh, self.mesh_name, self.primitive)
    }
}

/// Everything that can be wrong with a level file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: cannot read file: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a valid glTF 2.0 file: {source}")]
    Gltf { path: PathBuf, source: gltf::Error },
    #[error("{path}: {place}: has no POSITION attribute")]
    MissingPositions { path: PathBuf, place: Place },
    #[error("{path}: {place}: {attribute} accessor reads past the end of its buffer")]
    AccessorOutOfBounds { path: PathBuf, place: Place, attribute: &'static str },
    #[error("{path}: {place}: {attribute} of vertex {vertex} is not finite ({value})")]
    NonFinite { path: PathBuf, place: Place, attribute: &'static str, vertex: usize, value: String },
    #[error("{path}: {place}: index {position} is {value}, but the primitive has {vertex_count} vertices")]
    IndexOutOfRange { path: PathBuf, place: Place, position: usize, value: u32, vertex_count: usize },
    #[error("{path}: {place}: {count} indices is not a whole number of triangles")]
    PartialTriangle { path: PathBuf, place: Place, count: usize },
    #[error("{path}: material {material} ('{name}'): albedo {value:?} is outside [0, 1]")]
    AlbedoOutOfRange { path: PathBuf, material: usize, name: String, value: [f32; 3] },
    #[error("{path}: material {material} ('{name}'): emissive {value:?} is negative or not finite")]
    BadEmissive { path: PathBuf, material: usize, name: String, value: [f32; 3] },
    #[error("{path}: light {light} ('{name}'): {what}")]
    BadLight { path: PathBuf, light: usize, name: String, what: String },
    #[error("{path}: node {node}: transform is not finite or is singular")]
    BadTransform { path: PathBuf, node: usize },
    #[error("{path}: {place}: no TEXCOORD_1 (lightmap UVs) and --require-uv1 was given")]
    MissingUv1 { path: PathBuf, place: Place },
    #[error(
        "{path}: lightmap UVs overlap: {first} and {second} share UV area ({pairs} overlapping pairs in \
        all); two surfaces would share texels. Fix the UVs or pass --allow-overlap"
    )]
    UvOverlap { path: PathBuf, first: String, second: String, pairs: usize },
    #[error("{path}: lightmap UV generation failed: {reason}")]
    Unwrap { path: PathBuf, reason: String },
    #[error("{path}: texture {texture}: {what}")]
    BadTexture { path: PathBuf, texture: usize, what: String },
    #[error("{path}: the scene has no triangles")]
    NoGeometry { path: PathBuf },
    #[error("{path}: malformed glTF: {what}")]
    Malformed { path: PathBuf, what: String },
}

/// Load a level file into a world-space scene.
pub fn load_scene(path: impl AsRef<Path>, opts: &LoadOptions) -> Result<Scene, SceneError> {
    let path = path.as_ref();
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

/// One primitive's data before it joins the scene.
struct Prim {
    place: Place,
    node: usize,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uv1: Option<Vec<Vec2>>,
    uv_albedo: Vec<Vec2>,
    indices: Vec<u32>,
    material: u32,
}

fn load_from_bytes(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<Scene, SceneError> {
    let gerr = |source| SceneError::Gltf { path: path.into(), source };
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice(bytes).map_err(gerr)?;
    let base = path.parent();
    let buffers = gltf::import_buffers(&document, base, blob).map_err(gerr)?;

    let mut scene = Scene { source: path.display().to_string(), ..Default::default() };
    let mut report = LoadReport::default();
    let (materials, texture_of) = read_materials(path, &document)?;
    scene.materials = materials;
    scene.textures = read_textures(path, &document, &buffers, &texture_of)?;
    let default_material = scene.materials.len() as u32;
    scene.materials.push(Material::default());

    let mut prims = Vec::new();
    let roots: Vec<gltf::Node> = match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => document.nodes().filter(|n| !has_parent(&document, n.index())).collect(),
    };
    // Depth-first pre-order, children in file order: scene order decides ties between
    // triangles (texel ownership), so it must be the natural one.
    let mut stack: Vec<(gltf::Node, Mat4, usize)> =
        roots.into_iter().rev().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(SceneError::Malformed {
                path: path.into(),
                what: "node hierarchy deeper than 256 (a cycle?)".into(),
            });
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if !world.is_finite() {
            return Err(SceneError::BadTransform { path: path.into(), node: node.index() });
        }
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                let place = Place {
                    mesh: mesh.index(),
                    mesh_name: mesh.name().unwrap_or("").to_string(),
                    primitive: prim.index(),
                };
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    report.non_triangle_primitives += 1;
                    continue;
                }
                let mat = prim.material().index().map(|i| i as u32).unwrap_or(default_material);
                let tex_set = texture_of.get(mat as usize).copied().flatten().map(|(_, set)| set);
                let p = read_primitive(
                    path,
                    &buffers,
                    &prim,
                    place,
                    world,
                    mat,
                    tex_set,
                    node.index(),
                    &mut report,
                )?;
                prims.push(p);
            }
        }
        if let Some(light) = node.light() {
            scene.lights.push(read_light(path, &light, world)?);
        }
        if let Some(cam) = node.camera() {
            if let gltf::camera::Projection::Perspective(p) = cam.projection() {
                scene.cameras.push(Camera {
                    name: cam.name().or(node.name()).unwrap_or("camera").to_string(),
                    to_world: world,
                    yfov: p.yfov(),
                    aspect: p.aspect_ratio(),
                });
            } else {
                report.notes.push(format!("orthographic camera {} ignored", cam.index()));
            }
        }
        let children: Vec<gltf::Node> = node.children().collect();
        for child in children.into_iter().rev() {
            stack.push((child, world, depth + 1));
        }
    }

    let missing: Vec<&Prim> = prims.iter().filter(|p| p.uv1.is_none()).collect();
    if let Some(first) = missing.first() {
        if opts.require_uv1 {
            return Err(SceneError::MissingUv1 { path: path.into(), place: first.place.clone() });
        }
        report.primitives_without_uv1 = missing.len();
    }
    if prims.iter().all(|p| p.indices.is_empty()) {
        return Err(SceneError::NoGeometry { path: path.into() });
    }
    if report.primitives_without_uv1 > 0 {
        uv::unwrap_primitives(&mut prims_uv_view(&mut prims), opts.unwrap_resolution)
            .map_err(|reason| SceneError::Unwrap { path: path.into(), reason })?;
        report.uv1_generated = true;
        report.notes.push(format!(
            "{} primitive(s) had no TEXCOORD_1: lightmap UVs were generated for the whole level (uvunwrap, \
                packed for {}^2 with 2-texel padding)",
            report.primitives_without_uv1, opts.unwrap_resolution
        ));
    }

    for p in prims {
        let base = scene.positions.len() as u32;
        let Some(uv1) = p.uv1 else {
            return Err(SceneError::Unwrap {
                path: path.into(),
                reason: format!("{}: no lightmap UVs after unwrapping", p.place),
            });
        };
        scene.positions.extend(p.positions);
        scene.normals.extend(p.normals);
        scene.uv1.extend(uv1);
        scene.uv_albedo.extend(p.uv_albedo);
        for (k, t) in p.indices.chunks_exact(3).enumerate() {
            let tri = Triangle {
                v: [base + t[0], base + t[1], base + t[2]],
                material: p.material,
                node: p.node as u32,
                mesh: p.place.mesh as u32,
                primitive: p.place.primitive as u32,
                index: k as u32,
            };
            let [a, b, c] = tri.v.map(|i| scene.positions[i as usize]);
            let cross = (b - a).cross(c - a).length();
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            if !(cross > 1e-12 * longest * longest) {
                report.degenerate_dropped += 1;
                continue;
            }
            scene.triangles.push(tri);
        }
    }
    if scene.triangles.is_empty() {
        return Err(SceneError::NoGeometry { path: path.into() });
    }

    report.uv_out_of_range = uv::count_out_of_range(&scene);
    if report.uv_out_of_range > 0 {
        report.notes.push(format!(
            "{} triangle(s) have lightmap UVs outside [0, 1]; the parts outside get no texels",
            report.uv_out_of_range
        ));
    }
    let overlaps = uv::find_overlaps(&scene);
    if let Some(&(a, b)) = overlaps.first() {
        if !opts.allow_overlap {
            return Err(SceneError::UvOverlap {
                path: path.into(),
                first: scene.describe_triangle(a),
                second: scene.describe_triangle(b),
                pairs: overlaps.len(),
            });
        }
        report.uv_overlapping_pairs = overlaps.len();
        report.notes.push(format!(
            "{} pair(s) of triangles overlap in lightmap UV space (allowed): they share texels",
            overlaps.len()
        ));
    }
    scene.report = report;
    Ok(scene)
}

fn has_parent(doc: &gltf::Document, index: usize) -> bool {
    doc.nodes().any(|n| n.children().any(|c| c.index() == index))
}

/// The UV-generation view of the primitives: positions, indices and the UVs to fill.
fn prims_uv_view(prims: &mut [Prim]) -> Vec<uv::UnwrapPrim<'_>> {
    prims
        .iter_mut()
        .map(|p| uv::UnwrapPrim {
            positions: &mut p.positions,
            normals: &mut p.normals,
            uv_albedo: &mut p.uv_albedo,
            indices: &mut p.indices,
            uv1: &mut p.uv1,
        })
        .collect()
}

/// Materials, and for each the (texture index, UV set) of its albedo texture.
#[allow(clippy::type_complexity)]
fn read_materials(
    path: &Path,
    doc: &gltf::Document,
) -> Result<(Vec<Material>, Vec<Option<(usize, u32)>>), SceneError> {
    let mut out = Vec::new();
    let mut tex = Vec::new();
    for m in doc.materials() {
        let index = m.index().unwrap_or(out.len());
        let name = m.name().unwrap_or("").to_string();
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let albedo = [f[0], f[1], f[2]];
        if albedo.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(SceneError::AlbedoOutOfRange {
                path: path.into(),
                material: index,
                name,
                value: albedo,
            });
        }
        let strength = m.emissive_strength().unwrap_or(1.0);
        let e = m.emissive_factor();
        let emissive = [e[0] * strength, e[1] * strength, e[2] * strength];
        if emissive.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
            return Err(SceneError::BadEmissive {
                path: path.into(),
                material: index,
                name,
                value: emissive,
            });
        }
        let t = pbr.base_color_texture().map(|info| (info.texture().source().index(), info.tex_coord()));
        tex.push(t);
        out.push(Material {
            name,
            albedo: Vec3::from(albedo),
            albedo_texture: None,
            emissive: Vec3::from(emissive),
            double_sided: m.double_sided(),
        });
    }
    Ok((out, tex))
}

/// Decode the images that albedo textures use; link materials to them.
fn read_textures(
    path: &Path,
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    texture_of: &[Option<(usize, u32)>],
) -> Result<Vec<Texture>, SceneError> {
    if texture_of.iter().all(|t| t.is_none()) {
        return Ok(Vec::new());
    }
    let images = gltf::import_images(doc, path.parent(), buffers)
        .map_err(|source| SceneError::Gltf { path: path.into(), source })?;
    let mut out = Vec::with_capacity(images.len());
    for (k, img) in images.iter().enumerate() {
        out.push(decode_srgb(img).map_err(|what| SceneError::BadTexture {
            path: path.into(),
            texture: k,
            what,
        })?);
    }
    Ok(out)
}

/// sRGB-encoded 8- or 16-bit image data to linear RGB; float images are taken as linear.
fn decode_srgb(img: &gltf::image::Data) -> Result<Texture, String> {
    use gltf::image::Format as F;
    let n = (img.width as usize) * (img.height as usize);
    if n == 0 {
        return Err("image is empty".into());
    }
    let (channels, bytes) = match img.format {
        F::R8 => (1, 1),
        F::R8G8 => (2, 1),
        F::R8G8B8 => (3, 1),
        F::R8G8B8A8 => (4, 1),
        F::R16 => (1, 2),
        F::R16G16 => (2, 2),
        F::R16G16B16 => (3, 2),
        F::R16G16B16A16 => (4, 2),
        F::R32G32B32FLOAT => (3, 4),
        F::R32G32B32A32FLOAT => (4, 4),
    };
    if img.pixels.len() < n * channels * bytes {
        return Err("pixel data shorter than the image size".into());
    }
    let value = |i: usize, c: usize| -> f32 {
        let c = c.min(channels - 1);
        let at = (i * channels + c) * bytes;
        match bytes {
            1 => srgb_to_linear(img.pixels[at] as f32 / 255.0),
            2 => srgb_to_linear(u16::from_le_bytes([img.pixels[at], img.pixels[at + 1]]) as f32 / 65535.0),
            _ => {
                let v = f32::from_le_bytes(img.pixels[at..at + 4].try_into().unwrap_or([0; 4]));
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }
        }
    };
    let grey = channels < 3;
    let texels =
        (0..n)
            .map(|i| {
                if grey {
                    Vec3::splat(value(i, 0))
                } else {
                    Vec3::new(value(i, 0), value(i, 1), value(i, 2))
                }
            })
            .collect();
    Ok(Texture { width: img.width, height: img.height, texels })
}

/// The sRGB transfer function, decoded.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

#[allow(clippy::too_many_arguments)]
fn read_primitive(
    path: &Path,
    buffers: &[gltf::buffer::Data],
    prim: &gltf::Primitive,
    place: Place,
    world: Mat4,
    material: u32,
    tex_set: Option<u32>,
    node: usize,
    report: &mut LoadReport,
) -> Result<Prim, SceneError> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
    let oob =
        |attribute| SceneError::AccessorOutOfBounds { path: path.into(), place: place.clone(), attribute };
    if prim.get(&gltf::Semantic::Positions).is_none() {
        return Err(SceneError::MissingPositions { path: path.into(), place });
    }
    let local: Vec<Vec3> = reader.read_positions().ok_or_else(|| oob("POSITION"))?.map(Vec3::from).collect();
    let n = local.len();
    for (i, p) in local.iter().enumerate() {
        if !p.is_finite() {
            return Err(SceneError::NonFinite {
                path: path.into(),
                place,
                attribute: "POSITION",
                vertex: i,
                value: format!("{p}"),
            });
        }
    }
    let linear = Mat3::from_mat4(world);
    if !(linear.determinant().abs() > 0.0) {
        return Err(SceneError::BadTransform { path: path.into(), node });
    }
    let flip = linear.determinant() < 0.0;
    let positions: Vec<Vec3> = local.iter().map(|p| world.transform_point3(*p)).collect();
    if let Some((i, p)) = positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
        return Err(SceneError::NonFinite {
            path: path.into(),
            place,
            attribute: "POSITION (after the node transform)",
            vertex: i,
            value: format!("{p}"),
        });
    }

    let mut indices: Vec<u32> = match prim.indices() {
        Some(_) => reader.read_indices().ok_or_else(|| oob("indices"))?.into_u32().collect(),
        None => (0..n as u32).collect(),
    };
    if indices.len() % 3 != 0 {
        return Err(SceneError::PartialTriangle { path: path.into(), place, count: indices.len() });
    }
    if let Some((position, &value)) = indices.iter().enumerate().find(|(_, &v)| v as usize >= n) {
        return Err(SceneError::IndexOutOfRange {
            path: path.into(),
            place,
            position,
            value,
            vertex_count: n,
        });
    }
    if flip {
        for t in indices.chunks_exact_mut(3) {
            t.swap(1, 2);
        }
    }

    let normal_matrix = linear.inverse().transpose();
    let normals = match prim.get(&gltf::Semantic::Normals) {
        Some(_) => {
            let local: Vec<Vec3> =
                reader.read_normals().ok_or_else(|| oob("NORMAL"))?.map(Vec3::from).collect();
            if local.len() != n {
                return Err(SceneError::Malformed {
                    path: path.into(),
                    what: format!("{place}: NORMAL count differs from POSITION count"),
                });
            }
            if let Some((i, v)) = local.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(SceneError::NonFinite {
                    path: path.into(),
                    place,
                    attribute: "NORMAL",
                    vertex: i,
                    value: format!("{v}"),
                });
            }
            local.iter().map(|v| (normal_matrix * *v).normalize_or_zero()).collect()
        }
        None => {
            report.normals_generated += 1;
            crate::scene::generate_normals(&positions, &indices)
        }
    };

    let read_uv = |set: u32, name: &'static str| -> Result<Option<Vec<Vec2>>, SceneError> {
        if prim.get(&gltf::Semantic::TexCoords(set)).is_none() {
            return Ok(None);
        }
        let uv: Vec<Vec2> =
            reader.read_tex_coords(set).ok_or_else(|| oob(name))?.into_f32().map(Vec2::from).collect();
        if uv.len() != n {
            return Err(SceneError::Malformed {
                path: path.into(),
                what: format!("{place}: {name} count differs from POSITION count"),
            });
        }
        if let Some((i, v)) = uv.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(SceneError::NonFinite {
                path: path.into(),
                place: place.clone(),
                attribute: name,
                vertex: i,
                value: format!("{v}"),
            });
        }
        Ok(Some(uv))
    };
    let uv1 = read_uv(1, "TEXCOORD_1")?;
    let uv_albedo = match tex_set {
        Some(set) => read_uv(set, if set == 0 { "TEXCOORD_0" } else { "TEXCOORD_n" })?
            .unwrap_or_else(|| vec![Vec2::ZERO; n]),
        None => vec![Vec2::ZERO; n],
    };
    Ok(Prim { place, node, positions, normals, uv1, uv_albedo, indices, material })
}

fn read_light(
    path: &Path,
    light: &gltf::khr_lights_punctual::Light,
    world: Mat4,
) -> Result<Light, SceneError> {
    let name = light.name().unwrap_or("").to_string();
    let bad = |what: String| SceneError::BadLight {
        path: path.into(),
        light: light.index(),
        name: name.clone(),
        what,
    };
    let color = Vec3::from(light.color());
    let intensity = light.intensity();
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(bad(format!("intensity {intensity} is negative or not finite")));
    }
    if !(color.is_finite() && color.min_element() >= 0.0) {
        return Err(bad(format!("colour {color} is negative or not finite")));
    }
    let kind = match light.kind() {
        Kind::Point => LightKind::Point,
        Kind::Directional => LightKind::Directional,
        Kind::Spot { inner_cone_angle, outer_cone_angle } => {
            let (inner, outer) = (inner_cone_angle, outer_cone_angle);
            let half_pi = std::f32::consts::FRAC_PI_2;
            if !(0.0 <= inner && inner <= outer && outer <= half_pi + 1e-6) {
                return Err(bad(format!(
                    "spot cone angles inner {inner} / outer {outer} must satisfy 0 <= inner <= outer <= pi/2"
                )));
            }
            LightKind::Spot { inner, outer: outer.min(half_pi) }
        }
    };
    let position = world.transform_point3(Vec3::ZERO);
    let direction = world.transform_vector3(-Vec3::Z).normalize_or_zero();
    if !position.is_finite() || direction == Vec3::ZERO {
        return Err(bad("its node transform gives no finite position or direction".into()));
    }
    let range = light.range();
    if let Some(r) = range {
        if !(r.is_finite() && r > 0.0) {
            return Err(bad(format!("range {r} must be positive")));
        }
    }
    Ok(Light { name, kind, position, direction, intensity: color * intensity, range })
}
