//! kd-tree clustering of VPLs (paper 000 §5.2): split the bounding box's longest axis near the
//! median, at the point that maximises the gap criterion of the paper's eq. 1,
//! `|p_j - p_{j+1}| (1 - 2 |I_m - j| / n)^rho`, rho = 0.5, so lit areas separated by a shadow
//! split along the shadow instead of through a lit patch. Cells are split until they hold at
//! most `target` points; each leaf remembers its cell's bounds (for clipping polygons).

/// A leaf: indices into the input points and the cell's bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct Leaf<const D: usize> {
    pub members: Vec<u32>,
    pub lo: [f32; D],
    pub hi: [f32; D],
}

/// The paper's weighting exponent.
pub const RHO: f32 = 0.5;

/// Index j (0-based, split between `sorted[j]` and `sorted[j+1]`) maximising the gap criterion over
/// coordinates sorted ascending.
pub fn gap_split(sorted: &[f32]) -> usize {
    let n = sorted.len();
    debug_assert!(n >= 2);
    // The paper's 1-based j and I_m = (n + 1) / 2.
    let im = (n as f32 + 1.0) * 0.5;
    let mut best = (f32::NEG_INFINITY, (n - 1) / 2);
    for j in 0..n - 1 {
        let jj = (j + 1) as f32;
        let w = (1.0 - 2.0 * (im - jj).abs() / n as f32).max(0.0).powf(RHO);
        let score = (sorted[j + 1] - sorted[j]) * w;
        if score > best.0 {
            best = (score, j);
        }
    }
    best.1
}

/// Cluster `points` into leaves of at most `target` points (at least 1).
pub fn cluster<const D: usize>(
    points: &[[f32; D]],
    target: usize,
    lo: [f32; D],
    hi: [f32; D],
) -> Vec<Leaf<D>> {
    let mut out = Vec::new();
    let all: Vec<u32> = (0..points.len() as u32).collect();
    split(points, all, target.max(1), lo, hi, &mut out, 0);
    out
}

fn split<const D: usize>(
    points: &[[f32; D]],
    members: Vec<u32>,
    target: usize,
    lo: [f32; D],
    hi: [f32; D],
    out: &mut Vec<Leaf<D>>,
    depth: u32,
) {
    if members.len() <= target || depth > 60 {
        out.push(Leaf { members, lo, hi });
        return;
    }
    // Longest axis of the members' own bounding box.
    let mut blo = [f32::INFINITY; D];
    let mut bhi = [f32::NEG_INFINITY; D];
    for &m in &members {
        for d in 0..D {
            blo[d] = blo[d].min(points[m as usize][d]);
            bhi[d] = bhi[d].max(points[m as usize][d]);
        }
    }
    let axis = (0..D).max_by(|&a, &b| (bhi[a] - blo[a]).total_cmp(&(bhi[b] - blo[b]))).unwrap_or(0);
    if !(bhi[axis] > blo[axis]) {
        out.push(Leaf { members, lo, hi }); // all points coincide
        return;
    }
    let mut sorted = members;
    sorted.sort_by(|&a, &b| points[a as usize][axis].total_cmp(&points[b as usize][axis]).then(a.cmp(&b)));
    let coords: Vec<f32> = sorted.iter().map(|&m| points[m as usize][axis]).collect();
    let j = gap_split(&coords);
    let at = 0.5 * (coords[j] + coords[j + 1]);
    let right = sorted.split_off(j + 1);
    let (mut lhi, mut rlo) = (hi, lo);
    lhi[axis] = at;
    rlo[axis] = at;
    split(points, sorted, target, lo, lhi, out, depth + 1);
    split(points, right, target, rlo, hi, out, depth + 1);
}
