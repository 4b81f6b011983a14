//! Compute pipelines: SPIR-V + specialization constants + push constants.

use crate::context::Context;
use crate::spirv;
use anyhow::{bail, Context as _, Result};
use ash::vk;
use std::sync::Arc;

/// What a kernel is built from.
pub struct KernelDesc<'a> {
    /// Name used in errors and profiler scopes.
    pub name: &'a str,
    pub spirv: &'a [u8],
    /// Specialization constants as (constant_id, value).
    pub spec: &'a [(u32, u32)],
    /// Size in bytes of the push-constant block (0 for none).
    pub push_bytes: u32,
    /// Request this exact subgroup size (needs subgroup size control and must
    /// be within the device's range); `None` keeps the default.
    pub subgroup_size: Option<u32>,
    /// Require full subgroups (when the device allows it). The workgroup's x
    /// size must then be a multiple of the device's maximum subgroup size.
    pub full_subgroups: bool,
}

pub(crate) struct KernelInner {
    ctx: Arc<Context>,
    pub(crate) name: String,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pub(crate) bindings: usize,
    pub(crate) push_bytes: u32,
}

/// A compute pipeline ready to record (cheap to clone and to record many times).
#[derive(Clone)]
pub struct Kernel {
    pub(crate) inner: Arc<KernelInner>,
}

impl Kernel {
    pub fn new(ctx: &Arc<Context>, desc: &KernelDesc) -> Result<Kernel> {
        let name = desc.name;
        let words = spirv::words(desc.spirv).with_context(|| format!("kernel '{name}'"))?;
        let bindings = spirv::binding_count(&words);
        if desc.push_bytes > ctx.caps.max_push_constants {
            bail!("kernel '{name}' needs {} push-constant bytes; device allows {}", desc.push_bytes, ctx.caps.max_push_constants);
        }
        let d = &ctx.device;
        unsafe {
            let module = d
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None)
                .with_context(|| format!("creating shader module '{name}'"))?;
            let lb: Vec<_> = (0..bindings as u32)
                .map(|b| {
                    vk::DescriptorSetLayoutBinding::default()
                        .binding(b)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .descriptor_count(1)
                        .stage_flags(vk::ShaderStageFlags::COMPUTE)
                })
                .collect();
            let set_layout = d.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&lb), None)?;
            let ranges = [vk::PushConstantRange::default()
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
                .offset(0)
                .size(desc.push_bytes)];
            let sls = [set_layout];
            let mut pli = vk::PipelineLayoutCreateInfo::default().set_layouts(&sls);
            if desc.push_bytes > 0 {
                pli = pli.push_constant_ranges(&ranges);
            }
            let layout = d.create_pipeline_layout(&pli, None)?;

            let entries: Vec<_> = desc
                .spec
                .iter()
                .enumerate()
                .map(|(i, (id, _))| vk::SpecializationMapEntry { constant_id: *id, offset: (i * 4) as u32, size: 4 })
                .collect();
            let data: Vec<u8> = desc.spec.iter().flat_map(|(_, v)| v.to_le_bytes()).collect();
            let spec = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
            let mut flags = vk::PipelineShaderStageCreateFlags::empty();
            if desc.full_subgroups && ctx.features.compute_full_subgroups {
                flags |= vk::PipelineShaderStageCreateFlags::REQUIRE_FULL_SUBGROUPS;
            }
            let mut req = vk::PipelineShaderStageRequiredSubgroupSizeCreateInfo::default();
            let mut stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(c"main")
                .specialization_info(&spec)
                .flags(flags);
            if let Some(sg) = desc.subgroup_size {
                let c = &ctx.caps;
                if sg != c.subgroup_size {
                    if !c.subgroup_size_control || sg < c.min_subgroup_size || sg > c.max_subgroup_size {
                        d.destroy_shader_module(module, None);
                        d.destroy_pipeline_layout(layout, None);
                        d.destroy_descriptor_set_layout(set_layout, None);
                        bail!(
                            "kernel '{name}' asks for subgroup size {sg}; {} supports {}..{}{}",
                            c.device_name, c.min_subgroup_size, c.max_subgroup_size,
                            if c.subgroup_size_control { "" } else { " (no subgroup size control)" }
                        );
                    }
                    req = req.required_subgroup_size(sg);
                    stage = stage.push_next(&mut req);
                }
            }
            let info = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
            let res = d.create_compute_pipelines(vk::PipelineCache::null(), &info, None);
            d.destroy_shader_module(module, None);
            let pipeline = match res {
                Ok(p) => p[0],
                Err((_, e)) => {
                    d.destroy_pipeline_layout(layout, None);
                    d.destroy_descriptor_set_layout(set_layout, None);
                    bail!("creating compute pipeline '{name}': {e}");
                }
            };
            Ok(Kernel {
                inner: Arc::new(KernelInner {
                    ctx: ctx.clone(),
                    name: name.to_string(),
                    pipeline,
                    layout,
                    set_layout,
                    bindings,
                    push_bytes: desc.push_bytes,
                }),
            })
        }
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }
    /// Number of storage-buffer bindings the shader declares.
    pub fn bindings(&self) -> usize {
        self.inner.bindings
    }
}

impl Drop for KernelInner {
    fn drop(&mut self) {
        let d = &self.ctx.device;
        unsafe {
            d.destroy_pipeline(self.pipeline, None);
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}
