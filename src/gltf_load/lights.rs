//! `KHR_lights_punctual` lights into [`Light`]s (units: [`crate::light`]).

use std::path::Path;

use glam::{Mat4, Vec3};
use gltf::khr_lights_punctual::Kind;

use super::SceneError;
use crate::light::{Light, LightKind};

/// A light placed by its node's world transform; negative or non-finite intensity or colour,
/// bad spot cone angles and a non-positive range are errors.
pub(super) fn read_light(
    path: &Path,
    light: &gltf::khr_lights_punctual::Light,
    world: Mat4,
) -> Result<Light, SceneError> {
    let name = light.name().unwrap_or("").to_string();
    let bad = |what: String| SceneError::BadLight {
        path: path.into(),
        light: light.index(),
        name: name.clone(),
        what,
    };
    let color = Vec3::from(light.color());
    let intensity = light.intensity();
    if !(intensity.is_finite() && intensity >= 0.0) {
        return Err(bad(format!("intensity {intensity} is negative or not finite")));
    }
    if !(color.is_finite() && color.min_element() >= 0.0) {
        return Err(bad(format!("colour {color} is negative or not finite")));
    }
    let kind = match light.kind() {
        Kind::Point => LightKind::Point,
        Kind::Directional => LightKind::Directional,
        Kind::Spot { inner_cone_angle, outer_cone_angle } => {
            let (inner, outer) = (inner_cone_angle, outer_cone_angle);
            let half_pi = std::f32::consts::FRAC_PI_2;
            if !(0.0 <= inner && inner <= outer && outer <= half_pi + 1e-6) {
                return Err(bad(format!(
                    "spot cone angles inner {inner} / outer {outer} must satisfy 0 <= inner <= outer <= pi/2"
                )));
            }
            LightKind::Spot { inner, outer: outer.min(half_pi) }
        }
    };
    let position = world.transform_point3(Vec3::ZERO);
    let direction = world.transform_vector3(-Vec3::Z).normalize_or_zero();
    if !position.is_finite() || direction == Vec3::ZERO {
        return Err(bad("its node transform gives no finite position or direction".into()));
    }
    let range = light.range();
    if let Some(r) = range {
        if !(r.is_finite() && r > 0.0) {
            return Err(bad(format!("range {r} must be positive")));
        }
    }
    Ok(Light { name, kind, position, direction, intensity: color * intensity, range })
}
