//! The node hierarchy flattened to world transforms (matrix or TRS), and what hangs on each
//! node: mesh primitives, a light, a camera.

use std::path::Path;

use glam::Mat4;

use super::lights::read_light;
use super::primitive::{read_primitive, Prim, PrimSource, Use};
use super::{Place, SceneError};
use crate::scene::{Camera, LoadReport, Movable, Scene};

/// Visit every node with its world transform and the object it belongs to (0: the static
/// level; k: the k-th movable node met, numbered from 1, whose subtree moves with it).
/// Depth-first pre-order, children in file order: scene order decides ties between triangles
/// (texel ownership), so it must be the natural one.
pub(super) fn walk<'d>(
    path: &Path,
    document: &'d gltf::Document,
    scene: &mut Scene,
    mut visit: impl FnMut(&gltf::Node<'d>, Mat4, u32, &mut Scene) -> Result<(), SceneError>,
) -> Result<(), SceneError> {
    let mut stack: Vec<(gltf::Node, Mat4, usize, u32)> =
        root_nodes(document).into_iter().rev().map(|n| (n, Mat4::IDENTITY, 0, 0)).collect();
    // glTF's nodes form disjoint trees: a node met twice has two parents, or is a root and a
    // child, or sits on a cycle. Walked again it would be built twice, and a file of a few KB
    // that makes each of 40 pairs of nodes the children of both nodes before them would be
    // walked 2^40 times.
    let mut seen = vec![false; document.nodes().len()];
    while let Some((node, parent, depth, parent_object)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(SceneError::Malformed {
                path: path.into(),
                what: format!(
                    "node {}{} is reached twice (two parents, a root that is also a child, or a \
                     cycle); glTF nodes form disjoint trees",
                    node.index(),
                    node.name().map_or(String::new(), |n| format!(" ('{n}')")),
                ),
            });
        }
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
        let object = if movable(path, &node)? {
            if parent_object != 0 {
                let outer = &scene.movables[parent_object as usize - 1].name;
                return Err(SceneError::Movable {
                    path: path.into(),
                    node: node_name(&node),
                    what: format!("it is inside movable node '{outer}'; movables do not nest"),
                });
            }
            scene.movables.push(Movable { name: node_name(&node), node: node.index() as u32, rest: world });
            scene.movables.len() as u32
        } else {
            parent_object
        };
        visit(&node, world, object, scene)?;
        let children: Vec<gltf::Node> = node.children().collect();
        for child in children.into_iter().rev() {
            stack.push((child, world, depth + 1, object));
        }
    }
    Ok(())
}

/// A node's name, or `node N` for one without.
pub(super) fn node_name(node: &gltf::Node) -> String {
    node.name().map(str::to_string).unwrap_or_else(|| format!("node {}", node.index()))
}

/// Whether the node's extras mark it movable: `{"prm": {"movable": true}}`. Anything else under
/// `prm.movable` is an error naming the node; other extras are the file's own business.
fn movable(path: &Path, node: &gltf::Node) -> Result<bool, SceneError> {
    let Some(raw) = node.extras() else { return Ok(false) };
    let bad = |what: String| SceneError::Movable { path: path.into(), node: node_name(node), what };
    let extras: serde_json::Value =
        serde_json::from_str(raw.get()).map_err(|e| bad(format!("its extras are not JSON: {e}")))?;
    match extras.get("prm").and_then(|p| p.get("movable")) {
        None => Ok(false),
        Some(serde_json::Value::Bool(b)) => Ok(*b),
        Some(other) => Err(bad(format!("extras prm.movable is {other}; it must be true or false"))),
    }
}

/// The default scene's root nodes (else the first scene's); with no scene, every node
/// without a parent.
fn root_nodes(document: &gltf::Document) -> Vec<gltf::Node<'_>> {
    match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            // Marked in one pass: asking each node for a parent was quadratic (10^5 nodes and
            // no scene took minutes).
            let mut child = vec![false; document.nodes().len()];
            for c in document.nodes().flat_map(|n| n.children()) {
                child[c.index()] = true;
            }
            document.nodes().filter(|n| !child[n.index()]).collect()
        }
    }
}

/// What reading a node's contents needs from the rest of the file.
pub(super) struct NodeReader<'a> {
    pub path: &'a Path,
    pub buffers: &'a [gltf::buffer::Data],
    /// Per material, the (image index, UV set) of its albedo texture.
    pub texture_of: &'a [Option<(usize, u32)>],
    /// The material of primitives that name none.
    pub default_material: u32,
}

impl NodeReader<'_> {
    /// Read what hangs on `node`: its mesh's primitives into `prims`, its light and camera
    /// into `scene`.
    pub(super) fn read_node(
        &self,
        node: &gltf::Node,
        world: Mat4,
        object: u32,
        prims: &mut Vec<Prim>,
        scene: &mut Scene,
        report: &mut LoadReport,
    ) -> Result<(), SceneError> {
        if let Some(mesh) = node.mesh() {
            self.read_mesh(&mesh, (node.index(), object), world, prims, report)?;
        }
        if let Some(light) = node.light() {
            scene.lights.push(read_light(self.path, &light, world)?);
        }
        if let Some(cam) = node.camera() {
            read_camera(node, &cam, world, scene, report);
        }
        Ok(())
    }

    /// The mesh's triangle primitives (others are counted in `report` and skipped).
    fn read_mesh(
        &self,
        mesh: &gltf::Mesh,
        (node, object): (usize, u32),
        world: Mat4,
        prims: &mut Vec<Prim>,
        report: &mut LoadReport,
    ) -> Result<(), SceneError> {
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
            let material = prim.material().index().map(|i| i as u32).unwrap_or(self.default_material);
            let tex_set = self.texture_of.get(material as usize).copied().flatten().map(|(_, set)| set);
            let src = PrimSource { path: self.path, buffers: self.buffers, prim: &prim, place };
            prims.push(read_primitive(src, Use { node, object, world, material, tex_set }, report)?);
        }
        Ok(())
    }
}

/// A perspective camera into `scene`; an orthographic one is noted in `report` and ignored.
fn read_camera(
    node: &gltf::Node,
    cam: &gltf::Camera,
    world: Mat4,
    scene: &mut Scene,
    report: &mut LoadReport,
) {
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
