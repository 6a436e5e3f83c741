//! Irradiance from virtual polygon and sphere lights (paper 000 §6, §6.1).
//!
//! A virtual polygon light is a planar convex polygon emitting power Phi from its front face
//! (normal n_x) with Lambertian (uniform radiance) emission: L = Phi / (pi A). At a receiver
//! point p with normal n_y, the irradiance is `E = L pi F = Phi / A x F`, where
//! `F = 1/(2 pi) sum_i gamma_i n_y . Gamma_i / |Gamma_i|` (Lambert's contour integral; paper eq.
//! 3-4 is its reciprocal `F_{A->dA} = F dA / A`), `Gamma_i = V_i x V_{i+1}`, V_i the vectors from
//! p to the vertices and gamma_i the angle between V_i and V_{i+1}. The formula needs the whole
//! polygon above the receiver's plane, so the polygon is first clipped against it.
//!
//! **Epsilon shift.** A receiver within `eps` (half a texel) of the light's plane would see the
//! light at grazing angles and read dark in corners where a wall meets a lit floor. It is moved
//! along its own surface until it is `eps` above the light's plane (paper §6.1, Fig. 8).
//!
//! **Point fallback.** When the light's radius is under [`POINT_FALLBACK`] of its distance, the
//! contour sum loses precision (the angles are tiny); the light is then a point at its centroid:
//! `E = Phi cos_x cos_y / (pi d^2)`, which agrees to O((r/d)^2) there.
//!
//! **Sphere lights** (after Hasan et al. 2009, for clusters not on a plane): power Phi around
//! centre c with radius R (the members' RMS distance from c) and mean normal n_x:
//! `E = Phi max(cos_x, 0) max(cos_y, 0) / (pi max(d^2, R^2))`: a point light whose inverse
//! square is capped inside the cluster's extent. Outside it the point law holds exactly; the
//! `d^2 + R^2` form would dim it at every distance (by 20 % at d = 2R), which lost 7 % of the
//! chamber's indirect light where the curved pillars and arches carry many such lights.

use glam::Vec3;

/// Radius-to-distance ratio below which a polygon light is evaluated as a point light.
pub const POINT_FALLBACK: f32 = 1e-3;

pub use prm::form_factor::{clip_above_plane, point_to_polygon};

/// A planar polygon light.
#[derive(Clone, Debug, PartialEq)]
pub struct PolygonLight {
    /// Convex, counter-clockwise seen from the front; at most 8 vertices.
    pub vertices: Vec<Vec3>,
    /// Front normal.
    pub normal: Vec3,
    /// Emitted power, W per channel.
    pub power: Vec3,
    /// Its area, centroid and furthest vertex's distance from the centroid, made once: every
    /// texel's evaluation needs them.
    shape: (f32, Vec3, f32),
}

impl PolygonLight {
    pub fn new(vertices: Vec<Vec3>, normal: Vec3, power: Vec3) -> PolygonLight {
        let mut s = Vec3::ZERO;
        for k in 1..vertices.len().saturating_sub(1) {
            s += (vertices[k] - vertices[0]).cross(vertices[k + 1] - vertices[0]);
        }
        let c = vertices.iter().fold(Vec3::ZERO, |a, b| a + *b) / vertices.len().max(1) as f32;
        let radius = vertices.iter().map(|v| (*v - c).length()).fold(0.0f32, f32::max);
        PolygonLight { vertices, normal, power, shape: (0.5 * s.length(), c, radius) }
    }

    pub fn area(&self) -> f32 {
        self.shape.0
    }

    pub fn centroid(&self) -> Vec3 {
        self.shape.1
    }

    /// Irradiance at (p, n), without visibility, with the epsilon shift of receivers within
    /// `eps` of the light's plane.
    pub fn irradiance(&self, p: Vec3, n: Vec3, eps: f32) -> Vec3 {
        let (area, c, radius) = self.shape;
        if !(area > 0.0) || self.vertices.len() < 3 {
            return Vec3::ZERO;
        }
        let p = epsilon_shift(p, n, c, self.normal, eps);
        let h = (p - c).dot(self.normal);
        if h <= 0.0 {
            return Vec3::ZERO; // behind the emitting face
        }
        let d = p - c;
        let dist = d.length();
        let f = if radius < POINT_FALLBACK * dist {
            let (cx, cy) = (self.normal.dot(d) / dist, -n.dot(d) / dist);
            if cx <= 0.0 || cy <= 0.0 {
                return Vec3::ZERO;
            }
            area * cx * cy / (std::f32::consts::PI * dist * dist)
        } else {
            point_to_polygon(p, n, &self.vertices)
        };
        self.power / area * f
    }
}

/// Move receiver p (normal n) along its surface until it is `eps` above the plane through c
/// with normal nx, when it lies in front of that plane by less than `eps` (a concave corner:
/// a wall texel just above a lit floor) and the plane is not parallel to its own. Receivers
/// behind the plane (below a block's lit top, round a convex edge) are not moved: lifting them
/// over the edge would light a face the light cannot see.
pub fn epsilon_shift(p: Vec3, n: Vec3, c: Vec3, nx: Vec3, eps: f32) -> Vec3 {
    let h = (p - c).dot(nx);
    if !(0.0..eps).contains(&h) {
        return p;
    }
    // The direction along the receiver's surface that rises fastest above the light's plane.
    let t = nx - n * n.dot(nx);
    let rise = t.dot(nx);
    if rise <= 1e-4 {
        return p;
    }
    p + t * ((eps - h) / rise)
}

/// A sphere light: a cluster not on a plane.
#[derive(Clone, Debug, PartialEq)]
pub struct SphereLight {
    pub centre: Vec3,
    pub radius: f32,
    /// Mean normal of the cluster's VPLs (unit).
    pub normal: Vec3,
    pub power: Vec3,
}

impl SphereLight {
    /// Irradiance at (p, n) without visibility.
    pub fn irradiance(&self, p: Vec3, n: Vec3) -> Vec3 {
        let d = p - self.centre;
        let d2 = d.length_squared();
        if !(d2 > 0.0) {
            return Vec3::ZERO;
        }
        let dist = d2.sqrt();
        let (cx, cy) = (self.normal.dot(d) / dist, -n.dot(d) / dist);
        if cx <= 0.0 || cy <= 0.0 {
            return Vec3::ZERO;
        }
        self.power * (cx * cy / (std::f32::consts::PI * d2.max(self.radius * self.radius)))
    }
}
