//! Peak memory: handing freed memory back to the system between the precompute's phases.
//!
//! The precompute's memory target is its peak resident size (`prm precompute --json`'s
//! `peak_memory_bytes`, issue 13: at most twice the `.prm` it writes). glibc's allocator keeps
//! memory a phase freed (the near links' and far field's working sets, a band's walks) for
//! reuse, returning to the system only what lies at the top of its heap; the next phase's
//! allocations then land elsewhere, and the resident size holds both. Measured on the 4 x 4
//! halls (198 MB `.prm`): 268 MB resident when the walks start, of which about 45 MB was
//! freed memory kept, and a peak of 446 MB (2.25x the file) while the pane tiles were
//! assembled at the end. With [`release_freed`] before the walks, after each band and before
//! the assembly (and the walks' tables dropped before it, `precompute::finish`): 373 MB
//! (1.88x), the same bytes; 24 calls cost 88 ms of the 41 s bake. Elsewhere (another C
//! library, another OS) it does nothing.

/// Return the memory the allocator holds free to the system (glibc's `malloc_trim`; a no-op
/// on other platforms). Costs a walk over the heap's free lists: call it between phases, not
/// per item.
pub fn release_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free pages of glibc's own heap; it takes no pointers
    // and is safe to call at any time from any thread.
    unsafe {
        libc::malloc_trim(0);
    }
}
