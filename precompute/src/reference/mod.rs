//! The reference baker (paper 000, DESIGN.md §6): virtual polygon lights for one fixed light
//! setup. Built in stages; today the light models and their evaluation.

pub mod form_factor;
pub mod kdtree;
pub mod polygon;
pub mod vpl;
