//! A Gaussian set's arrays as checkpoints hold them: checked against the
//! names and sizes a header expects, and turned back into a host set or
//! uploaded into a device set.

use anyhow::{bail, Result};
use tgs_pipelines::{HostGaussians, TrainableSet};

/// Every array named and sized as `want`, all finite.
pub(crate) fn check_arrays(want: &[(String, usize)], have: &[(String, usize)], arrays: &[Vec<f32>]) -> Result<()> {
    if want != have || arrays.len() != want.len() {
        bail!("arrays {:?} do not match the expected {:?}", have.iter().map(|a| &a.0).collect::<Vec<_>>(), want.iter().map(|a| &a.0).collect::<Vec<_>>());
    }
    for ((name, len), data) in want.iter().zip(arrays) {
        if data.len() != *len || data.iter().any(|v| !v.is_finite()) {
            bail!("array '{name}' has {} values (expected {len}) or non-finite ones", data.len());
        }
    }
    Ok(())
}

/// A host set from the first five arrays of a set's layout (parameters).
pub(crate) fn host_set(channels: u32, coeffs: u32, arrays: &[Vec<f32>]) -> HostGaussians {
    HostGaussians::from_arrays(channels, coeffs, std::array::from_fn(|i| arrays[i].clone()))
}

/// Upload `arrays` (a set's arrays in `TrainableSet::layout` order, maybe
/// followed by others) into `set`.
pub(crate) fn upload_set(set: &TrainableSet, arrays: &[Vec<f32>]) -> Result<()> {
    for ((_, buf, _), data) in set.arrays().iter().zip(arrays) {
        if !data.is_empty() {
            buf.upload(data)?;
        }
    }
    Ok(())
}
