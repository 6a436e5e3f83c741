//! The incremental many-light baker (paper 001, DESIGN.md §6): a level designer's edits (move
//! an object, recolour a material, add, move, recolour or remove a light) update a lightmap
//! that is always a complete solution, most urgent change first.
//!
//! - [`level`]: immutable level versions and the edits between them;
//! - [`paths`]: light paths kept with their VPLs, validated by tracing again;
//! - [`clusters`]: the VPL octree's cut and each cell's polygon and disk lights;
//! - [`baker`]: baked cells, invalidation, prioritised atomic updates;
//! - [`editor`]: picks, drag planes and move edits for an interactive editor.

pub mod baker;
pub mod clusters;
pub mod diff;
pub mod editor;
pub mod level;
pub mod paths;

pub use baker::{Baker, BakerParams, CellKey, EditReport, Energy, Frame, StepReport, UpdateKind};
pub use level::{Aabb, Changes, Edit, EditError, Level, LightSlot, Version};
