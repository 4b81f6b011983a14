//! Choosing a physical device: by index, by name substring, or the best one.

use crate::caps::Capabilities;
use anyhow::{bail, Result};
use ash::vk;

/// How to pick a device: `--device` / `TGS_DEVICE` take an index (`0`) or a
/// case-insensitive name substring (`llvmpipe`, `h100`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum DeviceSelector {
    /// Prefer discrete, then integrated, virtual, CPU.
    #[default]
    Best,
    Index(usize),
    Name(String),
}

impl DeviceSelector {
    pub fn parse(s: &str) -> Self {
        let s = s.trim();
        if s.is_empty() {
            DeviceSelector::Best
        } else if let Ok(i) = s.parse::<usize>() {
            DeviceSelector::Index(i)
        } else {
            DeviceSelector::Name(s.to_string())
        }
    }

    /// The explicit choice if given, else `TGS_DEVICE`, else [`DeviceSelector::Best`].
    pub fn from_arg_or_env(arg: Option<&str>) -> Self {
        match arg {
            Some(a) => Self::parse(a),
            None => std::env::var("TGS_DEVICE").map(|v| Self::parse(&v)).unwrap_or_default(),
        }
    }
}

/// A physical device as listed by `tgs devices`.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    pub index: usize,
    pub caps: Capabilities,
    /// Compute-capable queue family, if any.
    pub compute_queue_family: Option<u32>,
    /// Why the device cannot be used by tgs, if it cannot.
    pub unusable: Option<String>,
}

pub(crate) fn pick_queue_family(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Option<u32> {
    // SAFETY: `pd` was enumerated from `instance`.
    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    // Prefer a compute-only family (async compute), then any with compute.
    let compute = |q: &vk::QueueFamilyProperties| q.queue_flags.contains(vk::QueueFlags::COMPUTE) && q.queue_count > 0;
    families
        .iter()
        .position(|q| compute(q) && !q.queue_flags.contains(vk::QueueFlags::GRAPHICS) && q.timestamp_valid_bits > 0)
        .or_else(|| families.iter().position(compute))
        .map(|i| i as u32)
}

pub(crate) fn describe_all(instance: &ash::Instance) -> Result<Vec<(vk::PhysicalDevice, DeviceInfo)>> {
    // SAFETY: the instance is live for this call.
    let pds = unsafe { instance.enumerate_physical_devices() }?;
    let mut out = Vec::new();
    for (index, pd) in pds.into_iter().enumerate() {
        let qf = pick_queue_family(instance, pd);
        // SAFETY: `pd` was enumerated from `instance`.
        let caps = unsafe { Capabilities::query(instance, pd, qf.unwrap_or(0)) };
        let unusable = if vk::api_version_minor(caps.api_version) < 2 && vk::api_version_major(caps.api_version) == 1 {
            Some(format!("Vulkan {} < 1.2", caps.api_version_string()))
        } else if qf.is_none() {
            Some("no compute queue".into())
        } else if !caps.subgroup_ops_ok {
            Some("missing subgroup basic/vote/arithmetic/ballot/shuffle in compute".into())
        } else {
            None
        };
        out.push((pd, DeviceInfo { index, caps, compute_queue_family: qf, unusable }));
    }
    Ok(out)
}

fn type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

pub(crate) fn choose(devices: &[(vk::PhysicalDevice, DeviceInfo)], sel: &DeviceSelector) -> Result<usize> {
    let names = || devices.iter().map(|(_, d)| format!("  [{}] {}", d.index, d.caps.device_name)).collect::<Vec<_>>().join("\n");
    if devices.is_empty() {
        bail!(
            "no Vulkan device found. Without a GPU, install Mesa's CPU driver lavapipe \
             (`apt-get install mesa-vulkan-drivers`, or run scripts/setup.sh)"
        );
    }
    let usable = |i: usize| -> Result<usize> {
        let d = &devices[i].1;
        if let Some(why) = &d.unusable {
            bail!("device [{}] {} is not usable by tgs: {}", d.index, d.caps.device_name, why);
        }
        Ok(i)
    };
    match sel {
        DeviceSelector::Index(i) => {
            if *i >= devices.len() {
                bail!("--device {i}: there are only {} Vulkan device(s):\n{}", devices.len(), names());
            }
            usable(*i)
        }
        DeviceSelector::Name(n) => {
            let lower = n.to_lowercase();
            let hits: Vec<usize> = (0..devices.len()).filter(|&i| devices[i].1.caps.device_name.to_lowercase().contains(&lower)).collect();
            match hits.as_slice() {
                [] => bail!("--device {n:?}: no Vulkan device name contains it; devices are:\n{}", names()),
                [i] => usable(*i),
                many => {
                    // Several match: take the first usable one.
                    many.iter().copied().find(|&i| devices[i].1.unusable.is_none()).map(Ok).unwrap_or_else(|| usable(many[0]))
                }
            }
        }
        DeviceSelector::Best => {
            let best = (0..devices.len()).filter(|&i| devices[i].1.unusable.is_none()).min_by_key(|&i| (type_rank(devices[i].1.caps.device_type), i));
            match best {
                Some(i) => Ok(i),
                None => bail!(
                    "no Vulkan device is usable by tgs (needs Vulkan 1.2, a compute queue and subgroup ops):\n{}",
                    devices.iter().map(|(_, d)| format!("  [{}] {}: {}", d.index, d.caps.device_name, d.unusable.clone().unwrap_or_default())).collect::<Vec<_>>().join("\n")
                ),
            }
        }
    }
}

/// List every Vulkan device (for `tgs devices`).
pub fn list_devices() -> Result<Vec<DeviceInfo>> {
    let entry = crate::context::load_entry()?;
    let instance = crate::context::create_instance(&entry, false)?.0;
    let list = describe_all(&instance);
    // SAFETY: nothing was created from this instance (describe_all only queries).
    unsafe { instance.destroy_instance(None) };
    Ok(list?.into_iter().map(|(_, d)| d).collect())
}
