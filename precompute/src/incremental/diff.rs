//! What changed between two loads of a level (an editor exported it again): node by node, the
//! edits that take the old level to the new one, for `prm bake --watch`.
//!
//! A node whose vertices moved gets the affine transform that maps its old world positions to
//! the new ones, fitted by least squares over its vertices and points one node-size along
//! their normals (so a flat node, a floor or a wall, still fixes the transform off its plane),
//! and accepted only if it reproduces every vertex. Materials give albedo edits, lights are
//! matched by name (by index when names repeat). What the incremental baker cannot follow is
//! refused with the reason: triangles added or removed, a lightmap layout that changed, a node
//! bent rather than moved, a material change other than its albedo.

use glam::{DMat3, DVec3, Mat4};
use prm::{Light, Scene};

use super::level::Edit;

/// A change the incremental baker cannot follow: bake the level afresh.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DiffError {
    #[error(
        "the level's triangles changed ({0}); the incremental baker follows moved objects, not new geometry"
    )]
    Topology(String),
    #[error("the lightmap UVs changed (vertex {0}); the texels are not the same ones")]
    Layout(usize),
    #[error(
        "node {node} did not move as one rigid or scaled object (a vertex is {residual} off the best fit)"
    )]
    NotAffine { node: u32, residual: f32 },
    #[error("material {0} changed in more than its albedo factor")]
    Material(u32),
}

/// The edits taking `old` to `new`, with lights named by the ids `ids` (one per light of
/// `old`, in order). Added lights come last, in `new`'s order; the caller learns their ids as
/// it applies them.
pub fn diff(old: &Scene, new: &Scene, ids: &[u32]) -> Result<Vec<Edit>, DiffError> {
    if old.triangles.len() != new.triangles.len() || old.positions.len() != new.positions.len() {
        return Err(DiffError::Topology(format!(
            "{} triangles and {} vertices, were {} and {}",
            new.triangles.len(),
            new.positions.len(),
            old.triangles.len(),
            old.positions.len()
        )));
    }
    for (t, (a, b)) in old.triangles.iter().zip(&new.triangles).enumerate() {
        if a.v != b.v || a.node != b.node || a.material != b.material {
            return Err(DiffError::Topology(format!("triangle {t} has other corners, node or material")));
        }
    }
    if let Some(i) = old.uv1.iter().zip(&new.uv1).position(|(a, b)| (*a - *b).abs().max_element() > 1e-6) {
        return Err(DiffError::Layout(i));
    }
    let mut edits = Vec::new();
    let mut nodes: Vec<u32> = old.triangles.iter().map(|t| t.node).collect();
    nodes.sort_unstable();
    nodes.dedup();
    for node in nodes {
        let mut verts: Vec<u32> = old.triangles.iter().filter(|t| t.node == node).flat_map(|t| t.v).collect();
        verts.sort_unstable();
        verts.dedup();
        if verts.iter().all(|&v| old.positions[v as usize] == new.positions[v as usize]) {
            continue;
        }
        edits.push(Edit::Transform { node, matrix: fit(old, new, &verts, node)? });
    }
    if old.materials.len() != new.materials.len() {
        return Err(DiffError::Topology(format!(
            "{} materials, were {}",
            new.materials.len(),
            old.materials.len()
        )));
    }
    for (m, (a, b)) in old.materials.iter().zip(&new.materials).enumerate() {
        if a.albedo_texture != b.albedo_texture
            || a.emissive != b.emissive
            || a.double_sided != b.double_sided
        {
            return Err(DiffError::Material(m as u32));
        }
        if a.albedo != b.albedo {
            edits.push(Edit::Albedo { material: m as u32, albedo: b.albedo });
        }
    }
    let (matched, added) = match_lights(&old.lights, &new.lights);
    for (i, l) in old.lights.iter().enumerate() {
        match matched.iter().position(|m| *m == Some(i)) {
            None => edits.push(Edit::RemoveLight { id: ids[i] }),
            Some(j) if new.lights[j] != *l => {
                edits.push(Edit::SetLight { id: ids[i], light: new.lights[j].clone() })
            }
            Some(_) => {}
        }
    }
    edits.extend(added.into_iter().map(|j| Edit::AddLight(new.lights[j].clone())));
    Ok(edits)
}

/// For each light of `new`, the light of `old` it is (by unique name, else by index among
/// the unnamed or repeated), and the lights of `new` that are new.
pub fn match_lights(old: &[Light], new: &[Light]) -> (Vec<Option<usize>>, Vec<usize>) {
    let unique =
        |ls: &[Light], name: &str| !name.is_empty() && ls.iter().filter(|l| l.name == name).count() == 1;
    let mut matched = vec![None; new.len()];
    let mut taken = vec![false; old.len()];
    for (j, l) in new.iter().enumerate() {
        if unique(new, &l.name) && unique(old, &l.name) {
            // The name is in `old` (once), so the position is found.
            if let Some(i) = old.iter().position(|o| o.name == l.name) {
                matched[j] = Some(i);
                taken[i] = true;
            }
        }
    }
    let mut rest = (0..old.len()).filter(|&i| !taken[i] && !unique(old, &old[i].name));
    for (j, l) in new.iter().enumerate() {
        if matched[j].is_none() && !unique(new, &l.name) {
            matched[j] = rest.next();
        }
    }
    let added = (0..new.len()).filter(|&j| matched[j].is_none()).collect();
    (matched, added)
}

/// The affine map taking node `node`'s vertices `verts` from `old` to `new`: a least-squares
/// fit over the vertices, or, for a flat node, over the vertices and points lifted along their
/// normals (a rigid or uniformly scaled move maps those too); accepted if every vertex lands
/// within 1e-4 of the node's size.
fn fit(old: &Scene, new: &Scene, verts: &[u32], node: u32) -> Result<Mat4, DiffError> {
    let at = |s: &Scene, v: u32| s.positions[v as usize].as_dvec3();
    let normal = |s: &Scene, v: u32| s.normals[v as usize].as_dvec3();
    let p: Vec<DVec3> = verts.iter().map(|&v| at(old, v)).collect();
    let q: Vec<DVec3> = verts.iter().map(|&v| at(new, v)).collect();
    let size = |x: &[DVec3]| {
        let c = x.iter().copied().sum::<DVec3>() / x.len() as f64;
        (x.iter().map(|v| (*v - c).length_squared()).sum::<f64>() / x.len() as f64).sqrt()
    };
    let (sp, sq) = (size(&p).max(1e-30), size(&q).max(1e-30));
    let solve = |src: &[DVec3], dst: &[DVec3]| -> Option<(DMat3, DVec3)> {
        let n = src.len() as f64;
        let (cs, cd) = (src.iter().copied().sum::<DVec3>() / n, dst.iter().copied().sum::<DVec3>() / n);
        let (mut a, mut b) = (DMat3::ZERO, DMat3::ZERO);
        for (s, d) in src.iter().zip(dst) {
            let (x, y) = (*s - cs, *d - cd);
            a += outer(x, x);
            b += outer(y, x);
        }
        // Well conditioned against the spread cubed (a flat set gives a near-zero volume).
        if !(a.determinant().abs() > 1e-9 * (n * sp * sp).powi(3)) {
            return None;
        }
        let m = b * a.inverse();
        Some((m, cd - m * cs))
    };
    let lifted = || {
        let src: Vec<DVec3> =
            p.iter().copied().chain(verts.iter().map(|&v| at(old, v) + normal(old, v) * sp)).collect();
        let dst: Vec<DVec3> =
            q.iter().copied().chain(verts.iter().map(|&v| at(new, v) + normal(new, v) * sq)).collect();
        solve(&src, &dst)
    };
    let Some((m, t)) = solve(&p, &q).or_else(lifted) else {
        return Err(DiffError::NotAffine { node, residual: f32::INFINITY });
    };
    let residual = p.iter().zip(&q).map(|(x, y)| (m * *x + t - *y).length()).fold(0.0f64, f64::max);
    if !(residual <= 1e-4 * sp.max(sq)) {
        return Err(DiffError::NotAffine { node, residual: residual as f32 });
    }
    let m = m.as_mat3();
    Ok(Mat4::from_cols(
        m.x_axis.extend(0.0),
        m.y_axis.extend(0.0),
        m.z_axis.extend(0.0),
        t.as_vec3().extend(1.0),
    ))
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}
