//! The rooms of a map as the runtime sees them: clusters joined by entries that see each other.
//!
//! [`super::lift_weights`] takes the energy of the near field's later bounces back from the
//! panes in proportion (`lambda`). That light stays in the room where the near field put it,
//! so it is taken back from that room's panes only. Over the whole map, a lamp nearing a wall
//! in one room dimmed every other room by its share: two sealed rooms, a light 10 cm above one
//! floor, and the other room's weights moved by 1 % a frame as it moved; and every atlas tile
//! of the level was composed again each frame (`crate::tile_changes`).
//!
//! The `.prm` does not store the precompute's rooms (`prm::rooms`), but its far field says
//! which entries see each other (`prm::prm_file::Far`), and the far field never joins two
//! rooms. So a room here is a connected set of entries under "sees", widened to whole
//! clusters (a cluster's members are one room: a cluster that took entries of two rooms joins
//! them). A map without a far field is one room.

use prm::prm_file::{Far, Prm};

/// Union-find over `n` items, the smaller root kept (so a set's root is its first item).
struct Sets(Vec<u32>);

impl Sets {
    fn new(n: usize) -> Sets {
        Sets((0..n as u32).collect())
    }

    fn root(&mut self, mut i: u32) -> u32 {
        while self.0[i as usize] != i {
            let up = self.0[self.0[i as usize] as usize];
            self.0[i as usize] = up;
            i = up;
        }
        i
    }

    fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.root(a), self.root(b));
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        self.0[hi as usize] = lo;
    }
}

/// How many rooms a [`cluster_rooms`] map has (at least 1).
pub fn room_count(cluster_room: &[u32]) -> usize {
    cluster_room.iter().max().map_or(1, |&r| r as usize + 1)
}

/// Per cluster, its room, numbered in the order of each room's first cluster (a map of one room:
/// all 0).
pub fn cluster_rooms(prm: &Prm) -> Vec<u32> {
    if prm.far().block_first.is_empty() {
        // No far field: nothing says which entries see each other (and there is no lift).
        return vec![0; prm.clusters().len()];
    }
    let n = prm.entries().len();
    let mut sets = Sets::new(n);
    join_seen(prm.far(), n, &mut sets);
    for cl in prm.clusters() {
        if let Some(&first) = cl.members.first() {
            for &m in &cl.members[1..] {
                sets.join(first, m);
            }
        }
    }
    let mut number = std::collections::HashMap::new();
    prm.clusters()
        .iter()
        .map(|cl| {
            let root = cl.members.first().map_or(u32::MAX, |&m| sets.root(m));
            let next = number.len() as u32;
            *number.entry(root).or_insert(next)
        })
        .collect()
}

/// Joins every two entries the far field says see each other. Each row of bits (entry i's
/// view of a block) is joined bit by bit only where it differs from the row before: where the
/// two rows share a set bit, entries i - 1 and i see a common entry, so joining them joins i to
/// every entry i - 1 sees, and only the bits i - 1 lacks remain.
fn join_seen(far: &Far, n: usize, sets: &mut Sets) {
    let bs = Far::BLOCK;
    for a in 0..Far::blocks(n) {
        let (Some(&start), Some(&end)) = (far.block_first.get(a), far.block_first.get(a + 1)) else {
            return;
        };
        for p in start as usize..end as usize {
            let b = far.pair_block[p] as usize;
            let mut before = 0u32;
            for r in 0..bs.min(n - a * bs) {
                let i = (a * bs + r) as u32;
                let row = far.visible.get(p * bs + r).copied().unwrap_or(0);
                let mut rest = row;
                if row & before != 0 {
                    sets.join(i, i - 1);
                    rest &= !before;
                }
                while rest != 0 {
                    let c = rest.trailing_zeros() as usize;
                    rest &= rest - 1;
                    if b * bs + c < n {
                        sets.join(i, (b * bs + c) as u32);
                    }
                }
                before = row;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The joins against a brute force over every pair of a random visibility.
    #[test]
    fn rows_joined_by_their_differences_give_the_components_of_every_pair() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for trial in 0..40 {
            let n = rng.random_range(1..200usize);
            let blocks = Far::blocks(n);
            // Sparse symmetric visibility, denser within bands of entries (rooms of a sort).
            let band = rng.random_range(1..60usize);
            let p = rng.random_range(0.0..0.3f64);
            let mut pairs = Vec::new();
            for i in 0..n {
                for j in i + 1..n {
                    let near = i / band == j / band;
                    if rng.random_bool(if near { p } else { p * 0.02 }) {
                        pairs.push((i, j));
                    }
                }
            }
            let sees: std::collections::HashSet<(usize, usize)> =
                pairs.iter().flat_map(|&(i, j)| [(i, j), (j, i)]).collect();
            let bs = Far::BLOCK;
            let (mut block_first, mut pair_block, mut visible) = (Vec::new(), Vec::new(), Vec::new());
            for a in 0..blocks {
                block_first.push(pair_block.len() as u32);
                for b in 0..blocks {
                    let words: Vec<u32> = (0..bs)
                        .map(|r| {
                            (0..bs)
                                .filter(|&c| sees.contains(&(a * bs + r, b * bs + c)))
                                .fold(0u32, |w, c| w | 1 << c)
                        })
                        .collect();
                    if words.iter().any(|&w| w != 0) {
                        pair_block.push(b as u32);
                        visible.extend(words);
                    }
                }
            }
            block_first.push(pair_block.len() as u32);
            let far = Far { block_first, pair_block, visible, ..Default::default() };
            let mut fast = Sets::new(n);
            join_seen(&far, n, &mut fast);
            let mut brute = Sets::new(n);
            for &(i, j) in &pairs {
                brute.join(i as u32, j as u32);
            }
            for i in 0..n as u32 {
                assert_eq!(fast.root(i), brute.root(i), "trial {trial}: entry {i} of {n}");
            }
        }
    }
}
