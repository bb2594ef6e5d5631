//! The GPU backend's scan cloud: the cloud is uploaded once per scan ([`DeviceCloud`]: points, normals given
//! or estimated on the device for every point, the cell table of the patch radius), and each description round
//! samples its keypoints' patches (and, in uniform keypoint mode, the keypoint order is drawn there too),
//! gathers them, computes their features and PPF-FoldNet codewords on the device. Per round only per-keypoint data crosses the bus: the keypoint indices and the per-(keypoint, cell)
//! candidate offsets up, the candidate counts and the kept keypoints' positions and normals down. Voxel
//! downsampling runs on the device ([`super::preprocess::voxel_downsample_held`]) and the scan is described
//! from its output buffer in place; the result is also read back once, because the described scan carries its
//! cloud (snapshots, pickling). The points' buffer stays with the described scan ([`DevicePoints`]) for ICP on
//! the device ([`super::icp`]).

use super::GpuBackend;
use super::icp::DevicePoints;
use super::preprocess::{DeviceCloud, NormalSource};
use crate::backend::{
    Backend, DescribedKeypoints, HeldPoints, Lap, ScanCloud, ScanRows, ScanSettings, check_points,
    normalise_usable_normals,
};
use crate::cloud::PointCloud;
use crate::error::{Error, Result};
use std::sync::Arc;

/// A scan kept on the device; see the module docs.
pub struct GpuScanCloud {
    backend: GpuBackend,
    cloud: DeviceCloud,
    /// Whether the normals were estimated (not in the host cloud until [`ScanCloud::complete_normals`]).
    estimated: bool,
    /// Whether the host cloud holds every normal.
    complete: bool,
}

impl GpuBackend {
    /// [`Backend::start_scan`] on the device.
    pub(super) async fn start_device_scan(
        &self,
        cloud: &PointCloud,
        settings: &ScanSettings,
        lap: Lap<'_>,
    ) -> Result<(PointCloud, Box<dyn ScanCloud>)> {
        let gpu = &self.gpu;
        // Downsampled on the device, the points stay there for the description (the host copy is part of the
        // described scan, e.g. for snapshots and pickling).
        let (mut host, held) = match settings.voxel {
            Some(v) => {
                self.run("voxel_downsample", async |_| super::preprocess::voxel_downsample_held(gpu, cloud, v).await)
                    .await?
            }
            None => (cloud.clone(), None),
        };
        check_points(&host, cloud.len(), settings)?;
        lap("downsample");
        let given = normalise_usable_normals(&mut host);
        let source = match (&host.normals, given) {
            (Some(ns), true) => NormalSource::Given(ns),
            _ => NormalSource::Estimate { k: settings.normal_neighbors, viewpoint: settings.viewpoint },
        };
        let device = self
            .run("start_scan", async |_| match held {
                Some(points) => {
                    DeviceCloud::from_buffer(gpu, points, host.len(), source, settings.largest_radius).await
                }
                None => DeviceCloud::new(gpu, &host.points, source, settings.largest_radius).await,
            })
            .await?;
        if !given {
            host.normals = None;
        }
        lap("index");
        let scan = GpuScanCloud { backend: self.handle(), cloud: device, estimated: !given, complete: given };
        Ok((host, Box::new(scan)))
    }
}

impl ScanCloud for GpuScanCloud {
    fn describe_keypoints<'a>(
        &'a mut self,
        _backend: &'a dyn Backend,
        _cloud: &'a mut PointCloud,
        (keypoints, radius): (&'a [usize], f32),
        seed: u64,
        rows: &'a dyn ScanRows,
        lap: Lap<'a>,
    ) -> crate::backend::StepFuture<'a, DescribedKeypoints> {
        Box::pin(async move {
            let b = &self.backend;
            let ks = keypoints
                .iter()
                .map(|&k| u32::try_from(k).map_err(|_| Error::invalid(format!("keypoint {k} does not fit 32 bits"))))
                .collect::<Result<Vec<u32>>>()?;
            // Normals were estimated for every point when the scan started; sampling, gathering and describing run
            // as one pass per part, timed as the encoder stage.
            lap("patches");
            lap("normals");
            let mut out = DescribedKeypoints::default();
            // Parts of the keypoints whose candidates fit a buffer, sampled and described in order.
            self.cloud
                .sample_in_parts(&b.gpu, (&ks, radius), seed, 0, async |first, sampled| {
                    b.describe_sampled(&self.cloud, &sampled, rows).await?;
                    out.kept.extend(sampled.kept.iter().map(|&s| first + s));
                    out.empty += sampled.empty.len();
                    out.centers.extend(sampled.centers);
                    out.center_normals.extend(sampled.center_normals);
                    Ok(())
                })
                .await?;
            lap("ppf_encoder");
            Ok(out)
        })
    }

    fn farthest_points<'a>(
        &'a self,
        _cloud: &'a PointCloud,
        count: usize,
        start: usize,
    ) -> crate::backend::StepFuture<'a, Vec<usize>> {
        Box::pin(async move {
            self.backend
                .run("farthest_point", async |_| self.cloud.farthest_points(&self.backend.gpu, count, start).await)
                .await
        })
    }

    fn held_points(&self) -> Option<Arc<dyn HeldPoints>> {
        Some(Arc::new(DevicePoints {
            gpu: std::sync::Arc::clone(self.backend.gpu_arc()),
            buffer: self.cloud.points().clone(),
            n: self.cloud.len(),
        }))
    }

    fn complete_normals<'a>(&'a mut self, cloud: &'a mut PointCloud) -> crate::backend::StepFuture<'a, ()> {
        Box::pin(async move {
            if self.estimated && !self.complete {
                cloud.normals = Some(
                    self.backend.run("normals", async |_| self.cloud.read_normals(&self.backend.gpu).await).await?,
                );
                self.complete = true;
            }
            Ok(())
        })
    }

    fn normals_complete(&self) -> bool {
        self.complete
    }
}
