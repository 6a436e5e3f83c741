//! Cube-map directions: six faces of `res` x `res` pixels around a point.
//!
//! Face `f` looks along axis `f / 2` with sign `+` for even `f` (+X, -X, +Y, -Y, +Z, -Z). A
//! direction `d` on face `f` is `main + u U + v V` with `u, v` in [-1, 1], where `U` and `V` are
//! the two other axes in increasing order; pixel (x, y) covers `u` in [2x/res - 1, 2(x+1)/res - 1]
//! and the same for `v` and `y`. Pixel `p` of the map is `f res² + y res + x`.

use glam::Vec3;

/// The axes (main, U, V) of face `f`.
#[inline]
fn axes(f: usize) -> (Vec3, Vec3, Vec3) {
    let a = f / 2;
    let s = if f % 2 == 0 { 1.0 } else { -1.0 };
    let unit = |k: usize| Vec3::AXES[k];
    let (u, v) = match a {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    (unit(a) * s, unit(u), unit(v))
}

/// The unit direction through the centre of pixel `p` of a `res` x `res` cube map.
pub fn pixel_direction(p: usize, res: u32) -> Vec3 {
    let r = res as usize;
    let (f, y, x) = (p / (r * r), (p / r) % r, p % r);
    let (m, u, v) = axes(f);
    let to = |k: usize| 2.0 * (k as f32 + 0.5) / res as f32 - 1.0;
    (m + u * to(x) + v * to(y)).normalize()
}

/// The face of direction `d` and its continuous pixel coordinates (x, y) in [0, res) on it;
/// `None` for a zero or non-finite direction.
pub fn locate(d: Vec3, res: u32) -> Option<(usize, f32, f32)> {
    if !d.is_finite() {
        return None;
    }
    let a = d.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let major = a[axis];
    if !(major > 0.0 && major.is_finite()) {
        return None;
    }
    let f = 2 * axis + (d[axis] < 0.0) as usize;
    let (_, u, v) = axes(f);
    let to = |t: f32| ((t / major + 1.0) * 0.5 * res as f32).clamp(0.0, res as f32 - 1e-3);
    Some((f, to(d.dot(u)), to(d.dot(v))))
}

/// The pixel index of direction `d` (its nearest pixel), `None` as for [`locate`].
pub fn pixel_of(d: Vec3, res: u32) -> Option<usize> {
    let (f, x, y) = locate(d, res)?;
    let r = res as usize;
    Some(f * r * r + (y as usize).min(r - 1) * r + (x as usize).min(r - 1))
}

/// Up to four pixels around direction `d` with bilinear weights summing to 1 (percentage-closer
/// filtering, paper 003 §3.2.2), on `d`'s face (clamped at its border).
pub fn bilinear(d: Vec3, res: u32) -> Option<[(usize, f32); 4]> {
    let (f, x, y) = locate(d, res)?;
    let r = res as usize;
    let (fx, fy) = ((x - 0.5).max(0.0), (y - 0.5).max(0.0));
    let (x0, y0) = ((fx as usize).min(r - 1), (fy as usize).min(r - 1));
    let (x1, y1) = ((x0 + 1).min(r - 1), (y0 + 1).min(r - 1));
    let (tx, ty) = ((fx - x0 as f32).clamp(0.0, 1.0), (fy - y0 as f32).clamp(0.0, 1.0));
    let at = |xx: usize, yy: usize| f * r * r + yy * r + xx;
    Some([
        (at(x0, y0), (1.0 - tx) * (1.0 - ty)),
        (at(x1, y0), tx * (1.0 - ty)),
        (at(x0, y1), (1.0 - tx) * ty),
        (at(x1, y1), tx * ty),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pixel_centre_maps_back_to_its_pixel() {
        for res in [1, 2, 7, 16] {
            for p in 0..6 * (res * res) as usize {
                let d = pixel_direction(p, res);
                assert!((d.length() - 1.0).abs() < 1e-5);
                assert_eq!(pixel_of(d, res), Some(p), "res {res} pixel {p}");
                let w: f32 = bilinear(d, res).unwrap().iter().map(|(_, w)| w).sum();
                assert!((w - 1.0).abs() < 1e-5);
            }
        }
        assert_eq!(pixel_of(Vec3::ZERO, 4), None);
        assert_eq!(pixel_of(Vec3::new(f32::NAN, 1.0, 0.0), 4), None);
    }
}
