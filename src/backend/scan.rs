//! The per-scan seam: a backend prepares a scan's cloud where it describes it ([`ScanCloud`]), and describes
//! ranges of its keypoint order there. The host version ([`HostScanCloud`], what the CPU backend and any backend
//! without a device cloud run) is the pipeline's code of before: k-d tree, patches by
//! [`crate::cpu::patch_sample`]'s rule, normals estimated where patches need them, gathering, then
//! [`Backend::describe`]. The GPU backend keeps the cloud on the device instead (`gpu::scan`).

use super::{Backend, PatchBatch, ScanRows, StepFuture, ready};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use crate::preprocess::{estimate_normals_at, extract_patches, gather, voxel_downsample};
use crate::spatial::PointIndex;

/// What preparing and describing a scan needs of the registration settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanSettings {
    /// Voxel size of the downsampling, if any.
    pub voxel: Option<f32>,
    /// Patch radius.
    pub radius: f32,
    /// The largest patch radius keypoints are described at (`radius` or a larger context radius): the GPU's
    /// cell table is built for it.
    pub largest_radius: f32,
    /// Points per patch (N).
    pub points_per_patch: usize,
    /// Neighbours of a PCA normal.
    pub normal_neighbors: usize,
    /// Where the sensor was (scan frame): estimated normals face it.
    pub viewpoint: [f32; 3],
    /// Fewest points the scan may have after downsampling.
    pub min_points: usize,
}

/// The outcome of describing keypoints: which kept a patch, and their positions and normals (what the host
/// needs for estimation, verification and ICP).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DescribedKeypoints {
    /// Positions (in the keypoints described) of those whose patch is not empty, ascending; one row each was
    /// appended to the scan's rows.
    pub kept: Vec<usize>,
    /// Keypoints dropped for an empty patch.
    pub empty: usize,
    /// Kept keypoints' positions.
    pub centers: Vec<[f32; 3]>,
    /// Kept keypoints' unit normals.
    pub center_normals: Vec<[f32; 3]>,
}

/// Called with a stage name as each stage of a scan's preparation or description ends (the pipeline's clock).
pub type Lap<'a> = &'a mut dyn FnMut(&str);

/// A scan's preprocessed points as the backend that prepared it holds them (the GPU backend: a device
/// buffer), kept with the described scan ([`super::ScanFeatures::held_points`]) so that stages after
/// description (ICP) read them where they are.
pub trait HeldPoints: Send + Sync + std::fmt::Debug {
    /// The concrete type, for the backend that made it.
    fn as_any(&self) -> &dyn std::any::Any;
}

/// A scan's preprocessed cloud where its backend describes it.
pub trait ScanCloud: Send + Sync {
    /// Describes `keypoints` (cloud indices, in order) with patches of `radius` (at most the settings'
    /// `largest_radius`) ranked by `seed`, appending the kept ones' rows to `rows`. `cloud` is the scan's host
    /// cloud (the host version fills the normals it estimates in).
    fn describe_keypoints<'a>(
        &'a mut self,
        backend: &'a dyn Backend,
        cloud: &'a mut PointCloud,
        keypoints: (&'a [usize], f32),
        seed: u64,
        rows: &'a dyn ScanRows,
        lap: Lap<'a>,
    ) -> StepFuture<'a, DescribedKeypoints>;

    /// `count` indices of `cloud` (count < its points) by farthest-point sampling from `start`
    /// ([`crate::cpu::farthest_point`]'s definition); the provided version runs on the host cloud.
    fn farthest_points<'a>(&'a self, cloud: &'a PointCloud, count: usize, start: usize) -> StepFuture<'a, Vec<usize>> {
        ready(Ok(crate::cpu::farthest_point::farthest_point(&cloud.points, count, start)))
    }

    /// The scan's points where the backend holds them, to keep after description; `None` (the provided
    /// version) when they are only the host cloud's.
    fn held_points(&self) -> Option<std::sync::Arc<dyn HeldPoints>> {
        None
    }

    /// `Some(k)` where the host cloud's normals are estimated on the host as they are needed (PCA over `k`
    /// neighbours facing the settings' viewpoint, [`estimate_normals_at`] on the cloud's own k-d tree; NaN until
    /// then); the provided version `None` (the file's normals, or normals another backend holds).
    fn host_estimated_normals(&self) -> Option<usize> {
        None
    }

    /// Fills every normal of `cloud` (estimating or reading back those not in it yet).
    fn complete_normals<'a>(&'a mut self, cloud: &'a mut PointCloud) -> StepFuture<'a, ()>;

    /// Whether `cloud`'s normals are all there (given by the file, or every one estimated and filled in).
    fn normals_complete(&self) -> bool;
}

/// Which estimated normals a host cloud still lacks (NaN placeholders until then), and where they face.
struct MissingNormals {
    ready: Vec<bool>,
    viewpoint: [f32; 3],
}

/// The host version of a scan's cloud; see the module docs.
pub struct HostScanCloud {
    index: PointIndex,
    missing: Option<MissingNormals>,
    /// Whether the normals are estimated here (the cloud had none usable).
    estimated: bool,
    settings: ScanSettings,
}

/// Downsamples `cloud` (`settings.voxel`) and checks it keeps `settings.min_points`.
pub fn downsample(input: &PointCloud, settings: &ScanSettings) -> Result<PointCloud> {
    let cloud = match settings.voxel {
        Some(v) => voxel_downsample(input, v)?,
        None => input.clone(),
    };
    check_points(&cloud, input.len(), settings)?;
    Ok(cloud)
}

/// An error unless `cloud` (preprocessed from `given` points) has `settings.min_points`.
pub fn check_points(cloud: &PointCloud, given: usize, settings: &ScanSettings) -> Result<()> {
    if cloud.len() < settings.min_points {
        return Err(Error::invalid(format!(
            "cloud has {} points after preprocessing its {given} points; at least {} are needed",
            cloud.len(),
            settings.min_points
        )));
    }
    Ok(())
}

/// Whether `cloud` has normals and every one is usable (non-zero); otherwise the backends estimate them all.
pub fn has_usable_normals(cloud: &PointCloud) -> bool {
    cloud.normals.as_ref().is_some_and(|ns| ns.iter().all(|n| n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 1e-12))
}

/// Normalises `cloud`'s normals in place when every one is usable (non-zero) and says whether they were.
pub fn normalise_usable_normals(cloud: &mut PointCloud) -> bool {
    let usable = has_usable_normals(cloud);
    if usable {
        for n in cloud.normals.as_mut().expect("checked") {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            *n = n.map(|c| c / len);
        }
    }
    usable
}

/// The host preparation of a scan (what [`Backend::start_scan`] does by default): downsampling, the k-d tree,
/// the file's normals normalised or placeholders for estimated ones.
pub fn host_start_scan(
    cloud: &PointCloud,
    settings: &ScanSettings,
    lap: Lap<'_>,
) -> Result<(PointCloud, Box<dyn ScanCloud>)> {
    let mut cloud = downsample(cloud, settings)?;
    lap("downsample");
    let index = PointIndex::new(&cloud.points)?;
    lap("index");
    // Estimated normals are computed where patches need them (`describe_keypoints`).
    let missing = if normalise_usable_normals(&mut cloud) {
        None
    } else {
        cloud.normals = Some(vec![[f32::NAN; 3]; cloud.len()]);
        Some(MissingNormals { ready: vec![false; cloud.len()], viewpoint: settings.viewpoint })
    };
    let estimated = missing.is_some();
    Ok((cloud, Box::new(HostScanCloud { index, missing, estimated, settings: *settings })))
}

/// Positions in `asked` of the `kept` keypoints (a subsequence of `asked`, in order).
pub fn kept_positions(asked: &[usize], kept: &[usize]) -> Vec<usize> {
    let mut next = kept.iter().peekable();
    let mut out = Vec::with_capacity(kept.len());
    for (pos, k) in asked.iter().enumerate() {
        if next.peek() == Some(&k) {
            next.next();
            out.push(pos);
        }
    }
    out
}

impl HostScanCloud {
    /// Estimates the normals of the points `ids` of `cloud` that are still missing.
    fn fill_normals(&mut self, cloud: &mut PointCloud, ids: Vec<usize>) {
        let Some(m) = self.missing.as_mut() else { return };
        // The missing ones among `ids`, ascending and once each (a mark per point, not a sort).
        let mut wanted = vec![false; m.ready.len()];
        for i in ids {
            wanted[i] = !m.ready[i];
        }
        let ids: Vec<usize> = wanted.iter().enumerate().filter_map(|(i, &w)| w.then_some(i)).collect();
        let computed =
            estimate_normals_at(&cloud.points, &self.index, &ids, self.settings.normal_neighbors, m.viewpoint);
        let normals = cloud.normals.as_mut().expect("placeholders set when the scan started");
        for (&i, n) in ids.iter().zip(computed) {
            normals[i] = n;
            m.ready[i] = true;
        }
        if m.ready.iter().all(|&r| r) {
            self.missing = None;
        }
    }
}

impl ScanCloud for HostScanCloud {
    fn describe_keypoints<'a>(
        &'a mut self,
        backend: &'a dyn Backend,
        cloud: &'a mut PointCloud,
        (keypoints, radius): (&'a [usize], f32),
        seed: u64,
        rows: &'a dyn ScanRows,
        lap: Lap<'a>,
    ) -> StepFuture<'a, DescribedKeypoints> {
        Box::pin(self.describe_on_host(backend, cloud, (keypoints, radius), seed, rows, lap))
    }

    fn complete_normals<'a>(&'a mut self, cloud: &'a mut PointCloud) -> StepFuture<'a, ()> {
        let all = (0..cloud.len()).collect();
        self.fill_normals(cloud, all);
        ready(Ok(()))
    }

    fn normals_complete(&self) -> bool {
        self.missing.is_none()
    }

    fn host_estimated_normals(&self) -> Option<usize> {
        self.estimated.then_some(self.settings.normal_neighbors)
    }
}

impl HostScanCloud {
    /// [`ScanCloud::describe_keypoints`] on the host: patches, the normals they need, gathering, then the
    /// backend's [`Backend::describe`].
    async fn describe_on_host(
        &mut self,
        backend: &dyn Backend,
        cloud: &mut PointCloud,
        (keypoints, radius): (&[usize], f32),
        seed: u64,
        rows: &dyn ScanRows,
        lap: Lap<'_>,
    ) -> Result<DescribedKeypoints> {
        let n = self.settings.points_per_patch;
        let patches = extract_patches(&cloud.points, &self.index, keypoints, radius, n, seed);
        lap("patches");
        let mut needed: Vec<usize> = patches.keypoints.clone();
        needed.extend(patches.neighbors.iter().map(|&j| j as usize));
        self.fill_normals(cloud, needed);
        let normals = cloud.normals.as_ref().expect("normals set when the scan started");
        let gathered = gather(&cloud.points, normals, &patches);
        lap("normals");
        backend.describe(PatchBatch::new(&gathered, n, radius)?, rows).await?;
        lap("ppf_encoder");
        Ok(DescribedKeypoints {
            kept: kept_positions(keypoints, &patches.keypoints),
            empty: patches.empty.len(),
            centers: gathered.centers,
            center_normals: gathered.center_normals,
        })
    }
}
