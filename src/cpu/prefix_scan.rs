//! CPU twin of `shaders/prefix_scan.wgsl`: the exclusive prefix sum of u32 values (wrapping), and the total.

/// The exclusive prefix sums of `values` and their total, both wrapping modulo 2^32 as the kernel's u32 adds.
pub fn prefix_scan(values: &[u32]) -> (Vec<u32>, u32) {
    let mut total = 0u32;
    let out = values
        .iter()
        .map(|&v| {
            let before = total;
            total = total.wrapping_add(v);
            before
        })
        .collect();
    (out, total)
}
