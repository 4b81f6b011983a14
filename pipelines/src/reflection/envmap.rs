//! The learnable environment cube map of Stage II (method-notes §2.6):
//! six faces (+X, -X, +Y, -Y, +Z, -Z) of `res` x `res` texels, three raw
//! (pre-sigmoid) channels each, texel t = (face * res + row) * res + col at
//! floats [3t, 3t + 3). Its GPU copy carries the gradient and Adam moments.

use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context};

/// Largest face size (the texel index must fit the sort's keys and the
/// per-texel reduction's loop budget comfortably).
pub const MAX_ENV_RES: u32 = 1024;

/// A cube map on the host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostEnvMap {
    pub res: u32,
    /// 6 * res * res * 3 raw texel values.
    pub raw: Vec<f32>,
    /// Where the map's light comes from ([`EnvProxy`]); `None`: infinitely far.
    pub proxy: Option<EnvProxy>,
    /// With a proxy: the distance from its centre to the scene along each
    /// texel's direction (6 res^2 values, texel order), which replaces the
    /// proxy's one radius per lookup direction ([`DEPTH_ITERS`] refinements;
    /// glsl/reflection/color_common.glsl `env_dir`). Frozen: no gradient.
    pub depth: Option<Vec<f32>>,
}

/// Refinements of a depth-mapped lookup: the radius from the depth in the
/// direction found so far, starting from the mirror direction's own.
pub const DEPTH_ITERS: u32 = 4;

/// A parallax proxy: the map holds the light of a sphere of `radius`
/// around `centre` (world space), so a reflection from a point p in
/// direction w looks up the direction from `centre` to where the ray
/// p + t w leaves that sphere, not w itself (a local cube map). A point on
/// or outside the sphere looks up w.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvProxy {
    pub centre: [f32; 3],
    pub radius: f32,
}

impl EnvProxy {
    /// (centre, radius) for the shaders' push constants; radius 0 = none.
    pub fn packed(p: Option<EnvProxy>) -> [f32; 4] {
        p.map(|p| [p.centre[0], p.centre[1], p.centre[2], p.radius]).unwrap_or([0.0; 4])
    }
}

impl HostEnvMap {
    /// Every texel at the raw value `raw` (0 = sigmoid 0.5, the default of
    /// method-notes §3.7).
    pub fn constant(res: u32, raw: f32) -> Result<HostEnvMap> {
        check_res(res)?;
        Ok(HostEnvMap { res, raw: vec![raw; texels(res) * 3], proxy: None, depth: None })
    }

    pub fn texels(&self) -> usize {
        texels(self.res)
    }

    pub fn validate(&self) -> Result<()> {
        check_res(self.res)?;
        if self.raw.len() != texels(self.res) * 3 {
            bail!("environment map of face size {} needs {} values, has {}", self.res, texels(self.res) * 3, self.raw.len());
        }
        if let Some(i) = self.raw.iter().position(|v| !v.is_finite()) {
            bail!("environment map value {i} is {}", self.raw[i]);
        }
        if let Some(p) = self.proxy {
            if !(p.radius > 0.0 && p.radius.is_finite() && p.centre.iter().all(|c| c.is_finite())) {
                bail!("environment map proxy {p:?}: the radius must be positive and everything finite");
            }
        }
        if let Some(d) = &self.depth {
            if self.proxy.is_none() {
                bail!("environment map depth without a parallax proxy (the depths are distances from its centre)");
            }
            if d.len() != texels(self.res) {
                bail!("environment map depth of face size {} needs {} values, has {}", self.res, texels(self.res), d.len());
            }
            if let Some(i) = d.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
                bail!("environment map depth {i} is {} (distances must be finite and non-negative)", d[i]);
            }
        }
        Ok(())
    }

    /// The direction (not unit length; major axis component ±1) through the
    /// centre of texel (face, row, col): face coordinates x = 2 (col + 0.5)
    /// / res - 1, y likewise from the row, on the faces of method-notes §2.6
    /// (the inverse of the lookup in glsl/reflection/).
    pub fn texel_direction(res: u32, face: u32, row: u32, col: u32) -> [f32; 3] {
        let s = 2.0 / res as f32;
        let (x, y) = ((col as f32 + 0.5) * s - 1.0, (row as f32 + 0.5) * s - 1.0);
        match face {
            0 => [1.0, -y, -x],
            1 => [-1.0, -y, x],
            2 => [x, 1.0, y],
            3 => [x, -1.0, -y],
            4 => [x, -y, 1.0],
            _ => [-x, -y, -1.0],
        }
    }

    /// Activated colour (sigmoid) of texel (face, row, col).
    pub fn texel_rgb(&self, face: u32, row: u32, col: u32) -> [f32; 3] {
        let t = ((face * self.res + row) * self.res + col) as usize;
        std::array::from_fn(|c| 1.0 / (1.0 + (-self.raw[3 * t + c]).exp()))
    }

    /// The map as a horizontal cross (4 res wide, 3 res high, RGB, row-major;
    /// faces not in the cross are black):
    /// ```text
    ///        +Y
    ///   -X   +Z   +X   -Z
    ///        -Y
    /// ```
    /// (the layout of the usual OpenGL cube cross).
    pub fn cross(&self) -> (u32, u32, Vec<[f32; 3]>) {
        self.cross_of(|face, row, col| self.texel_rgb(face, row, col))
    }

    /// The depth ([`HostEnvMap::depth`]) in the layout of [`HostEnvMap::cross`]
    /// (one value per texel, 0 off the cross), when the map has one.
    pub fn depth_cross(&self) -> Option<(u32, u32, Vec<f32>)> {
        let d = self.depth.as_ref()?;
        let r = self.res;
        let (w, h, px) = self.cross_of(|face, row, col| [d[((face * r + row) * r + col) as usize]; 3]);
        Some((w, h, px.into_iter().map(|p| p[0]).collect()))
    }

    fn cross_of<T: Copy + Default>(&self, texel: impl Fn(u32, u32, u32) -> T) -> (u32, u32, Vec<T>) {
        let r = self.res;
        let (w, h) = (4 * r, 3 * r);
        let mut img = vec![T::default(); (w * h) as usize];
        // (face, cell x, cell y)
        let cells = [(0u32, 2u32, 1u32), (1, 0, 1), (2, 1, 0), (3, 1, 2), (4, 1, 1), (5, 3, 1)];
        for (face, cx, cy) in cells {
            for row in 0..r {
                for col in 0..r {
                    img[((cy * r + row) * w + cx * r + col) as usize] = texel(face, row, col);
                }
            }
        }
        (w, h, img)
    }
}

fn texels(res: u32) -> usize {
    6 * res as usize * res as usize
}

fn check_res(res: u32) -> Result<()> {
    if res == 0 || res > MAX_ENV_RES {
        bail!("environment map face size must be 1..={MAX_ENV_RES}, not {res}");
    }
    Ok(())
}

/// A trainable cube map on the GPU: raw texels, their gradient, Adam moments.
pub struct EnvMap {
    pub res: u32,
    pub params: Buffer<f32>,
    pub grads: Buffer<f32>,
    pub m: Buffer<f32>,
    pub v: Buffer<f32>,
    pub proxy: Option<EnvProxy>,
    /// [`HostEnvMap::depth`] (frozen).
    pub depth: Option<Buffer<f32>>,
}

impl EnvMap {
    pub fn upload(ctx: &Arc<Context>, h: &HostEnvMap) -> Result<EnvMap> {
        h.validate()?;
        let n = h.raw.len();
        Ok(EnvMap {
            res: h.res,
            params: Buffer::from_slice(ctx, "env.params", &h.raw)?,
            grads: Buffer::new(ctx, "env.grads", n)?,
            m: Buffer::new(ctx, "env.adam_m", n)?,
            v: Buffer::new(ctx, "env.adam_v", n)?,
            proxy: h.proxy,
            depth: h.depth.as_ref().map(|d| Buffer::from_slice(ctx, "env.depth", d)).transpose()?,
        })
    }

    pub fn texels(&self) -> u32 {
        texels(self.res) as u32
    }

    /// Floats in each of the map's arrays.
    pub fn len(&self) -> usize {
        3 * texels(self.res)
    }
    pub fn is_empty(&self) -> bool {
        false
    }

    pub fn download(&self) -> Result<HostEnvMap> {
        let depth = self.depth.as_ref().map(|d| d.download_range(0, self.texels() as usize)).transpose()?;
        Ok(HostEnvMap { res: self.res, raw: self.params.download_range(0, self.len())?, proxy: self.proxy, depth })
    }

    /// Refinements the colour kernels make (0 without a depth map).
    pub fn depth_iters(&self) -> u32 {
        if self.depth.is_some() && self.proxy.is_some() {
            DEPTH_ITERS
        } else {
            0
        }
    }

    /// The arrays a checkpoint stores, named, in a fixed order (the
    /// frozen depth, when there is one, apart: [`EnvMap::depth`]).
    pub fn arrays(&self) -> [(&'static str, &Buffer<f32>); 3] {
        [("env.param", &self.params), ("env.adam_m", &self.m), ("env.adam_v", &self.v)]
    }
}
