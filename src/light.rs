//! The light model, shared by every stage (DESIGN.md §3).
//!
//! Units are radiometric and glTF `KHR_lights_punctual` numbers are used as they are:
//! point and spot `intensity x color` is the radiant intensity I in W/sr per RGB channel;
//! directional `intensity x color` is the irradiance E in W/m² on a surface facing the light.
//! Falloff is inverse-square; glTF `range`, when given, applies the spec's smooth window
//! `clamp(1 - (d/range)^4, 0, 1)^2`. Spot cones use the spec's smooth falloff
//! `t = clamp((cos θ - cos outer) / (cos inner - cos outer), 0, 1)`, attenuation `t²`;
//! `inner == outer` is a hard cone.
//!
//! **Apertures and profiles** (paper 001 §3.2: a light is aperture geometry, emission profile
//! and intensity). glTF lights are points; the bakers and the ground truth also take:
//! - a **sphere** of some radius, Lambertian on its surface: from outside it the same radiant
//!   intensity I in every direction as a point light (a Lambertian sphere of radiance L has
//!   I = L pi r²), so it differs from one only in its soft shadows and near field;
//! - a flat convex **polygon**, Lambertian from its front (corners counter-clockwise seen
//!   from there): `intensity` is the radiant intensity along its normal, I_n = L x area, so
//!   I(theta) = I_n cos theta and the flux is pi I_n. Emissive glTF surfaces become these;
//! - a **photometric profile** (IES / EULUMDAT, [`crate::photometry`]) on a point light:
//!   I(w) = `intensity` x the profile's intensity towards w relative to its peak.
//!
//! The runtime's shadow-mapped lights are punctual and refuse the others ([`Light::is_punctual`]).

use std::sync::Arc;

use glam::Vec3;

use crate::photometry::Photometry;

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

/// Where a light emits from.
#[derive(Clone, Debug, PartialEq, Default)]
pub enum Aperture {
    /// A point at the light's position (glTF punctual lights).
    #[default]
    Point,
    /// A Lambertian sphere of `radius` (scene units) around the light's position.
    Sphere { radius: f32 },
    /// A flat convex polygon, world-space corners counter-clockwise seen from its emitting
    /// front; the light's position is its centroid and its direction its normal.
    Polygon { corners: Arc<[Vec3]> },
}

/// A photometric profile placed on a light: the table and its C0 reference direction (unit,
/// perpendicular to the light's direction; the glTF node's +X).
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    pub table: Arc<Photometry>,
    pub c0: Vec3,
}

/// One light in world space.
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
    /// Where it emits from (a point unless said).
    pub aperture: Aperture,
    /// Its emission profile, if photometric (point lights only).
    pub profile: Option<Profile>,
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

/// The brightest light [`Light::check`] takes, a channel (W/sr, or W/m² for a directional
/// light): a thousand times a stadium floodlight. A brighter one is a typo, and its squares
/// overflow f32 in the error sums (a light of 1e38 baked to infinity).
pub const MAX_INTENSITY: f32 = 1e9;

/// How far from the origin [`Light::check`] takes a light, in metres: there f32 keeps a
/// position to a metre, and squared distances near f32's range.
pub const MAX_POSITION: f32 = 1e7;

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
            aperture: Aperture::Point,
            profile: None,
        }
    }

    /// A Lambertian sphere light of `radius` around `centre`, of radiant intensity `intensity`
    /// (W/sr per channel) in every direction.
    pub fn sphere(name: &str, centre: Vec3, radius: f32, intensity: Vec3) -> Light {
        Light { aperture: Aperture::Sphere { radius }, ..Light::point(name, centre, intensity) }
    }

    /// A Lambertian polygon light of uniform `radiance` (W/(m² sr) per channel) from its front,
    /// corners counter-clockwise seen from there. Check it with [`Light::check`].
    pub fn polygon(name: &str, corners: &[Vec3], radiance: Vec3) -> Light {
        let twice = polygon_twice_area(corners);
        let area = 0.5 * twice.length();
        let centroid = corners.iter().copied().sum::<Vec3>() / corners.len().max(1) as f32;
        Light {
            direction: twice.normalize_or_zero(),
            aperture: Aperture::Polygon { corners: corners.into() },
            ..Light::point(name, centroid, radiance * area)
        }
    }

    /// This light with a photometric profile, C0 along `c0` (made perpendicular to its
    /// direction).
    pub fn with_profile(mut self, table: Arc<Photometry>, c0: Vec3) -> Light {
        let c0 = (c0 - self.direction * c0.dot(self.direction)).try_normalize();
        let c0 = c0.unwrap_or_else(|| self.direction.any_orthonormal_vector());
        self.profile = Some(Profile { table, c0 });
        self
    }

    /// True for a glTF-style punctual light: a point aperture and no profile.
    pub fn is_punctual(&self) -> bool {
        self.aperture == Aperture::Point && self.profile.is_none()
    }

    /// The radius of a ball around `position` that holds the aperture (0 for a point): what
    /// a shadow from it can be cast from.
    pub fn aperture_radius(&self) -> f32 {
        match &self.aperture {
            Aperture::Point => 0.0,
            Aperture::Sphere { radius } => *radius,
            Aperture::Polygon { corners } => {
                corners.iter().map(|c| (*c - self.position).length()).fold(0.0, f32::max)
            }
        }
    }

    /// True for a sphere or polygon aperture.
    pub fn is_area(&self) -> bool {
        self.aperture != Aperture::Point
    }

    /// What is wrong with this light for the bakers, if anything: non-finite numbers, a
    /// non-positive sphere radius, a polygon that is not flat and convex, a profile on
    /// anything but a point light, an aperture on a directional light.
    pub fn check(&self) -> Result<(), String> {
        if !(self.intensity.is_finite() && self.intensity.min_element() >= 0.0) {
            return Err(format!("intensity {} must be finite and >= 0", self.intensity));
        }
        // A polygon light's intensity is its radiance times its area: its radiance is held to
        // the bound, as an emissive surface's is.
        let brightness = match &self.aperture {
            Aperture::Polygon { corners } => self.intensity / (0.5 * polygon_twice_area(corners).length()),
            _ => self.intensity,
        };
        if brightness.max_element() > MAX_INTENSITY {
            let what = if self.is_area() && !matches!(self.aperture, Aperture::Sphere { .. }) {
                "radiance"
            } else {
                "intensity"
            };
            return Err(format!("{what} {brightness} is beyond {MAX_INTENSITY:e} a channel"));
        }
        if self.is_positional() && !self.position.is_finite() {
            return Err(format!("position {} is not finite", self.position));
        }
        // Its corners and its reach too: corners at ±1e10 have their centroid at the origin.
        let far = match &self.aperture {
            Aperture::Polygon { corners } => corners.iter().fold(0.0f32, |m, c| m.max(c.abs().max_element())),
            Aperture::Sphere { radius } => self.position.abs().max_element() + radius.abs(),
            Aperture::Point => self.position.abs().max_element(),
        };
        if self.is_positional() && far > MAX_POSITION {
            return Err(format!(
                "light at {} reaches beyond {MAX_POSITION:e} m of the origin",
                self.position
            ));
        }
        match &self.aperture {
            Aperture::Point => {}
            _ if !self.is_positional() => return Err("a directional light has no aperture".into()),
            Aperture::Sphere { radius } => {
                if !(radius.is_finite() && *radius > 0.0) {
                    return Err(format!("sphere radius {radius} must be positive"));
                }
            }
            Aperture::Polygon { corners } => check_polygon(corners)?,
        }
        if matches!(self.aperture, Aperture::Polygon { .. }) && self.kind != LightKind::Point {
            return Err("a polygon light is Lambertian: it takes no spot cone".into());
        }
        if self.profile.is_some() && (self.is_area() || self.kind != LightKind::Point) {
            return Err("a photometric profile goes on a point light only (it gives the cone itself)".into());
        }
        Ok(())
    }

    /// Light arriving at point `p`, not yet multiplied by the receiver's cosine or visibility.
    /// Exact for point lights (with their profile) and for a sphere light seen from outside;
    /// for a polygon light the far field (a point at its centroid with I_n cos theta) that
    /// [`Light::irradiance`] refines.
    pub fn incident(&self, p: Vec3) -> Incident {
        match self.kind {
            LightKind::Directional => {
                Incident { to_light: -self.direction, distance: f32::INFINITY, irradiance: self.intensity }
            }
            LightKind::Point | LightKind::Spot { .. } => {
                let d = self.position - p;
                let mut dist2 = d.length_squared();
                if !(dist2 > 0.0) {
                    // A receiver exactly at the light: no defined direction, and the inverse
                    // square law has no finite value. We deliver nothing rather than infinity.
                    return Incident { to_light: Vec3::Z, distance: 0.0, irradiance: Vec3::ZERO };
                }
                let dist = dist2.sqrt();
                let to_light = d / dist;
                if let Aperture::Sphere { radius } = self.aperture {
                    // Inside the sphere: as bright as at its surface.
                    dist2 = dist2.max(radius * radius);
                }
                let mut scale = 1.0 / dist2 * self.window(dist);
                if let LightKind::Spot { inner, outer } = self.kind {
                    scale *= spot_falloff(self.direction.dot(-to_light), inner, outer);
                }
                if !self.is_punctual() {
                    scale *= self.shape(-to_light);
                }
                Incident { to_light, distance: dist, irradiance: self.intensity * scale }
            }
        }
    }

    /// Irradiance at `p` on a surface with unit normal `n`, without visibility (W/m²). A
    /// polygon light's is exact (Lambert's contour integral over the part above the
    /// receiver's plane: E = L pi F with L = I_n / area). A sphere light's is `I cos / d²`
    /// while the sphere is wholly above the receiver's plane (exact), the part of its cap
    /// above the plane when the plane cuts it (`L pi F` of its [`Silhouette`], L = I / (pi R²);
    /// the centre's cosine alone counts all of the sphere or none of it), and as at its surface
    /// from inside it.
    pub fn irradiance(&self, p: Vec3, n: Vec3) -> Vec3 {
        if let Aperture::Polygon { corners } = &self.aperture {
            if (p - self.position).dot(self.direction) <= 0.0 {
                return Vec3::ZERO;
            }
            let area = 0.5 * polygon_twice_area(corners).length();
            if !(area > 0.0) {
                return Vec3::ZERO;
            }
            let f = crate::form_factor::point_to_polygon(p, n, corners);
            let window = self.window((self.position - p).length());
            return self.intensity * (std::f32::consts::PI * f / area * window);
        }
        let inc = self.incident(p);
        let cos = n.dot(inc.to_light);
        if let Aperture::Sphere { radius } = self.aperture {
            let sin = radius / inc.distance;
            if cos.abs() < sin {
                // The receiver's plane cuts the sphere: the share of its cap above the plane.
                // Relative to the receiver: a small bulb far from the origin keeps its shape.
                if let Some(s) = Silhouette::new(self.position - p, radius, Vec3::ZERO) {
                    let f = crate::form_factor::point_to_polygon(Vec3::ZERO, n, &s.corners());
                    return inc.irradiance * (f / (sin * sin));
                }
            }
        }
        inc.irradiance * cos.max(0.0)
    }

    /// Radiant intensity emitted towards unit direction `dir` (W/sr): a spot's falloff, a
    /// polygon's cosine, a profile's table; zero for directional lights.
    pub fn intensity_towards(&self, dir: Vec3) -> Vec3 {
        let mut i = match self.kind {
            LightKind::Point => self.intensity,
            LightKind::Spot { inner, outer } => {
                self.intensity * spot_falloff(self.direction.dot(dir), inner, outer)
            }
            LightKind::Directional => return Vec3::ZERO,
        };
        if !self.is_punctual() {
            i *= self.shape(dir);
        }
        i
    }

    /// What the aperture and profile make of the intensity towards unit `dir`: a polygon's
    /// cosine, a profile's relative intensity; 1 for a point or sphere without a profile.
    fn shape(&self, dir: Vec3) -> f32 {
        let mut f = 1.0;
        if let Aperture::Polygon { .. } = self.aperture {
            f *= self.direction.dot(dir).max(0.0);
        }
        if let Some(pr) = &self.profile {
            f *= pr.table.towards(dir, self.direction, pr.c0);
        }
        f
    }

    /// The flux this light emits (W per channel); directional lights: zero (theirs depends
    /// on the level they fall on).
    pub fn flux(&self) -> Vec3 {
        use std::f32::consts::{PI, TAU};
        let sr = match (&self.kind, &self.aperture, &self.profile) {
            (LightKind::Directional, _, _) => 0.0,
            (_, Aperture::Polygon { .. }, _) => PI,
            (_, _, Some(pr)) => pr.table.solid_integral,
            (LightKind::Spot { inner, outer }, _, _) => {
                // 2 pi x the integral of the falloff t² over cos theta: (ci - co)/3 + 1 - ci.
                let (ci, co) = (inner.cos(), outer.cos());
                TAU * ((ci - co).max(0.0) / 3.0 + 1.0 - ci.max(co))
            }
            _ => 4.0 * PI,
        };
        self.intensity * sr
    }

    /// A point of the aperture to aim a shadow ray from `p` at, for `u` uniform in [0, 1)²:
    /// the position of a point light; a point of a sphere's disk facing `p`; a point of a
    /// polygon, uniform by area.
    pub fn aperture_point(&self, p: Vec3, u: [f32; 2]) -> Vec3 {
        match &self.aperture {
            Aperture::Point => self.position,
            Aperture::Sphere { radius } => {
                let Some(w) = (p - self.position).try_normalize() else { return self.position };
                let (t, b) = w.any_orthonormal_pair();
                let (r, phi) = (radius * u[0].sqrt(), std::f32::consts::TAU * u[1]);
                self.position + t * (r * phi.cos()) + b * (r * phi.sin())
            }
            Aperture::Polygon { corners } => polygon_point(corners, u),
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
    /// a small, far triangle keeps its precision. A spot's falloff is integrated over that
    /// solid angle ([`crate::cone`]: exact for a hard cone; a spot 1 cm above a floor lights a
    /// spot of it smaller than any cell triangle). A range's window is taken at the centroid's
    /// distance of each of up to 16² equal pieces of the triangle, more where the window falls
    /// more across it (`window_pieces`): at one centroid, a lamp of 0.5 m range 10 cm over a
    /// floor gave cell-sized triangles 0.72 of their power. Directional lights: `E x` the
    /// triangle's area projected along the light.
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
        let Some(range) = self.range.filter(|&r| r > 0.0) else {
            return self.intensity * self.cone_solid_angle(a, b, c, triple);
        };
        // The window along the triangle: split it where the window falls across it.
        let pieces = window_pieces([a, b, c], range);
        if pieces <= 1 {
            let scale =
                self.cone_solid_angle(a, b, c, triple) * range_window(((a + b + c) / 3.0).length(), range);
            return self.intensity * scale;
        }
        let n = pieces as f32;
        let (e1, e2) = ((b - a) / n, (c - a) / n);
        let at = |i: u32, j: u32| a + e1 * i as f32 + e2 * j as f32;
        let mut scale = 0.0;
        for i in 0..pieces {
            for j in 0..pieces - i {
                // The upward piece at (i, j), then the downward one beside it (not on the edge).
                let last = i + j + 1 == pieces;
                for down in [false, true] {
                    if down && last {
                        break;
                    }
                    let [p, q, r] = if down {
                        [at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]
                    } else {
                        [at(i, j), at(i + 1, j), at(i, j + 1)]
                    };
                    let t = -p.dot((q - p).cross(r - p));
                    if t > 0.0 {
                        let w = range_window(((p + q + r) / 3.0).length(), range);
                        scale += self.cone_solid_angle(p, q, r, t) * w;
                    }
                }
            }
        }
        self.intensity * scale
    }

    /// The solid angle of the triangle with corners `a`, `b`, `c` relative to the light (its
    /// triple product `triple` > 0: facing it), and for a spot its falloff integrated over it.
    fn cone_solid_angle(&self, a: Vec3, b: Vec3, c: Vec3, triple: f32) -> f32 {
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let denominator = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        let whole = 2.0 * triple.atan2(denominator);
        if let LightKind::Spot { inner, outer } = self.kind {
            let dirs = [a / la, b / lb, c / lc];
            return crate::cone::spot_solid_angle(dirs, whole, self.direction, inner.cos(), outer.cos());
        }
        whole
    }

    /// glTF range window ([`range_window`]); 1 without a range.
    pub(crate) fn window(&self, dist: f32) -> f32 {
        self.range.map_or(1.0, |r| range_window(dist, r))
    }

    /// True when this is a point-like light (has a position).
    pub fn is_positional(&self) -> bool {
        !matches!(self.kind, LightKind::Directional)
    }
}

/// Pieces a side to split a triangle into (corners relative to the light) so that the range
/// window is taken at each piece's centroid: as many as 16 x the window's fall across the
/// triangle (its value at a bound on the nearest point less at the farthest corner), 1 to 16;
/// 0 where the whole triangle lies beyond the range.
pub(crate) fn window_pieces(corners: [Vec3; 3], range: f32) -> u32 {
    let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
    let radius = corners.iter().map(|&p| (p - centroid).length()).fold(0.0f32, f32::max);
    let far = corners.iter().map(|p| p.length()).fold(0.0f32, f32::max);
    let near = (centroid.length() - radius).max(0.0);
    if near >= range {
        return 0;
    }
    let fall = range_window(near, range) - range_window(far, range);
    ((16.0 * fall).ceil() as u32).clamp(1, 16)
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

/// Twice the vector area of a polygon (its normal times twice its area, for counter-clockwise
/// corners seen from the front).
pub fn polygon_twice_area(corners: &[Vec3]) -> Vec3 {
    let mut s = Vec3::ZERO;
    for k in 1..corners.len().saturating_sub(1) {
        s += (corners[k] - corners[0]).cross(corners[k + 1] - corners[0]);
    }
    s
}

/// Levels of the kd-tree that splits a polygon light's aperture for its shadow rays:
/// 2^4 = 16 parts, one ray each (the [`crate::bvh::AREA_SHADOW_RAYS`] a light gets).
pub const APERTURE_LEVELS: u32 = 4;

/// A convex polygon split into parts (paper 001 §4.1, direct virtual lights): a kd-tree that
/// halves each part across the middle of its longest axis-aligned extent, `levels` deep. The
/// parts are convex, wound as `corners`, and tile the polygon (a cut that would leave one
/// side without area keeps the part whole), so their form factors sum to the polygon's.
pub fn aperture_parts(corners: &[Vec3], levels: u32) -> Vec<Vec<Vec3>> {
    let mut parts = vec![corners.to_vec()];
    for _ in 0..levels {
        let mut next = Vec::with_capacity(2 * parts.len());
        for part in parts {
            let (lo, hi) = part
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), c| (lo.min(*c), hi.max(*c)));
            let axis = (hi - lo).max_position();
            let mid = 0.5 * (lo[axis] + hi[axis]);
            let (below, above) = split_polygon(&part, axis, mid);
            let has_area = |q: &[Vec3]| q.len() >= 3 && polygon_twice_area(q).length_squared() > 0.0;
            if has_area(&below) && has_area(&above) {
                next.push(below);
                next.push(above);
            } else {
                next.push(part);
            }
        }
        parts = next;
    }
    parts
}

/// A convex polygon cut by the plane `x[axis] = at` into the parts at or below it and at or
/// above it (corners on the plane go to both).
fn split_polygon(poly: &[Vec3], axis: usize, at: f32) -> (Vec<Vec3>, Vec<Vec3>) {
    let (mut below, mut above) = (Vec::with_capacity(poly.len() + 1), Vec::with_capacity(poly.len() + 1));
    for k in 0..poly.len() {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        let (da, db) = (a[axis] - at, b[axis] - at);
        if da <= 0.0 {
            below.push(a);
        }
        if da >= 0.0 {
            above.push(a);
        }
        if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
            let mut q = a + (b - a) * (da / (da - db));
            q[axis] = at;
            below.push(q);
            above.push(q);
        }
    }
    (below, above)
}

/// A point of a convex polygon, uniform by area, for `u` uniform in [0, 1)²: a triangle of
/// its fan picked by area with `u[0]` (then rescaled), a point in it by the square-root warp.
pub fn polygon_point(corners: &[Vec3], u: [f32; 2]) -> Vec3 {
    let fan = |k: usize| 0.5 * (corners[k] - corners[0]).cross(corners[k + 1] - corners[0]).length();
    let total: f32 = (1..corners.len() - 1).map(fan).sum();
    let mut x = u[0] * total;
    let mut k = 1;
    while k + 2 < corners.len() && x >= fan(k) {
        x -= fan(k);
        k += 1;
    }
    let a = fan(k);
    let v = if a > 0.0 { (x / a).clamp(0.0, 1.0) } else { 0.5 };
    let s = v.sqrt();
    let (b0, b1) = (1.0 - s, s * (1.0 - u[1]));
    corners[0] * b0 + corners[k] * b1 + corners[k + 1] * (1.0 - b0 - b1)
}

/// Corners of the polygon that stands for a sphere light's silhouette ([`Silhouette`]).
pub const SILHOUETTE_CORNERS: usize = 32;

/// The disk a sphere light shows a point outside it: the circle where its rays graze the sphere,
/// at `R^2 / d` from the sphere's centre towards the point with radius `R sqrt(1 - R^2 / d^2)`.
/// The directions from the point to the disk are those to the sphere, so a Lambertian sphere's
/// light there is the disk's: `L pi F`, `F` the disk's form factor, horizon and occluders
/// included. It maps the unit plane (x, y, z = 0) onto the disk's plane, and stands for the disk
/// with a regular polygon of [`SILHOUETTE_CORNERS`] corners and the disk's area
/// ([`unit_silhouette`]).
#[derive(Clone, Copy, Debug)]
pub struct Silhouette {
    centre: Vec3,
    x: Vec3,
    y: Vec3,
}

impl Silhouette {
    /// The silhouette of the sphere (`centre`, `radius`) seen from `p`; none from on or inside
    /// it (closer than `1.0001 radius`), where it has none.
    pub fn new(centre: Vec3, radius: f32, p: Vec3) -> Option<Silhouette> {
        let d = p - centre;
        let dist = d.length();
        if !(dist > radius * 1.0001 && dist.is_finite()) {
            return None;
        }
        let w = d / dist;
        let sin = radius / dist;
        let rho = radius * (1.0 - sin * sin).max(0.0).sqrt();
        let (x, y) = w.any_orthonormal_pair();
        Some(Silhouette { centre: centre + w * (radius * sin), x: x * rho, y: y * rho })
    }

    /// The point of the disk's plane at unit-plane point `u` (its z ignored).
    pub fn at(&self, u: Vec3) -> Vec3 {
        self.centre + self.x * u.x + self.y * u.y
    }

    /// The polygon standing for the disk.
    pub fn corners(&self) -> Vec<Vec3> {
        unit_silhouette().0.iter().map(|&c| self.at(c)).collect()
    }
}

/// The unit disk as a regular polygon of [`SILHOUETTE_CORNERS`] corners and area pi (its
/// corners at `sqrt(2 pi / (n sin(2 pi / n)))`, so that its form factor is the disk's to
/// second order in its corners' angle, not 0.6 % short), in the plane z = 0, and its parts
/// ([`aperture_parts`] at [`APERTURE_LEVELS`]): the shadow rays of a receiver that sees the
/// whole sphere go through these, mapped by [`Silhouette::at`].
pub fn unit_silhouette() -> &'static (Vec<Vec3>, Vec<Vec<Vec3>>) {
    static DISK: std::sync::OnceLock<(Vec<Vec3>, Vec<Vec<Vec3>>)> = std::sync::OnceLock::new();
    DISK.get_or_init(|| {
        let n = SILHOUETTE_CORNERS as f64;
        let tau = std::f64::consts::TAU;
        let r = (tau / (n * (tau / n).sin())).sqrt();
        let corners: Vec<Vec3> = (0..SILHOUETTE_CORNERS)
            .map(|k| {
                let a = tau * k as f64 / n;
                Vec3::new((r * a.cos()) as f32, (r * a.sin()) as f32, 0.0)
            })
            .collect();
        let parts = aperture_parts(&corners, APERTURE_LEVELS);
        (corners, parts)
    })
}

/// The slow twin of a Lambertian sphere light's irradiance at `p` (unit normal `n`): its
/// surface facing `p` in `cells = (rings, sectors)` cells around the axis towards `p`, each
/// `L cos_p+ cos_q / r² dA` (L = I / (pi R²)) times `visible(cell centre)`, summed in f64. For
/// tests: shares nothing with the silhouette the bakers use.
pub fn sphere_irradiance_by_cells(
    centre: Vec3,
    radius: f32,
    intensity: f32,
    p: Vec3,
    n: Vec3,
    (rings, sectors): (usize, usize),
    visible: impl Fn(Vec3) -> bool,
) -> f64 {
    let (c, pd, nd) = (centre.as_dvec3(), p.as_dvec3(), n.as_dvec3());
    let r = radius as f64;
    let w = (pd - c).normalize();
    let (t, b) = w.any_orthonormal_pair();
    let alpha_max = (r / (pd - c).length()).acos();
    let radiance = intensity as f64 / (std::f64::consts::PI * r * r);
    let da = alpha_max / rings as f64;
    let dphi = std::f64::consts::TAU / sectors as f64;
    let mut e = 0.0;
    for i in 0..rings {
        let a = da * (i as f64 + 0.5);
        for j in 0..sectors {
            let phi = dphi * (j as f64 + 0.5);
            let normal = w * a.cos() + (t * phi.cos() + b * phi.sin()) * a.sin();
            let q = c + normal * r;
            let d = pd - q;
            let dist2 = d.length_squared();
            let dir = d / dist2.sqrt();
            let (cos_q, cos_p) = (normal.dot(dir), -nd.dot(dir));
            if cos_q > 0.0 && cos_p > 0.0 && visible(q.as_vec3()) {
                e += radiance * cos_p * cos_q / dist2 * (r * r * a.sin() * da * dphi);
            }
        }
    }
    e
}

/// Whether `corners` make a flat, convex polygon of positive area, with a reason if not.
pub(crate) fn check_polygon(corners: &[Vec3]) -> Result<(), String> {
    if corners.len() < 3 || corners.len() > 64 {
        return Err(format!("a polygon light needs 3 to 64 corners, not {}", corners.len()));
    }
    if corners.iter().any(|c| !c.is_finite()) {
        return Err("a polygon corner is not finite".into());
    }
    let twice = polygon_twice_area(corners);
    let size = corners.iter().map(|c| (*c - corners[0]).length()).fold(0.0f32, f32::max);
    let Some(n) = twice.try_normalize().filter(|_| twice.length() > 1e-10 * size * size) else {
        return Err("the polygon has no area".into());
    };
    let centroid = corners.iter().copied().sum::<Vec3>() / corners.len() as f32;
    for (k, c) in corners.iter().enumerate() {
        if (*c - centroid).dot(n).abs() > 1e-4 * size {
            return Err(format!("corner {k} is off the polygon's plane"));
        }
        let (a, b) = (corners[(k + 1) % corners.len()], corners[(k + 2) % corners.len()]);
        if (a - *c).cross(b - a).dot(n) < -1e-6 * size * size {
            return Err(format!("the polygon is not convex at corner {}", (k + 1) % corners.len()));
        }
    }
    Ok(())
}

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

    /// The square [-s, s]² in the plane y = 0, facing up, as two triangles and as a fan of
    /// eight about a point off its centre.
    fn square_pieces(s: f32) -> ([[Vec3; 3]; 2], Vec<[Vec3; 3]>) {
        let corners =
            [Vec3::new(-s, 0.0, -s), Vec3::new(-s, 0.0, s), Vec3::new(s, 0.0, s), Vec3::new(s, 0.0, -s)];
        let halves = [[corners[0], corners[1], corners[2]], [corners[0], corners[2], corners[3]]];
        let mid = Vec3::new(0.1, 0.0, -0.05);
        let fan = (0..4)
            .flat_map(|k| {
                let (p, q) = (corners[k], corners[(k + 1) % 4]);
                let m = (p + q) / 2.0;
                [[mid, p, m], [mid, m, q]]
            })
            .collect();
        (halves, fan)
    }

    /// The square [-s, s]² at height 0 seen from (0, h, 0) has solid angle
    /// `4 asin(s² / (s² + h²))`; split into two triangles or into a fan of eight, each piece's
    /// power must add up to `I x` that, from 1 m to 1e-4 m above it. Tolerance 1e-3: a light
    /// h above a shared edge makes both triangles' denominators cancel to ~0, and f32 (the
    /// GPU's precision too) leaves an error of about 2 eps |a|/h there (1e-4 at h = 1e-4 m).
    #[test]
    fn triangle_power_is_the_solid_angle_at_any_height() {
        let s = 0.5f32;
        let (halves, fan) = square_pieces(s);
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

    /// A spot aimed down at the square from 1 m to 1e-4 m above it, its cone's footprint
    /// inside the square: the pieces' power adds up to the cone's, `2 pi I (1 - cos outer)`
    /// for a hard cone and `2 pi I ((ci - co) / 3 + 1 - ci)` for a smooth one (the falloff
    /// `t²` integrated over the cosine), to 1e-3, and tilted 30° to what the pieces of a
    /// finer split give. The falloff along the pieces' mean direction gave 0.50 of it at
    /// 10 cm and nothing at 3 cm for a 20° cone.
    #[test]
    fn a_spots_power_on_a_plane_is_its_cones_at_any_height() {
        let s = 2.0f32;
        let (halves, fan) = square_pieces(s);
        for (inner, outer) in [(20f32, 20f32), (10.0, 20.0), (40.0, 60.0), (0.0, 5.0)] {
            let (ci, co) = (inner.to_radians().cos(), outer.to_radians().cos());
            let want = std::f32::consts::TAU * ((ci - co) / 3.0 + 1.0 - ci);
            for h in [0.5f32, 0.1, 0.03, 0.01, 1e-3, 1e-4] {
                let mut l = point(Vec3::new(0.0, h, 0.0), 1.0);
                l.kind = LightKind::Spot { inner: inner.to_radians(), outer: outer.to_radians() };
                l.direction = -Vec3::Y;
                for tris in [&halves[..], &fan[..]] {
                    let got: f32 = tris.iter().map(|t| l.triangle_power(t).x).sum();
                    assert!((got - want).abs() <= 1e-3 * want, "{inner}/{outer} at {h}: {got} vs {want}");
                }
                l.direction = Vec3::new(0.5, -0.75f32.sqrt(), 0.0);
                let coarse: f32 = halves.iter().map(|t| l.triangle_power(t).x).sum();
                let fine: f32 = fan.iter().map(|t| l.triangle_power(t).x).sum();
                assert!(
                    (coarse - fine).abs() <= 1e-3 * fine,
                    "{inner}/{outer} at {h}, tilted: {coarse} vs {fine}"
                );
            }
        }
    }

    /// A light with a glTF range over the 4 x 4 m square, from 30 cm to 3 cm above it: the
    /// pieces' power adds up to the range window integrated over the square (a midpoint sum
    /// on a 1000² grid, f64): within 3e-3 for a grid of 0.5 m triangles, a cell's size, and
    /// 5e-2 for the square's two halves, 8 ranges across. The window at each triangle's
    /// centroid gave the grid 0.55-0.72 of it at a 0.5 m range and the halves nothing.
    #[test]
    fn a_ranged_lights_power_on_a_plane_is_its_window_integrated() {
        let s = 2.0f32;
        let q = |a: usize, b: usize, m: usize| {
            Vec3::new(-s + 2.0 * s * a as f32 / m as f32, 0.0, -s + 2.0 * s * b as f32 / m as f32)
        };
        let split = |m: usize| -> Vec<[Vec3; 3]> {
            (0..m * m)
                .flat_map(|k| {
                    let (i, j) = (k / m, k % m);
                    let (p0, p1, p2, p3) = (q(i, j, m), q(i, j + 1, m), q(i + 1, j + 1, m), q(i + 1, j, m));
                    [[p0, p1, p2], [p0, p2, p3]]
                })
                .collect()
        };
        let (halves, grid) = (split(1), split(8));
        for (range, spot) in [(0.5f32, false), (1.0, false), (3.0, false), (1.0, true)] {
            for h in [0.3f32, 0.1, 0.03] {
                let mut l = point(Vec3::new(0.0, h, 0.0), 1.0);
                l.range = Some(range);
                if spot {
                    l.kind = LightKind::Spot { inner: 0.3, outer: 0.6 };
                    l.direction = Vec3::new(0.3, -1.0, 0.0).normalize();
                }
                let n = 1000;
                let mut want = 0.0f64;
                for i in 0..n {
                    for j in 0..n {
                        let at = |k: usize| -s as f64 + 2.0 * s as f64 * (k as f64 + 0.5) / n as f64;
                        let p = Vec3::new(at(i) as f32, 0.0, at(j) as f32);
                        want += (l.irradiance(p, Vec3::Y).x as f64) * (2.0 * s as f64 / n as f64).powi(2);
                    }
                }
                for (tris, tolerance) in [(&grid, 3e-3), (&halves, 5e-2)] {
                    let got: f64 = tris.iter().map(|t| l.triangle_power(t).x as f64).sum();
                    assert!(
                        (got / want - 1.0).abs() < tolerance,
                        "range {range} (spot {spot}) at {h}, {} triangles: {got} of {want}",
                        tris.len()
                    );
                }
            }
        }
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

    #[test]
    fn a_light_too_bright_or_too_far_is_refused_and_the_limits_are_not() {
        let at = |p: Vec3, i: f32| Light::point("l", p, Vec3::new(i, 0.0, 0.0)).check();
        assert_eq!(at(Vec3::ZERO, MAX_INTENSITY), Ok(()));
        assert_eq!(at(Vec3::splat(MAX_POSITION), 1.0), Ok(()));
        assert!(at(Vec3::ZERO, 2.0 * MAX_INTENSITY).unwrap_err().contains("beyond 1e9"));
        assert!(at(Vec3::new(0.0, -2.0 * MAX_POSITION, 0.0), 1.0).unwrap_err().contains("beyond 1e7 m"));
        // A polygon's corners count, not only its centroid; its radiance, not its intensity.
        let far = [Vec3::new(-1e10, 0.0, -1.0), Vec3::new(1e10, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0)];
        assert!(Light::polygon("far", &far, Vec3::ONE).check().unwrap_err().contains("beyond 1e7 m"));
        let square =
            [Vec3::ZERO, Vec3::new(0.0, 0.0, 10.0), Vec3::new(10.0, 0.0, 10.0), Vec3::new(10.0, 0.0, 0.0)];
        assert_eq!(Light::polygon("ceiling", &square, Vec3::splat(0.5 * MAX_INTENSITY)).check(), Ok(()));
        assert!(Light::polygon("sun", &square, Vec3::splat(2.0 * MAX_INTENSITY))
            .check()
            .unwrap_err()
            .contains("radiance"));
        // A sun has no position to be far.
        let mut sun = Light::point("sun", Vec3::splat(1e30), Vec3::ONE);
        sun.kind = LightKind::Directional;
        assert_eq!(sun.check(), Ok(()));
    }

    /// The form factor from a point at the origin (normal +Y) to the rectangle
    /// [x0, x1] x [z0, z1] at height h, parallel to it, by the textbook corner formula
    /// (Howell's catalogue, C-11) and superposition: independent of Lambert's contour code.
    pub(crate) fn rect_form_factor(x0: f64, x1: f64, z0: f64, z1: f64, h: f64) -> f64 {
        let corner = |x: f64, z: f64| {
            let (a, b) = (x.abs() / h, z.abs() / h);
            let (ra, rb) = ((1.0 + a * a).sqrt(), (1.0 + b * b).sqrt());
            let f = (a / ra * (b / ra).atan() + b / rb * (a / rb).atan()) / (2.0 * std::f64::consts::PI);
            f * x.signum() * z.signum()
        };
        corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0)
    }

    /// A square light of radiance L facing down over a floor: E = L pi F at points under it,
    /// beside it and far off, to 2e-4 relative (f32 round-off in the contour sum).
    #[test]
    fn a_polygon_light_gives_the_rectangle_s_form_factor() {
        let (h, s, radiance) = (0.5f32, 0.5f32, 3.0f32);
        let corners = [v3(-s, h, -s), v3(s, h, -s), v3(s, h, s), v3(-s, h, s)];
        let l = Light::polygon("panel", &corners, Vec3::splat(radiance));
        assert_eq!(l.check(), Ok(()));
        assert!((l.direction - -Vec3::Y).length() < 1e-6, "faces down: {}", l.direction);
        assert!((l.flux().x - std::f32::consts::PI * radiance * 4.0 * s * s).abs() < 1e-4);
        for (x, z) in [(0.0f32, 0.0f32), (0.3, -0.2), (0.5, 0.5), (0.9, 0.1), (2.0, -1.5), (6.0, 4.0)] {
            let p = v3(x, 0.0, z);
            let f =
                rect_form_factor((-s - x) as f64, (s - x) as f64, (-s - z) as f64, (s - z) as f64, h as f64);
            let want = radiance as f64 * std::f64::consts::PI * f;
            let got = l.irradiance(p, Vec3::Y).x as f64;
            assert!((got - want).abs() <= 2e-4 * want + 1e-9, "({x}, {z}): {got} vs {want}");
            // Seen from above the panel's plane, nothing.
            assert_eq!(l.irradiance(v3(x, h + 0.1, z), -Vec3::Y), Vec3::ZERO);
        }
    }

    /// A sphere light seen from outside, wholly above the receiver's plane, is its point:
    /// I cos / d²; its flux is 4 pi I; shadow-ray targets lie on its disk facing the receiver.
    #[test]
    fn a_sphere_light_is_its_point_from_outside() {
        let c = v3(0.2, 1.0, -0.1);
        let sph = Light::sphere("bulb", c, 0.1, Vec3::splat(2.0));
        let pt = Light::point("bulb", c, Vec3::splat(2.0));
        for p in [v3(0.0, 0.0, 0.0), v3(1.0, 0.0, 0.5), v3(-0.5, 0.3, 0.2)] {
            assert_eq!(sph.irradiance(p, Vec3::Y), pt.irradiance(p, Vec3::Y));
            let w = (p - c).normalize();
            for u in [[0.0, 0.0], [0.99, 0.3], [0.5, 0.75]] {
                let q = sph.aperture_point(p, u);
                assert!((q - c).length() <= 0.1 + 1e-6 && (q - c).dot(w).abs() < 1e-5);
            }
        }
        assert!((sph.flux().x - 4.0 * std::f32::consts::TAU).abs() < 1e-4);
        // Inside: as at the surface, never infinite.
        assert!((sph.incident(c + v3(0.0, 0.01, 0.0)).irradiance.x - 200.0).abs() < 1e-3);
    }

    /// A profile lit only around C0 lights the side its C0 reference points to, and C90 is
    /// counter-clockwise seen from above a downlight (IES type C): -Z for C0 = +X, axis -Y.
    #[test]
    fn a_profile_is_read_in_the_light_s_frame() {
        let table = Photometry::new(
            "IES",
            &[0.0, 90.0, 180.0],
            &[0.0, 90.0, 180.0, 270.0],
            &[vec![1.0, 1.0, 1.0], vec![0.0, 0.5, 0.0], vec![0.0, 0.0, 0.0], vec![0.0, 0.0, 0.0]],
        )
        .unwrap();
        let l = Light::point("ies", Vec3::ZERO, Vec3::splat(4.0)).with_profile(Arc::new(table), Vec3::X);
        assert_eq!(l.check(), Ok(()));
        let towards = |d: Vec3| l.intensity_towards(d.normalize()).x;
        assert!((towards(v3(1.0, 0.0, 0.0)) - 4.0).abs() < 1e-5, "C0, gamma 90");
        assert!((towards(v3(0.0, 0.0, -1.0)) - 2.0).abs() < 1e-5, "C90 is -Z");
        assert!(towards(v3(0.0, 0.0, 1.0)).abs() < 1e-6, "C270 is dark");
        assert!(towards(v3(-1.0, 0.0, 0.0)).abs() < 1e-6, "C180 is dark");
        // The incident light at a receiver follows the same table.
        let e = l.incident(v3(0.0, 0.0, -2.0)).irradiance.x;
        assert!((e - 2.0 / 4.0).abs() < 1e-5, "{e}");
        // A spot with a profile, a profile on a sphere, a bent polygon are refused.
        let spot = Light { kind: LightKind::Spot { inner: 0.1, outer: 0.2 }, ..l.clone() };
        assert!(spot.check().unwrap_err().contains("point light only"));
        let bent = [v3(0.0, 0.0, 0.0), v3(1.0, 0.0, 0.0), v3(1.0, 0.3, 1.0), v3(0.0, 0.0, 1.0)];
        assert!(Light::polygon("b", &bent, Vec3::ONE)
            .check()
            .unwrap_err()
            .contains("off the polygon's plane"));
        let dart = [v3(0.0, 0.0, 0.0), v3(0.0, 0.0, 1.0), v3(0.2, 0.0, 0.2), v3(1.0, 0.0, 0.0)];
        assert!(Light::polygon("d", &dart, Vec3::ONE).check().unwrap_err().contains("not convex"));
        assert!(Light::sphere("s", Vec3::ZERO, 0.0, Vec3::ONE).check().unwrap_err().contains("radius"));
        let line = [v3(0.0, 0.0, 0.0), v3(1.0, 0.0, 0.0), v3(2.0, 0.0, 0.0)];
        assert!(Light::polygon("l", &line, Vec3::ONE).check().unwrap_err().contains("no area"));
    }

    /// Uniform points of a polygon: every one inside, and their mean is the area centroid, to
    /// 1e-2 (a 200 x 200 grid of u whose rows straddle the fan's triangle boundaries moves
    /// the mean by up to size / 200 = 2e-2; 400 and 800 land within 3e-3 of it).
    #[test]
    fn polygon_points_are_uniform_by_area() {
        // An L-free convex pentagon with a long thin part, so uneven fan triangles.
        let c =
            [v3(0.0, 0.0, 0.0), v3(4.0, 0.0, 0.0), v3(4.0, 0.0, 1.0), v3(1.0, 0.0, 2.0), v3(0.0, 0.0, 2.0)];
        let n = 200;
        let mut mean = Vec3::ZERO;
        for a in 0..n {
            for b in 0..n {
                let q = polygon_point(&c, [(a as f32 + 0.5) / n as f32, (b as f32 + 0.5) / n as f32]);
                assert!(q.x >= -1e-5 && q.z >= -1e-5 && q.x <= 4.0 + 1e-5 && q.z <= 2.0 + 1e-5);
                mean += q;
            }
        }
        mean /= (n * n) as f32;
        // Area centroid by the shoelace formula in (x, z).
        let (mut a2, mut cx, mut cz) = (0.0f32, 0.0f32, 0.0f32);
        for k in 0..c.len() {
            let (p, q) = (c[k], c[(k + 1) % c.len()]);
            let cr = p.x * q.z - q.x * p.z;
            a2 += cr;
            cx += (p.x + q.x) * cr;
            cz += (p.z + q.z) * cr;
        }
        let want = v3(cx / (3.0 * a2), 0.0, cz / (3.0 * a2));
        assert!((mean - want).length() < 1e-2, "{mean} vs {want}");
    }

    fn v3(x: f32, y: f32, z: f32) -> Vec3 {
        Vec3::new(x, y, z)
    }

    /// A polygon's aperture parts tile it: 2^levels convex parts (a square halves evenly),
    /// areas summing to its area, and form factors from any receiver, one whose plane cuts
    /// the polygon included, summing to the whole's (the contour integral is additive), to
    /// 1e-5 of the whole's.
    #[test]
    fn aperture_parts_tile_the_polygon() {
        let pentagon =
            [v3(0.0, 0.0, 0.0), v3(0.0, 0.0, 2.0), v3(1.0, 0.0, 2.0), v3(4.0, 0.0, 1.0), v3(4.0, 0.0, 0.0)];
        let square = [v3(-1.0, 0.0, -1.0), v3(-1.0, 0.0, 1.0), v3(1.0, 0.0, 1.0), v3(1.0, 0.0, -1.0)];
        let triangle = [v3(0.0, 0.0, 0.0), v3(0.3, 0.0, 2.0), v3(1.0, 0.0, 0.0)];
        for (name, poly) in
            [("pentagon", &pentagon[..]), ("square", &square[..]), ("triangle", &triangle[..])]
        {
            let whole = polygon_twice_area(poly);
            assert!(whole.y > 0.0, "{name} faces up");
            for levels in 0..=APERTURE_LEVELS {
                let parts = aperture_parts(poly, levels);
                assert!(parts.len() <= 1 << levels);
                if name == "square" {
                    assert_eq!(parts.len(), 1 << levels, "a square halves evenly");
                }
                let mut area = 0.0;
                for part in &parts {
                    Light::polygon("part", part, Vec3::ONE).check().unwrap();
                    assert!(polygon_twice_area(part).normalize().dot(whole.normalize()) > 1.0 - 1e-6);
                    area += 0.5 * polygon_twice_area(part).length();
                }
                assert!((area - 0.5 * whole.length()).abs() < 1e-5 * whole.length(), "{name}: {area}");
                for (p, n) in [
                    (v3(1.0, 0.7, 0.5), Vec3::NEG_Y),
                    (v3(-0.5, 0.2, 3.0), v3(0.6, -0.8, 0.0)),
                    // Its plane cuts the polygon: clipping differs part by part.
                    (v3(0.5, 0.3, 0.4), v3(1.0, -0.2, 0.3).normalize()),
                ] {
                    let want = crate::form_factor::point_to_polygon(p, n, poly);
                    let sum: f32 = parts.iter().map(|q| crate::form_factor::point_to_polygon(p, n, q)).sum();
                    assert!(
                        want > 1e-3 && (sum - want).abs() <= 1e-5 * want.max(1e-2),
                        "{name} {levels}: {sum} vs {want}"
                    );
                }
            }
        }
    }

    /// A sphere light's unshadowed irradiance against its surface integrated cell by cell: exact
    /// (`I cos / d²`) wholly above the receiver's plane, and where the plane cuts the sphere
    /// (a bulb reaching past a wall's plane, a receiver beside it) the part of its cap above
    /// the plane, from the silhouette polygon, within 5e-4 (measured 8e-5 at most). The centre's cosine alone is printed:
    /// it counts all of the sphere or none of it.
    #[test]
    fn a_sphere_light_cut_by_the_receiver_s_plane_gives_its_cap_s_light() {
        let (c, radius, i) = (v3(0.2, 0.5, -0.1), 0.3f32, 5.0f32);
        let light = Light::sphere("bulb", c, radius, Vec3::splat(i));
        let n = Vec3::Y;
        let mut worst_cut = 0.0f64;
        for (k, p) in [
            // Wholly above: the sphere's lowest point 0.2 m over the plane y = 0.
            v3(0.0, 0.0, 0.0),
            v3(1.5, 0.0, 0.7),
            // Cut: the receivers' plane through the sphere (receivers above its centre and
            // below, near and far).
            v3(0.9, 0.45, -0.1),
            v3(0.6, 0.65, 0.3),
            v3(2.0, 0.35, 0.0),
            v3(-0.4, 0.72, -0.2),
            // Planes 1 cm below and above the sphere's lowest point.
            v3(1.0, 0.19, 0.0),
            v3(1.0, 0.21, 0.0),
        ]
        .into_iter()
        .enumerate()
        {
            let want = sphere_irradiance_by_cells(c, radius, i, p, n, (600, 1200), |_| true);
            let got = light.irradiance(p, n).x as f64;
            let point = (light.incident(p).irradiance.x * n.dot(light.incident(p).to_light).max(0.0)) as f64;
            let off = (got - want).abs() / want;
            eprintln!(
                "sphere case {k} at {p}: {got:.6} vs cells {want:.6} ({off:.2e}); centre's cosine {point:.6}"
            );
            assert!(want > 0.0);
            if k < 2 || k == 6 {
                assert!(off <= 1e-3, "wholly above, case {k}: {got} vs {want}");
            } else {
                worst_cut = worst_cut.max(off);
            }
        }
        assert!(worst_cut <= 5e-4, "cut by the plane: off by {worst_cut}");
    }

    /// The unit silhouette has the disk's area, its parts tile it, and a silhouette's polygon
    /// has the sphere's form factor (`(R/d)² cos`) from points that see the sphere whole.
    #[test]
    fn a_silhouette_polygon_stands_for_the_sphere() {
        let (corners, parts) = unit_silhouette();
        let area = 0.5 * polygon_twice_area(corners).length();
        assert!((area - std::f32::consts::PI).abs() < 1e-5, "{area}");
        assert_eq!(parts.len(), 1 << APERTURE_LEVELS);
        let sum: f32 = parts.iter().map(|q| 0.5 * polygon_twice_area(q).length()).sum();
        assert!((sum - area).abs() < 1e-5, "{sum} vs {area}");
        let (c, radius) = (v3(1.0, 2.0, 3.0), 0.5f32);
        for (p, n) in [
            (v3(1.0, 0.0, 3.0), Vec3::Y),
            (v3(3.0, 0.3, 2.0), v3(0.2, 1.0, 0.1).normalize()),
            (v3(1.2, 1.0, 3.1), Vec3::Y),
            (v3(-2.0, 2.0, 3.0), Vec3::X),
        ] {
            let s = Silhouette::new(c, radius, p).unwrap();
            let to_c = c - p;
            let want = (radius * radius / to_c.length_squared()) * n.dot(to_c.normalize());
            let got = crate::form_factor::point_to_polygon(p, n, &s.corners());
            assert!((got - want).abs() <= 1e-3 * want, "from {p}: {got} vs {want}");
        }
        assert!(Silhouette::new(c, radius, c + Vec3::X * 0.5).is_none(), "none from its surface");
    }
}
