// Shared WGSL module `distance_squared`, composed into a kernel at the line `// #include distance_squared`
// when its source is loaded (gpu/device/wgsl.rs): the squared distance summed in a fixed order, each square
// rounded on its own. Needs from the kernel: `fence(x: f32) -> f32`.

fn distance_squared(p: vec3<f32>, q: vec3<f32>) -> f32 {
    let d = p - q;
    return (fence(d.x * d.x) + fence(d.y * d.y)) + fence(d.z * d.z);
}
