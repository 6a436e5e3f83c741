//! PRM offline stages: the precompute (entries, clustering, light transport, pane atlases), the
//! ground-truth path tracer, and the generator of the bundled scenes. The reference baker joins
//! here.

pub mod cells;
pub mod cluster;
pub mod entries;
pub mod far;
pub mod ground_truth;
pub mod incremental;
pub mod memory;
pub mod near;
pub mod panes;
pub mod parallel;
pub mod params;
pub mod precompute;
pub mod reference;
pub mod scenes;
pub mod shard;
pub mod transport;
pub mod update;
pub mod visibility;
