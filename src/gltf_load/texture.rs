//! Albedo textures: the file's images decoded from sRGB to linear RGB.

use std::path::Path;

use glam::Vec3;

use super::SceneError;
use crate::scene::Texture;

/// Decode the images that albedo textures use; link materials to them.
pub(super) fn read_textures(
    path: &Path,
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    texture_of: &[Option<(usize, u32)>],
) -> Result<Vec<Texture>, SceneError> {
    if texture_of.iter().all(|t| t.is_none()) {
        return Ok(Vec::new());
    }
    let images = gltf::import_images(doc, path.parent(), buffers)
        .map_err(|source| SceneError::Gltf { path: path.into(), source })?;
    let mut out = Vec::with_capacity(images.len());
    for (k, img) in images.iter().enumerate() {
        out.push(decode_srgb(img).map_err(|what| SceneError::BadTexture {
            path: path.into(),
            texture: k,
            what,
        })?);
    }
    Ok(out)
}

/// sRGB-encoded 8- or 16-bit image data to linear RGB; float images are taken as linear.
fn decode_srgb(img: &gltf::image::Data) -> Result<Texture, String> {
    use gltf::image::Format as F;
    let n = (img.width as usize) * (img.height as usize);
    if n == 0 {
        return Err("image is empty".into());
    }
    let (channels, bytes) = match img.format {
        F::R8 => (1, 1),
        F::R8G8 => (2, 1),
        F::R8G8B8 => (3, 1),
        F::R8G8B8A8 => (4, 1),
        F::R16 => (1, 2),
        F::R16G16 => (2, 2),
        F::R16G16B16 => (3, 2),
        F::R16G16B16A16 => (4, 2),
        F::R32G32B32FLOAT => (3, 4),
        F::R32G32B32A32FLOAT => (4, 4),
    };
    if img.pixels.len() < n * channels * bytes {
        return Err("pixel data shorter than the image size".into());
    }
    let value = |i: usize, c: usize| -> f32 {
        let c = c.min(channels - 1);
        let at = (i * channels + c) * bytes;
        match bytes {
            1 => srgb_to_linear(img.pixels[at] as f32 / 255.0),
            2 => srgb_to_linear(u16::from_le_bytes([img.pixels[at], img.pixels[at + 1]]) as f32 / 65535.0),
            _ => {
                let v = f32::from_le_bytes(img.pixels[at..at + 4].try_into().unwrap_or([0; 4]));
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }
        }
    };
    let grey = channels < 3;
    let texels =
        (0..n)
            .map(|i| {
                if grey {
                    Vec3::splat(value(i, 0))
                } else {
                    Vec3::new(value(i, 0), value(i, 1), value(i, 2))
                }
            })
            .collect();
    Ok(Texture { width: img.width, height: img.height, texels })
}

/// The sRGB transfer function, decoded.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}
