//! Materials: `baseColorFactor` as linear albedo, `emissiveFactor` x
//! `KHR_materials_emissive_strength` as emission, and which texture the albedo takes.

use std::path::Path;

use glam::Vec3;

use super::SceneError;
use crate::scene::Material;

/// For each material, the (image index, UV set) of its albedo texture, if it has one.
pub(super) type AlbedoTextures = Vec<Option<(usize, u32)>>;

/// Materials, and for each the (texture index, UV set) of its albedo texture.
pub(super) fn read_materials(
    path: &Path,
    doc: &gltf::Document,
) -> Result<(Vec<Material>, AlbedoTextures), SceneError> {
    let mut out = Vec::new();
    let mut tex = Vec::new();
    for m in doc.materials() {
        let index = m.index().unwrap_or(out.len());
        let name = m.name().unwrap_or("").to_string();
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let albedo = [f[0], f[1], f[2]];
        if albedo.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return Err(SceneError::AlbedoOutOfRange {
                path: path.into(),
                material: index,
                name,
                value: albedo,
            });
        }
        let strength = m.emissive_strength().unwrap_or(1.0);
        let e = m.emissive_factor();
        let emissive = [e[0] * strength, e[1] * strength, e[2] * strength];
        if emissive.iter().any(|c| !(c.is_finite() && (0.0..=crate::light::MAX_INTENSITY).contains(c))) {
            return Err(SceneError::BadEmissive {
                path: path.into(),
                material: index,
                name,
                value: emissive,
            });
        }
        let t = pbr.base_color_texture().map(|info| (info.texture().source().index(), info.tex_coord()));
        tex.push(t);
        out.push(Material {
            name,
            albedo: Vec3::from(albedo),
            albedo_texture: None,
            emissive: Vec3::from(emissive),
            double_sided: m.double_sided(),
        });
    }
    Ok((out, tex))
}
