//! The incremental baker (paper 001): edits followed by convergence give the lightmap of a
//! fresh bake of the edited level; energy is accounted for at every step; no intermediate state
//! is further from the final one than the state before the edit; bad edits change nothing.

mod common;

use std::sync::Arc;

use common::{quads, unit_box_faces, v};
use glam::{Mat4, Vec3};
use prm::{Light, Scene, TexelSet};
use prm_precompute::incremental::baker::validation_ratio;
use prm_precompute::incremental::clusters::{
    balance_metric, balanced_cut, cell_lights, key, morton, Member, MAX_DEPTH,
};
use prm_precompute::incremental::paths::{luminance, trace_all, PathParams};
use prm_precompute::incremental::{
    Aabb, Baker, BakerParams, CellKey, Edit, EditError, Level, StepReport, UpdateKind,
};

/// Quad `a, b, c, d` wound so that its front faces `out`.
fn facing(q: [Vec3; 4], out: Vec3) -> [Vec3; 4] {
    let n = (q[1] - q[0]).cross(q[2] - q[0]);
    if n.dot(out) >= 0.0 {
        q
    } else {
        [q[3], q[2], q[1], q[0]]
    }
}

/// A closed unit room (node 0; the +x wall has its own material 1) with a block on the floor
/// (node 1) and a point light.
fn room() -> Scene {
    room_with(&[])
}

/// [`room`] with more quads in the block's node.
fn room_with(more: &[[Vec3; 4]]) -> Scene {
    let (lo, hi) = (v(0.3, 0.0, 0.35), v(0.55, 0.3, 0.6));
    let c = 0.5 * (lo + hi);
    let mut qs = unit_box_faces();
    let block = [
        facing([v(lo.x, hi.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)], Vec3::Y),
        facing([v(lo.x, 0., lo.z), v(lo.x, hi.y, lo.z), v(hi.x, hi.y, lo.z), v(hi.x, 0., lo.z)], -Vec3::Z),
        facing([v(lo.x, 0., hi.z), v(hi.x, 0., hi.z), v(hi.x, hi.y, hi.z), v(lo.x, hi.y, hi.z)], Vec3::Z),
        facing([v(lo.x, 0., lo.z), v(lo.x, 0., hi.z), v(lo.x, hi.y, hi.z), v(lo.x, hi.y, lo.z)], -Vec3::X),
        facing([v(hi.x, 0., lo.z), v(hi.x, hi.y, lo.z), v(hi.x, hi.y, hi.z), v(hi.x, 0., hi.z)], Vec3::X),
    ];
    for q in &block {
        let n = (q[1] - q[0]).cross(q[2] - q[0]);
        let mid = 0.25 * (q[0] + q[1] + q[2] + q[3]);
        assert!(n.dot(mid - c) > 0.0, "block faces point out");
    }
    qs.extend(block);
    qs.extend_from_slice(more);
    let mut s = quads(&qs, 0.6);
    for (t, tri) in s.triangles.iter_mut().enumerate() {
        if t >= 12 {
            tri.node = 1;
        }
        if t == 10 || t == 11 {
            tri.material = 1;
        }
    }
    let mut wall = s.materials[0].clone();
    wall.name = "wall".into();
    wall.albedo = Vec3::new(0.8, 0.3, 0.2);
    s.materials.push(wall);
    s.lights.push(Light::point("lamp", v(0.3, 0.8, 0.7), Vec3::splat(1.0)));
    s
}

fn params() -> BakerParams {
    BakerParams { paths: 3000, leaf_vpls: 128, max_depth: 6, visibility_samples: 2, ..Default::default() }
}

fn texels(s: &Scene) -> Arc<TexelSet> {
    Arc::new(TexelSet::build(s, 64, 64))
}

fn total(b: &Baker) -> Vec<Vec3> {
    let (d, i) = b.lightmap();
    d.iter().zip(&i).map(|(a, b)| *a + *b).collect()
}

fn rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| (*x - *y).length_squared() as f64).sum();
    (s / a.len() as f64).sqrt()
}

fn translate(x: f32, z: f32) -> Mat4 {
    Mat4::from_translation(v(x, 0.0, z))
}

#[test]
fn edits_then_convergence_give_a_fresh_bake_of_the_edited_level() {
    let scene = room();
    let tx = texels(&scene);
    let extent = scene.diagonal();
    let mut a = Baker::new(scene.clone(), tx.clone(), params()).unwrap();
    assert!(a.converge() > 0);
    let lamp = Light::point("lamp", v(0.7, 0.5, 0.2), Vec3::new(1.0, 0.9, 0.8));
    let edits = [
        Edit::Transform { node: 1, matrix: translate(0.15, -0.1) },
        Edit::Albedo { material: 1, albedo: v(0.2, 0.7, 0.4) },
        Edit::SetLight { id: 0, light: Light::point("lamp", v(0.25, 0.6, 0.3), Vec3::splat(1.0)) },
        Edit::AddLight(lamp),
        Edit::Transform { node: 1, matrix: Mat4::from_rotation_y(0.3) },
    ];
    for e in &edits {
        let r = a.apply(e).unwrap();
        assert!(r.pending > 0, "{e:?} queues updates");
        // Interleave: a few updates, then the next edit.
        for _ in 0..3 {
            a.step();
        }
    }
    a.converge();
    assert!(a.converged());

    let mut final_scene = a.level().current().scene.as_ref().clone();
    final_scene.lights = a.level().current().lights.iter().map(|l| l.light.clone()).collect();
    let mut b = Baker::with_frame(final_scene, tx, params(), a.frame(), extent).unwrap();
    b.converge();
    let (ta, tb) = (total(&a), total(&b));
    let mean = tb.iter().map(|x| x.length() as f64).sum::<f64>() / tb.len() as f64;
    let worst = ta.iter().zip(&tb).map(|(x, y)| (*x - *y).length() as f64).fold(0.0, f64::max);
    assert!(mean > 0.1, "the room is lit ({mean})");
    assert!(worst <= 1e-4 * mean, "incremental and fresh differ by {worst} W/m² at worst (mean {mean})");
    let (ia, ib) = (a.lightmap().1, b.lightmap().1);
    assert!(ib.iter().any(|x| x.x > 0.0), "indirect light is there");
    assert!(rms(&ia, &ib) <= 1e-5 * mean);
}

fn mean_length(a: &[Vec3]) -> f64 {
    a.iter().map(|x| x.length() as f64).sum::<f64>() / a.len() as f64
}

/// Updates the baker to convergence after two moves of the block (so that refreshes span
/// versions), checking at every fourth step and the last that its lightmap is its baked
/// entries evaluated afresh; the updates it made.
fn afresh_at_every_step(scene: &Scene) -> Vec<StepReport> {
    // Small corrections, so that an edit makes several.
    let p = BakerParams { delta_leaf_vpls: 48, ..params() };
    let mut b = Baker::new(scene.clone(), texels(scene), p).unwrap();
    b.converge();
    b.apply(&Edit::Transform { node: 1, matrix: translate(0.12, 0.05) }).unwrap();
    b.apply(&Edit::Transform { node: 1, matrix: translate(-0.05, 0.1) }).unwrap();
    let mut kinds = Vec::new();
    let mut k = 0;
    loop {
        if k % 4 == 0 || b.converged() {
            let (d, i) = b.lightmap();
            let (rd, ri) = b.recomputed();
            let scale = mean_length(&rd) + mean_length(&ri);
            let worst = d.iter().zip(&rd).chain(i.iter().zip(&ri)).map(|(x, y)| (*x - *y).length() as f64);
            let worst = worst.fold(0.0, f64::max);
            // Sums of f64 accumulators, read as f32: a few ulp of the largest texel.
            assert!(
                worst <= 1e-5 * scale,
                "step {k}: lightmap and its entries differ by {worst} (mean {scale})"
            );
        }
        match b.step() {
            Some(r) => kinds.push(r),
            None => break,
        }
        k += 1;
    }
    kinds
}

#[test]
fn the_lightmap_is_its_baked_entries_evaluated_afresh_at_every_step() {
    let kinds: Vec<UpdateKind> = afresh_at_every_step(&room()).iter().map(|r| r.kind).collect();
    for want in [UpdateKind::Rebuild, UpdateKind::Delta, UpdateKind::Refresh, UpdateKind::Consolidate] {
        assert!(kinds.contains(&want), "no {want:?} among {} updates", kinds.len());
    }
    // Consolidation comes last, after every update that carries invalid light.
    let first = kinds.iter().position(|x| *x == UpdateKind::Consolidate).unwrap();
    assert!(kinds[first..].iter().all(|x| *x == UpdateKind::Consolidate));
}

/// A moved object of two pieces apart, like the chamber's carpet (a runner along the floor
/// and a dais at its end): the refreshes test shadow rays against each piece's box, not the
/// one box around both (`parts_of` in the baker), and stay exact.
#[test]
fn a_moved_object_in_pieces_apart_is_refreshed_exactly() {
    // A runner 2 cm above the floor along the -z wall, part of the block's node.
    let runner =
        facing([v(0.1, 0.02, 0.08), v(0.9, 0.02, 0.08), v(0.9, 0.02, 0.18), v(0.1, 0.02, 0.18)], Vec3::Y);
    let scene = room_with(&[runner]);
    let steps = afresh_at_every_step(&scene);
    assert!(steps.iter().filter(|r| r.kind == UpdateKind::Refresh).count() > 3, "refreshes were made");
}

/// The direct light's refreshes re-cast only the shadow rays that cross what moved
/// (`shadow_change`): for a sphere light, a ceiling panel's parts, a spot and a directional
/// light (the ceiling lifted 10 m, so that it comes in above the walls) as for a point light,
/// the lightmap stays its entries evaluated afresh, and direct entries were refreshed.
#[test]
fn direct_refreshes_of_every_aperture_are_its_entries_evaluated_afresh() {
    let mut scene = room();
    // The ceiling (the second face: triangles 2 and 3, their own four vertices) up 10 m.
    for t in 2..4 {
        for v in scene.triangles[t].v {
            scene.positions[v as usize].y = 11.0;
        }
    }
    let panel = [v(0.6, 0.97, 0.2), v(0.9, 0.97, 0.2), v(0.9, 0.97, 0.5), v(0.6, 0.97, 0.5)];
    let mut spot = Light::point("spot", v(0.2, 0.7, 0.2), Vec3::splat(0.8));
    spot.kind = prm::LightKind::Spot { inner: 0.3, outer: 0.9 };
    spot.direction = (v(0.45, 0.0, 0.5) - spot.position).normalize();
    let mut sun = Light::point("sun", Vec3::ZERO, Vec3::splat(0.5));
    sun.kind = prm::LightKind::Directional;
    sun.direction = v(-0.6, -1.0, -0.3).normalize();
    scene.lights = vec![
        Light::sphere("ball", v(0.7, 0.75, 0.75), 0.08, Vec3::splat(0.6)),
        Light::polygon("panel", &facing(panel, -Vec3::Y), Vec3::splat(2.0)),
        spot,
        sun,
    ];
    scene.lights.iter().for_each(|l| l.check().unwrap());
    let steps = afresh_at_every_step(&scene);
    let direct: Vec<u32> = steps
        .iter()
        .filter_map(|r| match (r.kind, r.cell) {
            (UpdateKind::Refresh, CellKey::Direct(id)) => Some(id),
            _ => None,
        })
        .collect();
    for id in 0..4 {
        assert!(direct.contains(&id), "light {id}'s direct light refreshed: {direct:?}");
    }
}

#[test]
fn without_consolidation_the_lightmap_is_a_fresh_bake_within_its_noise() {
    let scene = room();
    let tx = texels(&scene);
    let extent = scene.diagonal();
    let p = BakerParams { consolidate: false, delta_leaf_vpls: 96, ..params() };
    let mut a = Baker::new(scene.clone(), tx.clone(), p.clone()).unwrap();
    a.converge();
    a.apply(&Edit::Transform { node: 1, matrix: translate(0.15, -0.1) }).unwrap();
    let steps = a.converge();
    assert!(steps > 0 && a.valid());
    let final_scene = a.level().current().scene.as_ref().clone();
    let fresh = |seed: u64| {
        let mut b = Baker::with_frame(
            final_scene.clone(),
            tx.clone(),
            BakerParams { seed, ..p.clone() },
            a.frame(),
            extent,
        )
        .unwrap();
        b.converge();
        b.lightmap().1
    };
    let (f0, f1) = (fresh(0), fresh(1));
    let ia = a.lightmap().1;
    let noise = rms(&f0, &f1);
    let off = rms(&ia, &f0);
    assert!(noise > 0.0);
    // Two fresh bakes differ by twice the variance of one; the edited bake against a fresh one
    // of the same seed shares its paths, so it must come within that.
    assert!(off <= noise, "edited bake {off} from a fresh one; two fresh bakes {noise} apart");
}

#[test]
fn energy_is_accounted_for_and_cells_disjoint_at_every_step() {
    let scene = room();
    let mut b = Baker::new(scene.clone(), texels(&scene), params()).unwrap();
    b.converge();
    b.apply(&Edit::Transform { node: 1, matrix: translate(-0.1, 0.2) }).unwrap();
    b.apply(&Edit::Albedo { material: 0, albedo: Vec3::splat(0.4) }).unwrap();
    let mut steps = 0;
    loop {
        let e = b.energy();
        let want = e.vpls;
        let have = e.baked + e.pending;
        assert!(
            (have - want).abs().max_element() <= 1e-4 * want.max_element(),
            "step {steps}: baked {} + pending {} vs VPLs {}",
            e.baked,
            e.pending,
            e.vpls
        );
        assert!(b.cells_disjoint(), "step {steps}: a cell inside another");
        if b.step().is_none() {
            break;
        }
        steps += 1;
    }
    assert!(steps > 0);
    let e = b.energy();
    assert_eq!(e.pending, Vec3::ZERO);
}

#[test]
fn no_intermediate_state_is_further_from_the_final_one_than_before_the_edit() {
    let scene = room();
    let mut b = Baker::new(scene.clone(), texels(&scene), params()).unwrap();
    b.converge();
    b.apply(&Edit::Transform { node: 1, matrix: translate(0.2, 0.1) }).unwrap();
    let mut states = vec![total(&b)];
    let mut reports = Vec::new();
    while let Some(r) = b.step() {
        states.push(total(&b));
        reports.push(r);
    }
    let last = states.last().unwrap().clone();
    let before = rms(&states[0], &last);
    assert!(before > 0.0, "the move changed the lightmap");
    for (k, s) in states.iter().enumerate() {
        let d = rms(s, &last);
        assert!(d <= before * (1.0 + 1e-3), "state {k}: {d} from the final, {before} before the edit");
    }
    // Most invalid flux per unit of expected work first (consolidations, resolving none, last).
    let urgency: Vec<f32> = reports.iter().map(|r| r.resolved / r.cost).collect();
    assert!(urgency.iter().all(|u| u.is_finite() && *u >= 0.0), "{urgency:?}");
    assert!(urgency.windows(2).all(|w| w[1] <= w[0] * (1.0 + 1e-5)), "{urgency:?}");
    let mut kinds: Vec<UpdateKind> = Vec::new();
    for r in reports.iter().filter(|r| r.resolved > 0.0) {
        if !kinds.contains(&r.kind) {
            kinds.push(r.kind);
        }
    }
    assert!(kinds.len() >= 2, "the move queues updates of more than one kind: {kinds:?}");
}

#[test]
fn a_closed_room_receives_the_power_of_its_vpls() {
    // Every virtual light's power lands somewhere in a closed room: the indirect irradiance
    // integrated over the receivers equals the VPLs' power (to the texel discretisation).
    let mut scene = quads(&unit_box_faces(), 0.5);
    scene.lights.push(Light::point("p", v(0.4, 0.6, 0.5), Vec3::splat(1.0)));
    let tx = Arc::new(TexelSet::build(&scene, 128, 128));
    let mut b = Baker::new(scene.clone(), tx.clone(), BakerParams { paths: 4000, ..params() }).unwrap();
    b.converge();
    let (direct, indirect) = b.lightmap();
    // Power received: each triangle's area times the mean irradiance of its texels.
    let received = |e: &[Vec3]| -> f64 {
        let mut sum = vec![(0.0f64, 0usize); scene.triangles.len()];
        for (t, x) in tx.texels.iter().zip(e) {
            sum[t.triangle as usize].0 += x.x as f64;
            sum[t.triangle as usize].1 += 1;
        }
        sum.iter()
            .enumerate()
            .filter(|(_, s)| s.1 > 0)
            .map(|(t, s)| scene.area(t) as f64 * s.0 / s.1 as f64)
            .sum()
    };
    // The direct light per texel is I cos / d² (a convex room hides nothing).
    let light = v(0.4, 0.6, 0.5);
    for (t, e) in tx.texels.iter().zip(&direct) {
        let d = light - t.position;
        let want = (t.normal.dot(d) / d.length()).max(0.0) / d.length_squared();
        assert!((e.x - want).abs() <= 1e-4 * want.max(1.0), "direct {} vs {want} at {}", e.x, t.position);
    }
    // The quadrature over texels is calibrated by the direct light's known total, 4 pi I.
    let quadrature = received(&direct) / (4.0 * std::f64::consts::PI);
    assert!((quadrature - 1.0).abs() < 0.06, "texel quadrature off by {quadrature}");
    let indirect_in = received(&indirect) / quadrature;
    let vpl = b.energy().vpls.x as f64;
    assert!(
        (indirect_in - vpl).abs() <= 0.02 * vpl,
        "indirect received {indirect_in} W vs VPL power {vpl} W"
    );
}

#[test]
fn bad_edits_are_refused_and_change_nothing() {
    let scene = room();
    let mut b = Baker::new(scene.clone(), texels(&scene), params()).unwrap();
    b.converge();
    let before = total(&b);
    let version = b.level().current().id;
    let bad = [
        (Edit::Transform { node: 7, matrix: Mat4::IDENTITY }, EditError::UnknownNode(7)),
        (
            Edit::Transform { node: 1, matrix: Mat4::from_translation(v(f32::NAN, 0., 0.)) },
            EditError::NonFinite("the transform"),
        ),
        (Edit::Transform { node: 1, matrix: Mat4::from_scale(v(1.0, 0.0, 1.0)) }, EditError::Singular(1)),
        (Edit::Transform { node: 1, matrix: Mat4::from_translation(v(1e20, 0., 0.)) }, EditError::TooFar(1)),
        (Edit::Albedo { material: 9, albedo: Vec3::splat(0.5) }, EditError::UnknownMaterial(9, 2)),
        (Edit::Albedo { material: 0, albedo: Vec3::splat(1.5) }, EditError::BadAlbedo(Vec3::splat(1.5))),
        (Edit::RemoveLight { id: 4 }, EditError::UnknownLight(4)),
        (
            Edit::AddLight(Light::point("x", v(0.5, f32::INFINITY, 0.5), Vec3::ONE)),
            EditError::NonFinite("the light"),
        ),
        (
            Edit::AddLight(Light::point("x", v(0.5, 0.5, 0.5), -Vec3::ONE)),
            EditError::NegativeIntensity(-Vec3::ONE),
        ),
    ];
    for (e, want) in bad {
        assert_eq!(b.apply(&e).unwrap_err(), want, "{e:?}");
        assert_eq!(b.level().current().id, version);
        assert!(b.converged());
    }
    assert_eq!(total(&b), before);
}

#[test]
fn each_edit_kind_changes_the_lightmap_where_it_should() {
    let scene = room();
    let mut b = Baker::new(scene.clone(), texels(&scene), params()).unwrap();
    b.converge();
    let l0 = b.lightmap();
    // Recolouring a light scales its paths: direct and indirect scale with it exactly.
    b.apply(&Edit::SetLight { id: 0, light: Light::point("lamp", v(0.3, 0.8, 0.7), Vec3::splat(2.0)) })
        .unwrap();
    b.converge();
    let l1 = b.lightmap();
    for (x, y) in l0.0.iter().chain(&l0.1).zip(l1.0.iter().chain(&l1.1)) {
        assert!((*y - 2.0 * *x).abs().max_element() <= 1e-4 * (1.0 + x.max_element()), "{x} -> {y}");
    }
    // Removing the only light leaves nothing (to round-off).
    b.apply(&Edit::RemoveLight { id: 0 }).unwrap();
    b.converge();
    let (d, i) = b.lightmap();
    let peak = l1.0.iter().map(|x| x.max_element()).fold(0.0, f32::max);
    assert!(d.iter().chain(&i).all(|x| x.abs().max_element() <= 1e-5 * peak));
    assert_eq!(b.energy().vpls, Vec3::ZERO);
    // A wall's albedo changes the light it reflects, not what it receives directly.
    let mut c = Baker::new(scene.clone(), texels(&scene), params()).unwrap();
    c.converge();
    let (d0, i0) = c.lightmap();
    let r = c.apply(&Edit::Albedo { material: 1, albedo: Vec3::ZERO }).unwrap();
    assert!(r.paths_changed > 0 && r.paths_changed < r.paths_total);
    c.converge();
    let (d1, i1) = c.lightmap();
    assert_eq!(d0, d1, "direct light does not depend on albedo");
    let sum = |x: &[Vec3]| x.iter().fold(Vec3::ZERO, |a, b| a + *b);
    assert!(sum(&i1).x < sum(&i0).x, "a black wall reflects less");
}

fn member(i: u32, p: Vec3, n: Vec3) -> Member {
    Member {
        code: 0,
        light: 0,
        path: i,
        vertex: 0,
        position: p,
        normal: n,
        power: Vec3::splat(0.01),
        onward: 0.0,
        reach: 0.0,
    }
}

#[test]
fn a_cell_s_lights_follow_its_planes_and_keep_its_power() {
    let cell = Aabb { lo: Vec3::ZERO, hi: Vec3::ONE };
    // A floor and a wall meeting in the cell: two polygons, each on its plane, inside the cell.
    let mut ms = Vec::new();
    for i in 0..400u32 {
        let (a, b) = ((i % 20) as f32 / 20.0 + 0.025, (i / 20) as f32 / 20.0 + 0.025);
        ms.push(member(i, v(a, 0.0, b), Vec3::Y));
        if i % 2 == 0 {
            ms.push(member(1000 + i, v(0.0, a, b), Vec3::X));
        }
    }
    let ls = cell_lights(&ms, &cell, 4, 10);
    assert_eq!(ls.len(), 2, "one polygon per plane");
    let power: Vec3 = ls.iter().fold(Vec3::ZERO, |a, l| a + l.polygon.power);
    assert!((power.x - 0.01 * ms.len() as f32).abs() < 1e-4);
    for l in &ls {
        let n = l.polygon.normal;
        assert!(n.dot(Vec3::Y).abs() > 0.999 || n.dot(Vec3::X).abs() > 0.999);
        for x in &l.polygon.vertices {
            assert!(
                x.cmpge(Vec3::splat(-1e-5)).all() && x.cmple(Vec3::splat(1.0 + 1e-5)).all(),
                "{x} in the cell"
            );
        }
        // Counter-clockwise seen from its front.
        let p = &l.polygon.vertices;
        assert!((p[1] - p[0]).cross(p[2] - p[0]).dot(n) > 0.0);
        // It covers its members: area close to the plane's part of the cell.
        assert!(l.polygon.area() > 0.8, "area {}", l.polygon.area());
    }
    // Scattered normals: no plane of 10, so disks, at most K of them, power kept.
    let scattered: Vec<Member> = (0..40u32)
        .map(|i| {
            let a = i as f32 * 2.4;
            member(i, v(0.5 + 0.3 * a.cos(), 0.5, 0.5 + 0.3 * a.sin()), v(a.cos(), 0.3, a.sin()).normalize())
        })
        .collect();
    let ls = cell_lights(&scattered, &cell, 4, 10);
    assert!(!ls.is_empty() && ls.len() <= 4);
    let power: f32 = ls.iter().map(|l| l.polygon.power.x).sum();
    assert!((power - 0.4).abs() < 1e-5);
}

#[test]
fn a_level_saved_again_diffs_into_edits_that_reproduce_it() {
    use prm_precompute::incremental::diff::{diff, DiffError};
    use prm_precompute::incremental::Level;
    let old = room();
    let mut new = old.clone();
    // The block turned and moved (positions and normals), the wall recoloured, the lamp moved
    // and a second lamp added.
    let m = Mat4::from_translation(v(0.1, 0.0, -0.05)) * Mat4::from_rotation_y(0.4);
    let block: Vec<u32> = {
        let mut b: Vec<u32> = old.triangles.iter().filter(|t| t.node == 1).flat_map(|t| t.v).collect();
        b.sort_unstable();
        b.dedup();
        b
    };
    for &i in &block {
        new.positions[i as usize] = m.transform_point3(old.positions[i as usize]);
        new.normals[i as usize] = m.transform_vector3(old.normals[i as usize]).normalize();
    }
    new.materials[1].albedo = v(0.1, 0.6, 0.3);
    new.lights[0].position = v(0.6, 0.7, 0.3);
    new.lights.push(Light::point("second", v(0.2, 0.5, 0.2), Vec3::splat(0.5)));
    let edits = diff(&old, &new, &[0]).unwrap();
    assert_eq!(edits.len(), 4, "{edits:?}");
    let mut level = Level::new(old.clone(), texels(&old));
    for e in &edits {
        level.apply(e).unwrap();
    }
    let cur = level.current();
    let worst =
        cur.scene.positions.iter().zip(&new.positions).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
    assert!(worst < 1e-5, "positions {worst} off");
    assert_eq!(cur.scene.materials[1].albedo, new.materials[1].albedo);
    let lights: Vec<Light> = cur.lights.iter().map(|l| l.light.clone()).collect();
    assert_eq!(lights, new.lights);
    // Nothing changed: no edits.
    assert!(diff(&new, &new, &[0, 1]).unwrap().is_empty());

    // A flat node (one quad) fixes no transform off its plane by its vertices alone: its
    // normals do.
    let flat = quads(&[[v(0., 0., 0.), v(1., 0., 0.), v(1., 0., 1.), v(0., 0., 1.)]], 0.5);
    let mut tilted = flat.clone();
    let m = Mat4::from_translation(v(0.0, 0.3, 0.1))
        * Mat4::from_rotation_x(0.5)
        * Mat4::from_scale(Vec3::splat(1.5));
    for i in 0..flat.positions.len() {
        tilted.positions[i] = m.transform_point3(flat.positions[i]);
        tilted.normals[i] = m.transform_vector3(flat.normals[i]).normalize();
    }
    let Edit::Transform { matrix, .. } = diff(&flat, &tilted, &[]).unwrap()[0] else { panic!("a transform") };
    let probe = v(0.3, 0.7, 0.2);
    assert!((matrix.transform_point3(probe) - m.transform_point3(probe)).length() < 1e-4, "{matrix} vs {m}");

    // What the incremental baker cannot follow is refused with the reason.
    let mut bent = old.clone();
    bent.positions[block[0] as usize] += v(0.0, 0.05, 0.0);
    assert!(matches!(diff(&old, &bent, &[0]), Err(DiffError::NotAffine { node: 1, .. })));
    let mut grown = old.clone();
    grown.triangles.pop();
    assert!(matches!(diff(&old, &grown, &[0]), Err(DiffError::Topology(_))));
    let mut relaid = old.clone();
    relaid.uv1[3].x += 0.01;
    assert_eq!(diff(&old, &relaid, &[0]), Err(DiffError::Layout(3)));
    let mut textured = old.clone();
    textured.materials[0].double_sided = !textured.materials[0].double_sided;
    assert_eq!(diff(&old, &textured, &[0]), Err(DiffError::Material(0)));
}

#[test]
fn eq_2_is_a_power_law_that_halves_at_t() {
    // Paper 001 calls eq. (2) quadratic; ratio = max(0.5, x^(log 0.5 / log t)) is a power law,
    // exponent log10(2) = 0.301 for t = 0.1: exclusive validation at x = 1, 50:50 from x = t
    // down.
    let t = 0.1;
    assert!((validation_ratio(1.0, t) - 1.0).abs() < 1e-6);
    assert!((validation_ratio(0.1, t) - 0.5).abs() < 1e-5);
    assert_eq!(validation_ratio(0.01, t), 0.5);
    assert!((validation_ratio(0.5, t) - 0.5f32.powf(std::f32::consts::LOG10_2)).abs() < 1e-5);
    assert_eq!(validation_ratio(0.25, 0.5), 0.5, "t = 0.5: the exponent is 1, clamped at 0.5");
    assert!((validation_ratio(0.8, 0.5) - 0.8).abs() < 1e-6);
    assert_eq!(validation_ratio(7.0, t), 1.0, "shares above 1 count as 1");
}

fn cluster_member(i: u32, p: Vec3, onward: f32, reach: f32) -> Member {
    Member { onward, reach, ..member(i, p, Vec3::Y) }
}

#[test]
fn the_balance_metric_is_visual_contribution_times_visibility_error() {
    // Two VPLs 2 m apart (r = 1), one passing 0.75 on at 2 m and one 0.25 at 6 m (weighted
    // d_avg = 3): Φ_Ω = 1, E_v = 1 / (3 + 1)² = 1/16.
    let ms = [cluster_member(0, v(0., 0., 0.), 0.75, 2.0), cluster_member(1, v(2., 0., 0.), 0.25, 6.0)];
    assert!((balance_metric(&ms) - 1.0 / 16.0).abs() < 1e-7, "{}", balance_metric(&ms));
    // Nothing carried on, or one VPL (r = 0): nothing to refine.
    let dead = [cluster_member(0, v(0., 0., 0.), 0.0, 0.0), cluster_member(1, v(1., 0., 0.), 0.0, 0.0)];
    assert_eq!(balance_metric(&dead), 0.0);
    assert_eq!(balance_metric(&ms[..1]), 0.0);
}

/// VPLs in a unit box with pseudo-random onward flux and reach, sorted by code.
fn scattered_members(n: u32) -> (Vec<Member>, Aabb) {
    let root = Aabb { lo: Vec3::ZERO, hi: Vec3::ONE };
    let mut rng = prm::sampling::stream(7, 0, 0);
    use rand::Rng;
    let mut ms: Vec<Member> = (0..n)
        .map(|i| {
            let p = v(rng.random(), rng.random::<f32>().powi(3), rng.random());
            let mut m = cluster_member(i, p, rng.random::<f32>(), 0.05 + 2.0 * rng.random::<f32>());
            m.code = morton(&root, p, MAX_DEPTH);
            m
        })
        .collect();
    ms.sort_by_key(|m| (m.code, m.path));
    (ms, root)
}

#[test]
fn the_balanced_cut_is_greedy_refinement_by_the_metric() {
    let (ms, _) = scattered_members(3000);
    let depth_cap = 6;
    for cells in [1usize, 2, 9, 40, 200, 100_000] {
        let got = balanced_cut(&ms, cells, depth_cap);
        // A partition of the members, each cell holding only members under its key.
        let mut next = 0;
        for (k, r) in &got {
            assert_eq!(r.start, next, "cells tile the members in order");
            next = r.end;
            let (d, prefix) = ((*k >> 32) as u32, *k as u32);
            assert!(ms[r.clone()].iter().all(|m| m.code >> (3 * (MAX_DEPTH - d)) == prefix));
        }
        assert_eq!(next, ms.len());
        // The twin: refine, one at a time, the selected cell of largest B (at the depth cap B
        // is 0), ties to the lower key, until `cells` are selected or B is 0 everywhere.
        let mut sel: Vec<(u64, std::ops::Range<usize>)> = vec![(key(0, 0), 0..ms.len())];
        let b = |k: u64, r: &std::ops::Range<usize>| {
            if (k >> 32) as u32 >= depth_cap {
                0.0
            } else {
                balance_metric(&ms[r.clone()])
            }
        };
        while sel.len() < cells {
            let (i, best) = sel
                .iter()
                .enumerate()
                .map(|(i, (k, r))| (i, (b(*k, r), *k)))
                .max_by(|x, y| x.1 .0.total_cmp(&y.1 .0).then(y.1 .1.cmp(&x.1 .1)))
                .unwrap();
            if !(best.0 > 0.0) {
                break;
            }
            let (k, r) = sel.remove(i);
            let (d, prefix) = ((k >> 32) as u32, k as u32);
            let shift = 3 * (MAX_DEPTH - d - 1);
            for child in 0..8u32 {
                let rr: Vec<usize> = r.clone().filter(|&j| (ms[j].code >> shift) & 7 == child).collect();
                if let (Some(&a), Some(&z)) = (rr.first(), rr.last()) {
                    sel.push((key(d + 1, prefix << 3 | child), a..z + 1));
                }
            }
        }
        sel.sort_by_key(|(_, r)| r.start);
        assert_eq!(got, sel, "{cells} cells");
        if cells <= 200 {
            assert!((cells..cells + 7).contains(&got.len()), "{cells} asked, {} cut", got.len());
        }
    }
}

#[test]
fn light_landing_close_by_gets_finer_cells() {
    // Two equal clusters of VPLs: the light of the one at x < 0.5 lands 5 cm away, the other's
    // 5 m away. Their visibility errors differ by (5 + r)² / (0.05 + r)², so the budget goes
    // to the near one.
    let root = Aabb { lo: Vec3::ZERO, hi: Vec3::ONE };
    let mut ms: Vec<Member> = (0..4096u32)
        .map(|i| {
            let p = v((i % 64) as f32 / 64.0 + 0.004, 0.5, (i / 64) as f32 / 64.0 + 0.004);
            let reach = if p.x < 0.5 { 0.05 } else { 5.0 };
            Member { code: morton(&root, p, MAX_DEPTH), ..cluster_member(i, p, 1.0, reach) }
        })
        .collect();
    ms.sort_by_key(|m| (m.code, m.path));
    let cut = balanced_cut(&ms, 64, 8);
    let near = cut.iter().filter(|(_, r)| ms[r.start].position.x < 0.5).count();
    let far = cut.len() - near;
    assert!(near >= 4 * far, "{near} cells where light lands close, {far} where it lands far");
}

#[test]
fn the_visual_contribution_of_a_closed_room_is_its_albedo_times_the_flux() {
    // Eq. (4): Φ_Ω = Φ/N_s Σ f(x_i) over the particles' hits, the flux times the albedo where it
    // lands; in a closed grey room of albedo 0.6 every particle hits, so Φ_Ω = 0.6 Φ. Our paths
    // carry equal energy under Russian roulette by albedo, and a VPL's onward flux (its next
    // vertex's power) estimates it without bias. (Eq. (3)'s 1/(2π) in front would make it
    // 0.6 Φ / 2π: a constant factor, harmless for balancing, but not the flux.)
    let scene = quads(&unit_box_faces(), 0.6);
    let mut lit = scene.clone();
    lit.lights.push(Light::point("lamp", v(0.5, 0.7, 0.4), Vec3::splat(1.0)));
    let level = Level::new(lit.clone(), texels(&lit));
    let cur = level.current();
    let bounds = (v(-0.01, -0.01, -0.01), v(1.01, 1.01, 1.01));
    let lp = trace_all(cur, &cur.lights[0], 40_000, bounds, PathParams { max_bounces: 64, seed: 3 });
    let (mut onward, mut power) = (0.0f64, 0.0f64);
    for p in &lp.paths {
        assert!(!p.vertices.is_empty(), "a closed room: every path hits");
        for (i, x) in p.vertices.iter().enumerate() {
            power += luminance(x.power) as f64;
            onward += p.vertices.get(i + 1).map_or(0.0, |y| luminance(y.power) as f64);
        }
    }
    let ratio = onward / power;
    // About 100,000 onward steps of equal energy: binomial noise near 0.3 %.
    assert!((ratio - 0.6).abs() < 0.012, "Φ_Ω / Φ = {ratio}");
}

#[test]
fn a_balanced_cut_follows_edits_with_interleaved_balancing_updates() {
    // Two sealed rooms, a lamp in each. The cut's budget is shared: when the first room's
    // floor goes dark, its VPLs carry less light on (Φ_Ω), its cells weigh less (B) and cede
    // cells to the second room, whose VPLs did not change: balancing updates (Merge there,
    // Refine here), interleaved by eq. (2) with the first room's partial rebuilds (only paths
    // that met the floor changed).
    let mut qs = unit_box_faces();
    qs.extend(unit_box_faces().iter().map(|q| q.map(|p| p + v(2.0, 0.0, 0.0))));
    let mut scene = quads(&qs, 0.6);
    let mut floor = scene.materials[0].clone();
    floor.name = "floor a".into();
    scene.materials.push(floor);
    scene.triangles[0].material = 1;
    scene.triangles[1].material = 1;
    scene.lights.push(Light::point("a", v(0.5, 0.7, 0.4), Vec3::splat(1.0)));
    scene.lights.push(Light::point("b", v(2.5, 0.7, 0.4), Vec3::splat(1.0)));
    let tx = texels(&scene);
    let extent = scene.diagonal();
    // t = 0.9: eq. (2) gives its floor of 0.5 to every validation update whose invalid share is
    // at most 0.9 (the partial rebuilds here), so balancing alternates with them from the
    // second update (the first is validation).
    let p = BakerParams { cells: Some(48), interleave_t: 0.9, ..params() };
    let mut a = Baker::new(scene.clone(), tx.clone(), p.clone()).unwrap();
    a.converge();
    a.apply(&Edit::Albedo { material: 1, albedo: Vec3::splat(0.02) }).unwrap();
    let mut kinds = Vec::new();
    let mut k = 0;
    loop {
        if k % 3 == 0 {
            let (d, i) = a.lightmap();
            let (rd, ri) = a.recomputed();
            let scale = mean_length(&rd) + mean_length(&ri);
            let worst = d.iter().zip(&rd).chain(i.iter().zip(&ri)).map(|(x, y)| (*x - *y).length() as f64);
            let worst = worst.fold(0.0, f64::max);
            assert!(worst <= 1e-5 * scale, "step {k}: lightmap and its entries differ by {worst}");
            assert!(a.cells_disjoint(), "step {k}");
        }
        match a.step() {
            Some(r) => kinds.push(r.kind),
            None => break,
        }
        k += 1;
    }
    let balance: Vec<usize> =
        kinds.iter().enumerate().filter(|(_, x)| **x == UpdateKind::Balance).map(|(i, _)| i).collect();
    let validation =
        |x: &UpdateKind| matches!(x, UpdateKind::Rebuild | UpdateKind::Delta | UpdateKind::Refresh);
    let last_validation = kinds.iter().rposition(validation).unwrap();
    assert!(!balance.is_empty(), "a dark floor re-balances the cut: {kinds:?}");
    assert!(balance[0] < last_validation, "balancing interleaved with validation (eq. 2): {kinds:?}");
    // Converged, it is a fresh bake of the edited level: same balanced cut, same lightmap.
    let mut final_scene = a.level().current().scene.as_ref().clone();
    final_scene.lights = a.level().current().lights.iter().map(|l| l.light.clone()).collect();
    let mut b = Baker::with_frame(final_scene, tx, p, a.frame(), extent).unwrap();
    b.converge();
    assert_eq!(a.counts(), b.counts(), "cells and virtual lights");
    let (ta, tb) = (total(&a), total(&b));
    let mean = mean_length(&tb);
    let worst = ta.iter().zip(&tb).map(|(x, y)| (*x - *y).length() as f64).fold(0.0, f64::max);
    assert!(worst <= 1e-4 * mean, "incremental and fresh differ by {worst} at worst (mean {mean})");
}

#[test]
fn the_editor_picks_drags_and_moves_objects_and_lights() {
    use prm_precompute::incremental::editor::{drag_plane, move_edit, on_plane, picks, Pick};
    let scene = room();
    let mut level = Level::new(scene.clone(), texels(&scene));
    let names = vec![Some("room".to_string()), Some("block".to_string())];
    let ps = picks(level.current(), &names);
    assert_eq!(ps.len(), 3, "two nodes and a light: {ps:?}");
    assert_eq!((ps[0].name(), ps[1].name(), ps[2].name()), ("room", "block", "light 'lamp'"));
    assert!((ps[1].at() - v(0.425, 0.15, 0.475)).length() < 1e-6, "the block's box centre");
    assert!((ps[2].at() - v(0.3, 0.8, 0.7)).length() < 1e-6);
    // A camera looking down 45 degrees drags on the floor plane; one looking level, on the
    // upright plane facing it.
    let down = v(1.0, -1.0, 0.0).normalize();
    assert_eq!(drag_plane(down), Vec3::Y);
    assert!((drag_plane(v(0.0, -0.2, 1.0)) - Vec3::Z).length() < 1e-6);
    // A mouse ray from above, 45 degrees down, meets the block's floor plane (y = 0.15) where
    // it should.
    let block_at = ps[1].at();
    let hit = on_plane(v(0.0, 1.15, 0.5), down, block_at, Vec3::Y).unwrap();
    assert!((hit - v(1.0, 0.15, 0.5)).length() < 1e-5, "{hit}");
    assert_eq!(on_plane(v(0.0, 1.0, 0.0), v(1.0, 0.0, 0.0), block_at, Vec3::Y), None, "along the plane");
    assert_eq!(on_plane(v(0.0, 1.0, 0.0), v(0.0, 1.0, 0.0), block_at, Vec3::Y), None, "the plane is behind");
    // Moving a pick moves it by exactly that.
    let by = v(0.1, 0.0, -0.05);
    for k in [1usize, 2] {
        let before = picks(level.current(), &names)[k].clone();
        let e = move_edit(level.current(), &before, by).unwrap();
        level.apply(&e).unwrap();
        let after = picks(level.current(), &names)[k].clone();
        assert!((after.at() - before.at() - by).length() < 1e-5, "{before:?} -> {after:?}");
    }
    // Bad moves are refused.
    let block = picks(level.current(), &names)[1].clone();
    assert!(move_edit(level.current(), &block, v(f32::NAN, 0.0, 0.0)).is_err());
    let ghost = Pick::Light { id: 9, name: "ghost".into(), position: Vec3::ZERO };
    assert_eq!(move_edit(level.current(), &ghost, by), Err(EditError::UnknownLight(9)));
}

#[test]
fn an_emissive_panel_s_light_moves_with_it() {
    // A closed room lit only by an emissive ceiling panel (node 1): its polygon lights
    // (`Scene::emissive_lights`) are the baker's lights. Moving the panel moves them, and the
    // lightmap converges to a fresh bake of the moved level with its own emissive lights.
    let mut qs = unit_box_faces();
    qs.push(facing([v(0.3, 0.95, 0.3), v(0.5, 0.95, 0.3), v(0.5, 0.95, 0.5), v(0.3, 0.95, 0.5)], -Vec3::Y));
    let mut scene = quads(&qs, 0.6);
    let mut glow = scene.materials[0].clone();
    glow.name = "glow".into();
    glow.emissive = Vec3::new(4.0, 3.5, 3.0);
    scene.materials.push(glow);
    for t in 12..14 {
        scene.triangles[t].node = 1;
        scene.triangles[t].material = 1;
    }
    scene.lights = scene.emissive_lights();
    assert_eq!(scene.lights.len(), 1, "the panel's two triangles merged into one polygon light");
    let tx = texels(&scene);
    let extent = scene.diagonal();
    let mut a = Baker::new(scene.clone(), tx.clone(), params()).unwrap();
    a.converge();
    let r = a.apply(&Edit::Transform { node: 1, matrix: translate(0.3, 0.2) }).unwrap();
    assert_eq!(r.changes.lights, vec![0], "the panel's light moved");
    a.converge();
    let mut moved = a.level().current().scene.as_ref().clone();
    moved.lights = moved.emissive_lights();
    let now: Vec<Light> = a.level().current().lights.iter().map(|l| l.light.clone()).collect();
    assert_eq!(now, moved.lights, "the lights are the moved panel's, exactly");
    let mut b = Baker::with_frame(moved.clone(), tx.clone(), params(), a.frame(), extent).unwrap();
    b.converge();
    let (ta, tb) = (total(&a), total(&b));
    let mean = mean_length(&tb);
    let worst = ta.iter().zip(&tb).map(|(x, y)| (*x - *y).length() as f64).fold(0.0, f64::max);
    assert!(mean > 0.1, "the room is lit ({mean})");
    assert!(worst <= 1e-4 * mean, "incremental and fresh differ by {worst} at worst (mean {mean})");

    // The editor does not offer the panel's lights (they go with the panel), and a light
    // recoloured by hand keeps its colour when the panel moves on.
    use prm_precompute::incremental::editor::picks;
    let ps = picks(a.level().current(), &[]);
    assert_eq!(ps.len(), 2, "the room and the panel, no light: {ps:?}");
    let mut level = Level::new(scene.clone(), tx);
    let mut brighter = scene.lights[0].clone();
    brighter.intensity *= 2.0;
    level.apply(&Edit::SetLight { id: 0, light: brighter }).unwrap();
    level.apply(&Edit::Transform { node: 1, matrix: translate(0.3, 0.2) }).unwrap();
    let now = &level.current().lights;
    let ratio = now[0].light.intensity / moved.lights[0].intensity;
    assert!((ratio - Vec3::splat(2.0)).abs().max_element() < 1e-5, "{ratio}");
    assert_eq!(now[0].light.aperture, moved.lights[0].aperture, "at the panel's new place");
}

/// A glowing strip of 40 quads, far from the origin, turned and moved twice: its one merged
/// light follows the node each time, exactly (its corners the transformed corners, however a
/// merge of the moved triangles would round its straight corners), and the editor never
/// offers it as a light of its own.
#[test]
fn a_merged_emissive_light_follows_its_node_through_turns_far_from_the_origin() {
    use prm_precompute::incremental::editor::picks;
    let far = v(3000.0, 0.0, -2000.0);
    let mut qs: Vec<[Vec3; 4]> = unit_box_faces().iter().map(|q| q.map(|c| c + far)).collect();
    for i in 0..40 {
        let (x0, x1) = (0.1 + 0.02 * i as f32, 0.12 + 0.02 * i as f32);
        qs.push(facing(
            [v(x0, 0.9, 0.45), v(x1, 0.9, 0.45), v(x1, 0.9, 0.55), v(x0, 0.9, 0.55)].map(|c| c + far),
            -Vec3::Y,
        ));
    }
    let mut scene = quads(&qs, 0.5);
    let mut glow = scene.materials[0].clone();
    glow.emissive = Vec3::splat(3.0);
    scene.materials.push(glow);
    // The strip's quads do not share vertices (`quads` gives each its own): edges match by
    // position.
    for t in 12..scene.triangles.len() {
        scene.triangles[t].node = 1;
        scene.triangles[t].material = 1;
    }
    scene.lights = scene.emissive_lights();
    assert_eq!(scene.lights.len(), 1, "80 triangles, one strip");
    let mut level = Level::new(scene.clone(), texels(&scene));
    let centre = far + v(0.5, 0.9, 0.5);
    let turn = Mat4::from_translation(centre) * Mat4::from_rotation_y(0.3) * Mat4::from_translation(-centre);
    for matrix in [turn, Mat4::from_translation(v(0.05, -0.1, 0.03)) * turn] {
        let before = level.current().lights[0].light.clone();
        level.apply(&Edit::Transform { node: 1, matrix }).unwrap();
        let now = &level.current().lights[0].light;
        let (prm::light::Aperture::Polygon { corners: a }, prm::light::Aperture::Polygon { corners: b }) =
            (&before.aperture, &now.aperture)
        else {
            panic!("a polygon light");
        };
        let moved: Vec<Vec3> = a.iter().map(|c| matrix.transform_point3(*c)).collect();
        assert_eq!(&moved[..], &b[..], "the light's corners, moved with the strip");
        // Its radiance kept; its area moves with the corners' rounding 3 km out (f32 steps of
        // 2.4e-4 m on a 0.1 m wide strip).
        let change = now.flux().x / before.flux().x - 1.0;
        assert!(change.abs() < 1e-2, "flux changed by {change}");
        let offered = picks(level.current(), &[]);
        assert!(
            offered.iter().all(|p| !matches!(p, prm_precompute::incremental::editor::Pick::Light { .. })),
            "{offered:?}"
        );
    }
}

#[test]
fn the_editor_moves_a_polygon_light_whole() {
    use prm::light::Aperture;
    use prm_precompute::incremental::editor::{move_edit, picks};
    let mut scene = room();
    let panel = [v(0.4, 0.9, 0.4), v(0.6, 0.9, 0.4), v(0.6, 0.9, 0.6), v(0.4, 0.9, 0.6)];
    scene.lights = vec![Light::polygon("panel", &facing(panel, -Vec3::Y), Vec3::splat(2.0))];
    let mut level = Level::new(scene.clone(), texels(&scene));
    let light = picks(level.current(), &[]).pop().unwrap();
    let by = v(0.1, -0.2, 0.05);
    level.apply(&move_edit(level.current(), &light, by).unwrap()).unwrap();
    let moved = &level.current().lights[0].light;
    let (Aperture::Polygon { corners: a }, Aperture::Polygon { corners: b }) =
        (&scene.lights[0].aperture, &moved.aperture)
    else {
        panic!("a polygon light")
    };
    for (p, q) in a.iter().zip(b.iter()) {
        assert!((*q - *p - by).length() < 1e-6, "corner {p} -> {q}");
    }
    assert!((moved.position - scene.lights[0].position - by).length() < 1e-6);
    assert_eq!(moved.intensity, scene.lights[0].intensity);
}
