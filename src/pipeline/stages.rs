//! The progressive keypoint schedule: a pair is first registered from a few keypoints per scan, and more are
//! described only while the result is not trusted. RelativeNet needs a single correct correspondence per
//! hypothesis, so easy pairs stop early; a hard pair ends with exactly the result of describing every keypoint
//! at once (descriptions extend prefix by prefix, see `scan`).

use crate::error::{Error, Result};
use crate::settings::{Correspondence, PoseEstimate};
use crate::verdict::Verdict;

/// The keypoint counts of the rounds: `first`, doubled while smaller than `keypoints`, then `keypoints`. Only
/// `keypoints` when there is no first count or it is not smaller.
pub fn keypoint_stages(first: Option<usize>, keypoints: usize) -> Vec<usize> {
    let mut stages = Vec::new();
    if let Some(mut k) = first.filter(|&f| f > 0) {
        while k < keypoints {
            stages.push(k);
            k = k.saturating_mul(2);
        }
    }
    stages.push(keypoints);
    stages
}

/// One round of a staged registration.
#[derive(Clone, Debug)]
pub struct Round {
    /// Keypoints per scan this round used (the first ones of each scan's order).
    pub keypoints: usize,
    /// The correspondences the estimate came from.
    pub correspondences: Vec<Correspondence>,
    /// The pose.
    pub estimate: PoseEstimate,
    /// Whether it is trusted.
    pub verdict: Verdict,
}

/// What a staged registration returns: the first trusted round, else the last round that gave a pose, else the
/// last round's error.
#[derive(Default)]
pub(crate) struct Outcome {
    latest: Option<Round>,
    error: Option<Error>,
}

impl Outcome {
    /// Takes one round's result; true when it is trusted (no further round is needed).
    pub(crate) fn offer(&mut self, round: Result<Round>) -> bool {
        match round {
            Ok(r) => {
                let trusted = r.verdict.success;
                self.latest = Some(r);
                trusted
            }
            Err(e) => {
                self.error = Some(e);
                false
            }
        }
    }

    /// Whether a round so far is trusted.
    pub(crate) fn trusted(&self) -> bool {
        self.latest.as_ref().is_some_and(|r| r.verdict.success)
    }

    /// The round to report.
    pub(crate) fn finish(self) -> Result<Round> {
        match (self.latest, self.error) {
            (Some(r), _) => Ok(r),
            (None, Some(e)) => Err(e),
            (None, None) => Err(Error::invalid("no registration round ran")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_double_from_the_first_count_and_end_at_the_keypoints() {
        assert_eq!(keypoint_stages(Some(500), 2500), vec![500, 1000, 2000, 2500]);
        assert_eq!(keypoint_stages(Some(500), 2000), vec![500, 1000, 2000]);
        assert_eq!(keypoint_stages(Some(2500), 2500), vec![2500]);
        assert_eq!(keypoint_stages(Some(4000), 2500), vec![2500]);
        assert_eq!(keypoint_stages(None, 2500), vec![2500]);
        assert_eq!(keypoint_stages(Some(0), 7), vec![7]);
    }
}
