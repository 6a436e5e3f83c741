//! Generator of the bundled scenes in `assets/` (`prm gen-assets`).
//!
//! - `cornell.glb`: the Cornell box from its published measurements (millimetres, here metres),
//!   reflectances as RGB albedos, one point light below the ceiling, the measured camera.
//! - `chamber.glb`: a hall with two arcades of pillars and arches (about 3,600 triangles) and
//!   two lights, standing in for paper 004's marble chamber.
//! - `two_rooms.glb`: two rooms joined by a door in a 10 cm wall, the light in one room: the
//!   light-leak test.
//! - `doorway.glb`: the two rooms with a door that opens and a block that slides, movable
//!   nodes for paper 003's moving objects (`doorway_rig.json` moves them).
//!
//! Surfaces are one-sided and face the space they bound. Lightmap UVs (`TEXCOORD_1`) come from
//! `uvunwrap`, each quad kept in one chart, packed for a 256^2 atlas with 2-texel padding.

use glam::Vec3;
use prm::glb::{GlbLight, GlbMaterial, GlbMesh, GlbNode, GlbScene};

/// Geometry collected per material, as quads and triangles.
#[derive(Default)]
pub struct Builder {
    materials: Vec<GlbMaterial>,
    /// Per material: the movable object (node name, pivot) its geometry forms, if any.
    movable: Vec<Option<(String, Vec3)>>,
    /// Per material: positions, normals, indices, polygon id per triangle.
    parts: Vec<Part>,
    polygons: u32,
}

#[derive(Default, Clone)]
struct Part {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    indices: Vec<u32>,
    polygon: Vec<u32>,
}

impl Builder {
    /// Add a material; returns its index.
    pub fn material(&mut self, name: &str, albedo: [f32; 3]) -> usize {
        self.materials.push(GlbMaterial {
            name: name.into(),
            base_color: [albedo[0], albedo[1], albedo[2], 1.0],
            emissive: [0.0; 3],
            double_sided: false,
        });
        self.parts.push(Part::default());
        self.movable.push(None);
        self.materials.len() - 1
    }

    /// A material whose geometry is a movable object of its own: one glTF node named `object`
    /// at `pivot` (positions stay in world space here), marked `{"prm": {"movable": true}}`.
    pub fn movable_material(&mut self, name: &str, albedo: [f32; 3], object: &str, pivot: Vec3) -> usize {
        let m = self.material(name, albedo);
        self.movable[m] = Some((object.into(), pivot));
        m
    }

    /// Turn the meshes of movable materials into movable nodes at their pivots.
    fn place_movables(movable: &[Option<(String, Vec3)>], mesh_of: &[(usize, usize)], scene: &mut GlbScene) {
        for &(m, mesh) in mesh_of {
            let Some((name, pivot)) = &movable[m] else { continue };
            for p in &mut scene.meshes[mesh].positions {
                *p = (Vec3::from_array(*p) - *pivot).to_array();
            }
            if let Some(node) = scene.nodes.iter_mut().find(|n| n.mesh == Some(mesh)) {
                node.name = name.clone();
                node.translation = Some(pivot.to_array());
                node.extras = Some(serde_json::json!({"prm": {"movable": true}}));
            }
        }
    }

    /// A planar convex polygon, counter-clockwise seen from its front (fan-triangulated).
    pub fn polygon(&mut self, m: usize, pts: &[Vec3]) {
        let n = (pts[1] - pts[0]).cross(pts[2] - pts[0]).normalize_or_zero();
        let part = &mut self.parts[m];
        let base = part.positions.len() as u32;
        for p in pts {
            part.positions.push(p.to_array());
            part.normals.push(n.to_array());
        }
        for k in 1..pts.len() as u32 - 1 {
            part.indices.extend_from_slice(&[base, base + k, base + k + 1]);
            part.polygon.push(self.polygons);
        }
        self.polygons += 1;
    }

    /// A quad a-b-c-d, counter-clockwise seen from its front.
    pub fn quad(&mut self, m: usize, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        self.polygon(m, &[a, b, c, d]);
    }

    /// An axis-aligned box with faces pointing out (`inward` = false) or in (a room).
    /// `skip` lists faces to leave out: 0 -x, 1 +x, 2 -y, 3 +y, 4 -z, 5 +z.
    pub fn boxed(&mut self, m: usize, lo: Vec3, hi: Vec3, inward: bool, skip: &[usize]) {
        let c = |x: usize, y: usize, z: usize| {
            Vec3::new(
                if x == 0 { lo.x } else { hi.x },
                if y == 0 { lo.y } else { hi.y },
                if z == 0 { lo.z } else { hi.z },
            )
        };
        // Outward counter-clockwise corner lists.
        let faces = [
            [c(0, 0, 0), c(0, 0, 1), c(0, 1, 1), c(0, 1, 0)],
            [c(1, 0, 0), c(1, 1, 0), c(1, 1, 1), c(1, 0, 1)],
            [c(0, 0, 0), c(1, 0, 0), c(1, 0, 1), c(0, 0, 1)],
            [c(0, 1, 0), c(0, 1, 1), c(1, 1, 1), c(1, 1, 0)],
            [c(0, 0, 0), c(0, 1, 0), c(1, 1, 0), c(1, 0, 0)],
            [c(0, 0, 1), c(1, 0, 1), c(1, 1, 1), c(0, 1, 1)],
        ];
        for (k, f) in faces.iter().enumerate() {
            if skip.contains(&k) {
                continue;
            }
            if inward {
                self.quad(m, f[3], f[2], f[1], f[0]);
            } else {
                self.quad(m, f[0], f[1], f[2], f[3]);
            }
        }
    }

    /// A vertical cylinder (sides only) of `sides` facets and `rings` bands, facing out.
    pub fn cylinder(&mut self, m: usize, base: Vec3, radius: f32, height: f32, sides: u32, rings: u32) {
        let at = |k: u32, r: u32| {
            let a = std::f32::consts::TAU * k as f32 / sides as f32;
            base + Vec3::new(radius * a.cos(), height * r as f32 / rings as f32, radius * a.sin())
        };
        for r in 0..rings {
            for k in 0..sides {
                self.quad(m, at(k, r), at(k, r + 1), at(k + 1, r + 1), at(k + 1, r));
            }
        }
    }

    /// The level without lightmap UVs (`TEXCOORD_1`): the loader generates them.
    pub fn finish_without_uv1(self) -> GlbScene {
        let mut scene = GlbScene { materials: self.materials, ..Default::default() };
        for (m, p) in self.parts.into_iter().enumerate() {
            if p.indices.is_empty() {
                continue;
            }
            scene.add_mesh(GlbMesh {
                name: scene.materials[m].name.clone(),
                positions: p.positions,
                normals: Some(p.normals),
                uv1: None,
                indices: Some(p.indices),
                material: Some(m),
            });
        }
        scene
    }

    /// Unwrap lightmap UVs and produce the level.
    pub fn finish(self, resolution: u32) -> Result<GlbScene, String> {
        let used: Vec<usize> = (0..self.parts.len()).filter(|&m| !self.parts[m].indices.is_empty()).collect();
        let inputs: Vec<uvunwrap::MeshInput> = used
            .iter()
            .map(|&m| {
                let p = &self.parts[m];
                uvunwrap::MeshInput {
                    polygons: Some(&p.polygon),
                    ..uvunwrap::MeshInput::new(&p.positions, &p.indices)
                }
            })
            .collect();
        let (atlas, v_scale, _) =
            prm::uv::unwrap_meshes(&inputs, prm::density::UnwrapLayout::OnePage(resolution))?;
        let mut scene = GlbScene { materials: self.materials, ..Default::default() };
        let mut mesh_of = Vec::new();
        for (&m, out) in used.iter().zip(&atlas.meshes) {
            let p = &self.parts[m];
            mesh_of.push((m, scene.meshes.len()));
            scene.add_mesh(GlbMesh {
                name: scene.materials[m].name.clone(),
                positions: out.vertices.iter().map(|v| p.positions[v.xref as usize]).collect(),
                normals: Some(out.vertices.iter().map(|v| p.normals[v.xref as usize]).collect()),
                uv1: Some(out.vertices.iter().map(|v| [v.uv[0], v.uv[1] * v_scale]).collect()),
                indices: Some(out.indices.clone()),
                material: Some(m),
            });
        }
        Self::place_movables(&self.movable, &mesh_of, &mut scene);
        Ok(scene)
    }
}

fn point_light(name: &str, color: [f32; 3], intensity: f32) -> GlbLight {
    GlbLight {
        name: name.into(),
        kind: "point",
        color,
        intensity,
        inner: 0.0,
        outer: 0.0,
        range: None,
        extras: None,
    }
}

fn camera(scene: &mut GlbScene, name: &str, eye: Vec3, target: Vec3, yfov: f32) {
    scene.add_node(GlbNode {
        name: name.into(),
        translation: Some(eye.to_array()),
        rotation: Some(prm::glb::look_rotation(target - eye, Vec3::Y)),
        camera: Some((yfov, 1.0)),
        ..Default::default()
    });
}

/// Cornell box albedos (RGB fits of the measured spectra).
pub const CORNELL_WHITE: [f32; 3] = [0.725, 0.71, 0.68];
pub const CORNELL_RED: [f32; 3] = [0.63, 0.065, 0.05];
pub const CORNELL_GREEN: [f32; 3] = [0.14, 0.45, 0.091];

/// The Cornell box, from the published measurements (converted from mm to m).
pub fn cornell() -> Result<GlbScene, String> {
    let mut b = Builder::default();
    let white = b.material("white", CORNELL_WHITE);
    let red = b.material("red", CORNELL_RED);
    let green = b.material("green", CORNELL_GREEN);
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * 0.001;
    // Floor, ceiling, back wall, right (green) and left (red) walls: facing into the box.
    b.quad(white, v(552.8, 0.0, 0.0), v(0.0, 0.0, 0.0), v(0.0, 0.0, 559.2), v(549.6, 0.0, 559.2));
    b.quad(white, v(556.0, 548.8, 0.0), v(556.0, 548.8, 559.2), v(0.0, 548.8, 559.2), v(0.0, 548.8, 0.0));
    b.quad(white, v(549.6, 0.0, 559.2), v(0.0, 0.0, 559.2), v(0.0, 548.8, 559.2), v(556.0, 548.8, 559.2));
    b.quad(green, v(0.0, 0.0, 559.2), v(0.0, 0.0, 0.0), v(0.0, 548.8, 0.0), v(0.0, 548.8, 559.2));
    b.quad(red, v(552.8, 0.0, 0.0), v(549.6, 0.0, 559.2), v(556.0, 548.8, 559.2), v(556.0, 548.8, 0.0));
    // Short block.
    b.quad(
        white,
        v(130.0, 165.0, 65.0),
        v(82.0, 165.0, 225.0),
        v(240.0, 165.0, 272.0),
        v(290.0, 165.0, 114.0),
    );
    b.quad(white, v(290.0, 0.0, 114.0), v(290.0, 165.0, 114.0), v(240.0, 165.0, 272.0), v(240.0, 0.0, 272.0));
    b.quad(white, v(130.0, 0.0, 65.0), v(130.0, 165.0, 65.0), v(290.0, 165.0, 114.0), v(290.0, 0.0, 114.0));
    b.quad(white, v(82.0, 0.0, 225.0), v(82.0, 165.0, 225.0), v(130.0, 165.0, 65.0), v(130.0, 0.0, 65.0));
    b.quad(white, v(240.0, 0.0, 272.0), v(240.0, 165.0, 272.0), v(82.0, 165.0, 225.0), v(82.0, 0.0, 225.0));
    // Tall block.
    b.quad(
        white,
        v(423.0, 330.0, 247.0),
        v(265.0, 330.0, 296.0),
        v(314.0, 330.0, 456.0),
        v(472.0, 330.0, 406.0),
    );
    b.quad(white, v(423.0, 0.0, 247.0), v(423.0, 330.0, 247.0), v(472.0, 330.0, 406.0), v(472.0, 0.0, 406.0));
    b.quad(white, v(472.0, 0.0, 406.0), v(472.0, 330.0, 406.0), v(314.0, 330.0, 456.0), v(314.0, 0.0, 456.0));
    b.quad(white, v(314.0, 0.0, 456.0), v(314.0, 330.0, 456.0), v(265.0, 330.0, 296.0), v(265.0, 0.0, 296.0));
    b.quad(white, v(265.0, 0.0, 296.0), v(265.0, 330.0, 296.0), v(423.0, 330.0, 247.0), v(423.0, 0.0, 247.0));
    let mut scene = b.finish(256)?;
    // The measured light opening is centred at (278, 548.8, 279.5); the point light hangs 10 cm
    // below it (closer, the ceiling above it becomes a 1/r^2 hot spot that dominates the
    // indirect light).
    scene.add_light(point_light("ceiling_light", [1.0, 0.85, 0.65], 8.0), v(278.0, 448.8, 279.5), -Vec3::Y);
    // Camera at (278, 273, -800) looking along +z; 35 mm lens on a 25 mm film.
    camera(
        &mut scene,
        "camera",
        v(278.0, 273.0, -800.0),
        v(278.0, 273.0, 0.0),
        2.0 * (12.5f32 / 35.0).atan(),
    );
    Ok(scene)
}

/// A hall with two arcades: 10 pillars, 8 arches, a dais, two lights.
pub fn chamber() -> Result<GlbScene, String> {
    let mut b = Builder::default();
    let wall = b.material("wall", [0.75, 0.72, 0.68]);
    let floor = b.material("floor", [0.55, 0.5, 0.45]);
    let marble = b.material("pillar", [0.8, 0.78, 0.74]);
    let arcade = b.material("arcade", [0.7, 0.68, 0.64]);
    let carpet = b.material("carpet", [0.6, 0.1, 0.08]);
    let apse = b.material("apse", [0.15, 0.3, 0.55]);
    let (hx, h, hz) = (6.0f32, 7.0f32, 10.0f32);
    // Half-width of the dais: clear of the pillar plinths at |x| = 3.5 +- 0.5.
    let dais = 2.5f32;
    // Shell: floor, ceiling, walls, facing in. The wall at +z (behind the dais) is blue. The
    // floor is cut around the dais and the carpet runner so no floor hides under them.
    let mut floor_rect = |m: usize, x0: f32, x1: f32, z0: f32, z1: f32| {
        b.quad(
            m,
            Vec3::new(x0, 0.0, z0),
            Vec3::new(x0, 0.0, z1),
            Vec3::new(x1, 0.0, z1),
            Vec3::new(x1, 0.0, z0),
        );
    };
    floor_rect(floor, -hx, -dais, -hz, hz);
    floor_rect(floor, -dais, -0.8, -hz, 6.5);
    floor_rect(floor, -0.8, 0.8, -hz, -9.0);
    floor_rect(carpet, -0.8, 0.8, -9.0, 6.5);
    floor_rect(floor, 0.8, dais, -hz, 6.5);
    floor_rect(floor, dais, hx, -hz, hz);
    b.quad(wall, Vec3::new(-hx, h, -hz), Vec3::new(hx, h, -hz), Vec3::new(hx, h, hz), Vec3::new(-hx, h, hz));
    b.quad(
        wall,
        Vec3::new(-hx, 0.0, -hz),
        Vec3::new(hx, 0.0, -hz),
        Vec3::new(hx, h, -hz),
        Vec3::new(-hx, h, -hz),
    );
    // The apse wall, cut around the dais (0.4 m high) that stands against it.
    let mut apse_rect = |x0: f32, x1: f32, y0: f32, y1: f32| {
        b.quad(
            apse,
            Vec3::new(x1, y0, hz),
            Vec3::new(x0, y0, hz),
            Vec3::new(x0, y1, hz),
            Vec3::new(x1, y1, hz),
        );
    };
    apse_rect(-hx, hx, 0.4, h);
    apse_rect(-hx, -dais, 0.0, 0.4);
    apse_rect(dais, hx, 0.0, 0.4);
    b.quad(
        wall,
        Vec3::new(-hx, 0.0, hz),
        Vec3::new(-hx, 0.0, -hz),
        Vec3::new(-hx, h, -hz),
        Vec3::new(-hx, h, hz),
    );
    b.quad(
        wall,
        Vec3::new(hx, 0.0, -hz),
        Vec3::new(hx, 0.0, hz),
        Vec3::new(hx, h, hz),
        Vec3::new(hx, h, -hz),
    );
    // Dais at the +z end, against the apse wall.
    b.boxed(carpet, Vec3::new(-dais, 0.0, 6.5), Vec3::new(dais, 0.4, hz), false, &[2, 5]);
    // Pillars: plinth, 24-sided shaft in 5 bands, capital; two rows of five.
    let (row_x, pr, spring) = (3.5f32, 0.35f32, 4.0f32);
    let zs = [-8.0f32, -4.0, 0.0, 4.0, 8.0];
    for &x in &[-row_x, row_x] {
        for &z in &zs {
            b.boxed(marble, Vec3::new(x - 0.5, 0.0, z - 0.5), Vec3::new(x + 0.5, 0.3, z + 0.5), false, &[2]);
            b.cylinder(marble, Vec3::new(x, 0.3, z), pr, spring - 0.6, 24, 5);
            b.boxed(
                marble,
                Vec3::new(x - 0.45, spring - 0.3, z - 0.45),
                Vec3::new(x + 0.45, spring, z + 0.45),
                false,
                &[3],
            );
        }
        arcade_row(&mut b, arcade, x, &zs, spring, 0.45, 6.2);
    }
    let mut scene = b.finish(256)?;
    scene.add_light(point_light("nave_lamp", [1.0, 0.9, 0.75], 60.0), Vec3::new(0.0, 5.0, -3.0), -Vec3::Y);
    scene.add_light(
        GlbLight {
            name: "dais_spot".into(),
            kind: "spot",
            color: [0.85, 0.9, 1.0],
            intensity: 250.0,
            inner: 0.45,
            outer: 0.6,
            range: None,
            extras: None,
        },
        Vec3::new(0.0, 6.8, 3.0),
        Vec3::new(0.0, -6.4, 5.0),
    );
    camera(&mut scene, "camera", Vec3::new(0.0, 2.2, -9.5), Vec3::new(0.0, 1.8, 4.0), 1.0);
    Ok(scene)
}

/// An arcade wall along z at `x`: arches between consecutive pillars, springing at `spring`,
/// wall from `spring` to `top`, half-thickness `ht`.
fn arcade_row(b: &mut Builder, m: usize, x: f32, zs: &[f32], spring: f32, ht: f32, top: f32) {
    let segs = 16;
    let (xl, xr) = (x - ht, x + ht);
    for pair in zs.windows(2) {
        let (za, zb) = (pair[0] + ht, pair[1] - ht);
        let (zc, r) = (0.5 * (za + zb), 0.5 * (zb - za));
        let arc = |k: u32| {
            let a = std::f32::consts::PI * (1.0 - k as f32 / segs as f32);
            (zc + r * a.cos(), spring + r * a.sin())
        };
        for k in 0..segs {
            let ((z0, y0), (z1, y1)) = (arc(k), arc(k + 1));
            // Spandrel strips on both faces, and the soffit under the arch.
            b.quad(
                m,
                Vec3::new(xl, y0, z0),
                Vec3::new(xl, y1, z1),
                Vec3::new(xl, top, z1),
                Vec3::new(xl, top, z0),
            );
            b.quad(
                m,
                Vec3::new(xr, y1, z1),
                Vec3::new(xr, y0, z0),
                Vec3::new(xr, top, z0),
                Vec3::new(xr, top, z1),
            );
            b.quad(
                m,
                Vec3::new(xl, y0, z0),
                Vec3::new(xr, y0, z0),
                Vec3::new(xr, y1, z1),
                Vec3::new(xl, y1, z1),
            );
        }
    }
    // Over each pillar, the wall between arches; the ends; the top.
    for z in zs {
        let z0 = z - ht;
        let z1 = z + ht;
        b.quad(
            m,
            Vec3::new(xl, spring, z1),
            Vec3::new(xl, top, z1),
            Vec3::new(xl, top, z0),
            Vec3::new(xl, spring, z0),
        );
        b.quad(
            m,
            Vec3::new(xr, spring, z0),
            Vec3::new(xr, top, z0),
            Vec3::new(xr, top, z1),
            Vec3::new(xr, spring, z1),
        );
    }
    let (zf, zl) = (zs[0] - ht, zs[zs.len() - 1] + ht);
    b.quad(
        m,
        Vec3::new(xl, spring, zf),
        Vec3::new(xl, top, zf),
        Vec3::new(xr, top, zf),
        Vec3::new(xr, spring, zf),
    );
    b.quad(
        m,
        Vec3::new(xr, spring, zl),
        Vec3::new(xr, top, zl),
        Vec3::new(xl, top, zl),
        Vec3::new(xl, spring, zl),
    );
    b.quad(m, Vec3::new(xl, top, zf), Vec3::new(xl, top, zl), Vec3::new(xr, top, zl), Vec3::new(xr, top, zf));
}

/// Two 4 x 3 x 4 m rooms joined by a 1 x 2.1 m door in a 10 cm wall; the light in room A.
pub fn two_rooms() -> Result<GlbScene, String> {
    let mut b = Builder::default();
    two_rooms_shell(&mut b);
    let mut scene = b.finish(256)?;
    scene.add_light(
        point_light("room_a_lamp", [1.0, 0.95, 0.85], 20.0),
        Vec3::new(-2.5, 2.4, -0.8),
        -Vec3::Y,
    );
    camera(&mut scene, "camera", Vec3::new(3.8, 1.6, 1.8), Vec3::new(-1.0, 1.0, -0.5), 1.1);
    Ok(scene)
}

/// Hinge of the doorway level's door (its node origin) and the door's size.
pub const DOOR_HINGE: Vec3 = Vec3::new(0.0, 0.0, -0.47);
/// Resting place of the doorway level's block (its node origin: the middle of its base).
pub const BLOCK_REST: Vec3 = Vec3::new(-2.2, 0.0, -1.0);

/// [`two_rooms`] with a door that opens and a block that slides (paper 003's moving objects):
/// the door (0.94 x 2.09 x 0.04 m, node `door`, origin on its hinge) closes the opening at rest
/// and turns about +Y into room A; the block (0.6 m cube without a base, node `block`) rests on
/// room A's floor. A lamp hangs in room A, a torch 15 cm from its end wall; room B is lit only
/// through the door. Atlas 128², the resolution paper 003 ran its Cornell box at.
pub fn doorway() -> Result<GlbScene, String> {
    let mut b = Builder::default();
    two_rooms_shell(&mut b);
    let wood = b.movable_material("door", [0.55, 0.36, 0.22], "door", DOOR_HINGE);
    b.boxed(wood, Vec3::new(-0.02, 0.005, -0.47), Vec3::new(0.02, 2.095, 0.47), false, &[]);
    let stone = b.movable_material("block", [0.35, 0.45, 0.7], "block", BLOCK_REST);
    let half = Vec3::new(0.3, 0.0, 0.3);
    b.boxed(stone, BLOCK_REST - half, BLOCK_REST + half + Vec3::Y * 0.6, false, &[2]);
    let mut scene = b.finish(128)?;
    scene.add_light(point_light("room_a_lamp", [1.0, 0.95, 0.85], 20.0), Vec3::new(-2.5, 2.4, 0.4), -Vec3::Y);
    scene.add_light(point_light("torch", [1.0, 0.6, 0.3], 3.0), Vec3::new(-3.85, 1.6, 0.3), -Vec3::Y);
    camera(&mut scene, "camera", Vec3::new(3.8, 1.6, 1.8), Vec3::new(-1.0, 1.0, -0.5), 1.1);
    Ok(scene)
}

/// The shell of [`two_rooms`]: two 4 x 3 x 4 m rooms (x < -5 cm and x > 5 cm, |z| < 2 m) and
/// the door opening |z| < 0.5 m, y < 2.1 m in the wall between them.
fn two_rooms_shell(b: &mut Builder) {
    let wall = b.material("wall", [0.7, 0.7, 0.7]);
    let floor = b.material("floor", [0.5, 0.45, 0.4]);
    let tint = b.material("room_b_wall", [0.3, 0.55, 0.35]);
    let (w, h, d, t) = (4.0f32, 3.0f32, 2.0f32, 0.05f32);
    let (door_z, door_h) = (0.5f32, 2.1f32);
    for (x0, x1, room_wall) in [(-w, -t, wall), (t, w, tint)] {
        b.quad(
            floor,
            Vec3::new(x0, 0.0, -d),
            Vec3::new(x0, 0.0, d),
            Vec3::new(x1, 0.0, d),
            Vec3::new(x1, 0.0, -d),
        );
        b.quad(wall, Vec3::new(x0, h, -d), Vec3::new(x1, h, -d), Vec3::new(x1, h, d), Vec3::new(x0, h, d));
        b.quad(
            room_wall,
            Vec3::new(x0, 0.0, -d),
            Vec3::new(x1, 0.0, -d),
            Vec3::new(x1, h, -d),
            Vec3::new(x0, h, -d),
        );
        b.quad(
            room_wall,
            Vec3::new(x1, 0.0, d),
            Vec3::new(x0, 0.0, d),
            Vec3::new(x0, h, d),
            Vec3::new(x1, h, d),
        );
    }
    // Outer end walls.
    b.quad(wall, Vec3::new(-w, 0.0, d), Vec3::new(-w, 0.0, -d), Vec3::new(-w, h, -d), Vec3::new(-w, h, d));
    b.quad(tint, Vec3::new(w, 0.0, -d), Vec3::new(w, 0.0, d), Vec3::new(w, h, d), Vec3::new(w, h, -d));
    // The thin wall at x = 0, both faces, with the door opening |z| < door_z, y < door_h.
    for (x, sign, m) in [(-t, -1.0f32, wall), (t, 1.0f32, tint)] {
        let face = |b: &mut Builder, z0: f32, z1: f32, y0: f32, y1: f32| {
            let (p0, p1, p2, p3) =
                (Vec3::new(x, y0, z0), Vec3::new(x, y0, z1), Vec3::new(x, y1, z1), Vec3::new(x, y1, z0));
            if sign > 0.0 {
                b.quad(m, p0, p3, p2, p1);
            } else {
                b.quad(m, p0, p1, p2, p3);
            }
        };
        face(b, -d, -door_z, 0.0, h);
        face(b, door_z, d, 0.0, h);
        face(b, -door_z, door_z, door_h, h);
    }
    // Door jambs, lintel and threshold floor.
    b.quad(
        wall,
        Vec3::new(-t, 0.0, -door_z),
        Vec3::new(t, 0.0, -door_z),
        Vec3::new(t, door_h, -door_z),
        Vec3::new(-t, door_h, -door_z),
    );
    b.quad(
        wall,
        Vec3::new(t, 0.0, door_z),
        Vec3::new(-t, 0.0, door_z),
        Vec3::new(-t, door_h, door_z),
        Vec3::new(t, door_h, door_z),
    );
    b.quad(
        wall,
        Vec3::new(-t, door_h, -door_z),
        Vec3::new(t, door_h, -door_z),
        Vec3::new(t, door_h, door_z),
        Vec3::new(-t, door_h, door_z),
    );
    b.quad(
        floor,
        Vec3::new(-t, 0.0, -door_z),
        Vec3::new(-t, 0.0, door_z),
        Vec3::new(t, 0.0, door_z),
        Vec3::new(t, 0.0, -door_z),
    );
}

/// The window of [`sunroom`]: its opening in the south wall (x, then y), and the wall's depth.
pub const SUNROOM_WINDOW: ([f32; 2], [f32; 2], f32) = ([-0.8, 0.8], [0.9, 2.3], 0.25);

/// A 6 x 3 x 5 m room lit by the sun through one window (the sunlit room of a game level,
/// which a time-of-day system moves): the opening 1.6 x 1.4 m in the south wall (z = -2.5,
/// 25 cm deep, with its reveals), a table and a cabinet, the sun from the south-west at 35
/// degrees and nothing outside. No sky: only the sun's light comes in.
pub fn sunroom() -> Result<GlbScene, String> {
    let mut b = Builder::default();
    let wall = b.material("plaster", [0.8, 0.77, 0.72]);
    let floor = b.material("floorboards", [0.5, 0.36, 0.24]);
    let ceiling = b.material("ceiling", [0.85, 0.85, 0.83]);
    let wood = b.material("table", [0.42, 0.3, 0.2]);
    let paint = b.material("cabinet", [0.3, 0.45, 0.6]);
    let (hx, h, hz) = (3.0f32, 3.0f32, 2.5f32);
    let ([x0, x1], [y0, y1], depth) = SUNROOM_WINDOW;
    let v = Vec3::new;
    b.quad(floor, v(-hx, 0.0, -hz), v(-hx, 0.0, hz), v(hx, 0.0, hz), v(hx, 0.0, -hz));
    b.quad(ceiling, v(-hx, h, -hz), v(hx, h, -hz), v(hx, h, hz), v(-hx, h, hz));
    b.quad(wall, v(-hx, 0.0, hz), v(-hx, 0.0, -hz), v(-hx, h, -hz), v(-hx, h, hz));
    b.quad(wall, v(hx, 0.0, -hz), v(hx, 0.0, hz), v(hx, h, hz), v(hx, h, -hz));
    b.quad(wall, v(hx, 0.0, hz), v(-hx, 0.0, hz), v(-hx, h, hz), v(hx, h, hz));
    // The south wall around the opening, facing +z.
    let south = |b: &mut Builder, xa: f32, xb: f32, ya: f32, yb: f32| {
        b.quad(wall, v(xa, ya, -hz), v(xb, ya, -hz), v(xb, yb, -hz), v(xa, yb, -hz));
    };
    south(&mut b, -hx, x0, 0.0, h);
    south(&mut b, x1, hx, 0.0, h);
    south(&mut b, x0, x1, 0.0, y0);
    south(&mut b, x0, x1, y1, h);
    // The reveals: sill, head and jambs, each facing into the opening.
    let zo = -hz - depth;
    b.quad(wall, v(x0, y0, zo), v(x0, y0, -hz), v(x1, y0, -hz), v(x1, y0, zo));
    b.quad(wall, v(x0, y1, zo), v(x1, y1, zo), v(x1, y1, -hz), v(x0, y1, -hz));
    b.quad(wall, v(x0, y0, zo), v(x0, y1, zo), v(x0, y1, -hz), v(x0, y0, -hz));
    b.quad(wall, v(x1, y0, zo), v(x1, y0, -hz), v(x1, y1, -hz), v(x1, y1, zo));
    // The outer face, so the wall is solid to the sun from outside too.
    let outer = |b: &mut Builder, xa: f32, xb: f32, ya: f32, yb: f32| {
        b.quad(wall, v(xa, ya, zo), v(xa, yb, zo), v(xb, yb, zo), v(xb, ya, zo));
    };
    outer(&mut b, -hx, x0, 0.0, h);
    outer(&mut b, x1, hx, 0.0, h);
    outer(&mut b, x0, x1, 0.0, y0);
    outer(&mut b, x0, x1, y1, h);
    // A table top on four legs in the sun's way, and a cabinet against the west wall.
    b.boxed(wood, v(-0.2, 0.72, -0.4), v(1.2, 0.76, 0.4), false, &[]);
    for (lx, lz) in [(-0.15, -0.35), (1.1, -0.35), (-0.15, 0.3), (1.1, 0.3)] {
        b.boxed(wood, v(lx, 0.0, lz), v(lx + 0.05, 0.72, lz + 0.05), false, &[2, 3]);
    }
    b.boxed(paint, v(-hx, 0.0, 0.6), v(-hx + 0.45, 1.9, 1.8), false, &[0, 2]);
    let mut scene = b.finish(256)?;
    let sun = GlbLight { kind: "directional", ..point_light("sun", [1.0, 0.93, 0.82], 12.0) };
    let toward = v(-0.35, 0.574, -0.74).normalize();
    scene.add_light(sun, v(0.0, 6.0, -8.0), -toward);
    camera(&mut scene, "camera", v(2.6, 1.7, 2.2), v(-0.6, 0.6, -1.2), 1.1);
    Ok(scene)
}

/// Room interior (x and z) and height, corridor length (the gap between rooms) and its cross
/// section, for [`halls`].
const HALL: f32 = 10.0;
const HALL_HEIGHT: f32 = 4.5;
const CORRIDOR: f32 = 3.0;
const DOOR_WIDTH: f32 = 2.0;
const DOOR_HEIGHT: f32 = 2.6;

/// A level of `nx` x `nz` pillared halls on a grid, each joined to its neighbours by a
/// corridor through doors in the walls; no lightmap UVs, so the loader's unwrapper lays out
/// the atlas. Every hall has a hanging lamp; every other one a torch 15 cm from a wall. Six
/// pillars of `sides` facets and `bands` bands per hall give the triangle count (32 x 8: about
/// 3,300 triangles a hall). Wall tints vary from hall to hall. A camera looks down the first
/// row from its first hall.
pub fn halls(nx: u32, nz: u32, sides: u32, bands: u32) -> GlbScene {
    let mut b = Builder::default();
    let floor = b.material("floor", [0.5, 0.46, 0.42]);
    let ceiling = b.material("ceiling", [0.78, 0.76, 0.72]);
    let stone = b.material("pillar", [0.8, 0.78, 0.74]);
    let corridor = b.material("corridor", [0.65, 0.63, 0.6]);
    let tints: [[f32; 3]; 4] = [[0.75, 0.72, 0.68], [0.62, 0.3, 0.22], [0.3, 0.5, 0.62], [0.45, 0.6, 0.35]];
    let walls: Vec<usize> =
        tints.iter().enumerate().map(|(k, &t)| b.material(&format!("wall_{k}"), t)).collect();
    let pitch = HALL + CORRIDOR;
    let origin = |i: u32, j: u32| Vec3::new(i as f32 * pitch, 0.0, j as f32 * pitch);
    let mut lights = Vec::new();
    for j in 0..nz {
        for i in 0..nx {
            let o = origin(i, j);
            let wall = walls[((i + 2 * j) % 4) as usize];
            let doors = [i > 0, i + 1 < nx, j > 0, j + 1 < nz];
            hall_shell(&mut b, o, floor, ceiling, wall, doors);
            // Six pillars in two rows, floor to ceiling.
            for (px, pz) in
                [(-2.5f32, -3.0f32), (-2.5, 0.0), (-2.5, 3.0), (2.5, -3.0), (2.5, 0.0), (2.5, 3.0)]
            {
                let c = o + Vec3::new(HALL * 0.5 + px, 0.0, HALL * 0.5 + pz);
                b.boxed(stone, c + Vec3::new(-0.45, 0.0, -0.45), c + Vec3::new(0.45, 0.3, 0.45), false, &[2]);
                b.cylinder(stone, c + Vec3::new(0.0, 0.3, 0.0), 0.3, HALL_HEIGHT - 0.6, sides, bands);
                let (lo, hi) = (Vec3::new(-0.4, HALL_HEIGHT - 0.3, -0.4), Vec3::new(0.4, HALL_HEIGHT, 0.4));
                b.boxed(stone, c + lo, c + hi, false, &[3]);
            }
            // A table in every hall, placed differently from hall to hall.
            let t =
                o + Vec3::new(HALL * 0.5 + [-0.8f32, 0.8][(i % 2) as usize], 0.0, 1.5 + (j % 3) as f32 * 3.0);
            b.boxed(floor, t + Vec3::new(-0.6, 0.0, -0.4), t + Vec3::new(0.6, 0.8, 0.4), false, &[2]);
            let shade = 0.8 + 0.05 * ((i * 7 + j * 3) % 5) as f32;
            let lamp = o + Vec3::new(HALL * 0.5 + 0.7 * (i % 3) as f32 - 0.7, 3.6, HALL * 0.5 - 1.5);
            lights.push((point_light(&format!("lamp_{i}_{j}"), [1.0, 0.9 * shade, 0.75], 30.0), lamp));
            if (i + j) % 2 == 0 {
                // A torch 15 cm off the hall's -x wall, 2 m up.
                let torch = o + Vec3::new(0.15, 2.0, HALL * 0.5 + 2.0);
                lights.push((point_light(&format!("torch_{i}_{j}"), [1.0, 0.6, 0.3], 6.0), torch));
            }
        }
    }
    // Corridors: +x from hall (i, j) to (i + 1, j), and +z from (i, j) to (i, j + 1).
    for j in 0..nz {
        for i in 0..nx {
            let o = origin(i, j);
            let (d0, d1) = (HALL * 0.5 - DOOR_WIDTH * 0.5, HALL * 0.5 + DOOR_WIDTH * 0.5);
            if i + 1 < nx {
                add_corridor(&mut b, corridor, floor, (o.x + HALL, o.x + pitch), (o.z + d0, o.z + d1), true);
            }
            if j + 1 < nz {
                add_corridor(&mut b, corridor, floor, (o.x + d0, o.x + d1), (o.z + HALL, o.z + pitch), false);
            }
        }
    }
    let mut scene = b.finish_without_uv1();
    for (light, at) in lights {
        scene.add_light(light, at, -Vec3::Y);
    }
    let eye = origin(0, 0) + Vec3::new(HALL * 0.5, 1.7, 0.6);
    camera(&mut scene, "camera", eye, eye + Vec3::new(0.0, -0.1, 1.0), 1.1);
    scene
}

/// A hall's floor, ceiling and four walls facing in, at corner `o`; `doors` (-x, +x, -z, +z)
/// cuts a door in the middle of that wall.
fn hall_shell(b: &mut Builder, o: Vec3, floor: usize, ceiling: usize, wall: usize, doors: [bool; 4]) {
    let (s, h) = (HALL, HALL_HEIGHT);
    let p = |x: f32, y: f32, z: f32| o + Vec3::new(x, y, z);
    b.quad(floor, p(0.0, 0.0, 0.0), p(0.0, 0.0, s), p(s, 0.0, s), p(s, 0.0, 0.0));
    b.quad(ceiling, p(0.0, h, 0.0), p(s, h, 0.0), p(s, h, s), p(0.0, h, s));
    // Wall k (-x, +x, -z, +z) maps (along, up) to a point, `along` running so that the quad
    // (a0,0)-(a1,0)-(a1,y)-(a0,y) faces into the hall.
    let at = |k: usize, a: f32, y: f32| match k {
        0 => p(0.0, y, s - a),
        1 => p(s, y, a),
        2 => p(a, y, 0.0),
        _ => p(s - a, y, s),
    };
    let (d0, d1) = (0.5 * (s - DOOR_WIDTH), 0.5 * (s + DOOR_WIDTH));
    for (k, &door) in doors.iter().enumerate() {
        let mut rect = |a0: f32, a1: f32, y0: f32, y1: f32| {
            b.quad(wall, at(k, a0, y0), at(k, a1, y0), at(k, a1, y1), at(k, a0, y1))
        };
        if door {
            rect(0.0, d0, 0.0, h);
            rect(d1, s, 0.0, h);
            rect(d0, d1, DOOR_HEIGHT, h);
        } else {
            rect(0.0, s, 0.0, h);
        }
    }
}

/// A corridor over [x0, x1] x [z0, z1], faces in, walled on its long sides: at z0 and z1 when
/// it runs along x, at x0 and x1 when along z.
fn add_corridor(
    b: &mut Builder,
    m: usize,
    floor: usize,
    (x0, x1): (f32, f32),
    (z0, z1): (f32, f32),
    along_x: bool,
) {
    let h = DOOR_HEIGHT;
    let v = Vec3::new;
    b.quad(floor, v(x0, 0.0, z0), v(x0, 0.0, z1), v(x1, 0.0, z1), v(x1, 0.0, z0));
    b.quad(m, v(x0, h, z0), v(x1, h, z0), v(x1, h, z1), v(x0, h, z1));
    if along_x {
        b.quad(m, v(x0, 0.0, z0), v(x1, 0.0, z0), v(x1, h, z0), v(x0, h, z0));
        b.quad(m, v(x1, 0.0, z1), v(x0, 0.0, z1), v(x0, h, z1), v(x1, h, z1));
    } else {
        b.quad(m, v(x0, 0.0, z1), v(x0, 0.0, z0), v(x0, h, z0), v(x0, h, z1));
        b.quad(m, v(x1, 0.0, z0), v(x1, 0.0, z1), v(x1, h, z1), v(x1, h, z0));
    }
}

/// The bundled large level: 4 x 4 halls, about 53,000 triangles, 24 lights.
pub fn halls_large() -> Result<GlbScene, String> {
    Ok(halls(4, 4, 32, 8))
}

/// Side-by-side spacing of [`chambers`]' copies (x, z): the chamber is 12 x 20 m, its walls
/// single surfaces, so a 1 m gap keeps every copy a closed room of its own.
pub const CHAMBER_PITCH: (f32, f32) = (13.0, 21.0);

/// `nx` x `nz` copies of the chamber side by side (issue 13's level of "16 copies of the
/// bundled chamber"), without lightmap UVs so that the unwrapper packs them, every node, mesh
/// and light copied with its place moved and its name suffixed `_I_J`; the first copy's camera
/// only. Each copy is a closed room: light does not pass between them.
pub fn chambers(nx: u32, nz: u32) -> Result<GlbScene, String> {
    grid_of(&chamber()?, "chamber", nx, nz, CHAMBER_PITCH)
}

/// Spacing of [`sunrooms`]' copies (x, z): the sunroom is 6 x 5 m (its south wall 25 cm
/// deep), so the rows stand 3.75 m apart and a 3 m row shades the windows of the one behind it
/// when the sun is below about 29 degrees (all of them below 11), as a street of houses does.
pub const SUNROOM_PITCH: (f32, f32) = (8.0, 9.0);

/// `nx` x `nz` copies of the sunroom under one sun (a sunlit level larger than one shadow map
/// resolves, for the runtime's tiled sun maps), laid out as [`chambers`] lays its copies.
pub fn sunrooms(nx: u32, nz: u32) -> Result<GlbScene, String> {
    grid_of(&sunroom()?, "sunroom", nx, nz, SUNROOM_PITCH)
}

/// `nx` x `nz` copies of `one` at `pitch` (x, z) apart, without lightmap UVs, every node, mesh
/// and light copied with its place moved and its name suffixed `_I_J`. The first copy's camera
/// only, and a directional light (the same sun over every copy) once, under its own name.
fn grid_of(one: &GlbScene, what: &str, nx: u32, nz: u32, pitch: (f32, f32)) -> Result<GlbScene, String> {
    let mut scene = GlbScene { materials: one.materials.clone(), ..Default::default() };
    for j in 0..nz {
        for i in 0..nx {
            let o = Vec3::new(i as f32 * pitch.0, 0.0, j as f32 * pitch.1);
            let first = (i, j) == (0, 0);
            for n in &one.nodes {
                if n.matrix.is_some() || !n.children.is_empty() {
                    return Err(format!("{what} node '{}' has a matrix or children", n.name));
                }
                let sun = n.light.is_some_and(|l| one.lights[l].kind == "directional");
                if (n.camera.is_some() || sun) && !first {
                    continue;
                }
                let mut c = n.clone();
                if !sun {
                    c.name = format!("{}_{i}_{j}", n.name);
                }
                c.translation = Some((Vec3::from_array(n.translation.unwrap_or_default()) + o).to_array());
                if let Some(m) = n.mesh {
                    let mut mesh = one.meshes[m].clone();
                    mesh.name = format!("{}_{i}_{j}", mesh.name);
                    mesh.uv1 = None;
                    scene.meshes.push(mesh);
                    c.mesh = Some(scene.meshes.len() - 1);
                }
                if let Some(l) = n.light {
                    let mut light = one.lights[l].clone();
                    if !sun {
                        light.name = format!("{}_{i}_{j}", light.name);
                    }
                    scene.lights.push(light);
                    c.light = Some(scene.lights.len() - 1);
                }
                scene.add_node(c);
            }
        }
    }
    Ok(scene)
}

/// A bundled scene's generator.
pub type SceneBuilder = fn() -> Result<GlbScene, String>;

/// All bundled scenes by file name.
pub fn all() -> Vec<(&'static str, SceneBuilder)> {
    vec![
        ("cornell.glb", cornell),
        ("chamber.glb", chamber),
        ("two_rooms.glb", two_rooms),
        ("doorway.glb", doorway),
        ("halls.glb", halls_large),
        ("sunroom.glb", sunroom),
    ]
}
