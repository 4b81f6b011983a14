//! Minimal SPIR-V reading: enough to check a kernel's declared bindings.

use anyhow::{bail, Result};

/// Words of a SPIR-V module from bytes (as embedded with `include_bytes!`).
pub(crate) fn words(bytes: &[u8]) -> Result<Vec<u32>> {
    if bytes.len() % 4 != 0 || bytes.len() < 20 {
        bail!("SPIR-V of {} bytes is not a whole module", bytes.len());
    }
    let w: Vec<u32> = bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if w[0] != 0x0723_0203 {
        bail!("not SPIR-V (magic {:#x})", w[0]);
    }
    Ok(w)
}

/// Number of descriptor bindings in set 0 (max binding + 1).
pub(crate) fn binding_count(words: &[u32]) -> usize {
    const OP_DECORATE: u32 = 71;
    const DEC_BINDING: u32 = 33;
    let mut i = 5;
    let mut count = 0usize;
    while i < words.len() {
        let n = (words[i] >> 16) as usize;
        let op = words[i] & 0xffff;
        if n == 0 {
            break;
        }
        if op == OP_DECORATE && n >= 4 && words[i + 2] == DEC_BINDING {
            count = count.max(words[i + 3] as usize + 1);
        }
        i += n;
    }
    count
}
