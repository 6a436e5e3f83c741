//! The level as an editor changes it: immutable versions (scene, BVH, receiver frames, lights)
//! and the edits that make a new one from the last.
//!
//! Light baked with one version is later taken out again with exactly that version (paper 001
//! §4.4), so a version is never changed once made; bake records hold it by `Arc` and it goes
//! when the last of them does.

use std::sync::Arc;

use glam::{Mat3, Mat4, Vec3};
use prm::light::Aperture;
use prm::{Bvh, Light, LightKind, Scene, TexelSet};

/// A light with an identity that survives edits (its paths' random streams are keyed by it).
#[derive(Clone, Debug, PartialEq)]
pub struct LightSlot {
    pub id: u32,
    pub light: Light,
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub lo: Vec3,
    pub hi: Vec3,
}

impl Aabb {
    pub fn of(points: impl IntoIterator<Item = Vec3>) -> Aabb {
        points.into_iter().fold(Aabb { lo: Vec3::INFINITY, hi: Vec3::NEG_INFINITY }, |b, p| Aabb {
            lo: b.lo.min(p),
            hi: b.hi.max(p),
        })
    }

    pub fn is_empty(&self) -> bool {
        !(self.lo.cmple(self.hi).all())
    }

    pub fn grown(&self, by: f32) -> Aabb {
        Aabb { lo: self.lo - Vec3::splat(by), hi: self.hi + Vec3::splat(by) }
    }

    /// Whether the segment from `a` along `d` for t in [0, tmax] meets the box (slab test).
    pub fn meets_segment(&self, a: Vec3, d: Vec3, tmax: f32) -> bool {
        let (mut t0, mut t1) = (0.0f32, tmax);
        for k in 0..3 {
            let inv = 1.0 / d[k];
            let (mut ta, mut tb) = ((self.lo[k] - a[k]) * inv, (self.hi[k] - a[k]) * inv);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            // A NaN (a zero direction component with the origin on a slab face) keeps the
            // interval: conservative.
            if ta > t0 {
                t0 = ta;
            }
            if tb < t1 {
                t1 = tb;
            }
            if t0 > t1 {
                return false;
            }
        }
        true
    }

    /// Whether some segment from `apex` to a point of the ball (`centre`, `radius`) may meet
    /// the box grown by `margin` (conservative). The segments fill a cone whose radius grows
    /// from 0 at the apex to `radius` at the centre; it is tested in pieces along its axis,
    /// each against the box grown by the cone's largest radius over the piece, so a texel
    /// near the box is not taken to be shadowed by it from every side as with one growth.
    pub fn meets_cone(&self, apex: Vec3, centre: Vec3, radius: f32, margin: f32) -> bool {
        let axis = centre - apex;
        let len = axis.length();
        if !(len > radius) {
            // The apex is inside the ball: every direction.
            return !self.grown(radius + margin).is_empty()
                && (apex - apex.clamp(self.lo, self.hi)).length() <= len + radius + margin;
        }
        let d = axis / len;
        // The cone's sides leave the axis at the ball's tangent: radius at distance t is
        // at most t * radius / sqrt(len² - radius²) along the axis, and the ball's far half is
        // within `radius` of the centre.
        let slope = radius / (len * len - radius * radius).sqrt();
        // Every piece's test below is within this one (its segment a part of the axis, its
        // box grown by no more), and most cones miss: one test settles those.
        let far_half = self.grown(radius + margin);
        if !self.grown(len * slope + margin).meets_segment(apex, d, len)
            && !far_half.meets_segment(centre, d, radius)
        {
            return false;
        }
        let mut t0 = 0.0f32;
        for t1 in [len / 16.0, len / 8.0, len / 4.0, len / 2.0, len] {
            if self.grown(t1 * slope + margin).meets_segment(apex + d * t0, d, t1 - t0) {
                return true;
            }
            t0 = t1;
        }
        far_half.meets_segment(centre, d, radius)
    }
}

/// One change an editor makes.
#[derive(Clone, Debug, PartialEq)]
pub enum Edit {
    /// Move, rotate or scale the triangles a glTF node placed: their world positions become
    /// `matrix` times what they were.
    Transform {
        node: u32,
        matrix: Mat4,
    },
    /// A material's albedo factor (linear RGB, each in [0, 1]).
    Albedo {
        material: u32,
        albedo: Vec3,
    },
    /// A new light; it gets the next free id.
    AddLight(Light),
    RemoveLight {
        id: u32,
    },
    /// Replace light `id` (move it, turn it, recolour it).
    SetLight {
        id: u32,
        light: Light,
    },
}

/// An edit that cannot be applied; the level is left as it was.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EditError {
    #[error("no glTF node {0} places any triangle of the level")]
    UnknownNode(u32),
    #[error("no material {0} (the level has {1})")]
    UnknownMaterial(u32, usize),
    #[error("no light with id {0}")]
    UnknownLight(u32),
    #[error("{0} is not finite")]
    NonFinite(&'static str),
    #[error("the move takes node {0} beyond {max:e} m of the origin", max = prm::light::MAX_POSITION)]
    TooFar(u32),
    #[error("the transform of node {0} is singular (it would flatten the object)")]
    Singular(u32),
    #[error("albedo {0} is outside [0, 1]")]
    BadAlbedo(Vec3),
    #[error("light intensity {0} is negative")]
    NegativeIntensity(Vec3),
    #[error("light '{0}': {1}")]
    BadLight(String, String),
}

/// What an edit changed, for invalidation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    /// Nodes whose triangles moved.
    pub moved_nodes: Vec<u32>,
    /// Boxes around moved geometry, where it was and where it is.
    pub regions: Vec<Aabb>,
    pub materials: Vec<u32>,
    /// Ids of lights added, removed or changed.
    pub lights: Vec<u32>,
}

/// One immutable state of the level.
pub struct Version {
    /// Counts up from 0 with each edit.
    pub id: u64,
    pub scene: Arc<Scene>,
    pub bvh: Arc<Bvh>,
    pub lights: Arc<Vec<LightSlot>>,
    /// Per receiver texel: world position, unit normal, half a texel's side (the epsilon shift).
    pub frames: Arc<Vec<(Vec3, Vec3, f32)>>,
}

/// Receiver frames of `texels` on `scene`: each texel stays on its triangle at its
/// barycentrics, so an edit that moves the triangle carries the texel along.
pub fn receiver_frames(scene: &Scene, texels: &TexelSet) -> Vec<(Vec3, Vec3, f32)> {
    texels
        .texels
        .iter()
        .map(|t| {
            let tri = t.triangle as usize;
            (scene.point(tri, t.bary), scene.face_normal(tri), 0.5 * texels.world_texel_size(scene, tri))
        })
        .collect()
}

/// The corners of the emissive triangles of `scene` (of `node` only, if given), by position
/// bits, each with one of its triangles: a polygon light without a profile whose corners are
/// all among them is that surface's emission ([`emission_of`]). A merged light's corners are
/// corners of its triangles ([`prm::emitters`]), so this finds it without merging again
/// (which, on moved positions rounded anew, could drop another straight corner).
pub(super) fn glowing_corners(
    scene: &Scene,
    node: Option<u32>,
) -> std::collections::HashMap<[u32; 3], usize> {
    let mut out = std::collections::HashMap::new();
    for t in 0..scene.triangles.len() {
        if node.is_none_or(|n| scene.triangles[t].node == n) && scene.material(t).emissive != Vec3::ZERO {
            for c in scene.corners(t) {
                out.entry(c.to_array().map(f32::to_bits)).or_insert(t);
            }
        }
    }
    out
}

/// The emissive triangle (one of them) whose surface `light` is the emission of, if it is one:
/// a polygon without a profile with every corner a corner of `glowing` ([`glowing_corners`]).
pub(super) fn emission_of(
    light: &Light,
    glowing: &std::collections::HashMap<[u32; 3], usize>,
) -> Option<usize> {
    match &light.aperture {
        Aperture::Polygon { corners } if light.profile.is_none() => {
            let mut found = None;
            for c in corners.iter() {
                found = Some(*glowing.get(&c.to_array().map(f32::to_bits))?);
            }
            found
        }
        _ => None,
    }
}

/// The level and its current version.
pub struct Level {
    texels: Arc<TexelSet>,
    /// The diagonal of the level's box when it was opened: ray offsets stay the same however
    /// objects move (see [`Bvh::build_with_extent`]).
    extent: f32,
    current: Arc<Version>,
    next_light: u32,
}

impl Level {
    /// Open `scene` with its own lights (ids 0, 1, ...) and lightmap receivers `texels`.
    pub fn new(scene: Scene, texels: Arc<TexelSet>) -> Level {
        let extent = scene.diagonal();
        Level::with_extent(scene, texels, extent)
    }

    /// The diagonal the ray offsets are made for.
    pub fn extent(&self) -> f32 {
        self.extent
    }

    /// As [`Level::new`] with the ray offsets of a level of diagonal `extent` (to compare a
    /// level reached by edits with a fresh one, give both the same).
    pub fn with_extent(scene: Scene, texels: Arc<TexelSet>, extent: f32) -> Level {
        let lights: Vec<LightSlot> = scene
            .lights
            .iter()
            .enumerate()
            .map(|(i, l)| LightSlot { id: i as u32, light: l.clone() })
            .collect();
        let next_light = lights.len() as u32;
        let current = Arc::new(make_version(0, scene, lights, &texels, extent));
        Level { texels, extent, current, next_light }
    }

    pub fn current(&self) -> &Arc<Version> {
        &self.current
    }

    pub fn texels(&self) -> &Arc<TexelSet> {
        &self.texels
    }

    /// Apply `edit`: a new current version and what changed. On error nothing changes.
    pub fn apply(&mut self, edit: &Edit) -> Result<Changes, EditError> {
        let cur = &self.current;
        let mut scene: Option<Scene> = None;
        let mut lights: Vec<LightSlot> = cur.lights.as_ref().clone();
        let mut changes = Changes::default();
        match edit {
            Edit::Transform { node, matrix } => {
                if !matrix.is_finite() {
                    return Err(EditError::NonFinite("the transform"));
                }
                let det = matrix.determinant();
                if !(det.abs() > 1e-12) {
                    return Err(EditError::Singular(*node));
                }
                let mut s = cur.scene.as_ref().clone();
                let mut verts: Vec<u32> =
                    s.triangles.iter().filter(|t| t.node == *node).flat_map(|t| t.v).collect();
                if verts.is_empty() {
                    return Err(EditError::UnknownNode(*node));
                }
                verts.sort_unstable();
                verts.dedup();
                let normal_matrix = Mat3::from_mat4(*matrix).inverse().transpose();
                let before = Aabb::of(verts.iter().map(|&v| s.positions[v as usize]));
                for &v in &verts {
                    let v = v as usize;
                    s.positions[v] = matrix.transform_point3(s.positions[v]);
                    s.normals[v] = (normal_matrix * s.normals[v]).normalize_or_zero();
                }
                let after = Aabb::of(verts.iter().map(|&v| s.positions[v as usize]));
                if !(after.lo.is_finite() && after.hi.is_finite()) {
                    return Err(EditError::NonFinite("the moved positions"));
                }
                // Squared distances there overflow f32, as they would for a light so far.
                if after.lo.abs().max(after.hi.abs()).max_element() > prm::light::MAX_POSITION {
                    return Err(EditError::TooFar(*node));
                }
                changes.moved_nodes.push(*node);
                changes.regions = vec![before, after];
                // An emissive surface's polygon lights (`Scene::emissive_lights`) move with it.
                let glowing = glowing_corners(&cur.scene, Some(*node));
                for slot in lights.iter_mut() {
                    let Some(t) = emission_of(&slot.light, &glowing) else { continue };
                    if let Aperture::Polygon { corners } = &slot.light.aperture {
                        let moved: Vec<Vec3> = corners.iter().map(|c| matrix.transform_point3(*c)).collect();
                        let emission = s.material(t).emissive;
                        let name = &slot.light.name;
                        let was = Light::polygon(name, corners, emission).intensity;
                        let mut light =
                            Light { range: slot.light.range, ..Light::polygon(name, &moved, emission) };
                        if slot.light.intensity != was {
                            // Recoloured since (a light edit): keep its radiance, on the new area.
                            light.intensity =
                                slot.light.intensity * (light.intensity / was.max(Vec3::splat(1e-30)));
                        }
                        slot.light = light;
                        changes.lights.push(slot.id);
                    }
                }
                scene = Some(s);
            }
            Edit::Albedo { material, albedo } => {
                if !albedo.is_finite() {
                    return Err(EditError::NonFinite("the albedo"));
                }
                if albedo.min_element() < 0.0 || albedo.max_element() > 1.0 {
                    return Err(EditError::BadAlbedo(*albedo));
                }
                let mut s = cur.scene.as_ref().clone();
                let count = s.materials.len();
                let m = s
                    .materials
                    .get_mut(*material as usize)
                    .ok_or(EditError::UnknownMaterial(*material, count))?;
                m.albedo = *albedo;
                changes.materials.push(*material);
                scene = Some(s);
            }
            Edit::AddLight(light) => {
                check_light(light)?;
                lights.push(LightSlot { id: self.next_light, light: light.clone() });
                changes.lights.push(self.next_light);
            }
            Edit::RemoveLight { id } => {
                let i = lights.iter().position(|l| l.id == *id).ok_or(EditError::UnknownLight(*id))?;
                lights.remove(i);
                changes.lights.push(*id);
            }
            Edit::SetLight { id, light } => {
                check_light(light)?;
                let slot = lights.iter_mut().find(|l| l.id == *id).ok_or(EditError::UnknownLight(*id))?;
                slot.light = light.clone();
                changes.lights.push(*id);
            }
        }
        if let Edit::AddLight(_) = edit {
            self.next_light += 1;
        }
        let id = cur.id + 1;
        self.current = Arc::new(match scene {
            Some(s) => make_version(id, s, lights, &self.texels, self.extent),
            None => Version {
                id,
                scene: cur.scene.clone(),
                bvh: cur.bvh.clone(),
                lights: Arc::new(lights),
                frames: cur.frames.clone(),
            },
        });
        Ok(changes)
    }
}

fn check_light(l: &Light) -> Result<(), EditError> {
    if !(l.position.is_finite() && l.direction.is_finite() && l.intensity.is_finite()) {
        return Err(EditError::NonFinite("the light"));
    }
    if l.intensity.min_element() < 0.0 {
        return Err(EditError::NegativeIntensity(l.intensity));
    }
    if matches!(l.kind, LightKind::Spot { .. } | LightKind::Directional) && !(l.direction.length() > 0.0) {
        return Err(EditError::NonFinite("the light's direction"));
    }
    l.check().map_err(|what| EditError::BadLight(l.name.clone(), what))
}

fn make_version(id: u64, scene: Scene, lights: Vec<LightSlot>, texels: &TexelSet, extent: f32) -> Version {
    let bvh = Bvh::build_with_extent(&scene, extent);
    let frames = receiver_frames(&scene, texels);
    Version {
        id,
        scene: Arc::new(scene),
        bvh: Arc::new(bvh),
        lights: Arc::new(lights),
        frames: Arc::new(frames),
    }
}
