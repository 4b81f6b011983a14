//! Compute pipelines: SPIR-V + specialization constants + push constants.
//!
//! A context builds each distinct pipeline once: [`Kernel::new`] with the
//! same SPIR-V, specialization constants, push-constant size and subgroup
//! requests returns the pipeline built before (a driver compiles SPIR-V to
//! machine code when a pipeline is created: 200 ms for the rasterizer's
//! backward on llvmpipe, and the trainer's stages, their rasterizers and
//! the tests build the same ones many times). The pipelines live as long
//! as the context: a run builds a few dozen distinct ones.

use crate::context::Context;
use crate::spirv::{self, BindingKind};
use anyhow::{bail, Context as _, Result};
use ash::vk;
use std::collections::HashMap;
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

/// What makes two kernels the same pipeline (all of [`KernelDesc`] but
/// the name).
#[derive(Clone, PartialEq, Eq, Hash)]
pub(crate) struct PipelineKey {
    spirv: Vec<u8>,
    spec: Vec<(u32, u32)>,
    push_bytes: u32,
    subgroup_size: Option<u32>,
    full_subgroups: bool,
}

/// A pipeline the context built, with its layouts; destroyed with the
/// context ([`destroy_pipelines`]).
#[derive(Clone)]
pub(crate) struct Pipeline {
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    set_layout: vk::DescriptorSetLayout,
    kinds: Arc<[BindingKind]>,
}

/// The pipelines a context built, by what they were built from.
pub(crate) type Pipelines = HashMap<PipelineKey, Pipeline>;

/// Destroy every pipeline of `built` (the context is being dropped and the
/// device is idle).
pub(crate) unsafe fn destroy_pipelines(d: &ash::Device, built: &mut Pipelines) {
    for (_, p) in built.drain() {
        d.destroy_pipeline(p.pipeline, None);
        d.destroy_pipeline_layout(p.layout, None);
        d.destroy_descriptor_set_layout(p.set_layout, None);
    }
}

pub(crate) struct KernelInner {
    /// Keeps the context, which owns the pipeline, alive.
    #[allow(dead_code)]
    ctx: Arc<Context>,
    pub(crate) name: String,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    /// What each binding is (storage buffer or texel buffer), from the SPIR-V.
    pub(crate) kinds: Arc<[BindingKind]>,
    pub(crate) push_bytes: u32,
}

/// A compute pipeline ready to record (cheap to clone and to record many times).
#[derive(Clone)]
pub struct Kernel {
    pub(crate) inner: Arc<KernelInner>,
}

impl Kernel {
    /// The kernel of `desc`: the context's pipeline for it, built now if
    /// this context has not built it before.
    pub fn new(ctx: &Arc<Context>, desc: &KernelDesc) -> Result<Kernel> {
        let key = PipelineKey {
            spirv: desc.spirv.to_vec(),
            spec: desc.spec.to_vec(),
            push_bytes: desc.push_bytes,
            subgroup_size: desc.subgroup_size,
            full_subgroups: desc.full_subgroups,
        };
        let mut built = ctx.pipelines.lock().map_err(|_| anyhow::anyhow!("kernel '{}': the context's pipeline table is poisoned", desc.name))?;
        let p = match built.get(&key) {
            Some(p) => p.clone(),
            None => {
                let p = Self::build(ctx, desc)?;
                built.insert(key, p.clone());
                p
            }
        };
        Ok(Kernel {
            inner: Arc::new(KernelInner {
                ctx: ctx.clone(),
                name: desc.name.to_string(),
                pipeline: p.pipeline,
                layout: p.layout,
                set_layout: p.set_layout,
                kinds: p.kinds,
                push_bytes: desc.push_bytes,
            }),
        })
    }

    fn build(ctx: &Arc<Context>, desc: &KernelDesc) -> Result<Pipeline> {
        let name = desc.name;
        let words = spirv::words(desc.spirv).with_context(|| format!("kernel '{name}'"))?;
        let kinds: Arc<[BindingKind]> = spirv::binding_kinds(&words, spirv::binding_count(&words)).into();
        // The Rust struct a kernel's wrapper passes must be the shader's
        // block, byte for byte in size: a field added on one side only
        // would shift every later one.
        if let Some(want) = spirv::push_constant_bytes(&words) {
            if want != desc.push_bytes {
                bail!(
                    "kernel '{name}': the shader's push-constant block is {want} bytes, its wrapper declares {} (the Rust struct and the GLSL block must match)",
                    desc.push_bytes
                );
            }
        }
        if desc.push_bytes > ctx.caps.max_push_constants {
            bail!("kernel '{name}' needs {} push-constant bytes; device allows {}", desc.push_bytes, ctx.caps.max_push_constants);
        }
        let d = &ctx.device;
        // SAFETY: `words` is a whole SPIR-V module (spirv::words checked its size) compiled from the crate's
        // GLSL; every create info and what it points to lives until its call returns, and each object is made
        // on this live device.
        unsafe {
            let module = d.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None).with_context(|| format!("creating shader module '{name}'"))?;
            let lb: Vec<_> = kinds
                .iter()
                .enumerate()
                .map(|(b, k)| {
                    vk::DescriptorSetLayoutBinding::default().binding(b as u32).descriptor_type(descriptor_type(*k)).descriptor_count(1).stage_flags(vk::ShaderStageFlags::COMPUTE)
                })
                .collect();
            let set_layout = d.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&lb), None)?;
            let ranges = [vk::PushConstantRange::default().stage_flags(vk::ShaderStageFlags::COMPUTE).offset(0).size(desc.push_bytes)];
            let sls = [set_layout];
            let mut pli = vk::PipelineLayoutCreateInfo::default().set_layouts(&sls);
            if desc.push_bytes > 0 {
                pli = pli.push_constant_ranges(&ranges);
            }
            let layout = d.create_pipeline_layout(&pli, None)?;

            let entries: Vec<_> = desc.spec.iter().enumerate().map(|(i, (id, _))| vk::SpecializationMapEntry { constant_id: *id, offset: (i * 4) as u32, size: 4 }).collect();
            let data: Vec<u8> = desc.spec.iter().flat_map(|(_, v)| v.to_le_bytes()).collect();
            let spec = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
            let mut flags = vk::PipelineShaderStageCreateFlags::empty();
            if desc.full_subgroups && ctx.features.compute_full_subgroups {
                flags |= vk::PipelineShaderStageCreateFlags::REQUIRE_FULL_SUBGROUPS;
            }
            let mut req = vk::PipelineShaderStageRequiredSubgroupSizeCreateInfo::default();
            let mut stage = vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::COMPUTE).module(module).name(c"main").specialization_info(&spec).flags(flags);
            if let Some(sg) = desc.subgroup_size {
                let c = &ctx.caps;
                if sg != c.subgroup_size {
                    if !c.subgroup_size_control || sg < c.min_subgroup_size || sg > c.max_subgroup_size {
                        d.destroy_shader_module(module, None);
                        d.destroy_pipeline_layout(layout, None);
                        d.destroy_descriptor_set_layout(set_layout, None);
                        bail!(
                            "kernel '{name}' asks for subgroup size {sg}; {} supports {}..{}{}",
                            c.device_name,
                            c.min_subgroup_size,
                            c.max_subgroup_size,
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
            Ok(Pipeline { pipeline, layout, set_layout, kinds })
        }
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }
    /// The Vulkan pipeline (the context's; kernels of the same pipeline
    /// share it).
    pub fn pipeline(&self) -> vk::Pipeline {
        self.inner.pipeline
    }
    /// Number of buffer bindings the shader declares (storage and texel).
    pub fn bindings(&self) -> usize {
        self.inner.kinds.len()
    }
}

/// The descriptor type of a binding of `kind`.
pub(crate) fn descriptor_type(kind: BindingKind) -> vk::DescriptorType {
    match kind {
        BindingKind::Storage => vk::DescriptorType::STORAGE_BUFFER,
        BindingKind::TexelF32 | BindingKind::TexelU32 => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
    }
}
