//! Mutation fuzzing of everything that reads user files: the `.prm` loader, the glTF loader
//! and the rig parser. Each target starts from a valid file and applies random mutations (bit
//! flips, byte overwrites with boundary values, deletions, insertions, duplications,
//! truncations; for `.prm` also header-number edits and a recomputed checksum, so mutations
//! reach past the checksum). Every mutated file must load or be refused with an error: never a
//! panic, never a single allocation over 256 MiB, and never more than `MAX_TOTAL` bytes
//! allocated in one load (a deterministic stand-in for a time limit: a loader that trusts a
//! length field, or loops on one, allocates far more than the file's size).
//!
//! Budget: a fixed number of mutations per target, `PRM_FUZZ_ITERATIONS` (default
//! [`ITERATIONS`]; raise it to soak), all of which must run; the seed is fixed per target
//! (`PRM_FUZZ_SEED` changes it), so a failure reproduces. cargo-fuzz needs a nightly compiler,
//! which this project does not use.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// Records, for the thread being "watched", the largest single allocation and the total bytes
/// allocated (a reallocation counts its new size). Per thread: the tests fuzz in parallel.
struct Watch;
thread_local! {
    static WATCHED: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    static TOTAL: Cell<usize> = const { Cell::new(0) };
}
fn record(size: usize) {
    if WATCHED.with(|w| w.get()) {
        LARGEST.with(|l| l.set(l.get().max(size)));
        TOTAL.with(|t| t.set(t.get().saturating_add(size)));
    }
}
unsafe impl GlobalAlloc for Watch {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        record(l.size());
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        record(new);
        unsafe { System.realloc(p, l, new) }
    }
}
#[global_allocator]
static GLOBAL: Watch = Watch;

const MAX_ALLOC: usize = 256 << 20;
/// Total bytes one load may allocate. The valid files (a few KB to 270 KB) and every mutation
/// seen at the default budget allocate under 0.1 MiB per load, so 16 MiB is 160x headroom, and
/// still far below what a loader trusting a corrupt count (1 << 30, u32::MAX) would allocate.
const MAX_TOTAL: usize = 16 << 20;
/// Mutations per target: ~0.3 ms each here, so the six targets take a few seconds in the dev
/// profile on 2 cores.
const ITERATIONS: usize = 10_000;

fn env_or<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d)
}

fn mutate(rng: &mut Pcg64, mut b: Vec<u8>) -> Vec<u8> {
    let rounds = rng.random_range(1..=4);
    for _ in 0..rounds {
        let n = b.len();
        let at = if n == 0 { 0 } else { rng.random_range(0..n) };
        match rng.random_range(0..7) {
            0 if n > 0 => b[at] ^= 1 << rng.random_range(0..8),
            1 if n > 0 => b[at] = [0u8, 0xff, 0x7f, 0x80, b'9', b'-', b'e'][rng.random_range(0..7)],
            2 if n >= 4 => {
                let at = at.min(n - 4);
                let v: u32 = [0, 1, u32::MAX, u32::MAX / 2, 0x7f80_0000, 0xffc0_0000, 65536, 1 << 30]
                    [rng.random_range(0..8)];
                b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            3 if n > 0 => {
                let len = rng.random_range(1..=16.min(n - at));
                b.drain(at..at + len);
            }
            4 => {
                let len = rng.random_range(1..=16);
                let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
                b.splice(at..at, bytes);
            }
            5 if n > 0 => {
                let len = rng.random_range(1..=64.min(n - at));
                let chunk = b[at..at + len].to_vec();
                let to = rng.random_range(0..=n);
                b.splice(to..to, chunk);
            }
            _ => b.truncate(at),
        }
    }
    b
}

/// Runs `load` on exactly the configured number of mutations of `valid`; returns
/// (mutations, accepted).
fn fuzz(
    name: &str,
    valid: &[u8],
    mut mutator: impl FnMut(&mut Pcg64, &[u8]) -> Vec<u8>,
    load: impl Fn(&[u8]) -> bool,
) -> (usize, usize) {
    let iterations: usize = env_or("PRM_FUZZ_ITERATIONS", ITERATIONS);
    let seed: u64 = env_or("PRM_FUZZ_SEED", 1);
    // Each target its own stream, from a hash of its whole name.
    let mut rng =
        Pcg64::seed_from_u64(seed ^ prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, name.as_bytes()));
    assert!(load(valid), "{name}: the valid starting file does not load");
    let (mut n, mut ok, mut most) = (0, 0, 0);
    for _ in 0..iterations {
        let m = mutator(&mut rng, valid);
        LARGEST.with(|l| l.set(0));
        TOTAL.with(|t| t.set(0));
        WATCHED.with(|w| w.set(true));
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load(&m)));
        WATCHED.with(|w| w.set(false));
        let dump = || {
            let p = std::env::temp_dir().join(format!("prm-fuzz-{name}-{n}.bin"));
            let _ = std::fs::write(&p, &m);
            p.display().to_string()
        };
        match r {
            Ok(accepted) => ok += accepted as usize,
            Err(_) => panic!("{name}: mutation {n} panicked (input saved to {})", dump()),
        }
        let (largest, total) = (LARGEST.with(Cell::get), TOTAL.with(Cell::get));
        assert!(
            largest <= MAX_ALLOC,
            "{name}: mutation {n} allocated {largest} bytes at once (input saved to {})",
            dump()
        );
        assert!(
            total <= MAX_TOTAL,
            "{name}: mutation {n} allocated {total} bytes in all (input saved to {})",
            dump()
        );
        most = most.max(total);
        n += 1;
    }
    println!(
        "{name}: {n} mutations, {ok} loaded, {} refused with an error; at most {most} bytes allocated \
        in one load",
        n - ok
    );
    (n, ok)
}

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// The checksum the loader expects: FNV-1a 64 of everything before the last 8 bytes.
fn fix_checksum(mut b: Vec<u8>) -> Vec<u8> {
    if b.len() >= 24 {
        let n = b.len() - 8;
        let h = prm::fingerprint::fnv1a(prm::fingerprint::FNV_START, &b[..n]);
        b[n..].copy_from_slice(&h.to_le_bytes());
    }
    b
}

/// Replaces one number in the JSON header with a boundary value, keeping the file well framed.
fn mutate_header(rng: &mut Pcg64, b: &[u8]) -> Vec<u8> {
    let len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&b[16..16 + len]).unwrap();
    let keys: Vec<String> =
        header.as_object().unwrap().iter().filter(|(_, v)| v.is_number()).map(|(k, _)| k.clone()).collect();
    let key = &keys[rng.random_range(0..keys.len())];
    let v: serde_json::Value = [0u64, 1, 7, 255, 65536, 65537, u32::MAX as u64, 1 << 40]
        .map(serde_json::Value::from)[rng.random_range(0..8)]
    .clone();
    header[key] = v;
    let text = serde_json::to_vec(&header).unwrap();
    let mut out = b[..12].to_vec();
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&b[16 + len..]);
    fix_checksum(out)
}

#[test]
fn mutated_prm_files_load_or_are_refused() {
    let scene = prm::gltf_load::load_scene(root().join("assets/cornell.glb"), &Default::default()).unwrap();
    let bvh = prm::Bvh::build(&scene);
    let p = prm_precompute::precompute::PrecomputeParams {
        entries: 128,
        paths: 4,
        clusters: 12,
        atlas: prm::density::Atlas::single(24),
        tile_size: 8,
        ..Default::default()
    };
    let (map, _) =
        prm_precompute::precompute::precompute(&scene, &bvh, &p, &|_, _, _| {}, &AtomicBool::new(false))
            .unwrap();
    let valid = map.to_bytes();
    let path = Path::new("fuzz.prm");
    let load = |b: &[u8]| prm::prm_file::Prm::from_bytes(path, b).is_ok();
    // Raw mutations: nearly all stop at the checksum, which is the point of having one.
    fuzz("prm-raw", &valid, |r, v| mutate(r, v.to_vec()), load);
    // Mutations with a valid checksum reach every section check.
    let (_, ok) = fuzz("prm-checksummed", &valid, |r, v| fix_checksum(mutate(r, v.to_vec())), load);
    // Header numbers at boundary values: most are refused (counts that disagree with the
    // sections, implausible atlases), some are harmless (statistics, provenance).
    let (n, header_ok) = fuzz("prm-header", &valid, mutate_header, load);
    assert!(header_ok > 0 && header_ok < n, "{header_ok} of {n} header mutations loaded");
    // Some checksummed mutations (inside pane data, say) are still valid files: the loader
    // must not refuse everything either.
    assert!(ok > 0, "no checksummed mutation loaded: the loader refuses valid files?");
}

#[test]
fn mutated_gltf_files_load_or_are_refused() {
    let valid = std::fs::read(root().join("assets/cornell.glb")).unwrap();
    // The gltf crate panics on some malformed files; `load_scene` catches those and reports
    // the file as malformed. A panic anywhere else (our loader included) is recorded here,
    // since `load_scene`'s own catch would otherwise hide it, and fails the mutation.
    static OURS: AtomicBool = AtomicBool::new(false);
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let in_gltf = info.location().is_some_and(|l| {
            l.file().contains("gltf-") || l.file().contains("gltf_json") || l.file().contains("/gltf/")
        });
        if !in_gltf {
            OURS.store(true, Ordering::SeqCst);
            default(info)
        }
    }));
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("fuzz.glb");
    let load = |b: &[u8]| {
        std::fs::write(&file, b).unwrap();
        let ok = prm::gltf_load::load_scene(&file, &Default::default()).is_ok();
        assert!(!OURS.swap(false, Ordering::SeqCst), "a panic outside the gltf crate while loading");
        ok
    };
    fuzz("gltf", &valid, |r, v| mutate(r, v.to_vec()), load);
    // The same mutations confined to the JSON chunk (GLB: 12-byte header, then JSON chunk
    // length at 12), keeping the container's lengths right.
    let json_len = u32::from_le_bytes(valid[12..16].try_into().unwrap()) as usize;
    let (json, rest) = (valid[20..20 + json_len].to_vec(), valid[20 + json_len..].to_vec());
    let glb = |j: Vec<u8>| {
        let mut j = j;
        while j.len() % 4 != 0 {
            j.push(b' ');
        }
        let mut out = b"glTF".to_vec();
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&((12 + 8 + j.len() + rest.len()) as u32).to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&j);
        out.extend_from_slice(&rest);
        out
    };
    fuzz("gltf-json", &glb(json.clone()), |r, _| glb(mutate(r, json.clone())), load);
}

#[test]
fn mutated_rigs_load_or_are_refused() {
    let scene = prm::gltf_load::load_scene(root().join("assets/chamber.glb"), &Default::default()).unwrap();
    let valid = std::fs::read(root().join("assets/chamber_rig.json")).unwrap();
    let path = Path::new("fuzz.json");
    let load = |b: &[u8]| match prm::rig::Rig::parse(path, &String::from_utf8_lossy(b), &scene.lights) {
        Ok(rig) => {
            // A rig that parses must also produce finite lights at any time.
            for f in 0..4 {
                for l in rig.frame(f, 4) {
                    assert!(
                        l.intensity.is_finite() && l.intensity.min_element() >= 0.0,
                        "rig accepted a bad light {l:?}"
                    );
                }
            }
            true
        }
        Err(_) => false,
    };
    fuzz("rig", &valid, |r, v| mutate(r, v.to_vec()), load);
}
