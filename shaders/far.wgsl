// Far field (runtime/src/far.rs; prm_precompute::far; twin: prm_runtime::cpu::far_sources and
// far_field). sources_main, one workgroup: phi_j = flux_j x deviation_j per entry, the sum of
// their luminances, and the entries whose |phi| luminance is at least sum / FAR_SOURCES,
// ascending, into source_index / source_flux (their number at source_index[FAR_SOURCES]).
// far_main, one invocation per far texel: sum over the sources of
// phi share V cos_x cos_j / (pi r² max(r², size²)), r to the cell's centroid, added to the texel's near_sum slot (written
// when the slot is past the near field's own texels). Structs, bindings, WG_LINEAR,
// WG_FAR_SOURCES, FAR_SOURCES, luminance, far_share: the generated prelude.

const PI: f32 = 3.14159265358979;

var<workgroup> partial: array<f32, WG_FAR_SOURCES>;
var<workgroup> scan: array<u32, WG_FAR_SOURCES>;
var<workgroup> listed: u32;

fn flux_of(j: u32) -> vec3f {
    return far_entries[j].flux * deviation[j].xyz;
}

@compute @workgroup_size(WG_FAR_SOURCES)
fn sources_main(@builtin(local_invocation_index) lid: u32) {
    let n = params.entry_count;
    var s = 0.0;
    for (var j = lid; j < n; j += WG_FAR_SOURCES) {
        s += luminance(abs(flux_of(j)));
    }
    partial[lid] = s;
    if lid == 0u {
        listed = 0u;
    }
    workgroupBarrier();
    for (var stride = WG_FAR_SOURCES / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    let threshold = partial[0] / f32(FAR_SOURCES);
    for (var start = 0u; start < n; start += WG_FAR_SOURCES) {
        let j = start + lid;
        var keep = 0u;
        var phi = vec3f(0.0);
        if j < n {
            phi = flux_of(j);
            let l = luminance(abs(phi));
            if l > 0.0 && l >= threshold {
                keep = 1u;
            }
        }
        scan[lid] = keep;
        workgroupBarrier();
        // Inclusive prefix sum (Hillis-Steele).
        for (var off = 1u; off < WG_FAR_SOURCES; off *= 2u) {
            var v = scan[lid];
            if lid >= off {
                v += scan[lid - off];
            }
            workgroupBarrier();
            scan[lid] = v;
            workgroupBarrier();
        }
        let at = listed + scan[lid] - keep;
        if keep == 1u && at < FAR_SOURCES {
            source_index[at] = j;
            source_flux[at] = vec4f(phi, 0.0);
        }
        workgroupBarrier();
        if lid == 0u {
            listed += scan[WG_FAR_SOURCES - 1u];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        source_index[FAR_SOURCES] = min(listed, FAR_SOURCES);
    }
}

// far_visible holds prm::prm_file::Far's blocks of 32 entries: B + 1 offsets (each block's first
// pair, then the pair count P), P other blocks (ascending within a block), then 32 words per
// pair (bit c of word r: entry 32 a + r sees entry 32 b + c).
fn blocks() -> u32 {
    return (params.entry_count + 31u) / 32u;
}

// Whether entry i (in block bi, whose run of pairs has reached `at`) sees entry j: `at` is the
// first pair of the run naming a block >= j's, so over ascending j each run is walked once.
fn sees_at(i: u32, j: u32, at: u32) -> f32 {
    if i == j {
        return 1.0;
    }
    let b = blocks();
    let pairs = far_visible[b];
    let end = far_visible[i / 32u + 1u];
    if at >= end || far_visible[b + 1u + at] != j / 32u {
        return 0.0;
    }
    let w = far_visible[b + 1u + pairs + at * 32u + i % 32u];
    return f32((w >> (j % 32u)) & 1u);
}

@compute @workgroup_size(WG_LINEAR)
fn far_main(@builtin(global_invocation_id) id: vec3u) {
    let k = id.x;
    if k >= params.far_texel_count {
        return;
    }
    let t = far_texels[k];
    let count = source_index[FAR_SOURCES];
    // The neighbours' cells, for which of them face a source (their bits say nothing of one
    // their own surface hides: prm_runtime::cpu's far-field vote).
    var at: array<vec3f, 4>;
    var facing: array<vec3f, 4>;
    // Each neighbour's place in its block's run of pairs (the sources ascend).
    var run: array<u32, 4>;
    let b = blocks();
    for (var q = 0u; q < 4u; q++) {
        let m = far_entries[t.entries[q]];
        at[q] = m.centroid;
        facing[q] = m.normal;
        run[q] = far_visible[t.entries[q] / 32u];
    }
    var sum = vec3f(0.0);
    for (var s = 0u; s < count; s++) {
        let j = source_index[s];
        for (var q = 0u; q < 4u; q++) {
            let end = far_visible[t.entries[q] / 32u + 1u];
            while run[q] < end && far_visible[b + 1u + run[q]] < j / 32u {
                run[q] += 1u;
            }
        }
        let e = far_entries[j];
        let share = far_share(distance(e.centroid, t.position), params.far_reach, e.size);
        let d = e.centroid - t.position;
        let r2 = dot(d, d);
        let cx = dot(t.normal, d);
        let cy = -dot(e.normal, d);
        if share <= 0.0 || cx <= 0.0 || cy <= 0.0 {
            continue;
        }
        var seen = 0.0;
        var total = 0.0;
        var every = 0.0;
        for (var q = 0u; q < 4u; q++) {
            let vote = t.weights[q] * sees_at(t.entries[q], j, run[q]);
            every += vote;
            if dot(facing[q], e.centroid - at[q]) > 0.0 {
                seen += vote;
                total += t.weights[q];
            }
        }
        var v = every;
        if total > 0.0 {
            v = seen / total;
        }
        sum += source_flux[s].xyz * (share * v * cx * cy / (PI * r2 * max(r2, e.size * e.size)));
    }
    if t.slot < params.near_texel_count {
        near_sum[t.slot] += vec4f(sum, 0.0);
    } else {
        near_sum[t.slot] = vec4f(sum, 0.0);
    }
}
