//! Triangle primitives: read from their accessors into world space, checked, and joined into
//! the scene's vertex arrays and triangle list.

use std::path::Path;

use glam::{Mat3, Mat4, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};

use super::{Place, SceneError};
use crate::scene::{LoadReport, Scene, Triangle};

/// One primitive's data before it joins the scene.
pub(super) struct Prim {
    pub place: Place,
    pub node: usize,
    /// 0: the static level; k: movable k - 1 ([`crate::scene::Scene::movables`]).
    pub object: u32,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uv1: Option<Vec<Vec2>>,
    pub uv_albedo: Vec<Vec2>,
    pub indices: Vec<u32>,
    pub material: u32,
}

impl Prim {
    /// World-space surface area of the triangles, in square metres.
    pub fn area(&self) -> f64 {
        self.indices
            .chunks_exact(3)
            .map(|t| {
                let [a, b, c] = [0, 1, 2].map(|k| self.positions[t[k] as usize]);
                0.5 * (b - a).cross(c - a).length() as f64
            })
            .sum()
    }
}

/// A glTF primitive being read, with what its errors name.
pub(super) struct PrimSource<'a> {
    pub path: &'a Path,
    pub buffers: &'a [gltf::buffer::Data],
    pub prim: &'a gltf::Primitive<'a>,
    pub place: Place,
}

/// How a primitive is used: by which node, at which world transform, with which material and
/// the UV set of that material's albedo texture.
pub(super) struct Use {
    pub node: usize,
    pub object: u32,
    pub world: Mat4,
    pub material: u32,
    pub tex_set: Option<u32>,
}

/// Read one triangle primitive in world space. Winding is flipped under a mirroring transform;
/// missing normals are generated (and counted in `report`).
pub(super) fn read_primitive(src: PrimSource, at: Use, report: &mut LoadReport) -> Result<Prim, SceneError> {
    let local = src.local_positions()?;
    let linear = Mat3::from_mat4(at.world);
    if !(linear.determinant().abs() > 0.0) {
        return Err(SceneError::BadTransform { path: src.path.into(), node: at.node });
    }
    let positions = src.world_positions(&local, at.world)?;
    let n = local.len();
    let mut indices = src.indices(n)?;
    if linear.determinant() < 0.0 {
        for t in indices.chunks_exact_mut(3) {
            t.swap(1, 2);
        }
    }
    let normals = match src.normals(linear, n)? {
        Some(normals) => normals,
        None => {
            report.normals_generated += 1;
            crate::scene::generate_normals(&positions, &indices)
        }
    };
    let uv1 = src.tex_coords(1, "TEXCOORD_1", n)?;
    let uv_albedo = match at.tex_set {
        Some(set) => src
            .tex_coords(set, if set == 0 { "TEXCOORD_0" } else { "TEXCOORD_n" }, n)?
            .unwrap_or_else(|| vec![Vec2::ZERO; n]),
        None => vec![Vec2::ZERO; n],
    };
    let (node, object, material) = (at.node, at.object, at.material);
    Ok(Prim { place: src.place, node, object, positions, normals, uv1, uv_albedo, indices, material })
}

impl<'a> PrimSource<'a> {
    fn reader(&self) -> gltf::mesh::Reader<'a, 'a, impl Clone + Fn(gltf::Buffer<'a>) -> Option<&'a [u8]>> {
        let buffers = self.buffers;
        self.prim.reader(move |b| buffers.get(b.index()).map(|d| &d.0[..]))
    }

    fn out_of_bounds(&self, attribute: &'static str) -> SceneError {
        SceneError::AccessorOutOfBounds { path: self.path.into(), place: self.place.clone(), attribute }
    }

    /// The gltf crate's readers assume an accessor of the kind its attribute allows, at least
    /// one element and a stride that holds one: anything else reaches `unreachable!`, an
    /// overflow or a read across elements inside the crate. Refused here, by name.
    fn check_accessor(
        &self,
        attribute: &str,
        accessor: &gltf::Accessor,
        allowed: &[(DataType, Dimensions)],
        allowed_in_words: &str,
    ) -> Result<(), SceneError> {
        let (kind, dims, index) = (accessor.data_type(), accessor.dimensions(), accessor.index());
        let malformed = |what: String| SceneError::Malformed {
            path: self.path.into(),
            what: format!("{}: {attribute} accessor {index} {what}", self.place),
        };
        if !allowed.contains(&(kind, dims)) {
            return Err(malformed(format!("holds {kind:?} {dims:?} where glTF allows {allowed_in_words}")));
        }
        if accessor.count() == 0 {
            return Err(malformed("has no elements".into()));
        }
        let size = accessor.size();
        let views = accessor.view().into_iter().chain(accessor.sparse().map(|s| s.values().view()));
        for view in views {
            if let Some(stride) = view.stride().filter(|&s| s < size) {
                return Err(malformed(format!(
                    "reads buffer view {} with a stride of {stride} bytes, less than one {size}-byte element",
                    view.index()
                )));
            }
        }
        if accessor.sparse().is_some_and(|s| s.count() == 0) {
            return Err(malformed("has a sparse part of no elements".into()));
        }
        Ok(())
    }

    fn non_finite(&self, attribute: &'static str, vertex: usize, value: String) -> SceneError {
        SceneError::NonFinite { path: self.path.into(), place: self.place.clone(), attribute, vertex, value }
    }

    fn count_differs(&self, attribute: &str) -> SceneError {
        SceneError::Malformed {
            path: self.path.into(),
            what: format!("{}: {attribute} count differs from POSITION count", self.place),
        }
    }

    /// POSITION as stored, all finite.
    fn local_positions(&self) -> Result<Vec<Vec3>, SceneError> {
        let Some(a) = self.prim.get(&gltf::Semantic::Positions) else {
            return Err(SceneError::MissingPositions { path: self.path.into(), place: self.place.clone() });
        };
        self.check_accessor("POSITION", &a, &[(DataType::F32, Dimensions::Vec3)], "float VEC3")?;
        let local: Vec<Vec3> = self
            .reader()
            .read_positions()
            .ok_or_else(|| self.out_of_bounds("POSITION"))?
            .map(Vec3::from)
            .collect();
        for (i, p) in local.iter().enumerate() {
            if !p.is_finite() {
                return Err(self.non_finite("POSITION", i, format!("{p}")));
            }
        }
        Ok(local)
    }

    /// Positions through the node transform, still finite.
    fn world_positions(&self, local: &[Vec3], world: Mat4) -> Result<Vec<Vec3>, SceneError> {
        let positions: Vec<Vec3> = local.iter().map(|p| world.transform_point3(*p)).collect();
        if let Some((i, p)) = positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(self.non_finite("POSITION (after the node transform)", i, format!("{p}")));
        }
        // As for lights (`Light::check`) and edits: f32 keeps a metre there.
        let far = |p: &Vec3| p.abs().max_element() > crate::light::MAX_POSITION;
        if let Some((vertex, p)) = positions.iter().enumerate().find(|(_, p)| far(p)) {
            let (path, place) = (self.path.into(), self.place.clone());
            return Err(SceneError::TooFar { path, place, vertex, value: format!("{p}") });
        }
        Ok(positions)
    }

    /// Triangle-list indices (0..n when the primitive has none), each below the vertex count `n`.
    fn indices(&self, n: usize) -> Result<Vec<u32>, SceneError> {
        if let Some(a) = self.prim.indices() {
            let kinds = [DataType::U8, DataType::U16, DataType::U32].map(|k| (k, Dimensions::Scalar));
            self.check_accessor("indices", &a, &kinds, "unsigned byte, short or int scalars")?;
        }
        let indices: Vec<u32> = match self.prim.indices() {
            Some(_) => self
                .reader()
                .read_indices()
                .ok_or_else(|| self.out_of_bounds("indices"))?
                .into_u32()
                .collect(),
            None => (0..n as u32).collect(),
        };
        let (path, place) = (self.path.into(), self.place.clone());
        if indices.len() % 3 != 0 {
            return Err(SceneError::PartialTriangle { path, place, count: indices.len() });
        }
        if let Some((position, &value)) = indices.iter().enumerate().find(|(_, &v)| v as usize >= n) {
            return Err(SceneError::IndexOutOfRange { path, place, position, value, vertex_count: n });
        }
        Ok(indices)
    }

    /// NORMAL in world space (through the inverse transpose of `linear`), or `None` when absent.
    fn normals(&self, linear: Mat3, n: usize) -> Result<Option<Vec<Vec3>>, SceneError> {
        let Some(a) = self.prim.get(&gltf::Semantic::Normals) else {
            return Ok(None);
        };
        self.check_accessor("NORMAL", &a, &[(DataType::F32, Dimensions::Vec3)], "float VEC3")?;
        let local: Vec<Vec3> = self
            .reader()
            .read_normals()
            .ok_or_else(|| self.out_of_bounds("NORMAL"))?
            .map(Vec3::from)
            .collect();
        if local.len() != n {
            return Err(self.count_differs("NORMAL"));
        }
        if let Some((i, v)) = local.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(self.non_finite("NORMAL", i, format!("{v}")));
        }
        let normal_matrix = linear.inverse().transpose();
        Ok(Some(local.iter().map(|v| (normal_matrix * *v).normalize_or_zero()).collect()))
    }

    /// UV set `set` (called `name` in errors), or `None` when absent.
    fn tex_coords(&self, set: u32, name: &'static str, n: usize) -> Result<Option<Vec<Vec2>>, SceneError> {
        let Some(a) = self.prim.get(&gltf::Semantic::TexCoords(set)) else {
            return Ok(None);
        };
        let kinds = [DataType::F32, DataType::U8, DataType::U16].map(|k| (k, Dimensions::Vec2));
        self.check_accessor(name, &a, &kinds, "float, unsigned byte or unsigned short VEC2")?;
        let uv: Vec<Vec2> = self
            .reader()
            .read_tex_coords(set)
            .ok_or_else(|| self.out_of_bounds(name))?
            .into_f32()
            .map(Vec2::from)
            .collect();
        if uv.len() != n {
            return Err(self.count_differs(name));
        }
        if let Some((i, v)) = uv.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(self.non_finite(name, i, format!("{v}")));
        }
        Ok(Some(uv))
    }
}

/// Append the primitives to the scene's vertex arrays and triangle list, in order. Zero-area
/// triangles are dropped (counted in `report`); every primitive must have lightmap UVs by now.
pub(super) fn join_primitives(
    path: &Path,
    prims: Vec<Prim>,
    scene: &mut Scene,
    report: &mut LoadReport,
) -> Result<(), SceneError> {
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
                object: p.object,
                mesh: p.place.mesh as u32,
                primitive: p.place.primitive as u32,
                index: k as u32,
            };
            if !has_area(scene, &tri) {
                report.degenerate_dropped += 1;
                continue;
            }
            scene.triangles.push(tri);
        }
    }
    Ok(())
}

/// Whether a triangle's area is more than negligible relative to its longest edge.
fn has_area(scene: &Scene, tri: &Triangle) -> bool {
    let [a, b, c] = tri.v.map(|i| scene.positions[i as usize]);
    let cross = (b - a).cross(c - a).length();
    let longest = (b - a).length().max((c - b).length()).max((a - c).length());
    cross > 1e-12 * longest * longest
}
