//! Minimal SPIR-V reading: enough to check a kernel's declared bindings
//! and the size of its push-constant block.

use anyhow::{bail, Result};

/// Words of a SPIR-V module from bytes (as embedded with `include_bytes!`).
pub(crate) fn words(bytes: &[u8]) -> Result<Vec<u32>> {
    if !bytes.len().is_multiple_of(4) || bytes.len() < 20 {
        bail!("SPIR-V of {} bytes is not a whole module", bytes.len());
    }
    let w: Vec<u32> = bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if w[0] != 0x0723_0203 {
        bail!("not SPIR-V (magic {:#x})", w[0]);
    }
    Ok(w)
}

const OP_DECORATE: u32 = 71;

/// The module's instructions after its 5-word header, each as its words
/// (opcode and word count first); stops at a malformed word count.
fn instructions(words: &[u32]) -> impl Iterator<Item = &[u32]> {
    let mut i = 5;
    std::iter::from_fn(move || {
        let n = (*words.get(i)? >> 16) as usize;
        if n == 0 || i + n > words.len() {
            return None;
        }
        let w = &words[i..i + n];
        i += n;
        Some(w)
    })
}

const DEC_BINDING: u32 = 33;

/// Number of descriptor bindings in set 0 (max binding + 1).
pub(crate) fn binding_count(words: &[u32]) -> usize {
    instructions(words).filter(|w| w[0] & 0xffff == OP_DECORATE && w.len() >= 4 && w[2] == DEC_BINDING).map(|w| w[3] as usize + 1).max().unwrap_or(0)
}

/// What a binding of the shader is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    /// A storage buffer (every binding but a texel buffer).
    Storage,
    /// A uniform texel buffer of 32-bit floats (`samplerBuffer`), read
    /// with `texelFetch`.
    TexelF32,
    /// A uniform texel buffer of 32-bit unsigned integers (`usamplerBuffer`).
    TexelU32,
}

/// The kind of each of the first `count` bindings: a texel buffer where the
/// binding's variable is a buffer-dimension sampled image (float or
/// unsigned 32-bit texels), a storage buffer otherwise.
pub(crate) fn binding_kinds(words: &[u32], count: usize) -> Vec<BindingKind> {
    use std::collections::HashMap;
    const OP_TYPE_INT: u32 = 21;
    const OP_TYPE_FLOAT: u32 = 22;
    const OP_TYPE_IMAGE: u32 = 25;
    const OP_TYPE_SAMPLED_IMAGE: u32 = 27;
    const OP_TYPE_POINTER: u32 = 32;
    const OP_VARIABLE: u32 = 59;
    const DIM_BUFFER: u32 = 5;
    let mut scalars: HashMap<u32, BindingKind> = HashMap::new();
    let mut images: HashMap<u32, BindingKind> = HashMap::new();
    let mut sampled: HashMap<u32, BindingKind> = HashMap::new();
    let mut pointers: HashMap<u32, BindingKind> = HashMap::new();
    let mut variables: HashMap<u32, BindingKind> = HashMap::new();
    let mut bound: Vec<(u32, usize)> = Vec::new();
    for w in instructions(words) {
        let (op, n) = (w[0] & 0xffff, w.len());
        match op {
            OP_TYPE_FLOAT if n >= 3 && w[2] == 32 => {
                scalars.insert(w[1], BindingKind::TexelF32);
            }
            OP_TYPE_INT if n >= 4 && w[2] == 32 && w[3] == 0 => {
                scalars.insert(w[1], BindingKind::TexelU32);
            }
            OP_TYPE_IMAGE if n >= 4 && w[3] == DIM_BUFFER => {
                if let Some(&k) = scalars.get(&w[2]) {
                    images.insert(w[1], k);
                }
            }
            OP_TYPE_SAMPLED_IMAGE if n >= 3 => {
                if let Some(&k) = images.get(&w[2]) {
                    sampled.insert(w[1], k);
                }
            }
            OP_TYPE_POINTER if n >= 4 => {
                if let Some(&k) = sampled.get(&w[3]) {
                    pointers.insert(w[1], k);
                }
            }
            OP_VARIABLE if n >= 4 => {
                if let Some(&k) = pointers.get(&w[1]) {
                    variables.insert(w[2], k);
                }
            }
            OP_DECORATE if n >= 4 && w[2] == DEC_BINDING => bound.push((w[1], w[3] as usize)),
            _ => {}
        }
    }
    let mut kinds = vec![BindingKind::Storage; count];
    for (var, b) in bound {
        if let (Some(&k), Some(slot)) = (variables.get(&var), kinds.get_mut(b)) {
            *slot = k;
        }
    }
    kinds
}

/// Size in bytes of the shader's push-constant block, as its members'
/// offsets and types lay it out (the end of its last byte; 0 when the
/// shader declares none). Arrays sized by a specialization constant count
/// at the constant's default. `None` when the block uses a type this
/// reader does not size (matrices, pointers), so that the caller can skip
/// its check rather than fail.
pub(crate) fn push_constant_bytes(words: &[u32]) -> Option<u32> {
    use std::collections::HashMap;
    const OP_TYPE_INT: u32 = 21;
    const OP_TYPE_FLOAT: u32 = 22;
    const OP_TYPE_VECTOR: u32 = 23;
    const OP_TYPE_ARRAY: u32 = 28;
    const OP_TYPE_STRUCT: u32 = 30;
    const OP_TYPE_POINTER: u32 = 32;
    const OP_CONSTANT: u32 = 43;
    const OP_SPEC_CONSTANT: u32 = 50;
    const OP_VARIABLE: u32 = 59;
    const OP_MEMBER_DECORATE: u32 = 72;
    const DEC_ARRAY_STRIDE: u32 = 6;
    const DEC_OFFSET: u32 = 35;
    const SC_PUSH_CONSTANT: u32 = 9;
    enum Ty {
        Scalar(u32),
        Vector(u32, u32),
        Array(u32, u32),
        Struct(Vec<u32>),
    }
    let mut types: HashMap<u32, Ty> = HashMap::new();
    let mut pointers: HashMap<u32, u32> = HashMap::new();
    let mut constants: HashMap<u32, u32> = HashMap::new();
    let mut strides: HashMap<u32, u32> = HashMap::new();
    let mut offsets: HashMap<(u32, u32), u32> = HashMap::new();
    let mut block = None;
    for w in instructions(words) {
        let (op, n) = (w[0] & 0xffff, w.len());
        match op {
            OP_TYPE_INT | OP_TYPE_FLOAT if n >= 3 => {
                types.insert(w[1], Ty::Scalar(w[2] / 8));
            }
            OP_TYPE_VECTOR if n >= 4 => {
                types.insert(w[1], Ty::Vector(w[2], w[3]));
            }
            OP_TYPE_ARRAY if n >= 4 => {
                types.insert(w[1], Ty::Array(w[2], w[3]));
            }
            OP_TYPE_STRUCT if n >= 2 => {
                types.insert(w[1], Ty::Struct(w[2..].to_vec()));
            }
            OP_TYPE_POINTER if n >= 4 && w[2] == SC_PUSH_CONSTANT => {
                pointers.insert(w[1], w[3]);
            }
            OP_CONSTANT | OP_SPEC_CONSTANT if n >= 4 => {
                constants.insert(w[2], w[3]);
            }
            OP_VARIABLE if n >= 4 && w[3] == SC_PUSH_CONSTANT => {
                block = pointers.get(&w[1]).copied();
            }
            OP_DECORATE if n >= 4 && w[2] == DEC_ARRAY_STRIDE => {
                strides.insert(w[1], w[3]);
            }
            OP_MEMBER_DECORATE if n >= 5 && w[3] == DEC_OFFSET => {
                offsets.insert((w[1], w[2]), w[4]);
            }
            _ => {}
        }
    }
    fn size(t: u32, types: &HashMap<u32, Ty>, constants: &HashMap<u32, u32>, strides: &HashMap<u32, u32>, offsets: &HashMap<(u32, u32), u32>) -> Option<u32> {
        match types.get(&t)? {
            Ty::Scalar(b) => Some(*b),
            Ty::Vector(c, k) => Some(size(*c, types, constants, strides, offsets)? * k),
            Ty::Array(e, len) => {
                let stride = match strides.get(&t) {
                    Some(s) => *s,
                    None => size(*e, types, constants, strides, offsets)?,
                };
                Some(stride * constants.get(len)?)
            }
            Ty::Struct(members) => {
                let mut end = 0;
                for (m, &mt) in members.iter().enumerate() {
                    let off = *offsets.get(&(t, m as u32))?;
                    end = end.max(off + size(mt, types, constants, strides, offsets)?);
                }
                Some(end)
            }
        }
    }
    match block {
        None => Some(0),
        Some(t) => size(t, &types, &constants, &strides, &offsets),
    }
}
