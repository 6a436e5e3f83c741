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
    /// The light's glTF `extras` (the `prm_*` keys of [`crate::gltf_load`]'s lights).
    pub extras: Option<Value>,
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
    /// The node's glTF `extras` (`{"prm": {"movable": true}}` marks a movable object).
    pub extras: Option<Value>,
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
        let mut buffer = BinaryBuffer::default();
        let meshes: Vec<Value> = self.meshes.iter().map(|m| mesh_json(m, &mut buffer)).collect();
        buffer.align();
        let materials: Vec<Value> = self.materials.iter().map(material_json).collect();
        let lights: Vec<Value> = self.lights.iter().map(light_json).collect();
        let mut cameras = Vec::new();
        let nodes: Vec<Value> = self.nodes.iter().map(|n| node_json(n, &mut cameras)).collect();
        let BinaryBuffer { bin, views, accessors } = buffer;
        let mut doc = json!({
            "asset": {"version": "2.0", "generator": "prm"},
            "scene": 0,
            "scenes": [{"nodes": self.root_nodes()}],
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

    /// The nodes no other node lists as a child, in index order.
    fn root_nodes(&self) -> Vec<usize> {
        let is_child: Vec<bool> =
            (0..self.nodes.len()).map(|i| self.nodes.iter().any(|n| n.children.contains(&i))).collect();
        (0..self.nodes.len()).filter(|&i| !is_child[i]).collect()
    }

    /// The `.glb` bytes.
    pub fn to_glb(&self) -> Vec<u8> {
        let (doc, bin) = self.to_json_and_bin();
        glb_bytes(&doc, &bin)
    }
}

/// glTF `bufferView.target` and `accessor.componentType` codes (OpenGL enums).
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const UNSIGNED_INT: u32 = 5125;
const FLOAT: u32 = 5126;

/// The binary buffer being written, with a buffer view and an accessor per array in it.
#[derive(Default)]
struct BinaryBuffer {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl BinaryBuffer {
    /// Pad the buffer to a 4-byte boundary with zeros.
    fn align(&mut self) {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
    }

    /// Append `bytes` (4-byte aligned) with a buffer view and an accessor of `count` elements of
    /// type `ty` and component type `comp`, optionally with per-component bounds; returns the
    /// accessor index.
    fn push(
        &mut self,
        bytes: &[u8],
        target: u32,
        comp: u32,
        count: usize,
        ty: &str,
        minmax: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        self.align();
        self.views.push(
            json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len(), "target": target}),
        );
        self.bin.extend_from_slice(bytes);
        let mut acc =
            json!({"bufferView": self.views.len() - 1, "componentType": comp, "count": count, "type": ty});
        if let Some((lo, hi)) = minmax {
            acc["min"] = json!(lo);
            acc["max"] = json!(hi);
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }

    /// Append float vectors (VEC2, VEC3) as a vertex attribute; returns the accessor index.
    fn push_vertex_attribute<const N: usize>(
        &mut self,
        values: &[[f32; N]],
        ty: &str,
        minmax: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        let bytes: Vec<u8> = values.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        self.push(&bytes, ARRAY_BUFFER, FLOAT, values.len(), ty, minmax)
    }
}

/// Per-component bounds of the finite coordinates of `positions` (glTF requires them on POSITION).
fn position_bounds(positions: &[[f32; 3]]) -> (Vec<f32>, Vec<f32>) {
    let (mut lo, mut hi) = (vec![f32::MAX; 3], vec![f32::MIN; 3]);
    for p in positions {
        for k in 0..3 {
            if p[k].is_finite() {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    (lo, hi)
}

/// A mesh with its one triangle-list primitive; its arrays go into `buffer`.
fn mesh_json(m: &GlbMesh, buffer: &mut BinaryBuffer) -> Value {
    let mut attrs = serde_json::Map::new();
    let pos = buffer.push_vertex_attribute(&m.positions, "VEC3", Some(position_bounds(&m.positions)));
    attrs.insert("POSITION".into(), json!(pos));
    if let Some(n) = &m.normals {
        attrs.insert("NORMAL".into(), json!(buffer.push_vertex_attribute(n, "VEC3", None)));
    }
    if let Some(uv) = &m.uv1 {
        attrs.insert("TEXCOORD_1".into(), json!(buffer.push_vertex_attribute(uv, "VEC2", None)));
    }
    let mut prim = json!({"attributes": attrs, "mode": 4});
    if let Some(idx) = &m.indices {
        let bytes: Vec<u8> = idx.iter().flat_map(|x| x.to_le_bytes()).collect();
        prim["indices"] =
            json!(buffer.push(&bytes, ELEMENT_ARRAY_BUFFER, UNSIGNED_INT, idx.len(), "SCALAR", None));
    }
    if let Some(mat) = m.material {
        prim["material"] = json!(mat);
    }
    json!({"name": m.name, "primitives": [prim]})
}

/// A metallic-roughness material: the base colour, not metallic, fully rough.
fn material_json(m: &GlbMaterial) -> Value {
    json!({
        "name": m.name,
        "pbrMetallicRoughness": {
            "baseColorFactor": m.base_color, "metallicFactor": 0.0, "roughnessFactor": 1.0,
        },
        "emissiveFactor": m.emissive,
        "doubleSided": m.double_sided,
    })
}

/// A `KHR_lights_punctual` light.
fn light_json(l: &GlbLight) -> Value {
    let mut v = json!({"name": l.name, "type": l.kind, "color": l.color, "intensity": l.intensity});
    if l.kind == "spot" {
        v["spot"] = json!({"innerConeAngle": l.inner, "outerConeAngle": l.outer});
    }
    if let Some(r) = l.range {
        v["range"] = json!(r);
    }
    if let Some(e) = &l.extras {
        v["extras"] = e.clone();
    }
    v
}

/// A node; its camera, if any, is appended to `cameras` and referenced by index.
fn node_json(n: &GlbNode, cameras: &mut Vec<Value>) -> Value {
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
    if let Some(e) = &n.extras {
        v["extras"] = e.clone();
    }
    v
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
