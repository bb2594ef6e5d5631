//! CPU twin of `shaders/pose_feature.wgsl`: a scan's pose features (PC-FoldNet codeword minus PPF-FoldNet
//! codeword, [`crate::model::pose_feature`]) from PC codewords encoded for some of its rows.

/// For each slot `s`, writes `pc[s] - ppf[rows[s]]` into row `rows[s]` of `out` (rows of `width` values; `pc`
/// holds `rows.len()` rows in slot order, `ppf` and `out` the scan's rows). Rows out of range are skipped.
pub fn pose_feature(pc: &[f32], ppf: &[f32], rows: &[u32], width: usize, out: &mut [f32]) {
    for (slot, &row) in rows.iter().enumerate() {
        let at = row as usize * width;
        if at + width > out.len() || at + width > ppf.len() || (slot + 1) * width > pc.len() {
            continue;
        }
        let feature = crate::model::pose_feature(&pc[slot * width..][..width], &ppf[at..at + width]);
        out[at..at + width].copy_from_slice(&feature);
    }
}
