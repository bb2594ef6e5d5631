//! Checks of a loaded scan before any work is done on it, so that an empty scan or one too far from the origin
//! for `f32` is refused naming its file and the cause (not later, as a failure of some stage with advice that
//! does not apply).

use super::LoadReport;
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::path::Path;

/// Largest `f32` rounding step at a scan's farthest coordinate, as a fraction of the scan's extent: beyond
/// 1/500 the points are rounded by more than a tenth of the default voxel size (radius / 24, the radius 0.6 x
/// the scan's size).
pub const MAX_ROUNDING_PER_EXTENT: f64 = 1.0 / 500.0;

/// Refuses a scan (read from `path`, `report` from its loading) with fewer than `min_points` usable points, or
/// lying so far from the coordinate origin (after the shift, which the first scan of a job chooses) that `f32`
/// rounds its points by more than [`MAX_ROUNDING_PER_EXTENT`] of its extent: a scan far from the others (1e7
/// units) cannot be registered with them in `f32`.
pub fn check_scan(path: &Path, cloud: &PointCloud, report: &LoadReport, min_points: usize) -> Result<()> {
    if cloud.len() < min_points {
        let dropped = report.dropped_non_finite + report.dropped_zero;
        let detail = if dropped > 0 {
            format!(
                " ({} points with a non-finite coordinate and {} zero points dropped)",
                report.dropped_non_finite, report.dropped_zero
            )
        } else {
            String::new()
        };
        return Err(Error::invalid(format!(
            "{}: {} usable points{detail}; a scan needs at least {min_points}",
            path.display(),
            cloud.len()
        )));
    }
    let (mut low, mut high) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &cloud.points {
        for a in 0..3 {
            low[a] = low[a].min(f64::from(p[a]));
            high[a] = high[a].max(f64::from(p[a]));
        }
    }
    let extent = (0..3).map(|a| (high[a] - low[a]).powi(2)).sum::<f64>().sqrt();
    let farthest = (0..3).map(|a| low[a].abs().max(high[a].abs())).fold(0.0, f64::max);
    let step = farthest * f64::from(f32::EPSILON);
    if step > extent * MAX_ROUNDING_PER_EXTENT {
        let shifted =
            if report.origin == [0; 3] { String::new() } else { format!(" (shifted by -{:?})", report.origin) };
        return Err(Error::invalid(format!(
            "{}: the scan lies {farthest:.4e} units from the origin{shifted} but spans only {extent:.4e}: f32 \
             rounds its points by {step:.2e}, too coarse to register; scans registered together must lie in one \
             local frame, near each other",
            path.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(offset: f32) -> PointCloud {
        PointCloud::from_points(
            (0..64).map(|i| [offset + (i % 4) as f32, (i / 4 % 4) as f32, (i / 16) as f32]).collect(),
        )
    }

    #[test]
    fn empty_and_far_scans_are_refused_with_the_cause() {
        let report = LoadReport { dropped_non_finite: 7, ..LoadReport::default() };
        let e = check_scan(Path::new("e.xyz"), &PointCloud::from_points(vec![]), &report, 10).unwrap_err();
        assert!(e.to_string().contains("e.xyz: 0 usable points (7 points with a non-finite"), "{e}");
        assert!(check_scan(Path::new("c.xyz"), &cube(0.0), &LoadReport::default(), 10).is_ok());
        assert!(check_scan(Path::new("c.xyz"), &cube(1e3), &LoadReport::default(), 10).is_ok());
        let e = check_scan(Path::new("far.xyz"), &cube(1e7), &LoadReport::default(), 10).unwrap_err().to_string();
        assert!(e.contains("far.xyz") && e.contains("one local frame"), "{e}");
    }
}
