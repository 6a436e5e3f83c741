//! Lights on the GPU: checking them, their shadow-map frusta, and the WGSL library
//! (`shaders/lights.wgsl`: incident light, cube-face choice, shadow-mapped visibility) that
//! the irradiance and shading shaders are built on.
//!
//! Shadow frusta (DESIGN.md §5 step 1), all reverse-Z (depth 1 at the light, 0 far away):
//! - point: a cube of six perspective faces (+X -X +Y -Y +Z -Z), each a little wider than 90°
//!   so the 3x3 PCF footprint at a face edge stays inside the face;
//! - spot: one perspective frustum just wider than the outer cone, or a cube when the cone is
//!   wider than 60° (a perspective frustum cannot hold a hemisphere);
//! - directional: one orthographic box fitted to the level's bounding sphere.
//!
//! The near plane of perspective frusta is 1e-6 of the level's diagonal, so a light almost
//! touching a surface still sees it (reverse-Z keeps the depth precision).

use glam::camera::rh::proj::directx::{orthographic, perspective_infinite_reverse};
use glam::camera::rh::view::look_to_mat4;
use glam::{Mat4, Vec3};
use prm::{Light, LightKind};

use crate::contract::CUBE_LAYERS;
use crate::layout::GpuLight;

/// The WGSL library of every shader that lights surfaces (after the prelude and bindings,
/// before the pass: [`crate::contract::Shader::source`]).
pub const LIBRARY: &str = include_str!("../../shaders/lights.wgsl");

/// Spot cones wider than this (half-angle, radians) get a cube of shadow maps.
pub const SPOT_CUBE_ABOVE: f32 = std::f32::consts::PI / 3.0;

/// A light the runtime refuses, with why.
#[derive(Debug, thiserror::Error)]
pub enum LightError {
    #[error("light '{name}' (#{index}): {what}")]
    Invalid { index: usize, name: String, what: String },
    #[error("{count} lights; the runtime's limit is {max} (prm::rig::MAX_LIGHTS)")]
    TooMany { count: usize, max: usize },
    #[error(
        "these lights need {needed} shadow-map layers (6 per point light or wide spot, 1 otherwise); the \
        device allows {max}"
    )]
    TooManyLayers { needed: u32, max: u32 },
}

/// Checks every light for values the shaders cannot use.
pub fn validate(lights: &[Light]) -> Result<(), LightError> {
    if lights.len() > prm::rig::MAX_LIGHTS {
        return Err(LightError::TooMany { count: lights.len(), max: prm::rig::MAX_LIGHTS });
    }
    for (index, l) in lights.iter().enumerate() {
        let bad = |what: String| Err(LightError::Invalid { index, name: l.name.clone(), what });
        if !l.is_punctual() {
            return bad(
                "a sphere or polygon aperture or a photometric profile is for the bakers; the runtime's \
                shadow-mapped lights are punctual"
                    .into(),
            );
        }
        if l.is_positional() && !l.position.is_finite() {
            return bad(format!("position {} is not finite", l.position));
        }
        if !l.intensity.is_finite() || l.intensity.min_element() < 0.0 {
            return bad(format!("intensity {} must be finite and >= 0", l.intensity));
        }
        let unit = l.direction.is_finite() && (l.direction.length() - 1.0).abs() < 1e-3;
        if !matches!(l.kind, LightKind::Point) && !unit {
            return bad(format!("direction {} is not a unit vector", l.direction));
        }
        if let LightKind::Spot { inner, outer } = l.kind {
            if !(0.0 <= inner && inner <= outer && outer <= std::f32::consts::FRAC_PI_2) {
                return bad(format!(
                    "cone angles inner {inner} outer {outer} rad must satisfy 0 <= inner <= outer <= pi/2"
                ));
            }
        }
        if let Some(r) = l.range {
            if !(r.is_finite() && r >= 0.0) {
                return bad(format!("range {r} must be finite and >= 0"));
            }
        }
    }
    Ok(())
}

/// Shadow layers a light owns.
pub fn layers(l: &Light) -> u32 {
    match l.kind {
        LightKind::Point => CUBE_LAYERS,
        LightKind::Spot { outer, .. } if outer > SPOT_CUBE_ABOVE => CUBE_LAYERS,
        _ => 1,
    }
}

/// The level's bounding sphere (centre, radius), used to fit directional frusta and near planes.
#[derive(Clone, Copy, Debug)]
pub struct Bounds {
    pub centre: Vec3,
    pub radius: f32,
}

/// View-projection matrices of a light's layers and the world size of one shadow texel
/// (per unit distance for perspective layers), for maps of `size` x `size`.
pub fn frusta(l: &Light, size: u32, bounds: Bounds) -> (Vec<Mat4>, f32) {
    let pad = 1.0 + 4.0 / size as f32;
    let near = (bounds.radius * 2e-6).max(f32::MIN_POSITIVE * 1e6);
    let cube = |pos: Vec3| {
        let half = pad.atan();
        let proj = perspective_infinite_reverse(2.0 * half, 1.0, near);
        let faces = [
            (Vec3::X, -Vec3::Y),
            (-Vec3::X, -Vec3::Y),
            (Vec3::Y, Vec3::Z),
            (-Vec3::Y, -Vec3::Z),
            (Vec3::Z, -Vec3::Y),
            (-Vec3::Z, -Vec3::Y),
        ];
        let mats = faces.iter().map(|&(d, up)| proj * look_to_mat4(pos, d, up)).collect();
        (mats, 2.0 * pad / size as f32)
    };
    match l.kind {
        LightKind::Point => cube(l.position),
        LightKind::Spot { outer, .. } if outer > SPOT_CUBE_ABOVE => cube(l.position),
        LightKind::Spot { outer, .. } => {
            let half = (outer.max(1e-3).tan() * pad).atan();
            let proj = perspective_infinite_reverse(2.0 * half, 1.0, near);
            (
                vec![proj * look_to_mat4(l.position, l.direction, up_for(l.direction))],
                2.0 * half.tan() / size as f32,
            )
        }
        LightKind::Directional => {
            let r = bounds.radius.max(1e-30) * 1.01;
            let eye = bounds.centre - l.direction * r;
            let proj = orthographic(-r, r, -r, r, 2.0 * r, 0.0);
            (vec![proj * look_to_mat4(eye, l.direction, up_for(l.direction))], 2.0 * r / size as f32)
        }
    }
}

fn up_for(dir: Vec3) -> Vec3 {
    if dir.y.abs() > 0.99 {
        Vec3::Z
    } else {
        Vec3::Y
    }
}

/// GPU lights and their layer matrices for `lights` (already validated).
pub fn pack(lights: &[Light], size: u32, bounds: Bounds) -> (Vec<GpuLight>, Vec<Mat4>) {
    let mut gpu = Vec::with_capacity(lights.len());
    let mut mats = Vec::new();
    for l in lights {
        let (m, texel) = frusta(l, size, bounds);
        gpu.push(GpuLight::new(l, mats.len() as u32, m.len() as u32, texel));
        mats.extend(m);
    }
    (gpu, mats)
}

/// The same shadow frusta: what decides whether a light's maps must be re-rendered.
pub fn same_shadow(a: &Light, b: &Light) -> bool {
    a.kind == b.kind
        && a.range == b.range
        && (!a.is_positional() || a.position == b.position)
        && (matches!(a.kind, LightKind::Point) || a.direction == b.direction)
}
