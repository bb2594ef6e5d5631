//! The orthographic views of a snapshot: the frame the views are taken in (the target's principal axes or the
//! world axes), the two in-plane axes of each view, and how a panel frames the points it shows.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// One orthographic view, named for a scan lying flat: the views are taken along the axes of the frame
/// chosen by [`ViewAxes`], `e1` (horizontal in Top and Front), `e2` and `e3`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum View {
    /// Looking down `-e3`: `e1` to the right, `e2` up.
    Top,
    /// Looking along `e2`: `e1` to the right, `e3` up.
    Front,
    /// Looking along `-e1`: `e2` to the right, `e3` up.
    Side,
}

impl View {
    /// The lowercase name ("top", "front", "side").
    pub fn name(self) -> &'static str {
        match self {
            View::Top => "top",
            View::Front => "front",
            View::Side => "side",
        }
    }

    /// Indices into the frame's axes of the (rightwards, upwards) panel directions.
    fn in_plane(self) -> (usize, usize) {
        match self {
            View::Top => (0, 1),
            View::Front => (0, 2),
            View::Side => (1, 2),
        }
    }
}

/// The frame whose axes `e1, e2, e3` the [`View`]s look along.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ViewAxes {
    /// The target's principal axes (by decreasing spread of its points), so the Top view faces the target's
    /// flattest direction whatever frame the scans are in. Signs are fixed for determinism: each of `e1`, `e2`
    /// has its largest-magnitude component positive, and `e3 = e1 x e2`.
    #[default]
    Principal,
    /// The world axes: `e1 = x`, `e2 = y`, `e3 = z` (Top looks down the z axis).
    World,
}

/// The axes `[e1, e2, e3]` (orthonormal, right-handed) of `axes` for the target points `target`.
pub(super) fn frame_axes(axes: ViewAxes, target: &[Vector3<f64>]) -> [Vector3<f64>; 3] {
    match axes {
        ViewAxes::World => [Vector3::x(), Vector3::y(), Vector3::z()],
        ViewAxes::Principal => principal_axes(target),
    }
}

/// Principal axes of `points` by decreasing variance, with the sign convention of [`ViewAxes::Principal`]
/// (the world axes for fewer than two points).
fn principal_axes(points: &[Vector3<f64>]) -> [Vector3<f64>; 3] {
    if points.len() < 2 {
        return [Vector3::x(), Vector3::y(), Vector3::z()];
    }
    let n = points.len() as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let covariance = points.iter().fold(Matrix3::zeros(), |acc, p| {
        let d = p - mean;
        acc + d * d.transpose()
    }) / n;
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]).then(a.cmp(&b)));
    let column = |k: usize| -> Vector3<f64> {
        let v: Vector3<f64> = eigen.eigenvectors.column(order[k]).into_owned();
        let largest = v.iter().copied().fold(0.0f64, |m, c| if c.abs() > m.abs() { c } else { m });
        if largest < 0.0 { -v } else { v }
    };
    let (e1, e2) = (column(0), column(1));
    [e1, e2, e1.cross(&e2)]
}

/// Share of points (at each end of each panel axis) left outside a panel's framing, so a few stray points do
/// not shrink the scans to a speck.
const FRAMING_TRIM: f64 = 0.002;

/// Pixels left free around the framed points inside a panel.
const FRAMING_MARGIN_PX: f64 = 6.0;

/// Maps points to the pixels of one square panel: orthographic projection on `right` and `up`, scaled
/// uniformly so the framed points fit, and centred.
#[derive(Clone, Copy, Debug)]
pub(super) struct PanelFrame {
    /// Panel direction to the right (a unit vector of the view frame).
    right: Vector3<f64>,
    /// Panel direction upwards.
    up: Vector3<f64>,
    /// Coordinates along (right, up) of the panel centre.
    centre: (f64, f64),
    /// Pixels per cloud unit.
    scale: f64,
    /// Panel side in pixels.
    side_px: f64,
}

impl PanelFrame {
    /// The frame of `view` (in the frame `axes`) for a `side_px` square panel showing `clouds`: the box
    /// between the [`FRAMING_TRIM`] quantiles of all their points along each panel axis fills the panel.
    pub(super) fn fit(view: View, axes: &[Vector3<f64>; 3], clouds: &[&[Vector3<f64>]], side_px: u32) -> PanelFrame {
        let (r, u) = view.in_plane();
        let (right, up) = (axes[r], axes[u]);
        let along =
            |dir: &Vector3<f64>| -> Vec<f64> { clouds.iter().flat_map(|c| c.iter().map(|p| p.dot(dir))).collect() };
        let (x0, x1) = trimmed_range(along(&right));
        let (y0, y1) = trimmed_range(along(&up));
        let side = f64::from(side_px);
        let usable = (side - 2.0 * FRAMING_MARGIN_PX).max(1.0);
        let extent = (x1 - x0).max(y1 - y0);
        let scale = if extent > 1e-12 { usable / extent } else { 1.0 };
        PanelFrame { right, up, centre: (0.5 * (x0 + x1), 0.5 * (y0 + y1)), scale, side_px: side }
    }

    /// The pixel position (x right, y down, panel origin top-left) of point `p`.
    pub(super) fn pixel(&self, p: &Vector3<f64>) -> (f64, f64) {
        let half = 0.5 * self.side_px;
        let x = half + (p.dot(&self.right) - self.centre.0) * self.scale;
        let y = half - (p.dot(&self.up) - self.centre.1) * self.scale;
        (x, y)
    }
}

/// The [`FRAMING_TRIM`] and `1 - FRAMING_TRIM` quantiles of `values` ((0, 0) when empty).
fn trimmed_range(mut values: Vec<f64>) -> (f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let last = values.len() - 1;
    let k = ((last as f64) * FRAMING_TRIM).floor() as usize;
    let low = *values.select_nth_unstable_by(k, f64::total_cmp).1;
    let high = *values.select_nth_unstable_by(last - k, f64::total_cmp).1;
    (low, high)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn principal_axes_follow_the_spread_and_are_right_handed() {
        // A slab: long along y, medium along z, thin along x.
        let points: Vec<Vector3<f64>> = (0..400)
            .map(|i| Vector3::new(0.01 * ((i % 3) as f64), 4.0 * ((i % 20) as f64), 1.0 * ((i / 20) as f64) / 20.0))
            .collect();
        let [e1, e2, e3] = principal_axes(&points);
        // The x jitter correlates slightly with the other coordinates: the axes tilt by a few 1e-5.
        assert!((e1.y.abs() - 1.0).abs() < 1e-6, "{e1}");
        assert!((e2.z.abs() - 1.0).abs() < 1e-6, "{e2}");
        assert!((e1.cross(&e2) - e3).norm() < 1e-12 && (e3.norm() - 1.0).abs() < 1e-12);
        assert!(e1.y > 0.0 && e2.z > 0.0, "sign convention: largest component positive");
    }

    #[test]
    fn framing_fits_the_points_and_keeps_the_aspect_ratio() {
        let points = [Vector3::new(0.0, 0.0, 0.0), Vector3::new(2.0, 1.0, 0.0)];
        let axes = [Vector3::x(), Vector3::y(), Vector3::z()];
        let frame = PanelFrame::fit(View::Top, &axes, &[&points], 100);
        let (a, b) = (frame.pixel(&points[0]), frame.pixel(&points[1]));
        assert!((a.0 - FRAMING_MARGIN_PX).abs() < 1e-9 && (b.0 - (100.0 - FRAMING_MARGIN_PX)).abs() < 1e-9);
        // Uniform scale: half the width in y, centred, y pointing down.
        assert!(((a.1 - b.1) - (b.0 - a.0) / 2.0).abs() < 1e-9 && ((a.1 + b.1) / 2.0 - 50.0).abs() < 1e-9);
    }

    #[test]
    fn trimmed_range_ignores_rare_outliers() {
        let mut values: Vec<f64> = (0..1000).map(f64::from).collect();
        values.push(1e9);
        values.push(-1e9);
        let (low, high) = trimmed_range(values);
        assert!((0.0..=2.0).contains(&low) && (997.0..=999.0).contains(&high), "{low} {high}");
    }
}
