//! What an interactive editor needs besides the baker (`prm view --edit`): the things a user
//! can pick in a level version (the glTF nodes that place triangles, and the lights), the plane
//! an object is dragged on and where a mouse ray meets it, and the edit that moves a pick.

use glam::{Mat4, Vec3};

use prm::light::Aperture;

use super::level::{emission_of, glowing_corners, Edit, EditError, Version};

/// A thing the user can pick and move.
#[derive(Clone, Debug, PartialEq)]
pub enum Pick {
    /// A glTF node's triangles; `centre` is the middle of their box.
    Node { node: u32, name: String, centre: Vec3 },
    /// A light (by its baker id).
    Light { id: u32, name: String, position: Vec3 },
}

impl Pick {
    /// Where the pick is: a node's box centre, a light's position.
    pub fn at(&self) -> Vec3 {
        match self {
            Pick::Node { centre, .. } => *centre,
            Pick::Light { position, .. } => *position,
        }
    }

    pub fn name(&self) -> &str {
        match self {
            Pick::Node { name, .. } | Pick::Light { name, .. } => name,
        }
    }
}

/// Every node that places triangles (in node order, named from `node_names` where the file
/// names it) and every light of `v` but the emission of its surfaces (a surface's polygon
/// lights move with its node).
pub fn picks(v: &Version, node_names: &[Option<String>]) -> Vec<Pick> {
    let mut boxes: std::collections::BTreeMap<u32, (Vec3, Vec3)> = Default::default();
    for (t, tri) in v.scene.triangles.iter().enumerate() {
        let e = boxes.entry(tri.node).or_insert((Vec3::INFINITY, Vec3::NEG_INFINITY));
        for p in v.scene.corners(t) {
            e.0 = e.0.min(p);
            e.1 = e.1.max(p);
        }
    }
    let mut out: Vec<Pick> = boxes
        .into_iter()
        .map(|(node, (lo, hi))| Pick::Node {
            node,
            name: node_names.get(node as usize).cloned().flatten().unwrap_or_else(|| format!("node {node}")),
            centre: 0.5 * (lo + hi),
        })
        .collect();
    let glowing = glowing_corners(&v.scene, None);
    let emission = |l: &prm::Light| emission_of(l, &glowing).is_some();
    out.extend(v.lights.iter().filter(|l| !emission(&l.light)).map(|l| Pick::Light {
        id: l.id,
        name: format!("light '{}'", l.light.name),
        position: l.light.position,
    }));
    out
}

/// The normal of the plane a pick is dragged on, for a camera looking along `forward`: the
/// floor plane (normal +Y) when the camera looks down or up steeply (more than 30 degrees), else
/// the upright plane facing the camera (a horizontal view meets the floor plane at a grazing
/// angle, where a small mouse move is a large move).
pub fn drag_plane(forward: Vec3) -> Vec3 {
    let f = forward.normalize_or_zero();
    let flat = Vec3::new(f.x, 0.0, f.z);
    if f.y.abs() >= 0.5 || flat.length_squared() < 1e-12 {
        Vec3::Y
    } else {
        flat.normalize()
    }
}

/// Where the ray from `origin` along `dir` meets the plane through `point` with normal
/// `normal`, if it does (ahead of the origin, not along the plane).
pub fn on_plane(origin: Vec3, dir: Vec3, point: Vec3, normal: Vec3) -> Option<Vec3> {
    let den = dir.dot(normal);
    if !(den.abs() > 1e-6) || !origin.is_finite() || !dir.is_finite() || !point.is_finite() {
        return None;
    }
    let t = (point - origin).dot(normal) / den;
    (t > 0.0 && t.is_finite()).then(|| origin + t * dir)
}

/// The edit that moves `pick` by `by` in `v`: a node's transform, or the light moved.
pub fn move_edit(v: &Version, pick: &Pick, by: Vec3) -> Result<Edit, EditError> {
    if !by.is_finite() {
        return Err(EditError::NonFinite("the move"));
    }
    match pick {
        Pick::Node { node, .. } => Ok(Edit::Transform { node: *node, matrix: Mat4::from_translation(by) }),
        Pick::Light { id, .. } => {
            let slot = v.lights.iter().find(|l| l.id == *id).ok_or(EditError::UnknownLight(*id))?;
            let mut light = slot.light.clone();
            light.position += by;
            if let Aperture::Polygon { corners } = &light.aperture {
                let moved: Vec<Vec3> = corners.iter().map(|c| *c + by).collect();
                light.aperture = Aperture::Polygon { corners: moved.into() };
            }
            Ok(Edit::SetLight { id: *id, light })
        }
    }
}
