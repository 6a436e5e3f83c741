//! The light on one triangle of an entry's cell, its visibility filtered over the triangle
//! (DESIGN.md §4: "times the cell's visibility, filtered over the cell, not at one point").
//!
//! The runtime's entry pass (`shaders/irradiance.wgsl`, and its CPU twin through
//! [`crate::bvh::cell_power`]) gives each cell triangle the exact unshadowed power of every
//! light (`Light::triangle_power`, its solid angle) times the share of it that arrives. That
//! share was one shadow test at the triangle's centroid. A cell is a fan of triangles from its
//! entry to its edges, often half a metre long, and a shadow edge across one (a pillar's shadow
//! on the plinth around it) made the whole triangle lit or dark: on the chamber's torch 15 cm
//! from a pillar, the plinth-top cell whose lit crescent lies right in front of the pillar's
//! foot read no light at all, and the foot 9 cm above it 0.32 W/m² of indirect light against
//! the ground truth's 2.47.
//!
//! Now each light is tested at four points of the triangle ([`probe_points`]: near each corner
//! and at the centroid). Where they agree (all at least half lit, or all less), the triangle
//! takes their mean (a fully lit or fully hidden triangle costs four tests); where they differ, the share is the
//! irradiance-weighted mean over [`FINE_SUB`]² points, and a bit per fine point says whether
//! it receives at least half the light (all lights together). Where those bits differ, a shadow
//! edge crosses the triangle and it is *mixed*: it keeps them ([`TriangleLight::fine`]), so that
//! the near field's concentration (`prm_runtime::cpu::concentrate`) sees where on the triangle
//! the light lands, not only how much of it does. Where they are all alike (a weak lamp's
//! shadow edge under a strong lamp's even light), it is not: on the 4 x 4 halls, with 24
//! lights, 39 % of the cells that were hot by a shadow edge had only such triangles, and the
//! concentration's work went with them.
//!
//! A light all four probes see nothing of (behind a wall, in another room) does not *reach*
//! the triangle ([`TriangleLight::reach`]): it is left out of the share, of the fine points'
//! test and of the concentration's sum of the lights' irradiance. Were it in, a lamp in the
//! next room would dilute the share of the torch that does light the triangle, and on a
//! mixed triangle its unshadowed light would outweigh the torch's at every fine point, leaving
//! no bit set where the torch lands. (The runtime's entry pass also skips, without probing, a
//! light its shadow maps hide from the whole cell: the same answer.)
//!
//! Each triangle also says where its light lands ([`TriangleLight::centre`], [`landing`]): a
//! spot 15 cm from the chamber's wall aimed at it lights a patch of a cell half a metre across
//! near one of its ends, and the far field (`prm_runtime::cpu::far_field`) sends that cell's
//! light from there, not from the cell's centroid.

use glam::Vec3;

use crate::Light;

/// Sub-triangles per side of a mixed triangle's fine test: 36 points, one bit each in
/// [`TriangleLight::fine`].
pub const FINE_SUB: u32 = 6;
/// Points of the fine test.
pub const FINE_POINTS: usize = (FINE_SUB * FINE_SUB) as usize;

/// The probe test's points: the fine points nearest the three corners, and the centroid. A
/// straight shadow edge across the triangle parts its corners; four points at the 2 x 2
/// sub-triangles' centroids, a sixth of the way in, missed the thin lit crescent between a
/// pillar and its plinth's edge (the torch by the pillar, seed 0: 9.3 % against 7.9 % with every
/// triangle's fine points, which these four probes give too).
pub fn probe_points(t: &[Vec3; 3]) -> [Vec3; 4] {
    let (s, e1, e2) = (FINE_SUB as f32, t[1] - t[0], t[2] - t[0]);
    let inset = |fa: f32, fb: f32| t[0] + e1 * (fa / s) + e2 * (fb / s);
    let third = 1.0 / 3.0;
    [
        inset(third, third),
        inset(s - 2.0 * third, third),
        inset(third, s - 2.0 * third),
        (t[0] + t[1] + t[2]) / 3.0,
    ]
}

/// The centroids of the `sub`² equal sub-triangles of `t` (corners `t[0] + e1 (a / sub) + e2 (b
/// / sub)`), row by row: for `a` in `0..sub`, for `b` in `0..sub - a`, the upward sub-triangle at
/// `(a, b)` and then, unless it is the row's last, the downward one beside it. The near field's
/// quadrature and the GPU walk them in this order.
pub fn sub_centroids(t: &[Vec3; 3], sub: u32) -> impl Iterator<Item = Vec3> + '_ {
    let s = sub as f32;
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    (0..sub).flat_map(move |a| {
        (0..sub - a).flat_map(move |b| {
            let up = (a as f32 + 1.0 / 3.0, b as f32 + 1.0 / 3.0);
            let down = (a as f32 + 2.0 / 3.0, b as f32 + 2.0 / 3.0);
            let last = a + b + 1 == sub;
            std::iter::once(up)
                .chain((!last).then_some(down))
                .map(move |(fa, fb)| t[0] + e1 * (fa / s) + e2 * (fb / s))
        })
    })
}

/// Which of the [`FINE_SUB`]² fine points' sub-triangles ([`sub_centroids`]' order) holds point
/// `y` of triangle `t` (a point off it counts as at the nearest edge): the fine point whose
/// shadow bit stands for `y` on a mixed triangle.
pub fn fine_index(t: &[Vec3; 3], y: Vec3) -> usize {
    let (e1, e2, d) = (t[1] - t[0], t[2] - t[0], y - t[0]);
    let (d00, d01, d11) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d20, d21) = (d.dot(e1), d.dot(e2));
    let denom = d00 * d11 - d01 * d01;
    let s = FINE_SUB as f32;
    let (fa, fb) = if denom > 0.0 {
        ((d11 * d20 - d01 * d21) / denom * s, (d00 * d21 - d01 * d20) / denom * s)
    } else {
        (s / 3.0, s / 3.0)
    };
    let fa = if fa.is_finite() { fa.clamp(0.0, s) } else { 0.0 };
    let fb = if fb.is_finite() { fb.clamp(0.0, s - fa) } else { 0.0 };
    let a = (fa.floor() as u32).min(FINE_SUB - 1);
    let b = (fb.floor() as u32).min(FINE_SUB - 1 - a);
    let down = a + b + 1 < FINE_SUB && (fa - a as f32) + (fb - b as f32) > 1.0;
    (a * (2 * FINE_SUB - a) + 2 * b + down as u32) as usize
}

/// This frame's light on one cell triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleLight {
    /// The power that arrives (W): each light's unshadowed power on the triangle times its
    /// visible share.
    pub power: Vec3,
    /// The visible share of the power of the lights that reach it, luminance-weighted over
    /// them; 1 where none does.
    pub share: f32,
    /// For a mixed triangle, bit k: fine point k ([`sub_centroids`] at [`FINE_SUB`]) receives
    /// at least half of the light the lights that reach the triangle would bring it
    /// unshadowed (luminance over them).
    pub fine: u64,
    /// Bit i: light i reaches the triangle (some unshadowed power, and some probe sees it).
    /// Only the first 64 lights have bits (the runtime takes at most 64); a reader takes a
    /// light past them as reaching.
    pub reach: u64,
    /// True when a shadow edge crosses the triangle: some light's probes disagreed (its share
    /// was filtered over the fine points) and the fine points' bits are not all alike.
    /// [`Self::fine`] then says where the light lands; where they are all alike, the triangle
    /// takes its share everywhere and its bits are 0.
    pub mixed: bool,
    /// Where the light that arrives lands: each light's [`landing`] point weighted by the
    /// luminance of the power it brings (the centroid where none arrives).
    pub centre: Vec3,
}

impl TriangleLight {
    /// The visibility to take at fine point `k` (a mixed triangle's bit, else the share).
    pub fn at_fine(&self, k: usize) -> f32 {
        if self.mixed {
            ((self.fine >> k) & 1) as f32
        } else {
            self.share
        }
    }
}

/// The light `lights` deliver to triangle `t`, `visible(point, normal, light)` giving the
/// visibility (0 to 1) of a light from a point of it. The GPU's entry pass
/// (`shaders/irradiance.wgsl`) runs the same steps: each light's probes; then, if some light's
/// disagree, the fine points, point by point, every light at each.
pub fn triangle_light(
    t: &[Vec3; 3],
    lights: &[Light],
    visible: impl Fn(Vec3, Vec3, &Light) -> f32,
) -> TriangleLight {
    let centroid = (t[0] + t[1] + t[2]) / 3.0;
    let Some(n) = (t[1] - t[0]).cross(t[2] - t[0]).try_normalize() else {
        return TriangleLight {
            power: Vec3::ZERO,
            share: 1.0,
            fine: 0,
            reach: 0,
            mixed: false,
            centre: centroid,
        };
    };
    let probes = probe_points(t);
    // Per light that reaches the triangle: its unshadowed power and its probes' verdict
    // (`None`: they disagree).
    let mut mask = 0u64;
    let reach: Vec<(&Light, Vec3, Option<f32>)> = lights
        .iter()
        .enumerate()
        .filter_map(|(i, l)| {
            let p = l.triangle_power(t);
            if p == Vec3::ZERO {
                return None;
            }
            let v = probes.map(|y| visible(y, n, l));
            if v == [0.0; 4] {
                return None;
            }
            // Lights past the 64th (more than the runtime takes) have no bit: see `reach`.
            mask |= 1u64.checked_shl(i as u32).unwrap_or(0);
            // Agreeing is on which side of one half each probe lies (a filtered shadow map's
            // fractions near an edge or at a grazing angle are not a shadow edge), and a
            // uniform triangle takes their mean.
            let agree = v.iter().all(|&x| (x >= 0.5) == (v[0] >= 0.5));
            Some((l, p, agree.then(|| v.iter().sum::<f32>() / 4.0)))
        })
        .collect();
    let mixed = reach.iter().any(|r| r.2.is_none());
    // Per light, over the fine points: the unshadowed light (luminance), what arrives, and the
    // visibility summed.
    let mut sums = vec![(0.0f32, 0.0f32, 0.0f32); reach.len()];
    let mut fine = 0u64;
    if mixed {
        for (k, y) in sub_centroids(t, FINE_SUB).enumerate() {
            let (mut all, mut lit) = (0.0f32, 0.0f32);
            for ((l, _, uniform), sum) in reach.iter().zip(sums.iter_mut()) {
                let e = crate::luminance(l.irradiance(y, n));
                let v = uniform.unwrap_or_else(|| visible(y, n, l));
                all += e;
                lit += e * v;
                *sum = (sum.0 + e, sum.1 + e * v, sum.2 + v);
            }
            fine |= ((lit >= 0.5 * all) as u64) << k;
        }
    }
    let (mut power, mut total, mut seen) = (Vec3::ZERO, 0.0f32, 0.0f32);
    let (mut landed, mut landed_weight) = (Vec3::ZERO, 0.0f32);
    for (&(l, p, uniform), &(e_sum, ev_sum, v_sum)) in reach.iter().zip(&sums) {
        let share = match uniform {
            Some(v) => v,
            None if e_sum > 0.0 => ev_sum / e_sum,
            None => v_sum / FINE_POINTS as f32,
        };
        power += p * share;
        total += crate::luminance(p);
        seen += crate::luminance(p) * share;
        let weight = crate::luminance(p * share);
        if weight > 0.0 {
            landed += landing(t, n, l) * weight;
            landed_weight += weight;
        }
    }
    let centre = if landed_weight > 0.0 { landed / landed_weight } else { centroid };
    let share = if total > 0.0 { seen / total } else { 1.0 };
    // A shadow edge is where the bits differ. A light whose probes disagreed but which every
    // fine point finds outweighed (a weak lamp's edge under a strong one's even light) or
    // outweighing, leaves them all alike: the triangle then takes its share at every point,
    // which is also what its power says (all bits set would have spread power / share).
    let edge = mixed && fine != 0 && fine != ALL_FINE;
    TriangleLight { power, share, fine: if edge { fine } else { 0 }, reach: mask, mixed: edge, centre }
}

/// Directions a side of the grid [`landing`] sends over a triangle (its square in all).
pub const LANDING_SIDE: u32 = 4;
/// A point or spot light nearer a triangle's centroid than this many times the triangle's
/// longest edge may light it unevenly enough for [`landing`] to look where.
pub const LANDING_REACH: f32 = 4.0;

/// Where light `l`'s power on triangle `t` (unit normal `n`, the light in front of it) lands:
/// the mean point of the triangle weighted by the light's unshadowed irradiance. For a point
/// or spot light nearer than [`LANDING_REACH`] longest edges, the mean of where a stratified
/// grid of [`LANDING_SIDE`]² directions it sends evenly over the triangle's solid angle
/// ([`crate::cone::spherical_triangle`]) meets the triangle's plane, each weighted by the
/// light's intensity that way (a spot's falloff, its range window): directions even in solid
/// angle land `cos / r²` per unit of area, as the irradiance does, so a lamp 2 cm over a floor
/// lands at the point under it. Anything else (a farther light, a directional one, a triangle
/// too thin to sample, no direction carrying light): the centroid. The GPU's entry pass
/// (`shaders/irradiance.wgsl`) does the same.
pub fn landing(t: &[Vec3; 3], n: Vec3, l: &Light) -> Vec3 {
    let centroid = (t[0] + t[1] + t[2]) / 3.0;
    let longest = (t[1] - t[0]).length().max((t[2] - t[1]).length()).max((t[0] - t[2]).length());
    let height = n.dot(l.position - t[0]);
    if !l.is_positional() || !(height > 0.0) || l.position.distance(centroid) >= LANDING_REACH * longest {
        return centroid;
    }
    let corners = t.map(|c| (c - l.position).normalize_or_zero());
    let (mut sum, mut weight) = (Vec3::ZERO, 0.0f32);
    let side = LANDING_SIDE as f32;
    for i in 0..LANDING_SIDE {
        for j in 0..LANDING_SIDE {
            let (u1, u2) = ((i as f32 + 0.5) / side, (j as f32 + 0.5) / side);
            let Some((dir, _)) = crate::cone::spherical_triangle(corners[0], corners[1], corners[2], u1, u2)
            else {
                continue;
            };
            let down = -n.dot(dir);
            if !(down > 1e-6) {
                continue;
            }
            let y = l.position + dir * (height / down);
            let w = crate::luminance(l.incident(y).irradiance) * y.distance_squared(l.position);
            if w > 0.0 && w.is_finite() {
                sum += y * w;
                weight += w;
            }
        }
    }
    if weight > 0.0 {
        sum / weight
    } else {
        centroid
    }
}

/// Every fine point's bit.
const ALL_FINE: u64 = (1u64 << FINE_POINTS) - 1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fine_index_finds_each_fine_point_and_the_points_about_it() {
        let t = [Vec3::new(0.2, 0.0, -0.3), Vec3::new(1.7, 0.1, 0.2), Vec3::new(0.5, 0.3, 1.4)];
        let fine: Vec<Vec3> = sub_centroids(&t, FINE_SUB).collect();
        for (k, y) in fine.iter().enumerate() {
            assert_eq!(fine_index(&t, *y), k, "fine point {k}");
        }
        // Points scattered over the triangle take the fine point of the sub-triangle holding
        // them: the nearest centroid, within a sub-triangle's size, and the same index for a
        // point nudged off the triangle's plane.
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
        for i in 0..50 {
            for j in 0..50 - i {
                let y = t[0]
                    + (t[1] - t[0]) * ((i as f32 + 0.3) / 50.0)
                    + (t[2] - t[0]) * ((j as f32 + 0.3) / 50.0);
                let k = fine_index(&t, y);
                assert!(fine[k].distance(y) < 0.3, "point ({i}, {j}) given fine point {k}");
                assert_eq!(fine_index(&t, y + n * 1e-3), k);
            }
        }
        assert!(fine_index(&t, t[0] - (t[1] - t[0])) < FINE_POINTS, "off the triangle");
    }

    fn tri() -> [Vec3; 3] {
        [Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 0.0)]
    }

    #[test]
    fn sub_centroids_tile_the_triangle() {
        for sub in 1..=7 {
            let pts: Vec<Vec3> = sub_centroids(&tri(), sub).collect();
            assert_eq!(pts.len(), (sub * sub) as usize);
            // Their mean is the triangle's centroid (equal areas), and all lie inside it.
            let mean = pts.iter().copied().sum::<Vec3>() / pts.len() as f32;
            assert!(mean.distance(Vec3::new(1.0 / 3.0, 0.0, 1.0 / 3.0)) < 1e-5, "sub {sub}: {mean}");
            assert!(pts.iter().all(|p| p.x > 0.0 && p.z > 0.0 && p.x + p.z < 1.0));
        }
    }

    /// The probes are the fine points at the corners (so a triangle's probes and fine points
    /// agree where they meet) and the centroid.
    #[test]
    fn the_probes_are_the_corner_fine_points_and_the_centroid() {
        let t = [Vec3::ZERO, Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.5, 0.2, 0.0)];
        let fine: Vec<Vec3> = sub_centroids(&t, FINE_SUB).collect();
        let p = probe_points(&t);
        let last_of_first_row = 2 * (FINE_SUB as usize - 1);
        for (probe, k) in p.iter().zip([0, FINE_POINTS - 1, last_of_first_row]) {
            assert!(probe.distance(fine[k]) < 1e-6, "{probe} against fine point {k}, {}", fine[k]);
        }
        assert!(p[3].distance((t[0] + t[1] + t[2]) / 3.0) < 1e-6);
    }

    #[test]
    fn an_unshadowed_triangle_gets_its_exact_power_and_is_not_mixed() {
        let lamp = Light::point("lamp", Vec3::new(0.3, 0.05, 0.3), Vec3::ONE);
        let got = triangle_light(&tri(), std::slice::from_ref(&lamp), |_, _, _| 1.0);
        assert_eq!(got.power, lamp.triangle_power(&tri()));
        assert_eq!((got.share, got.mixed), (1.0, false));
        assert_eq!(got.reach, 1);
        // A hidden light does not reach it: no light, and the share of none is 1.
        let hidden = triangle_light(&tri(), std::slice::from_ref(&lamp), |_, _, _| 0.0);
        assert_eq!((hidden.power, hidden.share, hidden.mixed, hidden.reach), (Vec3::ZERO, 1.0, false, 0));
    }

    /// A lamp in the next room, hidden from the whole triangle and a hundred times brighter
    /// than the torch whose shadow edge crosses it, changes nothing: the share and the bits
    /// are the torch's alone.
    #[test]
    fn a_hidden_light_leaves_the_share_and_the_bits_alone() {
        let torch = Light::point("torch", Vec3::new(0.5, 0.6, 0.2), Vec3::ONE);
        let lamp = Light::point("lamp", Vec3::new(0.3, 0.4, 0.6), Vec3::splat(100.0));
        let edge = 0.45;
        let vis =
            |y: Vec3, _: Vec3, l: &Light| if l.name == "lamp" { 0.0 } else { (y.x < edge) as u8 as f32 };
        let alone = triangle_light(&tri(), std::slice::from_ref(&torch), vis);
        let both = triangle_light(&tri(), &[lamp, torch], vis);
        assert!(alone.mixed && both.mixed);
        assert_eq!((both.power, both.share, both.fine), (alone.power, alone.share, alone.fine));
        assert_eq!((alone.reach, both.reach), (1, 2));
        assert!(both.fine != 0 && both.share > 0.3);
    }

    /// A weak lamp's shadow edge under a strong lamp's even light: the strong lamp outweighs
    /// the weak one at every fine point, so every bit is set and no edge shows. The triangle
    /// is not mixed and takes its share everywhere, and its power is still the weak lamp's
    /// filtered over the fine points (as alone, where it is mixed) plus the strong lamp's.
    #[test]
    fn an_edge_outweighed_at_every_point_is_not_a_shadow_edge() {
        let strong = Light::point("strong", Vec3::new(0.3, 0.5, 0.3), Vec3::splat(100.0));
        let weak = Light::point("weak", Vec3::new(0.5, 0.6, 0.2), Vec3::ONE);
        let edge = 0.45;
        let vis =
            |y: Vec3, _: Vec3, l: &Light| if l.name == "weak" { (y.x < edge) as u8 as f32 } else { 1.0 };
        let alone = triangle_light(&tri(), std::slice::from_ref(&weak), vis);
        assert!(alone.mixed && alone.fine != 0 && alone.share < 0.9);
        let got = triangle_light(&tri(), &[strong.clone(), weak.clone()], vis);
        assert!(!got.mixed);
        assert_eq!((got.fine, got.reach), (0, 3));
        let want = strong.triangle_power(&tri()) + weak.triangle_power(&tri()) * alone.share;
        assert!(
            (got.power - want).abs().max_element() <= 1e-5 * want.max_element(),
            "{} against {want}",
            got.power
        );
        assert!(got.share < 1.0 && got.share > 0.99);
        assert!((0..FINE_POINTS).all(|k| got.at_fine(k) == got.share));
        // Bits all clear: a light that only the centroid probe sees half of.
        let centroid = (tri()[0] + tri()[1] + tri()[2]) / 3.0;
        let faint = |y: Vec3, _: Vec3, _: &Light| if y.distance(centroid) < 1e-4 { 0.6 } else { 0.3 };
        let dim = triangle_light(&tri(), std::slice::from_ref(&weak), faint);
        assert!(!dim.mixed && dim.fine == 0);
        assert!((dim.share - 0.3).abs() < 1e-6, "share {}", dim.share);
    }

    /// Forty lights, only the 38th seen: its bit alone, past the first word the GPU keeps.
    #[test]
    fn the_reach_bits_name_the_lights_seen() {
        let lights: Vec<Light> = (0..40)
            .map(|i| Light::point(&format!("l{i}"), Vec3::new(0.3, 0.5 + i as f32 * 0.01, 0.3), Vec3::ONE))
            .collect();
        let got = triangle_light(&tri(), &lights, |_, _, l| (l.name == "l37") as u8 as f32);
        assert_eq!(got.reach, 1 << 37);
        assert_eq!(got.power, lights[37].triangle_power(&tri()));
        assert_eq!(got.share, 1.0);
    }

    /// A shadow edge across the triangle: the share is the lit part's irradiance over the
    /// whole's, against a dense sum, and the bits mark the lit side.
    #[test]
    fn a_shadow_edge_is_filtered_over_the_triangle() {
        let lamp = Light::point("lamp", Vec3::new(0.5, 0.6, 0.2), Vec3::ONE);
        let edge = 0.45;
        let got = triangle_light(&tri(), std::slice::from_ref(&lamp), |y, _, _| (y.x < edge) as u8 as f32);
        assert!(got.mixed);
        // Dense: 600 x 600 points of the triangle.
        let (mut lit, mut all) = (0.0f64, 0.0f64);
        let k = 600;
        for i in 0..k {
            for j in 0..k - i {
                let y = Vec3::new((i as f32 + 0.3) / k as f32, 0.0, (j as f32 + 0.3) / k as f32);
                let e = lamp.irradiance(y, Vec3::Y).x as f64;
                all += e;
                if y.x < edge {
                    lit += e;
                }
            }
        }
        let want = (lit / all) as f32;
        // 36 points across an edge: the six sub-triangles it cuts are taken whole or not at
        // all, each 1/36 of the area, so up to about 0.08 off. The centroid alone (lit) said 1.
        assert!((got.share - want).abs() < 0.08, "share {} against dense {want}", got.share);
        assert!(1.0 - want > 0.3);
        let pts: Vec<Vec3> = sub_centroids(&tri(), FINE_SUB).collect();
        for (k, y) in pts.iter().enumerate() {
            assert_eq!(got.at_fine(k), (y.x < edge) as u8 as f32, "point {k} at {y}");
        }
        assert!((got.power.x - lamp.triangle_power(&tri()).x * got.share).abs() < 1e-6);
    }

    /// Two lights, one hidden from half the triangle: the bits follow the light that dominates
    /// each point, and the share weighs the lights by their power.
    #[test]
    fn lights_are_weighed_by_their_light_at_each_point() {
        let near = Light::point("near", Vec3::new(0.1, 0.1, 0.1), Vec3::ONE);
        let far = Light::point("far", Vec3::new(0.5, 3.0, 0.5), Vec3::ONE);
        let vis = |y: Vec3, _: Vec3, l: &Light| if l.name == "near" && y.z > 0.5 { 0.0 } else { 1.0 };
        let got = triangle_light(&tri(), &[far.clone(), near.clone()], vis);
        assert!(got.mixed);
        // Where the near lamp is hidden, the far one (about 30 times weaker there) is all.
        let pts: Vec<Vec3> = sub_centroids(&tri(), FINE_SUB).collect();
        for (k, y) in pts.iter().enumerate() {
            assert_eq!(got.at_fine(k), (y.z <= 0.5) as u8 as f32, "point {k} at {y}");
        }
        let whole = prm_lum(far.triangle_power(&tri())) + prm_lum(near.triangle_power(&tri()));
        assert!(got.share > 0.0 && got.share < 1.0 && whole > 0.0);
        // The far light is uniform: its power arrives whole.
        assert!(got.power.x > far.triangle_power(&tri()).x);
    }

    fn prm_lum(v: Vec3) -> f32 {
        crate::luminance(v)
    }

    /// Where a light lands ([`landing`]) against the irradiance-weighted mean over 40,000
    /// equal sub-triangles, on a floor triangle 2 m on a side: a lamp 2 cm, 20 cm and 1 m over
    /// points inside it and beside it, a spot 15 cm up aimed across it. Within 3 % of the
    /// triangle's longest edge (measured: lamps at most 0.95 %, the spot 2.0 %, whose cone
    /// takes few of the 16 directions; a cell's triangles are a fifth this size, so a few mm
    /// for the far field, which looks from 1 m and more). A light farther than
    /// LANDING_REACH longest edges, one behind the triangle and a sun land at the centroid.
    #[test]
    fn a_light_lands_where_its_irradiance_is_on_the_triangle() {
        let t = [Vec3::ZERO, Vec3::new(0.0, 0.0, 2.0), Vec3::new(2.0, 0.0, 0.0)];
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
        assert!(n.y > 0.99);
        let centroid = (t[0] + t[1] + t[2]) / 3.0;
        let brute = |l: &Light| {
            let (mut sum, mut w) = (Vec3::ZERO, 0.0f64);
            for y in sub_centroids(&t, 200) {
                let e = crate::luminance(l.irradiance(y, n)) as f64;
                sum += y * e as f32;
                w += e;
            }
            sum / w as f32
        };
        let lamp = |p: Vec3| Light::point("lamp", p, Vec3::ONE);
        let mut spot = Light::point("spot", Vec3::new(0.2, 0.15, 0.2), Vec3::ONE);
        spot.kind = crate::LightKind::Spot { inner: 0.3, outer: 0.6 };
        spot.direction = Vec3::new(1.0, -0.6, 0.5).normalize();
        let mut worst = 0.0f32;
        for (name, l) in [
            ("2 cm over", lamp(Vec3::new(0.5, 0.02, 0.4))),
            ("20 cm over", lamp(Vec3::new(0.5, 0.2, 0.4))),
            ("1 m over", lamp(Vec3::new(0.5, 1.0, 0.4))),
            ("2 cm beside its edge", lamp(Vec3::new(1.2, 0.02, 1.2))),
            ("20 cm beside its corner", lamp(Vec3::new(-0.2, 0.2, -0.2))),
            ("a spot across it", spot),
        ] {
            let (got, want) = (landing(&t, n, &l), brute(&l));
            let off = got.distance(want) / 2.0f32.sqrt() / 2.0;
            assert!(off < 0.03, "{name}: {got} against {want}");
            assert!(got.distance(centroid) > 0.05, "{name}: landed at the centroid");
            worst = worst.max(off);
        }
        println!("worst: {:.2} % of the longest edge", 100.0 * worst);
        let far = lamp(Vec3::new(0.5, LANDING_REACH * 2.0 * 2.0f32.sqrt() + 1.0, 0.4));
        assert_eq!(landing(&t, n, &far), centroid, "beyond LANDING_REACH");
        assert_eq!(landing(&t, n, &lamp(Vec3::new(0.5, -0.1, 0.4))), centroid, "behind");
        let sun = Light { kind: crate::LightKind::Directional, direction: -Vec3::Y, ..lamp(Vec3::ZERO) };
        assert_eq!(landing(&t, n, &sun), centroid, "a sun");
    }
}
