//! `KHR_lights_punctual` lights into [`Light`]s (units: [`crate::light`]).
//!
//! A light's glTF `extras` may give it what `KHR_lights_punctual` cannot (paper 001 §3.2),
//! for the bakers and the ground truth (the runtime refuses such lights):
//!
//! | key | value | gives |
//! | --- | --- | --- |
//! | `prm_radius` | metres | a sphere aperture (point lights) |
//! | `prm_size` | [width, height], metres | a rectangle in the node's XY plane, emitting along its -Z, Lambertian: `intensity x color` is then its radiance in W/(m² sr) |
//! | `prm_profile` | a path, relative to the glTF file | an IES (`.ies`) or EULUMDAT (`.ldt`) profile, C0 along the node's +X (point lights) |

use std::path::Path;

use std::sync::Arc;

use glam::{Mat4, Vec3};
use gltf::khr_lights_punctual::Kind;

use super::SceneError;
use crate::light::{Aperture, Light, LightKind};
use crate::photometry::Photometry;

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
    let mut out = Light {
        name: name.clone(),
        kind,
        position,
        direction,
        intensity: color * intensity,
        range,
        aperture: Aperture::Point,
        profile: None,
    };
    if let Some(raw) = light.extras() {
        let extras: serde_json::Value =
            serde_json::from_str(raw.get()).map_err(|e| bad(format!("its extras are not JSON: {e}")))?;
        out = with_extras(path, out, &extras, world).map_err(bad)?;
    }
    out.check().map_err(bad)?;
    Ok(out)
}

/// Apply the `prm_*` keys of a light's extras (module doc).
fn with_extras(path: &Path, mut l: Light, extras: &serde_json::Value, world: Mat4) -> Result<Light, String> {
    if let Some(r) = extras.get("prm_radius") {
        let r = r.as_f64().ok_or_else(|| format!("prm_radius {r} is not a number"))? as f32;
        // The node's scale scales the sphere (its largest axis).
        let s = world.transform_vector3(Vec3::X).length().max(world.transform_vector3(Vec3::Y).length());
        l.aperture = Aperture::Sphere { radius: r * s };
    }
    if let Some(size) = extras.get("prm_size") {
        let wh: Vec<f64> = size
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_f64()).collect())
            .filter(|v: &Vec<f64>| v.len() == 2)
            .ok_or_else(|| format!("prm_size {size} is not [width, height]"))?;
        let (w, h) = (0.5 * wh[0] as f32, 0.5 * wh[1] as f32);
        // Counter-clockwise seen from the front, which faces the node's -Z.
        let local =
            [Vec3::new(-w, -h, 0.0), Vec3::new(-w, h, 0.0), Vec3::new(w, h, 0.0), Vec3::new(w, -h, 0.0)];
        let corners: Vec<Vec3> = local.iter().map(|c| world.transform_point3(*c)).collect();
        let radiance = l.intensity;
        l = Light { name: l.name.clone(), range: l.range, ..Light::polygon(&l.name, &corners, radiance) };
    }
    if let Some(file) = extras.get("prm_profile") {
        let rel = file.as_str().ok_or_else(|| format!("prm_profile {file} is not a path"))?;
        let full = path.parent().unwrap_or(Path::new(".")).join(rel);
        super::regular_file(path, &full).map_err(|e| format!("prm_profile: {e}"))?;
        let table = Photometry::load(&full).map_err(|e| e.to_string())?;
        l = l.with_profile(Arc::new(table), world.transform_vector3(Vec3::X));
    }
    Ok(l)
}
