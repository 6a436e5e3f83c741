//! What a radiance map was baked for: an FNV-1a 64 hash of the scene geometry, lightmap UVs,
//! albedos, sidedness and atlas size (DESIGN.md §8).
//!
//! A `.prm` stores it; loading one for another level (or another atlas) is refused instead of
//! lighting the wrong texels. Lights are not in it: they change at run time. FNV-1a is also the
//! `.prm` checksum: short, dependency-free and good enough against accidents (not attacks).

use crate::scene::Scene;

/// FNV-1a 64 offset basis.
pub const FNV_START: u64 = 0xcbf2_9ce4_8422_2325;

/// FNV-1a 64 over bytes, continuing from `h` (start with [`FNV_START`]).
pub fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Fingerprint of what a radiance map depends on: triangle corners, lightmap UVs, albedos,
/// sidedness and the atlas size.
pub fn scene_fingerprint(scene: &Scene, width: u32, height: u32) -> u64 {
    let h = fnv1a(FNV_START, &width.to_le_bytes());
    hash_triangles(scene, fnv1a(h, &height.to_le_bytes()), true)
}

/// [`scene_fingerprint`] without the lightmap UVs and the atlas size: the triangles' corners,
/// albedo factors, sidedness and whether an albedo texture is bound (not its texels, nor the
/// albedo UVs). A precompute's shard checks the level it traces against its plan's with it.
pub fn geometry_fingerprint(scene: &Scene) -> u64 {
    hash_triangles(scene, FNV_START, false)
}

/// The triangles' corners, their lightmap UVs (`uv1`), albedos and sidedness hashed on from `h`.
fn hash_triangles(scene: &Scene, mut h: u64, uv1: bool) -> u64 {
    h = fnv1a(h, &(scene.triangles.len() as u64).to_le_bytes());
    for t in 0..scene.triangles.len() {
        for p in scene.corners(t) {
            h = fnv1a(h, bytemuck::bytes_of(&p.to_array()));
        }
        if uv1 {
            for uv in scene.uv1_corners(t) {
                h = fnv1a(h, bytemuck::bytes_of(&uv.to_array()));
            }
        }
        let m = scene.material(t);
        h = fnv1a(h, bytemuck::bytes_of(&m.albedo.to_array()));
        h = fnv1a(h, &[m.double_sided as u8, m.albedo_texture.is_some() as u8]);
    }
    h
}

/// [`scene_fingerprint`] as the 16-digit hex string a `.prm` header stores.
pub fn fingerprint_hex(scene: &Scene, width: u32, height: u32) -> String {
    format!("{:016x}", scene_fingerprint(scene, width, height))
}
