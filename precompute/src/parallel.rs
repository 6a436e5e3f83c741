//! The one parallel loop over lightmap texels that every baker runs (precompute transport,
//! reference bake, ground truth): chunks on rayon's pool, a cancel flag checked per chunk, a
//! progress callback with the count done. Results come back in texel order, so the output does
//! not depend on the thread count (each texel seeds its own random stream from its index).

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use prm::Texel;
use rayon::prelude::*;

/// A long computation was stopped by its cancel flag before the end; it produced nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("stopped before the end")]
pub struct Cancelled;

/// How a long computation reports and is stopped: `progress(done)` after each chunk (texels
/// done so far, from any thread), `cancel` polled before each chunk.
#[derive(Clone, Copy)]
pub struct Control<'a> {
    pub progress: &'a (dyn Fn(usize) + Sync),
    pub cancel: &'a AtomicBool,
}

impl Control<'static> {
    /// No progress reports, never cancelled: for callers that just want the result.
    pub fn none() -> Self {
        static NEVER: AtomicBool = AtomicBool::new(false);
        fn ignore(_: usize) {}
        Control { progress: &ignore, cancel: &NEVER }
    }
}

impl Control<'_> {
    /// `Err(Cancelled)` once the cancel flag is set.
    pub fn check(&self) -> Result<(), Cancelled> {
        stop_if(self.cancel)
    }
}

/// `Err(Cancelled)` once `cancel` is set: the check between phases of a long computation.
pub fn stop_if(cancel: &AtomicBool) -> Result<(), Cancelled> {
    if cancel.load(Ordering::Relaxed) {
        Err(Cancelled)
    } else {
        Ok(())
    }
}

/// Texels per chunk: often enough progress and cancel checks, rare enough atomics.
const CHUNK: usize = 64;

/// `f(scratch, texel)` for every texel in parallel, in texel order. `init` makes one scratch
/// state per rayon job (reused across the texels of its chunks, so `f` must leave it clean).
pub fn par_texels<S, T: Send>(
    texels: &[Texel],
    control: Control,
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, &Texel) -> T + Sync + Send,
) -> Result<Vec<T>, Cancelled> {
    let done = AtomicUsize::new(0);
    let chunks: Vec<Option<Vec<T>>> = texels
        .par_chunks(CHUNK)
        .map_init(init, |scratch, chunk| {
            control.check().ok()?;
            let out: Vec<T> = chunk.iter().map(|t| f(scratch, t)).collect();
            (control.progress)(done.fetch_add(chunk.len(), Ordering::Relaxed) + chunk.len());
            Some(out)
        })
        .collect();
    let mut out = Vec::with_capacity(texels.len());
    for c in chunks {
        out.extend(c.ok_or(Cancelled)?);
    }
    Ok(out)
}
