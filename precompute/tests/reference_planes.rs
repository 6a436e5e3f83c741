//! RANSAC plane detection (`reference::planes::detect_planes`) on point sets whose planes are
//! known: the six faces of a box with noise inside it, and two coplanar squares.

use glam::Vec3;
use prm_precompute::reference::planes::{detect_planes, PlaneSegment};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Inlier distance used throughout: 1 % of the box.
const DELTA: f32 = 0.01;
const MIN_SIZE: usize = 30;

/// Points on a jittered grid of spacing `step` over the rectangle `origin + s a + t b`,
/// s, t in [0, 1], moved off the plane by up to 0.3 DELTA and with normals tilted by up to
/// ~3 degrees: a real VPL set is neither exactly planar nor exactly oriented.
fn rect(
    rng: &mut Pcg64Mcg,
    origin: Vec3,
    a: Vec3,
    b: Vec3,
    normal: Vec3,
    step: f32,
    (pos, nrm): (&mut Vec<Vec3>, &mut Vec<Vec3>),
) -> Vec<u32> {
    let (na, nb) = ((a.length() / step) as usize, (b.length() / step) as usize);
    let mut ids = Vec::new();
    for i in 0..=na {
        for j in 0..=nb {
            let s = ((i as f32 + rng.random_range(-0.3..0.3)) / na as f32).clamp(0.0, 1.0);
            let t = ((j as f32 + rng.random_range(-0.3..0.3)) / nb as f32).clamp(0.0, 1.0);
            let off = normal * rng.random_range(-0.3..0.3) * DELTA;
            ids.push(pos.len() as u32);
            pos.push(origin + a * s + b * t + off);
            let tilt = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            nrm.push((normal + (tilt - normal * tilt.dot(normal)) * 0.05).normalize());
        }
    }
    ids
}

/// A 2 x 1 x 1.5 box: its six faces (outward normals) and noise points strictly inside.
/// Returns (positions, normals, per-face point ids and normals, noise ids).
#[allow(clippy::type_complexity)]
fn box_points() -> (Vec<Vec3>, Vec<Vec3>, Vec<(Vec<u32>, Vec3)>, Vec<u32>) {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let (mut pos, mut nrm) = (Vec::new(), Vec::new());
    let size = Vec3::new(2.0, 1.0, 1.5);
    let (x, y, z) = (Vec3::X * size.x, Vec3::Y * size.y, Vec3::Z * size.z);
    let mut faces = Vec::new();
    for (o, a, b, n) in [
        (Vec3::ZERO, x, z, -Vec3::Y),
        (y, x, z, Vec3::Y),
        (Vec3::ZERO, y, z, -Vec3::X),
        (x, y, z, Vec3::X),
        (Vec3::ZERO, x, y, -Vec3::Z),
        (z, x, y, Vec3::Z),
    ] {
        faces.push((rect(&mut rng, o, a, b, n, 0.06, (&mut pos, &mut nrm)), n));
    }
    // Noise at least 0.1 from every face (10 DELTA), so no noise point can be an inlier of a
    // face plane; its normals are random, so it forms no plane of MIN_SIZE points either.
    let mut noise = Vec::new();
    for _ in 0..60 {
        noise.push(pos.len() as u32);
        let u = Vec3::new(rng.random(), rng.random(), rng.random());
        pos.push(Vec3::splat(0.1) + u * (size - Vec3::splat(0.2)));
        let d =
            Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        nrm.push(d.normalize_or(Vec3::Y));
    }
    (pos, nrm, faces, noise)
}

/// Every id of `members` is in exactly one segment or in `rest`, and nothing else is.
fn assert_partition(members: &[u32], segments: &[PlaneSegment], rest: &[u32]) {
    let mut all: Vec<u32> =
        segments.iter().flat_map(|s| s.members.iter().copied()).chain(rest.iter().copied()).collect();
    all.sort_unstable();
    let mut want = members.to_vec();
    want.sort_unstable();
    assert_eq!(all, want, "segments and rest do not partition the input");
    for s in segments {
        assert!(s.members.windows(2).all(|w| w[0] < w[1]), "segment members not ascending");
    }
    assert!(rest.windows(2).all(|w| w[0] < w[1]), "rest not ascending");
}

#[test]
fn a_box_with_noise_gives_its_six_faces() {
    let (pos, nrm, faces, noise) = box_points();
    // Leave every 11th point out of the call: only `members` may appear in the result.
    let members: Vec<u32> = (0..pos.len() as u32).filter(|i| i % 11 != 5).collect();
    let (segments, rest) = detect_planes(&pos, &nrm, &members, DELTA, MIN_SIZE, 7);
    assert_partition(&members, &segments, &rest);
    assert_eq!(segments.len(), 6, "{} segments", segments.len());
    let noise_in: Vec<u32> = noise.iter().copied().filter(|i| members.contains(i)).collect();
    assert_eq!(rest, noise_in, "rest is exactly the noise");
    for (ids, n) in &faces {
        let want: Vec<u32> = ids.iter().copied().filter(|i| members.contains(i)).collect();
        assert!(want.len() >= 150, "fixture: a face has only {} points", want.len());
        let seg = segments
            .iter()
            .find(|s| s.members == want)
            .unwrap_or_else(|| panic!("no segment is exactly the face with normal {n}"));
        // The refit normal is the mean of >= 150 normals tilted by up to ~3 degrees at random:
        // it is within a fraction of a degree; 1 degree (cos 0.99985) is generous.
        assert!(seg.normal.dot(*n) >= 1f32.to_radians().cos(), "normal {} vs {n}", seg.normal);
        // An orthonormal frame.
        for (a, b) in [(seg.u, seg.v), (seg.u, seg.normal), (seg.v, seg.normal)] {
            assert!(a.dot(b).abs() < 1e-5);
        }
        assert!((seg.u.length() - 1.0).abs() < 1e-5 && (seg.v.length() - 1.0).abs() < 1e-5);
        // Every member is an inlier of the final plane: within DELTA (and 10 degrees).
        for &i in &seg.members {
            let d = (pos[i as usize] - seg.origin).dot(seg.normal).abs();
            assert!(d <= DELTA, "point {i} is {d} off its plane");
            assert!(nrm[i as usize].dot(seg.normal) >= 0.985);
        }
    }
    // The same input and seed give the same answer.
    assert_eq!(detect_planes(&pos, &nrm, &members, DELTA, MIN_SIZE, 7), (segments, rest));
}

#[test]
fn two_coplanar_squares_with_a_gap_are_two_segments() {
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    for (gap, pieces) in [(0.5f32, 2usize), (0.0, 1)] {
        let (mut pos, mut nrm) = (Vec::new(), Vec::new());
        let a = rect(&mut rng, Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::Y, 0.05, (&mut pos, &mut nrm));
        let b = rect(
            &mut rng,
            Vec3::new(1.0 + gap, 0.0, 0.0),
            Vec3::X,
            Vec3::Z,
            Vec3::Y,
            0.05,
            (&mut pos, &mut nrm),
        );
        let members: Vec<u32> = (0..pos.len() as u32).collect();
        let (segments, rest) = detect_planes(&pos, &nrm, &members, DELTA, MIN_SIZE, 1);
        assert_partition(&members, &segments, &rest);
        assert!(rest.is_empty(), "gap {gap}: {} points left over", rest.len());
        assert_eq!(segments.len(), pieces, "gap {gap}");
        if pieces == 2 {
            // The gap (0.5) is ten point spacings: each square is one segment, on one plane.
            for want in [&a, &b] {
                assert!(
                    segments.iter().any(|s| &s.members == want),
                    "gap {gap}: a square was split or merged"
                );
            }
            assert_eq!(segments[0].normal, segments[1].normal);
        } else {
            // The control: touching squares are one floor.
            let mut both = [a, b].concat();
            both.sort_unstable();
            assert_eq!(segments[0].members, both);
        }
    }
}
