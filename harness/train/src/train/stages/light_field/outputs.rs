//! What Stage III writes: the message that starts it, and at the end of a
//! run the reflection set (`reflection.ply`) and the network
//! (`light_field.safetensors`).

use super::config::LightFieldConfig;
use super::LightFieldModel;
use crate::export::ply::write_reflection_splats;
use anyhow::Result;
use std::path::Path;

impl LightFieldModel {
    /// The network and its training, for the progress output (`label`:
    /// the schedule entry, "III" or "III.2").
    pub fn start_message(&self, label: &str, lf: &LightFieldConfig) -> String {
        let s = &self.net.shape;
        format!(
            "Stage {}: light field {} x {} (L {} / {}, {} parameters, {} kernel) on pixels with R > {}, {} iterations{}",
            label,
            s.depth,
            s.width,
            s.levels_x,
            s.levels_w,
            s.params(),
            self.mlp_kernel(),
            lf.threshold,
            lf.iterations,
            match (lf.train_scattering, lf.scattering_colour_only()) {
                (false, _) => " (scattering set frozen)",
                (true, true) => " (scattering colour trained, its geometry frozen)",
                (true, false) => " (scattering set trained)",
            }
        )
    }

    /// The reflection set and the network into the run directory `out`.
    pub fn write_outputs(&self, out: &Path) -> Result<()> {
        write_reflection_splats(&out.join("reflection.ply"), &self.set.params.download()?)?;
        crate::export::mlp::write(&out.join("light_field.safetensors"), &self.net.shape, &self.shade, &self.net.params.download()?)
    }
}
