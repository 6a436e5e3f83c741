//! A small glTF 2.0 binary (`.glb`) writer: the bundled-scene generator and the loader's tests
//! build levels with it. It writes what [`crate::gltf_load`] reads: meshes with POSITION,
//! NORMAL, TEXCOORD_1 and indices, base-colour materials, a node hierarchy with TRS or matrix,
//! `KHR_lights_punctual` lights and perspective cameras.

use glam::{Mat3, Quat, Vec3};
use serde_json::{json, Value};

/// A material: linear base colour, emission, sidedness.
#[derive(Clone, Debug)]
pub struct GlbMaterial {
    pub name: String,
    pub base_color: [f32; 4],
    pub emissive: [f32; 3],
    pub double_sided: bool,
}

/// One triangle-list primitive (one mesh with one primitive).
#[derive(Clone, Debug, Default)]
pub struct GlbMesh {
    pub name: String,
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uv1: Option<Vec<[f32; 2]>>,
    /// `None` writes a non-indexed primitive.
    pub indices: Option<Vec<u32>>,
    pub material: Option<usize>,
}

/// A `KHR_lights_punctual` light.
#[derive(Clone, Debug)]
pub struct GlbLight {
    pub name: String,
    /// "point", "spot" or "directional".
    pub kind: &'static str,
    pub color: [f32; 3],
    pub intensity: f32,
    /// Spot cone half-angles (radians).
    pub inner: f32,
    pub outer: f32,
    pub range: Option<f32>,
}

/// A node: transform (TRS or matrix) and what hangs on it.
#[derive(Clone, Debug, Default)]
pub struct GlbNode {
    pub name: String,
    pub translation: Option<[f32; 3]>,
    pub rotation: Option<[f32; 4]>,
    pub scale: Option<[f32; 3]>,
    /// Column-major 4x4; used instead of TRS when present.
    pub matrix: Option<[f32; 16]>,
    pub mesh: Option<usize>,
    pub light: Option<usize>,
    /// (yfov radians, aspect) of a perspective camera on this node.
    pub camera: Option<(f32, f32)>,
    pub children: Vec<usize>,
}

/// A level to write.
#[derive(Clone, Debug, Default)]
pub struct GlbScene {
    pub materials: Vec<GlbMaterial>,
    pub meshes: Vec<GlbMesh>,
    pub lights: Vec<GlbLight>,
    pub nodes: Vec<GlbNode>,
}

/// The rotation that turns a node's -Z onto `dir` with +Y as close to `up` as possible
/// (for lights and cameras), as glTF's (x, y, z, w).
pub fn look_rotation(dir: Vec3, up: Vec3) -> [f32; 4] {
    let f = dir.normalize();
    let up = if f.cross(up).length_squared() < 1e-8 { Vec3::Z } else { up };
    let right = f.cross(up).normalize();
    let true_up = right.cross(f);
    let q = Quat::from_mat3(&Mat3::from_cols(right, true_up, -f)).normalize();
    q.to_array()
}

impl GlbScene {
    /// Add a node at the scene root; returns its index.
    pub fn add_node(&mut self, node: GlbNode) -> usize {
        self.nodes.push(node);
        self.nodes.len() - 1
    }

    /// Add a mesh with a root node placing it at the origin; returns the mesh index.
    pub fn add_mesh(&mut self, mesh: GlbMesh) -> usize {
        self.meshes.push(mesh);
        let m = self.meshes.len() - 1;
        let name = self.meshes[m].name.clone();
        self.add_node(GlbNode { name, mesh: Some(m), ..Default::default() });
        m
    }

    /// Add a light with a node at `position` pointing along `direction`.
    pub fn add_light(&mut self, light: GlbLight, position: Vec3, direction: Vec3) -> usize {
        let name = light.name.clone();
        self.lights.push(light);
        let l = self.lights.len() - 1;
        self.add_node(GlbNode {
            name,
            translation: Some(position.to_array()),
            rotation: Some(look_rotation(direction, Vec3::Y)),
            light: Some(l),
            ..Default::default()
        });
        l
    }

    /// The glTF JSON and its binary buffer.
    pub fn to_json_and_bin(&self) -> (Value, Vec<u8>) {
        let mut bin: Vec<u8> = Vec::new();
        let mut views = Vec::new();
        let mut accessors = Vec::new();
        let mut push = |bytes: &[u8],
                        target: u32,
                        comp: u32,
                        count: usize,
                        ty: &str,
                        minmax: Option<(Vec<f32>, Vec<f32>)>|
         -> usize {
            while bin.len() % 4 != 0 {
                bin.push(0);
            }
            views.push(
                json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len(), "target": target}),
            );
            bin.extend_from_slice(bytes);
            let mut acc =
                json!({"bufferView": views.len() - 1, "componentType": comp, "count": count, "type": ty});
            if let Some((lo, hi)) = minmax {
                acc["min"] = json!(lo);
                acc["max"] = json!(hi);
            }
            accessors.push(acc);
            accessors.len() - 1
        };
        let f32_bytes = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let mut meshes = Vec::new();
        for m in &self.meshes {
            let flat: Vec<f32> = m.positions.iter().flatten().copied().collect();
            let (mut lo, mut hi) = (vec![f32::MAX; 3], vec![f32::MIN; 3]);
            for p in &m.positions {
                for k in 0..3 {
                    if p[k].is_finite() {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
            }
            let mut attrs = serde_json::Map::new();
            let pos = push(&f32_bytes(&flat), 34962, 5126, m.positions.len(), "VEC3", Some((lo, hi)));
            attrs.insert("POSITION".into(), json!(pos));
            if let Some(n) = &m.normals {
                let flat: Vec<f32> = n.iter().flatten().copied().collect();
                attrs.insert(
                    "NORMAL".into(),
                    json!(push(&f32_bytes(&flat), 34962, 5126, n.len(), "VEC3", None)),
                );
            }
            if let Some(uv) = &m.uv1 {
                let flat: Vec<f32> = uv.iter().flatten().copied().collect();
                attrs.insert(
                    "TEXCOORD_1".into(),
                    json!(push(&f32_bytes(&flat), 34962, 5126, uv.len(), "VEC2", None)),
                );
            }
            let mut prim = json!({"attributes": attrs, "mode": 4});
            if let Some(idx) = &m.indices {
                let bytes: Vec<u8> = idx.iter().flat_map(|x| x.to_le_bytes()).collect();
                prim["indices"] = json!(push(&bytes, 34963, 5125, idx.len(), "SCALAR", None));
            }
            if let Some(mat) = m.material {
                prim["material"] = json!(mat);
            }
            meshes.push(json!({"name": m.name, "primitives": [prim]}));
        }
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let materials: Vec<Value> = self
            .materials
            .iter()
            .map(|m| {
                json!({
                    "name": m.name,
                    "pbrMetallicRoughness": {
                        "baseColorFactor": m.base_color, "metallicFactor": 0.0, "roughnessFactor": 1.0,
                    },
                    "emissiveFactor": m.emissive,
                    "doubleSided": m.double_sided,
                })
            })
            .collect();
        let lights: Vec<Value> = self
            .lights
            .iter()
            .map(|l| {
                let mut v =
                    json!({"name": l.name, "type": l.kind, "color": l.color, "intensity": l.intensity});
                if l.kind == "spot" {
                    v["spot"] = json!({"innerConeAngle": l.inner, "outerConeAngle": l.outer});
                }
                if let Some(r) = l.range {
                    v["range"] = json!(r);
                }
                v
            })
            .collect();
        let mut cameras = Vec::new();
        let nodes: Vec<Value> = self
            .nodes
            .iter()
            .map(|n| {
                let mut v = json!({"name": n.name});
                if let Some(m) = n.matrix {
                    v["matrix"] = json!(m);
                } else {
                    if let Some(t) = n.translation {
                        v["translation"] = json!(t);
                    }
                    if let Some(r) = n.rotation {
                        v["rotation"] = json!(r);
                    }
                    if let Some(s) = n.scale {
                        v["scale"] = json!(s);
                    }
                }
                if let Some(m) = n.mesh {
                    v["mesh"] = json!(m);
                }
                if let Some(l) = n.light {
                    v["extensions"] = json!({"KHR_lights_punctual": {"light": l}});
                }
                if let Some((yfov, aspect)) = n.camera {
                    cameras.push(json!({"name": n.name, "type": "perspective",
                        "perspective": {"yfov": yfov, "aspectRatio": aspect, "znear": 0.01}}));
                    v["camera"] = json!(cameras.len() - 1);
                }
                if !n.children.is_empty() {
                    v["children"] = json!(n.children);
                }
                v
            })
            .collect();
        let is_child: Vec<bool> =
            (0..self.nodes.len()).map(|i| self.nodes.iter().any(|n| n.children.contains(&i))).collect();
        let roots: Vec<usize> = (0..self.nodes.len()).filter(|&i| !is_child[i]).collect();
        let mut doc = json!({
            "asset": {"version": "2.0", "generator": "prm"},
            "scene": 0,
            "scenes": [{"nodes": roots}],
            "nodes": nodes,
            "meshes": meshes,
            "accessors": accessors,
            "bufferViews": views,
            "buffers": [{"byteLength": bin.len()}],
        });
        if !materials.is_empty() {
            doc["materials"] = json!(materials);
        }
        if !cameras.is_empty() {
            doc["cameras"] = json!(cameras);
        }
        if !lights.is_empty() {
            doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
            doc["extensions"] = json!({"KHR_lights_punctual": {"lights": lights}});
        }
        (doc, bin)
    }

    /// The `.glb` bytes.
    pub fn to_glb(&self) -> Vec<u8> {
        let (doc, bin) = self.to_json_and_bin();
        glb_bytes(&doc, &bin)
    }
}

/// Pack a glTF JSON document and binary buffer into `.glb` container bytes.
pub fn glb_bytes(doc: &Value, bin: &[u8]) -> Vec<u8> {
    let mut json = serde_json::to_vec(doc).unwrap_or_default();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out
}
