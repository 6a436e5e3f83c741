//! PRM runtime (wgpu): per-frame indirect lightmaps from a precomputed radiance map.
//!
//! Not built yet: it arrives with the runtime issue (shadow-mapped entry weights, top-K panes,
//! compose, shading, and its CPU twin). The crate exists now so the workspace has its final
//! shape and a game's dependency on `prm-runtime` pulls in only the core library.
