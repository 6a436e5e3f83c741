//! The CPU twin of the runtime's lightmap (DESIGN.md §5 steps 2-4), with rayon.
//!
//! 1. Entry irradiance `E_j = sum_lights I(w) V cos / r²` (or E V cos for directional lights).
//!    **Visibility is ray-traced** (one shadow ray per entry and light, offset as everywhere
//!    else), not shadow-mapped: the twin is the exact answer the GPU's shadow maps approximate.
//! 2. Cluster weights: the mean irradiance of each cluster's members, balanced against the near
//!    field's energy ([`cluster_weights`]), then lifted by what the near field puts on each
//!    cluster ([`lift_weights`]).
//! 3. Selection: the K clusters with the largest `luminance(w_c) x energy_c`; clusters with zero
//!    weight are never selected. Ties go to the lower index.
//! 4. Compose: `sum w_c pane_c` over the selected clusters' stored tiles only, plus (with
//!    `residual`, the default) each group's pane weighted by its left-out clusters' light
//!    ([`residual_weights`]). When the lights have not changed since the last frame, nothing
//!    is recomposed (`CpuTwin::composes` counts the composes that did happen).
//!
//! Steps 2-4 ([`cluster_weights`], [`select_top_k`], [`compose_selected`]) are plain functions
//! of the map, always built; step 1 and `CpuTwin` frames need the scene's BVH and rayon
//! and come with the `cpu-twin` feature.

mod budget;
mod compose;
pub mod concentrate;
#[cfg(feature = "cpu-twin")]
pub mod radiosity;
pub mod rooms;
#[cfg(feature = "cpu-twin")]
mod twin;

pub use budget::{
    blend, compose_local, stored_tile_energy, tiles_around, vertex_weights, LocalCompose, TileBudget,
    TileRecord,
};
pub use compose::{
    add_and_clamp, add_pane, cell_means, cluster_weights, cluster_weights_with, compose, compose_selected,
    echo_bounce, echo_input, far_field, far_sources, far_threshold, lands_apart, lift_weights, lightmap,
    link_field, near_deviation, near_field, pane_weights, pane_weights_with, point_cells, residual_weights,
    select_top_k, sight_eye, sight_share, sighted, tint_of, up_close, FarSource, LightSight, NearTables,
    UpClose, CLOSE_SIGHTS, CONE_REACH, ECHO_BOUNCES, EYE_BACK, FAR_SOURCES, FAR_SOURCE_SCALE, LANDING_APART,
    LANDING_TURN, POWER_KEPT_LIMITS,
};
pub use concentrate::LinkLight;
#[cfg(feature = "cpu-twin")]
pub use twin::{cell_lights, entry_irradiance, entry_irradiance_from, light_sight, link_light, CpuTwin};
