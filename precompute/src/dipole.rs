//! The clusters' dipole frames (`prm::prm_file::Dipole`): where each cluster's first-order
//! panes are measured from and along which axes.
//!
//! A light that is uneven over a cluster is fitted, by least squares over its cells (weights:
//! cell areas), as `w + g . (y - o)`, o the cells' area-weighted centroid. With `M = sum_j a_j
//! (x_j - o)(x_j - o)^T` (x_j: cell centroid, a_j: cell area) the fit gives `w` = the cluster's
//! mean irradiance, the weight its pane already gets, and `g = M^-1 sum_j P_j (x_j - o)` (P_j:
//! the cell's power). In M's eigenbasis (v_k, lambda_k) that is `g . v_k = (1 / lambda_k) sum_j
//! P_j v_k . (x_j - o)`: the weight of the pane that answers irradiance `v_k . (y - o)`. A flat
//! cluster has no spread along its normal (lambda 0): that axis, and any whose spread is under
//! [`MIN_SPREAD`] of the largest, is left out, and clusters of fewer than [`MIN_MEMBERS`] cells
//! have no dipole at all (too few points to fit a slope to).

use glam::{Mat3, Vec3};
use prm::prm_file::{Cells, Dipole, DipoleAxis, Entry};

use crate::transport::Frame;

/// An axis is kept when its spread (eigenvalue) is at least this share of the largest.
pub const MIN_SPREAD: f32 = 1e-2;
/// Clusters with fewer members have no dipole.
pub const MIN_MEMBERS: usize = 4;

/// Each cluster's frame for the transport and its dipole record (tile counts and energies left
/// at zero, for the tiling to fill in).
pub fn frames(entries: &[Entry], cells: &Cells, members: &[Vec<u32>]) -> (Vec<Frame>, Vec<Dipole>) {
    members
        .iter()
        .map(|m| {
            let points: Vec<(Vec3, f32)> = m
                .iter()
                .map(|&j| {
                    let j = j as usize;
                    (cells.centroid(j).unwrap_or(entries[j].position), cells.area(j))
                })
                .filter(|(_, a)| *a > 0.0)
                .collect();
            let area: f32 = points.iter().map(|p| p.1).sum();
            if points.len() < MIN_MEMBERS || !(area > 0.0) {
                return (Frame::default(), Dipole::default());
            }
            let origin = points.iter().fold(Vec3::ZERO, |s, (x, a)| s + *x * *a) / area;
            let mut spread = Mat3::ZERO;
            for (x, a) in &points {
                let d = *x - origin;
                spread += Mat3::from_cols(d * d.x, d * d.y, d * d.z) * *a;
            }
            let (values, vectors) = symmetric_eigen(spread);
            let top = values[0];
            let mut frame = Frame { origin, axes: [Vec3::ZERO; 3] };
            let mut dipole = Dipole { origin, ..Default::default() };
            for k in 0..3 {
                if top > 0.0 && values[k] >= MIN_SPREAD * top {
                    frame.axes[k] = vectors[k];
                    dipole.axes[k] = DipoleAxis {
                        direction: vectors[k],
                        inv_lambda: 1.0 / values[k],
                        ..Default::default()
                    };
                }
            }
            (frame, dipole)
        })
        .unzip()
}

/// Eigenvalues (descending) and unit eigenvectors of a symmetric 3 x 3 matrix, by cyclic
/// Jacobi rotations (exact to float precision after a handful of sweeps).
#[allow(clippy::needless_range_loop)] // rows and columns of one rotation, side by side
pub fn symmetric_eigen(m: Mat3) -> ([f32; 3], [Vec3; 3]) {
    let mut a = [[0.0f64; 3]; 3];
    for (i, row) in a.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m.col(j)[i] as f64;
        }
    }
    let mut v = [[1.0f64, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off <= 1e-15 * (a[0][0].abs() + a[1][1].abs() + a[2][2].abs()) || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = order.map(|i| a[i][i] as f32);
    let vectors =
        order.map(|i| Vec3::new(v[0][i] as f32, v[1][i] as f32, v[2][i] as f32).normalize_or_zero());
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_of_a_rotated_diagonal_matrix() {
        let r = Mat3::from_rotation_y(0.7) * Mat3::from_rotation_x(0.3);
        let m = r * Mat3::from_diagonal(Vec3::new(2.0, 5.0, 0.0)) * r.transpose();
        let (values, vectors) = symmetric_eigen(m);
        assert!((values[0] - 5.0).abs() < 1e-5 && (values[1] - 2.0).abs() < 1e-5 && values[2].abs() < 1e-5);
        for k in 0..3 {
            let mv = m * vectors[k];
            assert!(
                (mv - vectors[k] * values[k]).length() < 1e-5,
                "axis {k}: {mv} vs {}",
                vectors[k] * values[k]
            );
        }
        assert!((vectors[0] - r.col(1)).length() < 1e-4 || (vectors[0] + r.col(1)).length() < 1e-4);
    }

    /// A flat 2 x 1 m patch of cells: two in-plane axes, the long one first, none along the
    /// normal, and 1/lambda the inverse of the cells' second moment.
    #[test]
    fn a_flat_cluster_has_two_axes() {
        let mut lists = Vec::new();
        let mut entries = Vec::new();
        for i in 0..8 {
            for k in 0..4 {
                let (x, z) = (i as f32 * 0.25, k as f32 * 0.25);
                let (a, b, c, d) = (
                    Vec3::new(x, 0.0, z),
                    Vec3::new(x, 0.0, z + 0.25),
                    Vec3::new(x + 0.25, 0.0, z + 0.25),
                    Vec3::new(x + 0.25, 0.0, z),
                );
                lists.push(vec![[a, b, c], [a, c, d]]);
                entries.push(Entry {
                    position: (a + c) / 2.0,
                    normal: Vec3::Y,
                    albedo: Vec3::ONE,
                    area: 0.0625,
                    triangle: 0,
                });
            }
        }
        let cells = Cells::from_lists(lists);
        let (frames, dipoles) = frames(&entries, &cells, &[(0..32).collect()]);
        let d = &dipoles[0];
        assert!((d.origin - Vec3::new(1.0, 0.0, 0.5)).length() < 1e-5);
        assert!(d.axes[0].direction.x.abs() > 0.999 && d.axes[1].direction.z.abs() > 0.999);
        assert_eq!(d.axes[2].inv_lambda, 0.0);
        // Along x: 4 cells at each of x = 0.125 .. 1.875, offsets +-0.125 .. +-0.875.
        let lambda: f32 = (0..8).map(|i| 4.0 * 0.0625 * (i as f32 * 0.25 + 0.125 - 1.0).powi(2)).sum();
        assert!((d.axes[0].inv_lambda * lambda - 1.0).abs() < 1e-4);
        assert_eq!(frames[0].axes[2], Vec3::ZERO);
    }
}
