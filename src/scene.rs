//! The world-space scene every stage works on.
//!
//! A glTF level is flattened into one triangle soup: every primitive's vertices are transformed
//! by their node's world matrix, so later stages never see the node hierarchy. Each triangle
//! remembers where it came from (mesh, primitive, triangle index) so errors and reports can name
//! it. Surfaces are Lambertian and one-sided unless their material is `doubleSided`: the front
//! face is the counter-clockwise one (glTF), and its geometric normal is [`Scene::face_normal`].

use glam::{Mat4, Vec2, Vec3};

use crate::light::Light;

/// A triangle of the scene, indexing [`Scene::positions`] and friends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    /// Vertex indices, counter-clockwise seen from the front.
    pub v: [u32; 3],
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// glTF node that placed it (one mesh may be placed by several nodes).
    pub node: u32,
    /// 0: the static level; k: [`Scene::movables`]`[k - 1]`, a rigid object that may move.
    pub object: u32,
    /// glTF mesh index this triangle came from.
    pub mesh: u32,
    /// Primitive index within that mesh.
    pub primitive: u32,
    /// Triangle index within that primitive (before degenerate triangles were dropped).
    pub index: u32,
}

/// An albedo texture, decoded to linear RGB.
#[derive(Clone, Debug)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    /// Row-major linear RGB, `width * height` entries.
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Bilinear lookup with wrap-around addressing (glTF's default sampler).
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !x.is_finite() || !y.is_finite() {
            return self.texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: i64, j: i64| self.texels[(j.rem_euclid(h) * w + i.rem_euclid(w)) as usize];
        let (i, j) = (x0 as i64, y0 as i64);
        let top = at(i, j).lerp(at(i + 1, j), fx);
        let bottom = at(i, j + 1).lerp(at(i + 1, j + 1), fx);
        top.lerp(bottom, fy)
    }
}

/// A Lambertian material (DESIGN.md §3).
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    /// Linear RGB albedo factor in [0, 1] (glTF `baseColorFactor`).
    pub albedo: Vec3,
    /// Optional albedo texture (index into [`Scene::textures`]), multiplied with `albedo`.
    pub albedo_texture: Option<u32>,
    /// Emitted radiance in W/(m² sr), linear RGB (`emissiveFactor` x `emissive_strength`).
    pub emissive: Vec3,
    /// Both faces reflect; otherwise the back face absorbs.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: "default".into(),
            albedo: Vec3::ONE,
            albedo_texture: None,
            emissive: Vec3::ZERO,
            double_sided: false,
        }
    }
}

/// A perspective camera from the glTF.
#[derive(Clone, Debug)]
pub struct Camera {
    pub name: String,
    /// Camera-to-world transform; the camera looks down its local -Z with +Y up.
    pub to_world: Mat4,
    /// Vertical field of view in radians.
    pub yfov: f32,
    /// Width / height, when the file gives one.
    pub aspect: Option<f32>,
}

impl Camera {
    /// Width x height of an image `width` pixels wide at the camera's aspect (1 without one,
    /// clamped to [0.01, 100]).
    pub fn image_size(&self, width: u32) -> (u32, u32) {
        let aspect = self.aspect.unwrap_or(1.0).clamp(0.01, 100.0);
        (width, ((width as f32 / aspect).round() as u32).max(1))
    }

    /// The primary ray (origin, unit direction) through continuous pixel position (x, y) of a
    /// w x h image: (0, 0) is the top-left corner, (w, h) the bottom-right.
    pub fn ray(&self, x: f32, y: f32, w: u32, h: u32) -> (glam::Vec3, glam::Vec3) {
        use glam::Vec4Swizzles;
        let origin = self.to_world.col(3).xyz();
        let (right, up, back) = (
            self.to_world.col(0).xyz().normalize(),
            self.to_world.col(1).xyz().normalize(),
            self.to_world.col(2).xyz().normalize(),
        );
        let tan = (self.yfov * 0.5).tan();
        let aspect = w as f32 / h as f32;
        let sx = (2.0 * x / w as f32 - 1.0) * tan * aspect;
        let sy = (1.0 - 2.0 * y / h as f32) * tan;
        (origin, (right * sx + up * sy - back).normalize())
    }
}

/// What loading found and did that a user should know about. Never fatal.
#[derive(Clone, Debug, Default)]
pub struct LoadReport {
    /// Zero-area triangles dropped.
    pub degenerate_dropped: usize,
    /// Primitives skipped because they are not triangles (points, lines).
    pub non_triangle_primitives: usize,
    /// Lightmap UVs were generated because the file had no `TEXCOORD_1` (on some primitive).
    pub uv1_generated: bool,
    /// The atlas generated lightmap UVs were packed into.
    pub generated_atlas: Option<crate::density::Atlas>,
    /// How they were laid out (with several pages, the texel size that loads them again).
    pub generated_layout: Option<crate::density::UnwrapLayout>,
    /// Primitives that lacked `TEXCOORD_1`.
    pub primitives_without_uv1: usize,
    /// Triangles whose lightmap UVs leave [0, 1] (those parts get no texels).
    pub uv_out_of_range: usize,
    /// Pairs of triangles whose lightmap UVs overlap (only non-zero with `allow_overlap`).
    pub uv_overlapping_pairs: usize,
    /// Normals were generated for primitives that had none.
    pub normals_generated: usize,
    /// Free-form notes (one line each) for the user.
    pub notes: Vec<String>,
}

/// One world-space scene.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Where it was loaded from, for messages.
    pub source: String,
    pub positions: Vec<Vec3>,
    /// Unit shading normals, world space.
    pub normals: Vec<Vec3>,
    /// Lightmap UVs (`TEXCOORD_1` or generated), in [0, 1] for a valid level.
    pub uv1: Vec<Vec2>,
    /// UVs the material's albedo texture uses (zero when untextured).
    pub uv_albedo: Vec<Vec2>,
    pub triangles: Vec<Triangle>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<Light>,
    pub cameras: Vec<Camera>,
    /// Rigid objects that may move at run time, in the order their nodes were met.
    pub movables: Vec<Movable>,
    /// Every glTF node's name (`node N` without one), by node index, for messages.
    pub node_names: Vec<String>,
    pub report: LoadReport,
}

/// A glTF node marked movable (`extras: {"prm": {"movable": true}}`) with its subtree: a rigid
/// object whose triangles have `object` = its index + 1. Its motion (a rig's `objects`) is
/// given in its own frame, on top of `rest` ([`crate::rig`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Movable {
    pub name: String,
    /// Its glTF node index.
    pub node: u32,
    /// The node's world transform in the file: the object at rest.
    pub rest: Mat4,
}

impl Scene {
    /// A one-material scene from raw arrays (tests and tools): positions, lightmap UVs and a
    /// triangle list, albedo 0.5 everywhere, normals from the faces.
    pub fn from_mesh(positions: Vec<Vec3>, uv1: Vec<Vec2>, indices: &[u32]) -> Scene {
        let normals = generate_normals(&positions, indices);
        let n = positions.len();
        let triangles = indices
            .chunks_exact(3)
            .enumerate()
            .map(|(k, t)| Triangle {
                v: [t[0], t[1], t[2]],
                material: 0,
                node: 0,
                object: 0,
                mesh: 0,
                primitive: 0,
                index: k as u32,
            })
            .collect();
        Scene {
            source: "mesh".into(),
            positions,
            normals,
            uv1,
            uv_albedo: vec![Vec2::ZERO; n],
            triangles,
            materials: vec![Material { albedo: Vec3::splat(0.5), ..Default::default() }],
            ..Default::default()
        }
    }

    /// The three corner positions of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let v = self.triangles[t].v;
        [self.positions[v[0] as usize], self.positions[v[1] as usize], self.positions[v[2] as usize]]
    }

    /// The three lightmap UVs of triangle `t`.
    #[inline]
    pub fn uv1_corners(&self, t: usize) -> [Vec2; 3] {
        let v = self.triangles[t].v;
        [self.uv1[v[0] as usize], self.uv1[v[1] as usize], self.uv1[v[2] as usize]]
    }

    /// Unit geometric normal of triangle `t` (front face, counter-clockwise).
    #[inline]
    pub fn face_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// The one sidedness rule of every tracer: a ray travelling along `dir` that hits triangle
    /// `t` sees its front face (the face normal is returned), the back of a double-sided
    /// surface (the negated normal: it shades like a front), or the back of a one-sided
    /// surface, which absorbs (`None`: closed solids have one-sided walls, and light that got
    /// behind one must not bounce on).
    #[inline]
    pub fn facing_normal(&self, t: usize, dir: Vec3) -> Option<Vec3> {
        let n = self.face_normal(t);
        if n.dot(dir) > 0.0 {
            self.material(t).double_sided.then_some(-n)
        } else {
            Some(n)
        }
    }

    /// Area of triangle `t` in square scene units.
    #[inline]
    pub fn area(&self, t: usize) -> f32 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Point of triangle `t` at barycentrics `(w0, w1, w2)`.
    #[inline]
    pub fn point(&self, t: usize, bary: Vec3) -> Vec3 {
        let [a, b, c] = self.corners(t);
        a * bary.x + b * bary.y + c * bary.z
    }

    /// Linear albedo of triangle `t` at barycentrics `bary` (factor x texture).
    pub fn albedo(&self, t: usize, bary: Vec3) -> Vec3 {
        let tri = &self.triangles[t];
        let m = &self.materials[tri.material as usize];
        match m.albedo_texture {
            None => m.albedo,
            Some(ti) => {
                let v = tri.v;
                let uv = self.uv_albedo[v[0] as usize] * bary.x
                    + self.uv_albedo[v[1] as usize] * bary.y
                    + self.uv_albedo[v[2] as usize] * bary.z;
                m.albedo * self.textures[ti as usize].sample(uv)
            }
        }
    }

    /// The material of triangle `t`.
    #[inline]
    pub fn material(&self, t: usize) -> &Material {
        &self.materials[self.triangles[t].material as usize]
    }

    /// The emissive surfaces as polygon area lights for the bakers (paper 001 §3.2): coplanar
    /// triangles of one node and material merged into convex polygons
    /// ([`crate::emitters::emitters`]), each of the material's radiance (the back face of a
    /// double-sided material emits too). The ground truth does not take these: its paths meet
    /// the emitters themselves, which checks the bakers' lights independently.
    pub fn emissive_lights(&self) -> Vec<crate::Light> {
        crate::emitters::emitters(self, |_| true).into_iter().map(|e| e.light).collect()
    }

    /// Axis-aligned bounds (min, max) of all vertices; zero for an empty scene.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        if self.positions.is_empty() {
            return (Vec3::ZERO, Vec3::ZERO);
        }
        self.positions
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
    }

    /// Length of the bounds' diagonal: the scene's scale for offsets and tolerances.
    pub fn diagonal(&self) -> f32 {
        let (lo, hi) = self.bounds();
        (hi - lo).length()
    }

    /// Total surface area.
    pub fn total_area(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.area(t) as f64).sum()
    }

    /// Distance from `p` to triangle `t` (to its plane inside it, else to its nearest edge);
    /// infinite for a degenerate triangle.
    pub fn distance_to_triangle(&self, t: usize, p: Vec3) -> f32 {
        let [a, b, c] = self.corners(t);
        let Some(n) = (b - a).cross(c - a).try_normalize() else { return f32::INFINITY };
        let q = p - n * n.dot(p - a);
        let edges = [(a, b), (b, c), (c, a)];
        if edges.iter().all(|&(u, v)| (v - u).cross(q - u).dot(n) >= 0.0) {
            return (p - q).length();
        }
        edges
            .iter()
            .map(|&(u, v)| {
                let s = ((p - u).dot(v - u) / (v - u).length_squared()).clamp(0.0, 1.0);
                (p - (u + (v - u) * s)).length()
            })
            .fold(f32::INFINITY, f32::min)
    }

    /// Distance from `p` to the nearest surface, by brute force over the triangles (for tools
    /// and tests: where a light sits, not a per-frame query).
    pub fn nearest_surface_distance(&self, p: Vec3) -> f32 {
        (0..self.triangles.len()).map(|t| self.distance_to_triangle(t, p)).fold(f32::INFINITY, f32::min)
    }

    /// The scene with every movable object moved: `poses[k]` is movable k's rigid world-space
    /// transform from its rest pose ([`crate::rig::Motion::at_time`]). Static geometry, the
    /// lightmap UVs and the triangle list are unchanged, so texels keep their triangles.
    pub fn moved(&self, poses: &[Mat4]) -> Scene {
        let mut out = self.clone();
        if self.movables.is_empty() {
            return out;
        }
        let mut object_of_vertex = vec![0u32; self.positions.len()];
        for t in &self.triangles {
            for v in t.v {
                object_of_vertex[v as usize] = t.object;
            }
        }
        for (v, &o) in object_of_vertex.iter().enumerate() {
            if o == 0 {
                continue;
            }
            let m = poses.get(o as usize - 1).copied().unwrap_or(Mat4::IDENTITY);
            out.positions[v] = m.transform_point3(self.positions[v]);
            out.normals[v] = m.transform_vector3(self.normals[v]).normalize_or_zero();
        }
        out
    }

    /// The object (0 static, k movable k - 1) triangle `t` belongs to.
    #[inline]
    pub fn object(&self, t: usize) -> u32 {
        self.triangles[t].object
    }

    /// "node N mesh M primitive P triangle T" for messages.
    pub fn describe_triangle(&self, t: usize) -> String {
        let tri = &self.triangles[t];
        format!("node {} mesh {} primitive {} triangle {}", tri.node, tri.mesh, tri.primitive, tri.index)
    }
}

/// Area-weighted vertex normals of an indexed triangle list.
pub fn generate_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in indices.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.into_iter().map(|n| n.normalize_or_zero()).collect()
}
