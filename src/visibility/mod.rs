//! Precomputed visibility for levels with moving rigid objects (paper 003 §3): the data, the
//! point-to-point query and the file. [`prm_precompute::visibility`] builds it by ray casting.
//!
//! Every object (the static level is object 0; movable `k` is object `k + 1`) has a
//! [`Cssm`] over its own texels and its own geometry only, in its rest frame; every movable has
//! besides a [`Csm`] that tests segments passing it. Visibility between texels `r` and `s`
//! under the frame's poses (§3.3):
//!
//! 1. `r`'s cube map sees `s` (in `r`'s object's frame). When `s` is on the same object and
//!    that lookup is at an edge (its filtered value between 0 and 1, [`cssm::EDGE`] from both), the mean of it
//!    and `s`'s map seeing `r`: both maps hold the same geometry, and a second look settles
//!    most pairs the first filtered to near 1/2. On the doorway level, pairs away from shadow
//!    edges agreed with ray casting on 98.1-98.8 % with one look, 99.4-99.7 % with the second
//!    at edges (99.3-99.5 % with it always: the second map's own conservative filtering then
//!    darkens pairs the first sees clearly, and the radiosity's error grew by 0.4 points
//!    where the second at edges lowered it by 0.9-1.0). When `s` is on another object, the
//!    product of `r`'s map seeing `s` and `s`'s map seeing `r` (self-occlusion of each, in
//!    its frame);
//! 2. no third *movable* object blocks the segment (its [`Csm`], in its frame).
//!
//! Not tested, as in the paper: the static level blocking a segment between two points on
//! movables (no static cube map sits at either end), and objects whose convex hulls overlap.
//!
//! [`prm_precompute::visibility`]: ../../prm_precompute/visibility/index.html

pub mod csm;
pub mod cssm;
pub mod cube;
mod file;

use glam::{Mat4, Vec3};
use serde::{Deserialize, Serialize};

pub use csm::Csm;
pub use cssm::{Cssm, CssmBuilder};
pub use file::{read_visibility, visibility_atlas, write_visibility, VisibilityError};

/// One object's visibility data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectVisibility {
    pub cssm: Cssm,
    /// `None` for the static level (it does not move, and nothing is outside it).
    pub occluder: Option<Csm>,
    /// Texel index (in the level's texel set) of each cube map, in sequence order.
    pub texels: Vec<u32>,
}

/// The visibility of a level (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Visibility {
    /// By object: 0 the static level, then the movables in the level's order.
    pub objects: Vec<ObjectVisibility>,
    /// Per texel: (object, sequence index in that object's CSSM).
    pub slots: Vec<(u32, u32)>,
    /// Per texel: the cosine-weighted share of its hemisphere that meets nothing of its own
    /// object (the sky of an open level; 0 inside a closed one). Movables' texels are 0: they
    /// are taken to sit inside the level.
    pub escape: Vec<f32>,
    /// Atlas size the texels belong to.
    pub width: u32,
    pub height: u32,
}

/// The objects' poses for one frame: per object (0 static, identity), the rigid world
/// transform from its rest pose, and its inverse.
#[derive(Clone, Debug)]
pub struct Poses {
    pub to_world: Vec<Mat4>,
    pub to_rest: Vec<Mat4>,
}

impl Poses {
    /// From the movables' transforms (`prm::rig::Motion::at_time`).
    pub fn new(movables: &[Mat4]) -> Poses {
        let to_world: Vec<Mat4> = std::iter::once(Mat4::IDENTITY).chain(movables.iter().copied()).collect();
        let to_rest = to_world.iter().map(|m| m.inverse()).collect();
        Poses { to_world, to_rest }
    }

    /// Every object at rest.
    pub fn at_rest(objects: usize) -> Poses {
        Poses { to_world: vec![Mat4::IDENTITY; objects], to_rest: vec![Mat4::IDENTITY; objects] }
    }

    /// The texels' points and unit normals under these poses (`texels` at rest in `scene`).
    #[cfg(feature = "texels")]
    pub fn texel_points(&self, scene: &crate::Scene, texels: &[crate::Texel]) -> Vec<(Vec3, Vec3)> {
        texels
            .iter()
            .map(|t| {
                let m = self.to_world[scene.object(t.triangle as usize) as usize];
                (m.transform_point3(t.position), m.transform_vector3(t.normal).normalize_or_zero())
            })
            .collect()
    }
}

impl Visibility {
    /// Fraction in [0, 1] of texel `r` and texel `s` seeing each other, given their current
    /// world positions `pr` and `ps` (module doc).
    pub fn between(&self, poses: &Poses, r: usize, pr: Vec3, s: usize, ps: Vec3) -> f32 {
        let (or, kr) = self.slots[r];
        let (os, ks) = self.slots[s];
        let (or, os) = (or as usize, os as usize);
        let mut v = self.objects[or].cssm.visible(kr, poses.to_rest[or].transform_point3(ps));
        let back = || self.objects[os].cssm.visible(ks, poses.to_rest[os].transform_point3(pr));
        if os == or {
            if v > cssm::EDGE && v < 1.0 - cssm::EDGE {
                v = 0.5 * (v + back());
            }
        } else if v > 0.0 {
            v *= back();
        }
        for (o, obj) in self.objects.iter().enumerate().skip(1) {
            if v == 0.0 {
                break;
            }
            if o == or || o == os {
                continue;
            }
            if let Some(csm) = &obj.occluder {
                let m = poses.to_rest[o];
                v *= 1.0 - csm.blocks(m.transform_point3(pr), m.transform_point3(ps));
            }
        }
        v
    }

    /// Bytes of the data (runs, offsets, origins, occluder maps).
    pub fn bytes(&self) -> usize {
        self.objects
            .iter()
            .map(|o| o.cssm.bytes() + o.occluder.as_ref().map_or(0, Csm::bytes) + o.texels.len() * 4)
            .sum()
    }

    /// Cube maps in all, and the bytes they would take uncompressed (16-bit depth).
    pub fn uncompressed_bytes(&self) -> usize {
        self.objects.iter().map(|o| o.cssm.len() * 6 * (o.cssm.res as usize).pow(2) * 2).sum()
    }

    #[cfg(feature = "texels")]
    /// Whether the visibility was made for this arrangement of objects: one per movable plus
    /// the static level, and every texel on the object its triangle belongs to (a level whose
    /// movable flags changed since has the same geometry but not the same objects).
    pub fn check_objects(&self, scene: &crate::Scene, texels: &[crate::Texel]) -> Result<(), String> {
        if self.objects.len() != scene.movables.len() + 1 {
            return Err(format!(
                "made for {} movable objects, the level has {}",
                self.objects.len().saturating_sub(1),
                scene.movables.len()
            ));
        }
        for (t, tex) in texels.iter().enumerate() {
            if self.slots.get(t).map(|s| s.0) != Some(scene.object(tex.triangle as usize)) {
                return Err(format!("texel {t} is on another object than when it was made"));
            }
        }
        Ok(())
    }

    /// Whether the tables are consistent with each other (a file's contents are checked with it).
    pub fn check(&self, texels: usize) -> Result<(), String> {
        if self.objects.is_empty() || self.slots.len() != texels || self.escape.len() != texels {
            return Err(format!("{} texel slots for {texels} texels", self.slots.len()));
        }
        for (o, obj) in self.objects.iter().enumerate() {
            obj.cssm.check().map_err(|e| format!("object {o}: {e}"))?;
            if let Some(c) = &obj.occluder {
                c.check().map_err(|e| format!("object {o}: {e}"))?;
            }
            if obj.texels.len() != obj.cssm.len() {
                return Err(format!(
                    "object {o}: {} texels for {} cube maps",
                    obj.texels.len(),
                    obj.cssm.len()
                ));
            }
            for (k, &t) in obj.texels.iter().enumerate() {
                if self.slots.get(t as usize) != Some(&(o as u32, k as u32)) {
                    return Err(format!("object {o}: cube map {k} and texel {t} disagree"));
                }
            }
        }
        if self.escape.iter().any(|e| !(0.0..=1.0).contains(e)) {
            return Err("an escape share outside [0, 1]".into());
        }
        for (t, &(o, k)) in self.slots.iter().enumerate() {
            let obj = self.objects.get(o as usize).ok_or("a texel names an object that does not exist")?;
            if obj.texels.get(k as usize) != Some(&(t as u32)) {
                return Err(format!("texel {t} and its cube map disagree"));
            }
        }
        Ok(())
    }
}
