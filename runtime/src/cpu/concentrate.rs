//! How a texel sees a hot cell (DESIGN.md §4; the GPU's `shaders/concentrate.wgsl`).
//!
//! A near-field link adds `albedo factor (E_j - w_c t_j)`: entry j's cell power spread evenly
//! over the cell. A light a few cm from a wall puts its power into a spot much smaller than the
//! cell, and a texel next to that cell (the floor at the foot of the wall, the other walls of a
//! corner) sees the part of the cell nearest to it far more than the rest. Measured on the
//! chamber's corner torch, 15 cm from three surfaces: the three texels at the corner read 67
//! W/m² against the ground truth's 200-231.
//!
//! So when entry j's cell is *hot* (a point or spot light that reaches it closer to its centroid than
//! [`HOT_REACH`] times the cell's size, the square root of its area, or a spot whose cone's
//! edge passes over it ([`concentrates`]), or a shadow edge across one of its triangles:
//! [`prm::cell_light::TriangleLight::mixed`]), its links use `E_j kappa`
//! instead of `E_j`. A shadow makes a cell's light as uneven as a near lamp does: a pillar's
//! shadow across the plinth around it leaves the plinth's lit crescent in front of the
//! pillar's foot and its dark half behind it, and the foot saw the cell's mean. kappa (per colour channel) is the ratio of two means of the
//! unshadowed irradiance over the cell, each quadrature point's value times its visibility
//! from the entry pass: its triangle's visible share, or where a shadow edge crosses the
//! triangle, the point's own ([`prm::cell_light`]; the chamber's torch by a pillar, seeds
//! 0-2: 10.4 -> 8.4 %, and 7.5 % with such cells hot, below). On a cell no light is near
//! (hot only by a shadow edge) the unshadowed irradiance is each triangle's level
//! ([`unshadowed_level`]) instead of every light's at every point:
//!
//! - the mean weighted by how the texel sees each point, the point-to-point form factor kernel
//!   `cos_x cos_y / r²` from the texel's point and normal (`.prm` v4 stores them per linked
//!   texel);
//! - the plain area mean.
//!
//! The first counts only the cell triangles the texel sees (the link's
//! [`prm::prm_file::NearLink::hidden`] bits, from the bake's shadow rays): a narrow beam on a
//! pillar's upper shaft, seen from the floor just before its plinth, whose edge hides the
//! lower shaft, was weighed as if the floor saw the dark lower part too (the chamber's
//! flashlight across the nave, seeds 0-2: 8.10 -> 6.45 %).
//!
//! Both use the same quadrature: the centroids of [`SUB`]² equal sub-triangles of every cell
//! triangle. Under even light kappa is 1, the quadrature's own error largely cancels in the
//! ratio, and the cell's power stays what the entry pass integrated exactly (the solid angle).
//! Where a point or spot light is near the cell, its light peaks in a spot smaller than a
//! sub-triangle (a spot 8 cm over the chamber's floor lights a disk 11 cm across, the centroids
//! are 5-8 cm apart): its part of the weighted mean also takes points it sends over the
//! triangle's solid angle, combined with the centroids by the balance heuristic (`footprint`),
//! and the plain kernel mean is then the exact one (Lambert's contour integral).
//!
//! The cluster weight's energy balance counts a hot entry's links at the power its cell
//! reflects, as any other's, not at the light these links deliver to texels that read a
//! spot's peak (`crate::cpu::cluster_weights` says why).

use glam::Vec3;
use prm::cell_light::{fine_index, sub_centroids, TriangleLight};
use prm::cone::spherical_triangle;
use prm::prm_file::{sees_triangle, Prm};
use prm::Light;

use super::{LightSight, NearTables};

/// Sub-triangles per side of a cell triangle in the quadrature (SUB² centroids each) for a
/// texel within [`NEAR_SIZES`] cell sizes of the cell's centroid, and for a mixed triangle: the
/// entry pass's fine points ([`prm::cell_light::FINE_SUB`]).
pub const SUB: u32 = prm::cell_light::FINE_SUB;
/// The same for a texel farther away, which sees the cell under a kernel that varies little.
pub const SUB_FAR: u32 = 2;
/// Where the quadrature turns from [`SUB`] to [`SUB_FAR`], in cell sizes from the centroid.
pub const NEAR_SIZES: f32 = 2.0;
/// A spot's band narrower than a cell's diameter (not its radius) makes the cell hot for the
/// texels within this many cell sizes of its centroid only ([`concentrates`]).
pub const BAND_SIZES: f32 = 1.0;
/// A cell is hot for a point or spot light closer to its centroid than this many cell sizes.
pub const HOT_REACH: f32 = 2.0;

/// True when a point or spot light that reaches the cell (some probe of one of its triangles
/// sees it: a bit of `reach`, the union of its triangles' [`TriangleLight::reach`]; a light
/// past the 64th is taken as reaching) may light the cell (centroid, size) unevenly
/// ([`concentrates`]): closer than [`HOT_REACH`] sizes, its irradiance may vary over the cell
/// by more than a few times; a spot's cone edge over it lights part of it. A torch behind the
/// wall the cell lies on brings it nothing to concentrate. `near`: for a texel within
/// [`BAND_SIZES`] of the cell ([`concentrates`]).
pub fn is_hot(centroid: Vec3, size: f32, lights: &[Light], reach: u64, near: bool) -> bool {
    lights
        .iter()
        .enumerate()
        .any(|(i, l)| (i >= 64 || (reach >> i) & 1 == 1) && concentrates(l, centroid, size, near))
}

/// True when light `l` may light the cell (centroid, size) unevenly: a point or spot light
/// closer than [`HOT_REACH`] sizes, or a spot whose cone's edge (the band between its inner
/// and outer angles) passes over the cell as the light sees it (a disk of radius the cell's
/// size about its centroid) and is narrower than that radius, so that the falloff goes from
/// nothing to whole within the cell: a narrow spot 3 m over a plinth lights a disk 0.8 m
/// across, whose rim crosses cells as a shadow edge does.
///
/// For a texel near the cell (`near`: within [`BAND_SIZES`] of its centroid) a band narrower
/// than the disk's diameter counts too. A 15-30 degree spot 3 cm over a floor, aimed along it
/// at a wall 1 m off, lights the wall's foot cells from nothing at their top to whole at the
/// floor, with a band wider than their radius; the floor texels at the wall's foot, which see
/// the cells' lit bottom from a few cm, read 4.9-6.8 W/m² against the ground truth's 7.5-9.4
/// (session 77, two_rooms against a 1024-sample ground truth, its noise 4.2 % not removed:
/// 15.0 -> 5.6 %; the chamber's spot 15 cm from the side wall aimed down along it 9.3 -> 8.0 %,
/// noise 5.0 %; every other placement of the two levels' spot rigs and the chamber's own
/// lights within 0.3 % of before). Taken for texels within [`NEAR_SIZES`] it read 5.3 % there,
/// and for every texel 5.2 %, but made the chamber's moving rig's concentration pass 1.8x and
/// 2.2x on lavapipe (the dais spot's band over cells of the arcade and floor 5-8 m from it,
/// whose error did not move); within one size, 1.25-1.35x. A band wider than the disk only
/// tilts its light (the chamber's dais spot, 26-34 degrees from 7 m: every cell its band
/// touched hot cost the concentration 4x on lavapipe and moved no error).
pub fn concentrates(l: &Light, centroid: Vec3, size: f32, near: bool) -> bool {
    if !l.is_positional() {
        return false;
    }
    let d = l.position.distance(centroid);
    if d < HOT_REACH * size {
        return true;
    }
    match l.kind {
        prm::LightKind::Spot { inner, outer } => {
            let spread = (size / d).atan();
            let angle = l.direction.dot((centroid - l.position) / d).clamp(-1.0, 1.0).acos();
            let across = if near { 2.0 * spread } else { spread };
            across > outer - inner && angle - spread < outer && angle + spread > inner
        }
        _ => false,
    }
}

/// The lights that reach any of a cell's triangles (bits as [`TriangleLight::reach`]).
pub fn cell_reach(vis: &[TriangleLight]) -> u64 {
    vis.iter().fold(0, |a, t| a | t.reach)
}

/// kappa of the module doc for the texel at `x` (unit normal `nx`) and the cell `tris` (with
/// each triangle's light this frame, `vis`; centroid and size as [`crate::cpu::NearTables`]
/// has them): 1 in a channel with no light or no view of the cell. A point's visibility is its
/// triangle's visible share, or on a mixed triangle (a shadow edge across it) its own
/// ([`TriangleLight::at_fine`]); a mixed triangle always takes the [`SUB`] quadrature, whose
/// points are the entry pass's fine points, and the others within [`NEAR_SIZES`] of a cell a
/// light is near ([`is_hot`]). `hidden`: the link's bits of the triangles the texel does not
/// see ([`prm::prm_file::NearLink::hidden`]), left out of the seen mean.
pub fn concentration(
    x: Vec3,
    nx: Vec3,
    (centroid, size): (Vec3, f32),
    tris: &[[Vec3; 3]],
    vis: &[TriangleLight],
    lights: &[Light],
    hidden: u64,
) -> Vec3 {
    let (mut seen, mut weight, mut plain, mut area_sum) = (Vec3::ZERO, 0.0f32, Vec3::ZERO, 0.0f32);
    let mut exact = 0.0f32;
    // Near a cell a light is near, every triangle takes the fine quadrature; near one hot only by
    // a shadow edge, its mixed triangles (their light is smooth elsewhere, and the fine points
    // of every triangle made the concentration most of a moving light's frame on lavapipe).
    let close = x.distance(centroid) < BAND_SIZES * size;
    // The lights that reach the cell and concentrate on it for this texel ([`is_hot`]'s test,
    // light by light), found once: not again at every point.
    let reach = cell_reach(vis);
    let takes: Vec<bool> = lights
        .iter()
        .enumerate()
        .map(|(i, l)| (i >= 64 || (reach >> i) & 1 == 1) && concentrates(l, centroid, size, close))
        .collect();
    let lit_near = takes.iter().any(|&t| t);
    let near = lit_near && x.distance(centroid) < NEAR_SIZES * size;
    for (q, (t, v)) in tris.iter().zip(vis).enumerate() {
        let cross = (t[1] - t[0]).cross(t[2] - t[0]);
        let Some(n) = cross.try_normalize() else { continue };
        // A triangle the texel does not see (its link's `hidden` bits: a plinth's edge between
        // the floor before it and a pillar's lower shaft) adds its light to the cell's plain
        // mean but not to the mean as the texel sees it.
        let sees = if sees_triangle(hidden, q) { 1.0 } else { 0.0 };
        let sub = if near || v.mixed { SUB } else { SUB_FAR };
        let area = 0.5 * cross.length() / (sub * sub) as f32;
        let level = unshadowed_level(v, 0.5 * cross.length());
        // Only the lights that reach the triangle (`TriangleLight::reach`), as its share; a
        // light past the 64th has no bit: taken as reaching.
        let reaches = |i: usize| i >= 64 || (v.reach >> i) & 1 == 1;
        // A light that concentrates on the cell ([`concentrates`]: near it, or a spot's sharp
        // cone edge over it) lands where the area points may miss it: its light is taken at
        // points it sends evenly over its solid angle as well ([`footprint`]).
        let sampled = |i: usize| reaches(i) && takes[i];
        // Near a light, the footprint takes the lights it samples and the kernel's mean is
        // exact: the centroids are needed only for the other lights that reach the triangle.
        let others = (0..lights.len()).any(|i| reaches(i) && !sampled(i));
        if lit_near && !others {
            area_sum += 0.5 * cross.length();
        }
        for (k, y) in sub_centroids(t, sub).enumerate().filter(|_| !lit_near || others) {
            // The other lights vary little over one triangle: near a light, each at the
            // point; else the level the entry pass found stands for them all (a shadow edge is
            // what varies).
            let e = if lit_near {
                lights
                    .iter()
                    .enumerate()
                    .filter(|&(i, _)| reaches(i) && !sampled(i))
                    .map(|(_, l)| l.irradiance(y, n))
                    .sum()
            } else {
                level
            };
            let e = e * v.at_fine(k) * area;
            plain += e;
            area_sum += area;
            let d = y - x;
            let r2 = d.length_squared();
            let g = sees * nx.dot(d).max(0.0) * (-n.dot(d)).max(0.0) / (r2 * r2).max(1e-30);
            seen += e * g;
            weight += g * area;
        }
        if lit_near {
            // The kernel's integral over the part of the triangle facing x, exact (Lambert).
            let kernel = if n.dot(x - t[0]) > 0.0 {
                std::f32::consts::PI * prm::form_factor::point_to_polygon(x, nx, t)
            } else {
                0.0
            };
            exact += kernel * sees;
            for (_, l) in lights.iter().enumerate().filter(|&(i, _)| sampled(i)) {
                let (s, p) = footprint(x, nx, t, n, v, l, sub, kernel);
                let s = s * sees;
                seen += s;
                plain += p;
            }
        }
    }
    // Where a light is near, the footprint's points crowd where it lands, which may be next to
    // the texel (the floor at a corner's foot, 6 mm from the wall's hot spot); the area
    // points' kernel mean misses that, so the mean is the exact one.
    let weight = if lit_near { exact } else { weight };
    if !(weight > 0.0 && area_sum > 0.0) {
        return Vec3::ONE;
    }
    let ratio =
        |seen: f32, plain: f32| if plain > 0.0 { (seen.max(0.0) / weight) / (plain / area_sum) } else { 1.0 };
    Vec3::new(ratio(seen.x, plain.x), ratio(seen.y, plain.y), ratio(seen.z, plain.z))
}

/// Light `l`'s part of the concentration's sums on cell triangle `t` (unit normal `n`, its
/// light this frame `v`) for the texel at `x` (unit normal `nx`): `(sum of E G dA, sum of E dA)`
/// over the triangle, E the light's irradiance times the visibility of the point (a mixed
/// triangle's fine bit there, else the triangle's share) and G the form-factor kernel from x.
///
/// Two sets of points, combined by multiple importance sampling (the balance heuristic): the
/// area quadrature's `sub`² sub-triangle centroids, even over the area, and [`light_side`]²
/// points the light sends evenly over the solid angle the triangle subtends from it
/// ([`prm::cone::spherical_triangle`]), which crowd where its light lands. A point's
/// weight is `1 / (1 / a + 1 / p)`, `a` the area a centroid stands for and `p` the patch of
/// plane a direction stands for there (`r² / cos` times the solid angle's share): a lamp 2 cm
/// over a floor puts most of its light in a spot smaller than one sub-triangle, which the
/// centroids put at their nearest one and the directions resolve; far from the light the
/// centroids carry the sum. `kernel` is G's exact integral over the triangle (see the control
/// below).
#[allow(clippy::too_many_arguments)]
fn footprint(
    x: Vec3,
    nx: Vec3,
    t: &[Vec3; 3],
    n: Vec3,
    v: &TriangleLight,
    l: &Light,
    sub: u32,
    kernel: f32,
) -> (Vec3, Vec3) {
    let (mut seen, mut plain) = (Vec3::ZERO, Vec3::ZERO);
    let height = n.dot(t[0] - l.position);
    let corners = t.map(|c| (c - l.position).normalize_or_zero());
    let omega = prm::cone::solid_angle(corners[0], corners[1], corners[2]);
    if height >= 0.0 || !(omega > 0.0) {
        // The light is behind the triangle's plane (or in it): nothing arrives.
        return (seen, plain);
    }
    let m2 = (sub * sub) as f32;
    let side = light_side(sub);
    let l2 = (side * side) as f32;
    let cell_area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
    let a = cell_area / m2;
    // The control, for a texel nearer the triangle than twice its size, where the kernel
    // grows without bound: the light at the triangle's point nearest the texel, whose product
    // with the kernel is integrated exactly, the points carrying only the difference. Farther
    // off the kernel is smooth and the points alone do (the light at one point of a lit spot
    // times the whole triangle's kernel would then be all error).
    let y0 = closest_point(t, x);
    let e0 = if y0.distance_squared(x) < 4.0 * cell_area {
        l.irradiance(y0, n) * v.at_fine(fine_index(t, y0))
    } else {
        Vec3::ZERO
    };
    let mut add = |y: Vec3, k: usize| {
        let to = y - l.position;
        let cos = -n.dot(to) / to.length();
        // The patch of the plane a direction stands for at y (none: behind the light).
        let inv_patch = if cos > 0.0 { cos * l2 / (to.length_squared() * omega) } else { 0.0 };
        let w = 1.0 / (1.0 / a + inv_patch);
        let e = l.irradiance(y, n) * v.at_fine(k);
        let d = y - x;
        let r2 = d.length_squared();
        // As a disk of the point's area seen from x: a point next to the texel (a corner's
        // other wall) counts no more than its area can give it.
        let g = nx.dot(d).max(0.0) * (-n.dot(d)).max(0.0) / (r2 * (r2 + w / std::f32::consts::PI)).max(1e-30);
        seen += (e - e0) * (g * w);
        plain += e * w;
    };
    for (k, y) in sub_centroids(t, sub).enumerate() {
        // The centroids are the fine points only at the fine quadrature; else the share.
        add(y, if sub == prm::cell_light::FINE_SUB { k } else { fine_index(t, y) });
    }
    for i in 0..side {
        for j in 0..side {
            let u = ((i as f32 + 0.5) / side as f32, (j as f32 + 0.5) / side as f32);
            let Some((dir, _)) = spherical_triangle(corners[0], corners[1], corners[2], u.0, u.1) else {
                continue;
            };
            let cos = -n.dot(dir);
            if cos > 1e-6 {
                let y = l.position + dir * (-height / cos);
                add(y, fine_index(t, y));
            }
        }
    }
    (seen + e0 * kernel, plain)
}

/// Directions per side of the footprint's light points for `sub` centroids a side: half as
/// many (rounded up), a quarter of the points.
pub fn light_side(sub: u32) -> u32 {
    sub.div_ceil(2)
}

pub use prm::form_factor::closest_point;

/// The unshadowed irradiance over a cell triangle of area `area` as its light this frame tells
/// it: the power that arrives over its visible share and its area (0 where none arrives). On a
/// cell no light is near (hot only by a shadow edge across it), [`concentration`] takes this
/// level at every point, times the point's visibility, instead of each light's irradiance
/// there: the same kappa within a few per cent (the unit tests), for a fraction of the work.
pub fn unshadowed_level(light: &TriangleLight, area: f32) -> Vec3 {
    if light.share > 0.0 && area > 0.0 {
        light.power / (light.share * area)
    } else {
        Vec3::ZERO
    }
}

/// This frame's light on the near-field links of hot cells.
#[derive(Clone, Debug, Default)]
pub struct LinkLight {
    /// Per entry: whether its cell is hot this frame.
    pub hot: Vec<bool>,
    /// Per link (in `Prm::near` order): `E_j kappa` where the link's entry is hot, else unused.
    pub value: Vec<Vec3>,
    /// How the far texels see the lights that light cells up close (none here: the twin fills
    /// it, `crate::cpu::light_sight`).
    pub sight: LightSight,
    /// Per entry: where its cell's light lands, its triangles' [`TriangleLight::centre`]
    /// weighted by the luminance of their power (the cell's centroid where none arrives;
    /// empty: every centroid). The far field sends a cell lit up close, or whose light lands
    /// apart from its centroid or its normal ([`lands_apart`](crate::cpu::lands_apart)), from
    /// there (`crate::cpu::far_field`).
    pub landing: Vec<Vec3>,
    /// Per entry: which way its cell's light leaves, its triangles' unit normals weighted as
    /// `landing` weights their centres, normalised (the entry's normal where none arrives;
    /// empty: every entry's normal). A cell wraps round a pillar: lit on the face toward a
    /// spot, it sends that light the way that face looks, not the way its entry point's does.
    pub landing_normal: Vec<Vec3>,
}

impl LinkLight {
    /// No hot cells: every link uses its entry's mean irradiance.
    pub fn none(prm: &Prm) -> LinkLight {
        let n = prm.entries().len();
        LinkLight {
            hot: vec![false; n],
            value: Vec::new(),
            sight: LightSight::default(),
            landing: Vec::new(),
            landing_normal: Vec::new(),
        }
    }

    /// The link light of `lights` from the entries' irradiance and the light on every cell
    /// triangle this frame (`cell_lights`, in [`prm::prm_file::Cells`] order:
    /// [`prm::cell_light::triangle_light`]). A cell is hot when a light is near it
    /// ([`is_hot`]) or a shadow edge crosses one of its triangles (mixed): either way its light
    /// is uneven over it.
    pub fn new(
        prm: &Prm,
        tables: &NearTables,
        entry_irradiance: &[Vec3],
        cell_lights: &[TriangleLight],
        lights: &[Light],
    ) -> LinkLight {
        let n = prm.entries().len();
        let cells = prm.cells();
        let of = |j: usize| &cell_lights[cells.first[j] as usize..cells.first[j + 1] as usize];
        // Hot for every texel, and (`near_only`) for the texels within BAND_SIZES alone.
        let hot_for = |j: usize, near: bool| {
            is_hot(tables.centroid[j], tables.size[j], lights, cell_reach(of(j)), near)
        };
        let near_light: Vec<bool> = (0..n).map(|j| hot_for(j, false)).collect();
        let near_only: Vec<bool> = (0..n).map(|j| !near_light[j] && hot_for(j, true)).collect();
        let hot: Vec<bool> =
            (0..n).map(|j| near_light[j] || near_only[j] || of(j).iter().any(|t| t.mixed)).collect();
        let mut value = vec![Vec3::ZERO; prm.near().len()];
        if hot.iter().any(|&h| h) {
            let mut k = 0;
            let runs = prm.near().chunk_by(|a, b| a.texel == b.texel);
            for (links, p) in runs.zip(prm.near_points()) {
                for l in links {
                    let j = l.entry as usize;
                    if hot[j] {
                        let cell = (tables.centroid[j], tables.size[j]);
                        // A cell hot only by a shadow edge, or by a spot's band for near
                        // texels only: the texels beyond NEAR_SIZES see it under a kernel
                        // that varies little, so its mean (kappa 1).
                        let seen = near_light[j] || p.position.distance(cell.0) < NEAR_SIZES * cell.1;
                        let kappa = if seen {
                            concentration(p.position, p.normal, cell, cells.of(j), of(j), lights, l.hidden)
                        } else {
                            Vec3::ONE
                        };
                        value[k] = entry_irradiance[j] * kappa;
                    }
                    k += 1;
                }
            }
        }
        let (mut landing, mut landing_normal) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for j in 0..n {
            let (mut at, mut toward, mut weight) = (Vec3::ZERO, Vec3::ZERO, 0.0f32);
            for (t, tri) in of(j).iter().zip(cells.of(j)) {
                let w = prm::luminance(t.power);
                at += t.centre * w;
                // The cells' triangles are wound counter-clockwise seen from the front.
                toward += (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero() * w;
                weight += w;
            }
            let normal = prm.entries()[j].normal;
            landing.push(if weight > 0.0 { at / weight } else { tables.centroid[j] });
            landing_normal.push(if weight > 0.0 { toward.try_normalize().unwrap_or(normal) } else { normal });
        }
        LinkLight { hot, value, sight: LightSight::default(), landing, landing_normal }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 m square cell on the floor (y = 0, facing up), as two triangles.
    const GEOM: (Vec3, f32) = (Vec3::new(0.5, 0.0, 0.5), 1.0);

    fn floor_cell() -> Vec<[Vec3; 3]> {
        let (a, b, c, d) = (Vec3::ZERO, Vec3::Z, Vec3::new(1.0, 0.0, 1.0), Vec3::X);
        vec![[a, b, c], [a, c, d]]
    }

    /// A triangle's light with visible share `share` everywhere on it, every light reaching it.
    fn even(share: f32) -> TriangleLight {
        TriangleLight { power: Vec3::ZERO, share, fine: 0, reach: u64::MAX, mixed: false, centre: Vec3::ZERO }
    }

    /// kappa by brute force: a 400 x 400 grid of the cell's square, the same two means.
    fn kappa_dense(x: Vec3, nx: Vec3, light: &Light) -> f32 {
        kappa_dense_hidden(x, nx, light, |_| false)
    }

    /// The same with the points where `hidden` holds in shadow.
    fn kappa_dense_hidden(x: Vec3, nx: Vec3, light: &Light, hidden: impl Fn(Vec3) -> bool) -> f32 {
        kappa_dense_seen(x, nx, light, hidden, |_| true)
    }

    /// The same with the points where `dark` holds in shadow and the texel seeing only the
    /// points where `sees` holds: the seen mean over those, the plain mean over the whole cell.
    fn kappa_dense_seen(
        x: Vec3,
        nx: Vec3,
        light: &Light,
        dark: impl Fn(Vec3) -> bool,
        sees: impl Fn(Vec3) -> bool,
    ) -> f32 {
        let (mut seen, mut weight, mut plain) = (0.0f64, 0.0f64, 0.0f64);
        let k = 1000;
        for i in 0..k {
            for j in 0..k {
                let y = Vec3::new((i as f32 + 0.5) / k as f32, 0.0, (j as f32 + 0.5) / k as f32);
                let e = if dark(y) { 0.0 } else { prm::luminance(light.irradiance(y, Vec3::Y)) as f64 };
                plain += e;
                if sees(y) {
                    let d = y - x;
                    let r2 = d.length_squared();
                    let g = (nx.dot(d).max(0.0) * (-Vec3::Y.dot(d)).max(0.0) / (r2 * r2)) as f64;
                    seen += e * g;
                    weight += g;
                }
            }
        }
        ((seen / weight) / (plain / (k * k) as f64)) as f32
    }

    #[test]
    fn even_light_gives_one_and_a_far_texel_sees_the_mean() {
        let cell = floor_cell();
        let geom = GEOM;
        let vis = [even(1.0), even(1.0)];
        let mut sun = Light::point("sun", Vec3::ZERO, Vec3::ONE);
        sun.kind = prm::LightKind::Directional;
        sun.direction = Vec3::NEG_Y;
        let wall_texel = (Vec3::new(-0.01, 0.3, 0.5), Vec3::X);
        // No light is near, so each triangle's level stands for the sun: the triangles'
        // light as the entry pass finds it.
        let sunlit: Vec<TriangleLight> = cell
            .iter()
            .map(|t| prm::cell_light::triangle_light(t, std::slice::from_ref(&sun), |_, _, _| 1.0))
            .collect();
        assert!(sunlit.iter().all(|v| v.power.x > 0.0));
        let k = concentration(wall_texel.0, wall_texel.1, geom, &cell, &sunlit, &[sun], 0);
        assert!((k - Vec3::ONE).abs().max_element() < 1e-5, "even light: kappa {k}");
        // A lamp 10 cm over one corner, seen from 20 m away: every point of the cell looks
        // the same, so the seen mean is the plain mean.
        let lamp = Light::point("lamp", Vec3::new(0.05, 0.1, 0.05), Vec3::ONE);
        let k = concentration(
            Vec3::new(0.5, 20.0, 0.5),
            Vec3::NEG_Y,
            geom,
            &cell,
            &vis,
            std::slice::from_ref(&lamp),
            0,
        );
        assert!((k - Vec3::ONE).abs().max_element() < 0.01, "far texel: kappa {k}");
        // No light at all: 1, not NaN.
        assert_eq!(concentration(wall_texel.0, wall_texel.1, geom, &cell, &vis, &[], 0), Vec3::ONE);
    }

    /// A link that hides one of its cell's two triangles from its texel
    /// (`prm::prm_file::NearLink::hidden`): the texel's mean is over the other one alone. A lamp
    /// 10 cm over the cell's middle lights both; a texel on the wall at x = 0 hidden from the
    /// triangle x > z (the bits 0b10) takes kappa within 10 % of a brute-force twin that sees
    /// only x < z, and not the kappa of a texel that sees both.
    #[test]
    fn a_hidden_triangle_is_left_out_of_the_seen_mean() {
        let cell = floor_cell();
        let lamp = Light::point("lamp", Vec3::new(0.6, 0.1, 0.4), Vec3::ONE);
        let (x, nx) = (Vec3::new(-0.02, 0.1, 0.7), Vec3::X);
        let lit = [even(1.0), even(1.0)];
        let one = std::slice::from_ref(&lamp);
        let both = concentration(x, nx, GEOM, &cell, &lit, one, 0).x;
        let left = concentration(x, nx, GEOM, &cell, &lit, one, 0b10).x;
        let dense_both = kappa_dense(x, nx, &lamp);
        let dense_left = kappa_dense_seen(x, nx, &lamp, |_| false, |y| y.x < y.z);
        println!("kappa seeing both {both} (dense {dense_both}), seeing x < z {left} (dense {dense_left})");
        assert!((both / dense_both - 1.0).abs() < 0.1, "seeing both: {both} vs dense {dense_both}");
        assert!((left / dense_left - 1.0).abs() < 0.1, "seeing x < z: {left} vs dense {dense_left}");
        assert!(
            (dense_left / dense_both - 1.0).abs() > 0.2,
            "the hidden triangle must matter: {dense_left} vs {dense_both}"
        );
        // Both hidden: no view of the cell, kappa 1.
        assert_eq!(concentration(x, nx, GEOM, &cell, &lit, one, 0b11), Vec3::ONE);
    }

    /// A lamp 15 cm over a corner of a 1 m floor cell, texels on the wall at that corner and at
    /// the far one: the quadrature's kappa follows a brute-force twin (20 % at the hot corner,
    /// where 16 points a triangle resolve a 15 cm spot only roughly; 10 % at the far corner),
    /// and is far above 1 where the hot spot is near, below 1 where it is far.
    #[test]
    fn the_quadrature_follows_a_dense_twin() {
        let cell = floor_cell();
        let geom = GEOM;
        let lamp = Light::point("lamp", Vec3::new(0.15, 0.15, 0.15), Vec3::ONE);
        let near = (Vec3::new(-0.02, 0.05, 0.1), Vec3::X);
        let far = (Vec3::new(-0.02, 0.05, 0.9), Vec3::X);
        let lit = [even(1.0), even(1.0)];
        let k_near = concentration(near.0, near.1, geom, &cell, &lit, std::slice::from_ref(&lamp), 0).x;
        let k_far = concentration(far.0, far.1, geom, &cell, &lit, std::slice::from_ref(&lamp), 0).x;
        let (d_near, d_far) = (kappa_dense(near.0, near.1, &lamp), kappa_dense(far.0, far.1, &lamp));
        assert!(d_near > 3.0 && d_far < 0.7, "dense twin: near {d_near}, far {d_far}");
        assert!((k_near / d_near - 1.0).abs() < 0.2, "near the hot spot: {k_near} vs dense {d_near}");
        assert!((k_far / d_far - 1.0).abs() < 0.1, "far from it: {k_far} vs dense {d_far}");
        // Each triangle's visibility scales its points: a shadowed half darkens what it holds.
        let half = concentration(near.0, near.1, geom, &cell, &[even(1.0), even(0.0)], &[lamp], 0).x;
        assert!(half != k_near && half.is_finite());
    }

    /// A spot's band (15-30 degrees, 4 m off) across the 1 m cell from whole at one edge to
    /// nothing at the other: narrower than the cell's diameter as the spot sees it, wider than
    /// its radius. A texel on the wall at the bright edge, 5 cm up, sees the bright part; its
    /// kappa is the dense twin's within 10 %, where the dense twin is over 1.4 (the triangles'
    /// even levels, what such a cell took before, are near 1).
    #[test]
    fn a_band_across_the_cell_is_seen_by_a_texel_next_to_it() {
        let cell = floor_cell();
        let mut spot = Light::point("spot", Vec3::new(0.0, 4.0, 0.5), Vec3::ONE);
        spot.kind = prm::LightKind::Spot { inner: 15f32.to_radians(), outer: 30f32.to_radians() };
        let tilt = 15f32.to_radians();
        spot.direction = Vec3::new(-tilt.sin(), -tilt.cos(), 0.0);
        assert!(!concentrates(&spot, GEOM.0, GEOM.1, false) && concentrates(&spot, GEOM.0, GEOM.1, true));
        let lit: Vec<TriangleLight> = cell
            .iter()
            .map(|t| prm::cell_light::triangle_light(t, std::slice::from_ref(&spot), |_, _, _| 1.0))
            .collect();
        let (x, nx) = (Vec3::new(-0.01, 0.05, 0.5), Vec3::X);
        let dense = kappa_dense(x, nx, &spot);
        assert!(dense > 1.4, "the dense twin: {dense}");
        let k = prm::luminance(concentration(x, nx, GEOM, &cell, &lit, std::slice::from_ref(&spot), 0));
        assert!((k / dense - 1.0).abs() < 0.1, "next to the bright edge: {k} vs dense {dense}");
    }

    /// A spot's cone edge makes a cell hot as a near light does: a 6-8 degree spot 3 m over a
    /// floor lights a disk about 0.8 m across; 0.2 m cells on its rim are hot, those well inside
    /// it or outside it are not, nor any under a point light at the same height, nor those on
    /// a 20-35 degree spot's wider band; a wall's foot cell 1 m from a 15-30 degree spot 3 cm
    /// over the floor is for a texel near it, not for one far off; within HOT_REACH sizes every
    /// positional light is, a directional one never.
    #[test]
    fn a_spot_s_cone_edge_over_a_cell_makes_it_hot() {
        let mut spot = Light::point("spot", Vec3::new(0.0, 3.0, 0.0), Vec3::ONE);
        spot.kind = prm::LightKind::Spot { inner: 6f32.to_radians(), outer: 8f32.to_radians() };
        spot.direction = Vec3::NEG_Y;
        let lamp = Light::point("lamp", spot.position, Vec3::ONE);
        let rim = 3.0 * 7f32.to_radians().tan();
        let cell = |r: f32| Vec3::new(r, 0.0, 0.0);
        assert!(concentrates(&spot, cell(rim), 0.2, false), "on the rim");
        assert!(
            concentrates(&spot, cell(rim - 0.15), 0.2, false)
                && concentrates(&spot, cell(rim + 0.15), 0.2, false)
        );
        assert!(!concentrates(&spot, cell(0.0), 0.2, false), "inside the inner cone");
        assert!(!concentrates(&spot, cell(1.5), 0.2, false), "outside the outer cone");
        assert!(!concentrates(&lamp, cell(rim), 0.2, false), "a point light 3 m off");
        // A cell larger than the whole disk holds the rim.
        assert!(concentrates(&spot, cell(0.0), 1.0, false));
        // A band wider than the cell (20-35 degrees) only tilts its light: not hot.
        let mut wide = spot.clone();
        wide.kind = prm::LightKind::Spot { inner: 20f32.to_radians(), outer: 35f32.to_radians() };
        let wide_rim = 3.0 * 27f32.to_radians().tan();
        assert!(!concentrates(&wide, cell(wide_rim), 0.2, false), "a wide band over a small cell");
        assert!(concentrates(&wide, cell(wide_rim), 1.2, false), "a cell wider than the band");
        // A 15-30 degree spot 3 cm over a floor aimed along it: the wall's foot 1 m off is lit
        // from nothing to whole within one 0.2 m cell (the band, 15 degrees, is narrower than
        // the cell's 23 degrees across, though wider than its 11 degrees of radius).
        let mut low = spot.clone();
        low.position = Vec3::new(0.0, 0.03, 0.0);
        low.direction = Vec3::new(-0.98, -0.2, 0.0).normalize();
        low.kind = prm::LightKind::Spot { inner: 15f32.to_radians(), outer: 30f32.to_radians() };
        assert!(
            concentrates(&low, Vec3::new(-1.0, 0.1, 0.0), 0.2, true),
            "the wall's foot 1 m off, a texel near it"
        );
        assert!(!concentrates(&low, Vec3::new(-1.0, 0.1, 0.0), 0.2, false), "the same, a texel far from it");
        // The chamber's dais spot (26-34 degrees from 7 m): its band is wider than a 0.3 m cell
        // on its rim, 8 m off.
        let mut dais = spot.clone();
        dais.position = Vec3::new(0.0, 7.0, 0.0);
        dais.kind = prm::LightKind::Spot { inner: 26f32.to_radians(), outer: 34f32.to_radians() };
        assert!(
            !concentrates(&dais, Vec3::new(7.0 * 30f32.to_radians().tan(), 0.0, 0.0), 0.3, true),
            "the dais spot's rim"
        );
        assert!(concentrates(&lamp, Vec3::new(0.0, 2.7, 0.0), 0.2, false), "within HOT_REACH sizes");
        let mut sun = lamp.clone();
        sun.kind = prm::LightKind::Directional;
        assert!(!concentrates(&sun, Vec3::new(0.0, 2.9, 0.0), 0.2, false));
    }

    /// Lights a few cm over the cell, where the irradiance peaks in a spot smaller than the
    /// area quadrature's sub-triangles: a lamp 2 cm over a point 10 cm in from the corner, a
    /// spot 3 cm over it aimed down, and a lamp 1 cm over the middle; texels on the wall at the
    /// cell's edge (5 mm and 5 cm off the floor), by it and across the cell, and over the cell
    /// looking down. Within 10 % of the dense twin (measured: -8.5 % at worst, the lamp seen from
    /// the wall 5 mm up; the spot -7.4 % from 5 cm up; the rest within 3.5 %).
    #[test]
    fn lights_a_few_cm_over_the_cell_are_seen_where_they_land() {
        let cell = floor_cell();
        let lit = [even(1.0), even(1.0)];
        let mut spot = Light::point("spot", Vec3::new(0.1, 0.03, 0.1), Vec3::ONE);
        spot.kind = prm::LightKind::Spot { inner: 0.3, outer: 0.5 };
        spot.direction = Vec3::NEG_Y;
        let lights = [
            Light::point("lamp", Vec3::new(0.1, 0.02, 0.1), Vec3::ONE),
            spot,
            Light::point("low", Vec3::new(0.5, 0.01, 0.5), Vec3::ONE),
        ];
        let texels = [
            (Vec3::new(-0.005, 0.005, 0.1), Vec3::X),
            (Vec3::new(-0.005, 0.05, 0.3), Vec3::X),
            (Vec3::new(1.005, 0.05, 0.5), Vec3::NEG_X),
            (Vec3::new(0.6, 0.4, 0.7), Vec3::NEG_Y),
        ];
        for l in &lights {
            for (x, nx) in texels {
                let k = concentration(x, nx, GEOM, &cell, &lit, std::slice::from_ref(l), 0).x;
                let d = kappa_dense(x, nx, l);
                assert!(
                    (k / d - 1.0).abs() < 0.1,
                    "{} and the texel at {x}: kappa {k} against dense {d}",
                    l.name
                );
            }
        }
    }

    /// A shadow across the cell (a pillar's on the plinth around it): the lit part lies in
    /// front of one texel and the dark part in front of another. With each triangle's fine
    /// points kappa follows the dense twin with the same shadow; with the triangles' shares
    /// alone, both texels read about the same.
    /// The floor cell with the part beyond z = 0.35 in shadow under `lamp`: each triangle's
    /// light as the entry pass finds it (all mixed), and kappa at a texel by the lit side and
    /// one by the dark side held to the dense twin with the same shadow (within 15 %). Returns
    /// the triangles' light and the lit side's texel's kappa.
    fn shadow_across_the_cell(lamp: &Light) -> (Vec<TriangleLight>, f32) {
        let cell = floor_cell();
        let lamps = std::slice::from_ref(lamp);
        let hidden = |y: Vec3| y.z > 0.35;
        let vis: Vec<TriangleLight> = cell
            .iter()
            .map(|t| prm::cell_light::triangle_light(t, lamps, |y, _, _| (!hidden(y)) as u8 as f32))
            .collect();
        assert!(vis.iter().all(|v| v.mixed));
        let by_lit = (Vec3::new(0.5, 0.05, -0.02), Vec3::Z);
        let by_dark = (Vec3::new(0.5, 0.05, 1.02), Vec3::NEG_Z);
        for (x, nx) in [by_lit, by_dark] {
            let k = concentration(x, nx, GEOM, &cell, &vis, lamps, 0).x;
            let d = kappa_dense_hidden(x, nx, lamp, hidden);
            assert!((k / d - 1.0).abs() < 0.15, "texel at {x}: kappa {k} against dense {d}");
        }
        let k_lit = concentration(by_lit.0, by_lit.1, GEOM, &cell, &vis, lamps, 0).x;
        assert!(k_lit > 2.0, "the lit side's texel sees the light: {k_lit}");
        (vis, k_lit)
    }

    #[test]
    fn a_shadow_across_the_cell_is_seen_where_it_falls() {
        let cell = floor_cell();
        let lamp = Light::point("lamp", Vec3::new(0.5, 1.2, 0.5), Vec3::ONE);
        let (vis, k_lit) = shadow_across_the_cell(&lamp);
        let by_lit = (Vec3::new(0.5, 0.05, -0.02), Vec3::Z);
        let shares: Vec<TriangleLight> = vis.iter().map(|v| even(v.share)).collect();
        let k_shares =
            concentration(by_lit.0, by_lit.1, GEOM, &cell, &shares, std::slice::from_ref(&lamp), 0).x;
        // Measured: 1.58 against the dense 2.65.
        assert!(k_shares < 0.7 * k_lit, "shares alone: {k_shares} against {k_lit}");
    }

    /// The same shadow under a lamp 2.5 m over the cell (farther than HOT_REACH sizes: the
    /// cell is hot only by the shadow edge): each triangle's level times its points' bits
    /// follows the dense twin with the lamp's own falloff as closely as the light at every
    /// point did, and a triangle with no light has level 0, not NaN.
    #[test]
    fn a_cell_no_light_is_near_takes_each_triangles_level() {
        let lamp = Light::point("lamp", Vec3::new(0.5, 2.5, 0.5), Vec3::ONE);
        assert!(!is_hot(GEOM.0, GEOM.1, std::slice::from_ref(&lamp), 1, false));
        let (vis, _) = shadow_across_the_cell(&lamp);
        // The level: the triangle's power over its share and area.
        let area = 0.5;
        let level = unshadowed_level(&vis[0], area);
        assert!((level * vis[0].share * area - vis[0].power).abs().max_element() < 1e-6);
        let dark = TriangleLight {
            power: Vec3::ZERO,
            share: 1.0,
            fine: 0,
            reach: 0,
            mixed: false,
            centre: Vec3::ZERO,
        };
        assert_eq!(unshadowed_level(&dark, area), Vec3::ZERO);
    }

    #[test]
    fn a_cell_is_hot_only_for_a_point_or_spot_light_within_reach() {
        let lamp = Light::point("lamp", Vec3::new(0.0, 1.0, 0.0), Vec3::ONE);
        // 1 m away: hot for a cell of 0.6 m (1 < 2 x 0.6), not for one of 0.4 m.
        assert!(is_hot(Vec3::ZERO, 0.6, std::slice::from_ref(&lamp), 1, false));
        assert!(!is_hot(Vec3::ZERO, 0.4, std::slice::from_ref(&lamp), 1, false));
        let mut sun = lamp.clone();
        sun.kind = prm::LightKind::Directional;
        assert!(!is_hot(Vec3::ZERO, 10.0, &[sun], 1, false));
        // Near but reaching no triangle of the cell (a torch behind its wall): not hot; as the
        // second light, only its own bit counts.
        assert!(!is_hot(Vec3::ZERO, 0.6, std::slice::from_ref(&lamp), 0, false));
        let far = Light::point("far", Vec3::new(0.0, 9.0, 0.0), Vec3::ONE);
        assert!(!is_hot(Vec3::ZERO, 0.6, &[far.clone(), lamp.clone()], 0b01, false));
        assert!(is_hot(Vec3::ZERO, 0.6, &[far, lamp], 0b10, false));
        // A light past the 64th has no bit and is taken as reaching.
        let mut many = vec![Light::point("far", Vec3::new(0.0, 9.0, 0.0), Vec3::ONE); 64];
        many.push(Light::point("lamp", Vec3::new(0.0, 1.0, 0.0), Vec3::ONE));
        assert!(is_hot(Vec3::ZERO, 0.6, &many, 0, false));
    }
}
