// Shared WGSL module `run_keys`, composed into a kernel at the line `// #include run_keys` when its source is
// loaded (gpu/device/wgsl.rs). The binary search over a sorted cell table's run keys. Needs from the kernel:
// `grid` (storage array<i32>, the cell count at [7]), `run_keys` (storage array<vec2<u32>>, sorted), `NONE`.

// The run of cell key `key`, or NONE (lower bound over the sorted run keys).
fn find(key: vec2<u32>) -> u32 {
    let cells = u32(grid[7]);
    var lo = 0u;
    var hi = cells;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        let r = run_keys[mid];
        if r.x < key.x || (r.x == key.x && r.y < key.y) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    if lo < cells && all(run_keys[lo] == key) {
        return lo;
    }
    return NONE;
}
