// Shared WGSL module `point`, composed into a kernel at the line `// #include point` when its source is loaded
// (gpu/device/wgsl.rs). Needs from the kernel: `points` (storage array<f32>, n x 3).

fn point(i: u32) -> vec3<f32> {
    return vec3<f32>(points[i * 3u], points[i * 3u + 1u], points[i * 3u + 2u]);
}
