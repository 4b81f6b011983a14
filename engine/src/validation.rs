//! Khronos validation layer hook-up: messages of error severity are kept so a
//! test can fail on them.

use ash::vk;
use std::ffi::{c_void, CStr};
use std::sync::Mutex;

pub(crate) const LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Errors reported by the validation layer for one context.
#[derive(Default)]
pub(crate) struct ValidationLog {
    pub errors: Mutex<Vec<String>>,
}

/// The validation layer's messenger callback: errors go to the context's log.
///
/// # Safety
/// Called by the layer only, with `data` null or valid for the call and
/// `user` null or the context's `ValidationLog`, which outlives the messenger.
pub(crate) unsafe extern "system" fn callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if data.is_null() || user.is_null() {
        return vk::FALSE;
    }
    let msg = if (*data).p_message.is_null() { String::from("(no message)") } else { CStr::from_ptr((*data).p_message).to_string_lossy().into_owned() };
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        eprintln!("[vulkan validation error] {msg}");
        let log = &*(user as *const ValidationLog);
        if let Ok(mut e) = log.errors.lock() {
            e.push(msg);
        }
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
        eprintln!("[vulkan validation warning] {msg}");
    }
    vk::FALSE
}

pub(crate) fn layer_available(entry: &ash::Entry) -> bool {
    // SAFETY: the entry holds the loaded loader; the query has no other precondition.
    unsafe { entry.enumerate_instance_layer_properties() }.map(|ls| ls.iter().any(|l| l.layer_name_as_c_str().ok() == Some(LAYER))).unwrap_or(false)
}
