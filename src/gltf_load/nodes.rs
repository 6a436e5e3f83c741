//! The node hierarchy flattened to world transforms (matrix or TRS), and what hangs on each
//! node: mesh primitives, a light, a camera.

use std::path::Path;

use glam::Mat4;

use super::lights::read_light;
use super::primitive::{read_primitive, Prim, PrimSource, Use};
use super::{Place, SceneError};
use crate::scene::{Camera, LoadReport, Scene};

/// Visit every node with its world transform. Depth-first pre-order, children in file order:
/// scene order decides ties between triangles (texel ownership), so it must be the natural one.
pub(super) fn walk<'d>(
    path: &Path,
    document: &'d gltf::Document,
    mut visit: impl FnMut(&gltf::Node<'d>, Mat4) -> Result<(), SceneError>,
) -> Result<(), SceneError> {
    let mut stack: Vec<(gltf::Node, Mat4, usize)> =
        root_nodes(document).into_iter().rev().map(|n| (n, Mat4::IDENTITY, 0)).collect();
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
        visit(&node, world)?;
        let children: Vec<gltf::Node> = node.children().collect();
        for child in children.into_iter().rev() {
            stack.push((child, world, depth + 1));
        }
    }
    Ok(())
}

/// The default scene's root nodes (else the first scene's); with no scene, every node
/// without a parent.
fn root_nodes(document: &gltf::Document) -> Vec<gltf::Node<'_>> {
    match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => document.nodes().filter(|n| !has_parent(document, n.index())).collect(),
    }
}

fn has_parent(doc: &gltf::Document, index: usize) -> bool {
    doc.nodes().any(|n| n.children().any(|c| c.index() == index))
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
        prims: &mut Vec<Prim>,
        scene: &mut Scene,
        report: &mut LoadReport,
    ) -> Result<(), SceneError> {
        if let Some(mesh) = node.mesh() {
            self.read_mesh(&mesh, node.index(), world, prims, report)?;
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
        node: usize,
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
            prims.push(read_primitive(src, Use { node, world, material, tex_set }, report)?);
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
