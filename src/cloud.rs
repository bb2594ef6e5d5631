//! The point cloud type shared by every stage.

use crate::error::{Error, Result};

/// A point cloud in one frame: positions (metres unless the user says otherwise) and optional unit normals.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions.
    pub points: Vec<[f32; 3]>,
    /// One normal per point, when known (from the file or estimated).
    pub normals: Option<Vec<[f32; 3]>>,
}

impl PointCloud {
    /// A cloud without normals.
    pub fn from_points(points: Vec<[f32; 3]>) -> Self {
        PointCloud { points, normals: None }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Checks the invariants every stage relies on: finite coordinates, and one finite normal per point when
    /// normals are present. `what` names the cloud in the error ("source", a file name...).
    pub fn validate(&self, what: &str) -> Result<()> {
        if let Some(i) = self.points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::invalid(format!("{what}: point {i} has a non-finite coordinate")));
        }
        if let Some(normals) = &self.normals {
            if normals.len() != self.points.len() {
                return Err(Error::invalid(format!(
                    "{what}: {} normals for {} points",
                    normals.len(),
                    self.points.len()
                )));
            }
            if let Some(i) = normals.iter().position(|n| !n.iter().all(|c| c.is_finite())) {
                return Err(Error::invalid(format!("{what}: normal {i} has a non-finite component")));
            }
        }
        Ok(())
    }

    /// The cloud with every point (and normal) mapped by `target_from_source`.
    pub fn transformed(&self, target_from_source: &nalgebra::Matrix4<f64>) -> PointCloud {
        let r = target_from_source.fixed_view::<3, 3>(0, 0).into_owned();
        let t = target_from_source.fixed_view::<3, 1>(0, 3).into_owned();
        let map = |p: &[f32; 3], with_t: bool| {
            let v = nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let q = if with_t { r * v + t } else { r * v };
            [q.x as f32, q.y as f32, q.z as f32]
        };
        PointCloud {
            points: self.points.iter().map(|p| map(p, true)).collect(),
            normals: self.normals.as_ref().map(|ns| ns.iter().map(|n| map(n, false)).collect()),
        }
    }
}
