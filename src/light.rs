//! The light model, shared by every stage (DESIGN.md §3).
//!
//! Units are radiometric and glTF `KHR_lights_punctual` numbers are used as they are:
//! point and spot `intensity x color` is the radiant intensity I in W/sr per RGB channel;
//! directional `intensity x color` is the irradiance E in W/m² on a surface facing the light.
//! Falloff is inverse-square; glTF `range`, when given, applies the spec's smooth window
//! `clamp(1 - (d/range)^4, 0, 1)^2`. Spot cones use the spec's smooth falloff
//! `t = clamp((cos θ - cos outer) / (cos inner - cos outer), 0, 1)`, attenuation `t²`;
//! `inner == outer` is a hard cone.

use glam::Vec3;

/// The kind of a punctual light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    Point,
    /// Cone half-angles in radians, `0 <= inner <= outer <= pi/2`.
    Spot {
        inner: f32,
        outer: f32,
    },
    Directional,
}

/// One punctual light in world space.
#[derive(Clone, Debug, PartialEq)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    /// World position (unused for directional lights).
    pub position: Vec3,
    /// Unit direction the light points along (spot, directional): the node's -Z.
    pub direction: Vec3,
    /// W/sr per channel (point, spot) or W/m² (directional).
    pub intensity: Vec3,
    /// glTF `range` in scene units, if given.
    pub range: Option<f32>,
}

/// What a light delivers to a receiver, before visibility.
#[derive(Clone, Copy, Debug)]
pub struct Incident {
    /// Unit direction from the receiver towards the light.
    pub to_light: Vec3,
    /// Distance to the light (`f32::INFINITY` for directional lights).
    pub distance: f32,
    /// Irradiance on a surface facing the light (W/m²): I/d² x falloff, or E.
    pub irradiance: Vec3,
}

impl Light {
    /// A point light at `position` of `intensity` W/sr per channel, no range.
    pub fn point(name: &str, position: Vec3, intensity: Vec3) -> Light {
        Light {
            name: name.into(),
            kind: LightKind::Point,
            position,
            direction: -Vec3::Y,
            intensity,
            range: None,
        }
    }

    /// Light arriving at point `p`, not yet multiplied by the receiver's cosine or visibility.
    pub fn incident(&self, p: Vec3) -> Incident {
        match self.kind {
            LightKind::Directional => {
                Incident { to_light: -self.direction, distance: f32::INFINITY, irradiance: self.intensity }
            }
            LightKind::Point | LightKind::Spot { .. } => {
                let d = self.position - p;
                let dist2 = d.length_squared();
                if !(dist2 > 0.0) {
                    // A receiver exactly at the light: no defined direction, and the inverse
                    // square law has no finite value. We deliver nothing rather than infinity.
                    return Incident { to_light: Vec3::Z, distance: 0.0, irradiance: Vec3::ZERO };
                }
                let dist = dist2.sqrt();
                let to_light = d / dist;
                let mut scale = 1.0 / dist2 * self.window(dist);
                if let LightKind::Spot { inner, outer } = self.kind {
                    scale *= spot_falloff(self.direction.dot(-to_light), inner, outer);
                }
                Incident { to_light, distance: dist, irradiance: self.intensity * scale }
            }
        }
    }

    /// Irradiance at `p` on a surface with unit normal `n`, without visibility (W/m²).
    pub fn irradiance(&self, p: Vec3, n: Vec3) -> Vec3 {
        let inc = self.incident(p);
        inc.irradiance * n.dot(inc.to_light).max(0.0)
    }

    /// Radiant intensity emitted towards unit direction `dir` (W/sr), for point and spot lights.
    pub fn intensity_towards(&self, dir: Vec3) -> Vec3 {
        match self.kind {
            LightKind::Point => self.intensity,
            LightKind::Spot { inner, outer } => {
                self.intensity * spot_falloff(self.direction.dot(dir), inner, outer)
            }
            LightKind::Directional => Vec3::ZERO,
        }
    }

    /// Power (W per channel) this light delivers to the front of triangle `tri` (corners
    /// counter-clockwise seen from the front), without visibility: its irradiance integrated
    /// over the triangle.
    ///
    /// Point and spot lights: `I x` the triangle's solid angle seen from the light (Van
    /// Oosterom and Strackee's formula, `tan(omega/2) = |a.(b x c)| / (abc + (a.b)c + (a.c)b +
    /// (b.c)a)` for corners a, b, c relative to the light), exact at any distance, a light
    /// touching the triangle included; the triple product is taken from the triangle's edges so
    /// a small, far triangle keeps its precision. A spot's falloff is taken along the mean of
    /// the corner directions and the range window at the centroid's distance (both smooth
    /// over one entry's cell). Directional lights: `E x` the triangle's area projected along
    /// the light.
    pub fn triangle_power(&self, tri: &[Vec3; 3]) -> Vec3 {
        let [p0, p1, p2] = *tri;
        let twice_area = (p1 - p0).cross(p2 - p0);
        if let LightKind::Directional = self.kind {
            return self.intensity * (0.5 * twice_area.dot(-self.direction)).max(0.0);
        }
        let (a, b, c) = (p0 - self.position, p1 - self.position, p2 - self.position);
        // Positive when the light is in front of the triangle.
        let triple = -a.dot(twice_area);
        if !(triple > 0.0) {
            return Vec3::ZERO;
        }
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        let mut scale = 2.0 * triple.atan2(denominator);
        if let LightKind::Spot { inner, outer } = self.kind {
            let mean = (a / la + b / lb + c / lc).normalize_or_zero();
            scale *= spot_falloff(self.direction.dot(mean), inner, outer);
        }
        scale *= self.window(((a + b + c) / 3.0).length());
        self.intensity * scale
    }

    /// glTF range window ([`range_window`]); 1 without a range.
    fn window(&self, dist: f32) -> f32 {
        self.range.map_or(1.0, |r| range_window(dist, r))
    }

    /// True when this is a point-like light (has a position).
    pub fn is_positional(&self) -> bool {
        !matches!(self.kind, LightKind::Directional)
    }
}

/// glTF's smooth range window `clamp(1 - (distance/range)^4, 0, 1)^2` at `distance` from a
/// light of `range` (scene units); 1 when `range` is not positive (no range).
pub fn range_window(distance: f32, range: f32) -> f32 {
    if !(range > 0.0) {
        return 1.0;
    }
    let x = distance / range;
    let w = (1.0 - x * x * x * x).clamp(0.0, 1.0);
    w * w
}

/// [`range_window`] in WGSL, for the GPU (the runtime's shader prelude). The same operations in
/// the same order, so both sides round alike; a GPU test holds them together.
pub const RANGE_WINDOW_WGSL: &str = "fn range_window(distance: f32, range: f32) -> f32 {
    if !(range > 0.0) {
        return 1.0;
    }
    let x = distance / range;
    let w = clamp(1.0 - x * x * x * x, 0.0, 1.0);
    return w * w;
}
";

/// glTF spot falloff for `cos_angle` = cos of the angle off the spot axis, cone angles in
/// radians.
pub fn spot_falloff(cos_angle: f32, inner: f32, outer: f32) -> f32 {
    spot_falloff_cos(cos_angle, inner.cos(), outer.cos())
}

/// [`spot_falloff`] from the cones' cosines (what the GPU light carries): the glTF smooth
/// step squared, a hard cone when the cosines (nearly) meet.
pub fn spot_falloff_cos(cos_angle: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    let (ci, co) = (cos_inner, cos_outer);
    if ci - co <= 1e-6 {
        return if cos_angle >= co { 1.0 } else { 0.0 };
    }
    let t = ((cos_angle - co) / (ci - co)).clamp(0.0, 1.0);
    t * t
}

/// [`spot_falloff_cos`] in WGSL, for the runtime's shader prelude: the same operations in the
/// same order; a GPU test holds the two together.
pub const SPOT_FALLOFF_WGSL: &str = "fn spot_falloff(cos_angle: f32, ci: f32, co: f32) -> f32 {
    if ci - co <= 1e-6 {
        return select(0.0, 1.0, cos_angle >= co);
    }
    let t = clamp((cos_angle - co) / (ci - co), 0.0, 1.0);
    return t * t;
}
";

#[cfg(test)]
mod tests {
    use super::*;

    fn point(pos: Vec3, i: f32) -> Light {
        Light::point("p", pos, Vec3::splat(i))
    }

    #[test]
    fn point_light_is_inverse_square_times_cosine() {
        let l = point(Vec3::new(0.0, 2.0, 0.0), 10.0);
        // Directly below: E = I / r^2.
        let e = l.irradiance(Vec3::ZERO, Vec3::Y);
        assert!((e.x - 2.5).abs() < 1e-6);
        // Off to the side at (2, 0, 0): r^2 = 8, cos = 2/sqrt 8.
        let e = l.irradiance(Vec3::new(2.0, 0.0, 0.0), Vec3::Y);
        let want = 10.0 / 8.0 * (2.0 / 8f32.sqrt());
        assert!((e.x - want).abs() < 1e-6);
        // Facing away: nothing.
        assert_eq!(l.irradiance(Vec3::ZERO, -Vec3::Y), Vec3::ZERO);
        // At the light: finite zero.
        assert_eq!(l.irradiance(Vec3::new(0.0, 2.0, 0.0), Vec3::Y), Vec3::ZERO);
    }

    #[test]
    fn spot_falloff_matches_gltf_and_hard_cone() {
        let (inner, outer) = (0.2f32, 0.4f32);
        assert_eq!(spot_falloff(1.0, inner, outer), 1.0);
        assert_eq!(spot_falloff(0.5f32.cos(), inner, outer), 0.0);
        let mid = 0.3f32.cos();
        let t = (mid - outer.cos()) / (inner.cos() - outer.cos());
        assert!((spot_falloff(mid, inner, outer) - t * t).abs() < 1e-6);
        assert_eq!(spot_falloff(0.29f32.cos(), 0.3, 0.3), 1.0);
        assert_eq!(spot_falloff(0.31f32.cos(), 0.3, 0.3), 0.0);
    }

    /// The square [-s, s]² at height 0 seen from (0, h, 0) has solid angle
    /// `4 asin(s² / (s² + h²))`; split into two triangles or into a fan of eight, each piece's
    /// power must add up to `I x` that, from 1 m to 1e-4 m above it. Tolerance 1e-3: a light
    /// h above a shared edge makes both triangles' denominators cancel to ~0, and f32 (the
    /// GPU's precision too) leaves an error of about 2 eps |a|/h there (1e-4 at h = 1e-4 m).
    #[test]
    fn triangle_power_is_the_solid_angle_at_any_height() {
        let s = 0.5f32;
        let corners =
            [Vec3::new(-s, 0.0, -s), Vec3::new(-s, 0.0, s), Vec3::new(s, 0.0, s), Vec3::new(s, 0.0, -s)];
        let halves = [[corners[0], corners[1], corners[2]], [corners[0], corners[2], corners[3]]];
        let mid = Vec3::new(0.1, 0.0, -0.05);
        let fan: Vec<[Vec3; 3]> = (0..4)
            .flat_map(|k| {
                let (p, q) = (corners[k], corners[(k + 1) % 4]);
                let m = (p + q) / 2.0;
                [[mid, p, m], [mid, m, q]]
            })
            .collect();
        for h in [1.0f32, 0.1, 0.01, 1e-3, 1e-4] {
            let l = point(Vec3::new(0.0, h, 0.0), 2.0);
            let want = 2.0 * 4.0 * ((s * s) / (s * s + h * h)).asin();
            for tris in [&halves[..], &fan[..]] {
                let got: f32 = tris.iter().map(|t| l.triangle_power(t).x).sum();
                assert!((got - want).abs() <= 1e-3 * want, "h {h}: {got} vs {want}");
            }
            // From behind, nothing.
            let below = point(Vec3::new(0.0, -h, 0.0), 2.0);
            assert_eq!(halves.iter().map(|t| below.triangle_power(t)).sum::<Vec3>(), Vec3::ZERO);
        }
        // Directional: E x projected area.
        let sun = Light {
            kind: LightKind::Directional,
            direction: Vec3::new(0.6, -0.8, 0.0),
            ..point(Vec3::ZERO, 3.0)
        };
        let got: f32 = halves.iter().map(|t| sun.triangle_power(t).x).sum();
        assert!((got - 3.0 * 0.8).abs() < 1e-5, "{got}");
    }

    /// A small far triangle: its power is I x area x cos / d², to the precision of f32.
    #[test]
    fn triangle_power_of_a_small_far_triangle_is_inverse_square() {
        let l = point(Vec3::new(0.0, 300.0, 400.0), 1.0);
        let e = 1e-3f32;
        let tri = [Vec3::ZERO, Vec3::new(0.0, 0.0, e), Vec3::new(e, 0.0, 0.0)];
        let d = l.position.length();
        let want = 0.5 * e * e * (300.0 / d) / (d * d);
        let got = l.triangle_power(&tri).x;
        assert!((got - want).abs() <= 1e-3 * want, "{got} vs {want}");
    }

    #[test]
    fn range_window_reaches_zero_at_range() {
        let mut l = point(Vec3::ZERO, 1.0);
        l.range = Some(2.0);
        assert_eq!(l.incident(Vec3::new(0.0, 2.0, 0.0)).irradiance, Vec3::ZERO);
        let e = l.incident(Vec3::new(0.0, 1.0, 0.0)).irradiance.x;
        assert!((e - (1.0f32 - 1.0 / 16.0).powi(2)).abs() < 1e-6);
    }
}
