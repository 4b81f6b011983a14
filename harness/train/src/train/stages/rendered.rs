//! A render of one view as the trainer returns it, downloaded: the
//! scattering set's planes (`Rendered`), and in Stages II and III the
//! reflection layer it was composited with (`ReflRendered`).

use tgs_pipelines::Plane;

/// Render planes of one view, downloaded.
pub struct Rendered {
    pub width: u32,
    pub height: u32,
    /// Planes in the rasterizer's order (see `Plane`).
    pub planes: Vec<f32>,
    /// In Stage II: the scattering render and the reflection render this
    /// image was composited from.
    pub layers: Option<Box<(Rendered, ReflRendered)>>,
}

impl Rendered {
    pub fn plane(&self, p: Plane) -> &[f32] {
        let n = (self.width * self.height) as usize;
        let i = p.index(3) as usize;
        &self.planes[i * n..(i + 1) * n]
    }
}

/// The plane of R = sum w r in the reflection render, in both stages
/// (Stage II: [A (3), R, ...], Stage III: [F0 sum (3), R]).
pub const R_PLANE: usize = 3;

/// A Stage II render of one view, downloaded.
pub struct ReflRendered {
    pub width: u32,
    pub height: u32,
    /// The composite colour (3 planes) followed by the reflection set's
    /// alpha, depth, normal (3), median, distortion planes.
    pub composite: Vec<f32>,
    /// The reflection render: in Stage II [A (3), R, F0 sum (3) with
    /// Schlick], in Stage III [F0 sum (3), R]; then its geometry planes
    /// (`Plane` order for `channels`).
    pub refl: Vec<f32>,
    pub channels: u32,
    /// Stage III's light-field layers (None in Stage II).
    pub phi: Option<PhiLayers>,
}

/// What Stage III adds to a render.
pub struct PhiLayers {
    /// I_refl = F Phi per pixel (3 planes; 0 where Phi was not evaluated).
    pub reflected: Vec<f32>,
    /// 1 where Phi was evaluated (R > light_field.threshold), else 0.
    pub mask: Vec<f32>,
}

impl ReflRendered {
    /// I_refl (3 planes): Stage II's rasterized colour, Stage III's F Phi.
    pub fn i_refl(&self) -> &[f32] {
        match &self.phi {
            Some(p) => &p.reflected,
            None => &self.refl[..3 * self.pixels()],
        }
    }
    /// R = sum w r.
    pub fn r(&self) -> &[f32] {
        let n = self.pixels();
        &self.refl[R_PLANE * n..(R_PLANE + 1) * n]
    }
    /// sum w f0 (3 planes) when this render has it.
    pub fn f0_sum(&self) -> Option<&[f32]> {
        let n = self.pixels();
        match (&self.phi, self.channels) {
            (Some(_), _) => Some(&self.refl[..3 * n]),
            (None, 7) => Some(&self.refl[4 * n..7 * n]),
            _ => None,
        }
    }
    pub fn pixels(&self) -> usize {
        (self.width * self.height) as usize
    }
    pub fn refl_plane(&self, p: Plane) -> &[f32] {
        let n = self.pixels();
        let i = p.index(self.channels) as usize;
        &self.refl[i * n..(i + 1) * n]
    }
}
