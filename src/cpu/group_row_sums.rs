//! CPU twin of `shaders/group_row_sums.wgsl`, and what the trainer runs: the rows of a matrix summed over
//! each group of consecutive rows. The backward pass of an input shared by a group of rows (the broadcast
//! global feature, the folding decoder's codeword) sums the group's output gradients first.

/// `x` (`rows x width`) summed over each group of `rows_per_group` consecutive rows, each sum from zero in row
/// order: `groups x width` with `groups = rows / rows_per_group` (rows past the last whole group are ignored).
pub fn group_row_sums(x: &[f32], rows_per_group: usize, width: usize) -> Vec<f32> {
    let rpg = rows_per_group.max(1);
    let groups = x.len() / width.max(1) / rpg;
    let mut sums = vec![0.0f32; groups * width];
    for (r, row) in x.chunks_exact(width.max(1)).take(groups * rpg).enumerate() {
        for (s, &v) in sums[(r / rpg) * width..][..width].iter_mut().zip(row) {
            *s += v;
        }
    }
    sums
}
