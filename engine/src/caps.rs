//! Device capabilities that kernels and their callers size themselves by.

use ash::vk;
use std::ffi::CStr;

/// What a compute kernel needs to know about a device. Read once at context
/// creation (see [`Capabilities::query`]).
#[derive(Clone, Debug)]
pub struct Capabilities {
    pub device_name: String,
    pub driver_name: String,
    pub driver_info: String,
    pub vendor_id: u32,
    pub device_type: vk::PhysicalDeviceType,
    pub api_version: u32,
    /// Default subgroup size (`VkPhysicalDeviceSubgroupProperties::subgroupSize`).
    pub subgroup_size: u32,
    /// Range a pipeline may request with subgroup size control (min = max = subgroup_size without it).
    pub min_subgroup_size: u32,
    pub max_subgroup_size: u32,
    /// Subgroup size control (`VK_EXT_subgroup_size_control` / Vulkan 1.3) is available.
    pub subgroup_size_control: bool,
    /// `computeFullSubgroups` is available.
    pub compute_full_subgroups: bool,
    /// Supported subgroup operations: basic, vote, arithmetic, ballot, shuffle present.
    pub subgroup_ops_ok: bool,
    pub max_shared_memory: u32,
    pub max_storage_buffer_range: u64,
    pub max_workgroup_count: [u32; 3],
    pub max_workgroup_invocations: u32,
    pub max_workgroup_size: [u32; 3],
    pub max_push_constants: u32,
    /// Storage buffers one compute shader may bind.
    pub max_storage_buffers_per_stage: u32,
    pub max_memory_allocation: u64,
    pub min_storage_buffer_offset_alignment: u64,
    /// Texels one texel-buffer view may hold (`maxTexelBufferElements`).
    pub max_texel_buffer_elements: u64,
    /// Alignment of a texel-buffer view's offset (`minTexelBufferOffsetAlignment`).
    pub min_texel_buffer_offset_alignment: u64,
    /// `bufferDeviceAddress` supported.
    pub buffer_device_address: bool,
    /// 32-bit float atomic add on storage buffers (`VK_EXT_shader_atomic_float`).
    /// tgs never uses them for gradients; reported for information.
    pub float_atomics: bool,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period: f32,
    /// Valid timestamp bits on the compute queue (0: no timestamps).
    pub timestamp_valid_bits: u32,
    pub device_local_bytes: u64,
}

impl Capabilities {
    /// Query `pd`. `queue_family` is the compute queue family that will be used.
    ///
    /// # Safety
    /// `pd` must come from `instance`.
    pub unsafe fn query(instance: &ash::Instance, pd: vk::PhysicalDevice, queue_family: u32) -> Self {
        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut sg_ctrl = vk::PhysicalDeviceSubgroupSizeControlProperties::default();
        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut subgroup).push_next(&mut sg_ctrl).push_next(&mut driver);
        instance.get_physical_device_properties2(pd, &mut props2);
        let props = props2.properties;

        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
        let exts = instance.enumerate_device_extension_properties(pd).unwrap_or_default();
        let has_ext = |name: &CStr| exts.iter().any(|e| e.extension_name_as_c_str().ok() == Some(name));
        let atomic_float_ext = has_ext(ash::ext::shader_atomic_float::NAME);
        let mut fatomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
        {
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut f13);
            if atomic_float_ext {
                f2 = f2.push_next(&mut fatomic);
            }
            instance.get_physical_device_features2(pd, &mut f2);
        }
        let api13 = vk::api_version_major(props.api_version) >= 1 && vk::api_version_minor(props.api_version) >= 3;
        let sg_ctrl_ok = api13 && f13.subgroup_size_control == vk::TRUE && sg_ctrl.required_subgroup_size_stages.contains(vk::ShaderStageFlags::COMPUTE);
        let (min_sg, max_sg) = if sg_ctrl_ok { (sg_ctrl.min_subgroup_size, sg_ctrl.max_subgroup_size) } else { (subgroup.subgroup_size, subgroup.subgroup_size) };
        let need = vk::SubgroupFeatureFlags::BASIC
            | vk::SubgroupFeatureFlags::VOTE
            | vk::SubgroupFeatureFlags::ARITHMETIC
            | vk::SubgroupFeatureFlags::BALLOT
            | vk::SubgroupFeatureFlags::SHUFFLE;
        let subgroup_ops_ok = subgroup.supported_stages.contains(vk::ShaderStageFlags::COMPUTE) && subgroup.supported_operations.contains(need);

        let qf = instance.get_physical_device_queue_family_properties(pd);
        let ts_bits = qf.get(queue_family as usize).map(|q| q.timestamp_valid_bits).unwrap_or(0);
        let mem = instance.get_physical_device_memory_properties(pd);
        let device_local_bytes = mem.memory_heaps_as_slice().iter().filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL)).map(|h| h.size).max().unwrap_or(0);
        let mut maint3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut maint3);
        instance.get_physical_device_properties2(pd, &mut p2);

        let cstr = |s: &[std::ffi::c_char]| -> String {
            let bytes: Vec<u8> = s.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
            String::from_utf8_lossy(&bytes).into_owned()
        };
        Capabilities {
            device_name: cstr(&props.device_name),
            driver_name: cstr(&driver.driver_name),
            driver_info: cstr(&driver.driver_info),
            vendor_id: props.vendor_id,
            device_type: props.device_type,
            api_version: props.api_version,
            subgroup_size: subgroup.subgroup_size,
            min_subgroup_size: min_sg,
            max_subgroup_size: max_sg,
            subgroup_size_control: sg_ctrl_ok,
            compute_full_subgroups: api13 && f13.compute_full_subgroups == vk::TRUE,
            subgroup_ops_ok,
            max_shared_memory: props.limits.max_compute_shared_memory_size,
            max_storage_buffer_range: props.limits.max_storage_buffer_range as u64,
            max_workgroup_count: props.limits.max_compute_work_group_count,
            max_workgroup_invocations: props.limits.max_compute_work_group_invocations,
            max_workgroup_size: props.limits.max_compute_work_group_size,
            max_push_constants: props.limits.max_push_constants_size,
            max_storage_buffers_per_stage: props.limits.max_per_stage_descriptor_storage_buffers,
            max_memory_allocation: maint3.max_memory_allocation_size,
            min_storage_buffer_offset_alignment: props.limits.min_storage_buffer_offset_alignment,
            max_texel_buffer_elements: props.limits.max_texel_buffer_elements as u64,
            min_texel_buffer_offset_alignment: props.limits.min_texel_buffer_offset_alignment,
            buffer_device_address: f12.buffer_device_address == vk::TRUE,
            float_atomics: atomic_float_ext && fatomic.shader_buffer_float32_atomic_add == vk::TRUE,
            timestamp_period: props.limits.timestamp_period,
            timestamp_valid_bits: ts_bits,
            device_local_bytes,
        }
    }

    pub fn api_version_string(&self) -> String {
        format!("{}.{}.{}", vk::api_version_major(self.api_version), vk::api_version_minor(self.api_version), vk::api_version_patch(self.api_version))
    }

    pub fn is_cpu(&self) -> bool {
        self.device_type == vk::PhysicalDeviceType::CPU
    }

    /// One-line description used by benchmarks and logs.
    pub fn describe(&self) -> String {
        format!(
            "{} ({}; {}; Vulkan {}; subgroup {} [{}..{}])",
            self.device_name,
            self.driver_name,
            self.driver_info,
            self.api_version_string(),
            self.subgroup_size,
            self.min_subgroup_size,
            self.max_subgroup_size
        )
    }
}
