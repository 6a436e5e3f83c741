//! The reference baker (paper 000, DESIGN.md §6): virtual polygon lights for one fixed light
//! setup: photons to VPLs per light and bounce (`vpl`), planes (`planes`), kd-tree clusters
//! (`kdtree`), light polygons (`polygon`), light models (`form_factor`), the bake (`bake`).

pub mod bake;
pub mod form_factor;
pub mod kdtree;
pub mod planes;
pub mod polygon;
pub mod vpl;
