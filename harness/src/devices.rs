//! `tgs devices`: every Vulkan device with what tgs cares about.

use anyhow::Result;
use serde_json::json;
use tgs_engine::{list_devices, DeviceInfo, DeviceSelector};

pub fn to_json(d: &DeviceInfo) -> serde_json::Value {
    let c = &d.caps;
    json!({
        "index": d.index,
        "name": c.device_name,
        "type": format!("{:?}", c.device_type),
        "driver": c.driver_name,
        "driver_info": c.driver_info,
        "vulkan": c.api_version_string(),
        "subgroup_size": c.subgroup_size,
        "subgroup_size_range": [c.min_subgroup_size, c.max_subgroup_size],
        "subgroup_size_control": c.subgroup_size_control,
        "max_shared_memory": c.max_shared_memory,
        "max_storage_buffer_range": c.max_storage_buffer_range,
        "max_workgroup_count": c.max_workgroup_count,
        "max_workgroup_invocations": c.max_workgroup_invocations,
        "max_push_constants": c.max_push_constants,
        "max_memory_allocation": c.max_memory_allocation,
        "device_local_bytes": c.device_local_bytes,
        "buffer_device_address": c.buffer_device_address,
        "float_atomics": c.float_atomics,
        "timestamp_period_ns": c.timestamp_period,
        "timestamp_valid_bits": c.timestamp_valid_bits,
        "usable": d.unusable.is_none(),
        "unusable_reason": d.unusable,
    })
}

/// The devices `sel` names (all of them for the default): an index or a
/// name that matches none is an error listing what there is.
pub fn select(devs: Vec<DeviceInfo>, sel: &DeviceSelector) -> Result<Vec<DeviceInfo>> {
    let names = || devs.iter().map(|d| format!("[{}] {}", d.index, d.caps.device_name)).collect::<Vec<_>>().join(", ");
    let picked: Vec<DeviceInfo> = match sel {
        DeviceSelector::Best => return Ok(devs),
        DeviceSelector::Index(i) => devs.iter().filter(|d| d.index == *i).cloned().collect(),
        DeviceSelector::Name(n) => devs.iter().filter(|d| d.caps.device_name.to_lowercase().contains(&n.to_lowercase())).cloned().collect(),
    };
    if picked.is_empty() {
        anyhow::bail!(
            "--device {}: no such Vulkan device (there are: {})",
            match sel {
                DeviceSelector::Index(i) => i.to_string(),
                DeviceSelector::Name(n) => n.clone(),
                _ => String::new(),
            },
            if devs.is_empty() { "none".to_string() } else { names() }
        );
    }
    Ok(picked)
}

pub fn run(json_out: bool, sel: &DeviceSelector) -> Result<()> {
    let devs = select(list_devices()?, sel)?;
    if json_out {
        println!("{}", serde_json::to_string_pretty(&devs.iter().map(to_json).collect::<Vec<_>>())?);
        return Ok(());
    }
    if devs.is_empty() {
        println!("no Vulkan devices (install mesa-vulkan-drivers for the CPU driver lavapipe)");
    }
    for d in &devs {
        let c = &d.caps;
        println!("[{}] {} ({:?})", d.index, c.device_name, c.device_type);
        println!("    driver        {} — {} (Vulkan {})", c.driver_name, c.driver_info, c.api_version_string());
        println!("    subgroup      {} (range {}..{}{})", c.subgroup_size, c.min_subgroup_size, c.max_subgroup_size, if c.subgroup_size_control { ", size control" } else { "" });
        println!(
            "    limits        shared {} KiB, storage range {} MiB, workgroups {:?}, invocations {}, push {} B",
            c.max_shared_memory / 1024,
            c.max_storage_buffer_range >> 20,
            c.max_workgroup_count,
            c.max_workgroup_invocations,
            c.max_push_constants
        );
        println!(
            "    memory        {:.1} GiB device-local, max allocation {:.1} GiB",
            c.device_local_bytes as f64 / (1u64 << 30) as f64,
            c.max_memory_allocation as f64 / (1u64 << 30) as f64
        );
        println!(
            "    features      buffer device address: {}, float atomics: {}, timestamps: {} bits @ {} ns",
            c.buffer_device_address, c.float_atomics, c.timestamp_valid_bits, c.timestamp_period
        );
        if let Some(why) = &d.unusable {
            println!("    NOT USABLE    {why}");
        }
    }
    Ok(())
}
