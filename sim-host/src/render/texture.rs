//! Procedural textures (multi-octave value noise plus speckle), baked into a table of brightness multipliers.
use crate::rng::splitmix64;
use rayon::prelude::*;

/// A baked texture over a rectangle of a plane: `multiplier(a, b)` around 1.0.
#[derive(Clone, Debug)]
pub struct Texture {
    width: usize,
    height: usize,
    origin: [f64; 2],
    inv_texel: f64,
    origin_f32: [f32; 2],
    inv_texel_f32: f32,
    data: Vec<f32>,
}

fn lattice(ix: i64, iy: i64, seed: u64) -> f32 {
    let mut s = seed
        ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    let h = splitmix64(&mut s);
    ((h >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
}

/// The four lattice values around a cell, kept while consecutive texels fall in the same cell (a texel is
/// 1-4 mm, a cell 8-500 mm: the hashes were most of a bake's cost).
#[derive(Clone, Copy)]
struct CellCorners {
    cell: Option<(i64, i64)>,
    /// At (ix, iy), (ix + 1, iy), (ix, iy + 1), (ix + 1, iy + 1).
    v: [f32; 4],
}

impl CellCorners {
    fn new() -> Self {
        Self { cell: None, v: [0.0; 4] }
    }

    fn at(&mut self, ix: i64, iy: i64, seed: u64) -> [f32; 4] {
        if self.cell != Some((ix, iy)) {
            self.cell = Some((ix, iy));
            self.v = [
                lattice(ix, iy, seed),
                lattice(ix + 1, iy, seed),
                lattice(ix, iy + 1, seed),
                lattice(ix + 1, iy + 1, seed),
            ];
        }
        self.v
    }
}

fn value_noise(x: f64, y: f64, cell: f64, seed: u64, corners: &mut CellCorners) -> f32 {
    let (fx, fy) = (x / cell, y / cell);
    let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
    let (tx, ty) = ((fx - ix as f64) as f32, (fy - iy as f64) as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(tx), s(ty));
    let [l00, l10, l01, l11] = corners.at(ix, iy, seed);
    let a = l00 + sx * (l10 - l00);
    let b = l01 + sx * (l11 - l01);
    a + sy * (b - a)
}

/// What the texture looks like.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextureKind {
    /// Smooth plaster: large soft blotches and a fine grain.
    Plaster,
    /// Concrete: blotches, grain and sparse dark and light speckles.
    Concrete,
    /// Speckled vinyl: dense chips of about a centimetre over a fine grain (good features for optical flow
    /// from a metre up).
    Speckled,
}

impl Texture {
    /// Bakes a texture covering `[origin, origin + size_m]` with square texels of `texel_m`.
    /// `contrast` is the relative amplitude (0 gives a uniform texture).
    pub fn bake(
        kind: TextureKind,
        contrast: f64,
        seed: u64,
        origin: [f64; 2],
        size_m: [f64; 2],
        texel_m: f64,
    ) -> Self {
        let width = (size_m[0] / texel_m).ceil().max(1.0) as usize;
        let height = (size_m[1] / texel_m).ceil().max(1.0) as usize;
        let mut data = vec![1.0f32; width * height];
        if contrast > 0.0 {
            let octaves: &[(f64, f32)] = match kind {
                TextureKind::Plaster => &[(0.5, 0.35), (0.12, 0.3), (0.03, 0.2), (0.008, 0.15)],
                TextureKind::Concrete => &[(0.4, 0.25), (0.08, 0.25), (0.02, 0.25), (0.006, 0.25)],
                TextureKind::Speckled => &[(0.3, 0.15), (0.05, 0.15), (0.01, 0.2)],
            };
            // Each texel is a pure function of its position: rows are baked on the thread pool.
            data.par_chunks_mut(width).enumerate().for_each(|(j, row)| {
                let mut corners = vec![CellCorners::new(); octaves.len()];
                for (i, texel) in row.iter_mut().enumerate() {
                    let (x, y) =
                        (origin[0] + (i as f64 + 0.5) * texel_m, origin[1] + (j as f64 + 0.5) * texel_m);
                    let mut v = 0.0f32;
                    for (k, (&(cell, amp), c)) in octaves.iter().zip(&mut corners).enumerate() {
                        v += amp * value_noise(x, y, cell, seed.wrapping_add(k as u64 * 7919), c);
                    }
                    if kind == TextureKind::Concrete {
                        // Speckles: sparse texels much darker or lighter.
                        let mut s = seed ^ ((i as u64) << 32 | j as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93);
                        let h = splitmix64(&mut s);
                        if h.is_multiple_of(97) {
                            v -= 1.2;
                        } else if h.is_multiple_of(89) {
                            v += 0.9;
                        }
                    }
                    if kind == TextureKind::Speckled {
                        // Chips: cells of 12 mm on a grid jittered per row, 40 % of them lighter or darker.
                        let cell = 0.012;
                        let (cx, cy) = ((x / cell).floor() as i64, (y / cell).floor() as i64);
                        let mut s = seed
                            ^ (cx as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                            ^ (cy as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93);
                        let h = splitmix64(&mut s);
                        if h % 10 < 4 {
                            v += ((h >> 32) as f32 / u32::MAX as f32) * 2.4 - 1.2;
                        }
                    }
                    *texel = (1.0 + contrast as f32 * v).max(0.05);
                }
            });
        }
        Self {
            width,
            height,
            origin,
            inv_texel: 1.0 / texel_m,
            origin_f32: origin.map(|v| v as f32),
            inv_texel_f32: (1.0 / texel_m) as f32,
            data,
        }
    }

    /// Width and height in texels.
    pub fn dims(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The texels, row-major.
    pub fn texels(&self) -> &[f32] {
        &self.data
    }

    /// Brightness multiplier at plane coordinates `(a, b)` (nearest texel; clamped at the border).
    #[inline(always)]
    pub fn sample(&self, a: f32, b: f32) -> f32 {
        // Saturating float-to-int casts, then clamps: no branches, no f64.
        let i =
            (((a - self.origin_f32[0]) * self.inv_texel_f32) as i32).clamp(0, self.width as i32 - 1) as usize;
        let j = (((b - self.origin_f32[1]) * self.inv_texel_f32) as i32).clamp(0, self.height as i32 - 1)
            as usize;
        self.data[j * self.width + i]
    }

    /// Bilinear sample (for fine renders such as the downward camera).
    pub fn sample_bilinear(&self, a: f64, b: f64) -> f32 {
        let fx = (a - self.origin[0]) * self.inv_texel - 0.5;
        let fy = (b - self.origin[1]) * self.inv_texel - 0.5;
        let (ix, iy) = (fx.floor(), fy.floor());
        let (tx, ty) = ((fx - ix) as f32, (fy - iy) as f32);
        let at = |i: f64, j: f64| {
            let i = (i as i64).clamp(0, self.width as i64 - 1) as usize;
            let j = (j as i64).clamp(0, self.height as i64 - 1) as usize;
            self.data[j * self.width + i]
        };
        let a0 = at(ix, iy) + tx * (at(ix + 1.0, iy) - at(ix, iy));
        let a1 = at(ix, iy + 1.0) + tx * (at(ix + 1.0, iy + 1.0) - at(ix, iy + 1.0));
        a0 + ty * (a1 - a0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The value noise as it was computed before the cell corners were kept: every corner hashed each time.
    fn value_noise_direct(x: f64, y: f64, cell: f64, seed: u64) -> f32 {
        let (fx, fy) = (x / cell, y / cell);
        let (ix, iy) = (fx.floor() as i64, fy.floor() as i64);
        let (tx, ty) = ((fx - ix as f64) as f32, (fy - iy as f64) as f32);
        let s = |t: f32| t * t * (3.0 - 2.0 * t);
        let (sx, sy) = (s(tx), s(ty));
        let a = lattice(ix, iy, seed) + sx * (lattice(ix + 1, iy, seed) - lattice(ix, iy, seed));
        let b = lattice(ix, iy + 1, seed) + sx * (lattice(ix + 1, iy + 1, seed) - lattice(ix, iy + 1, seed));
        a + sy * (b - a)
    }

    #[test]
    fn keeping_the_cell_corners_bakes_the_same_value_noise() {
        // Texels across cell boundaries in both directions, negative coordinates included, a cell smaller
        // than a texel, and the cache moved back and forth between cells.
        let mut c = CellCorners::new();
        let mut checked = 0;
        for &cell in &[0.5, 0.03, 0.008, 0.001] {
            for j in 0..40 {
                for i in 0..400 {
                    let (x, y) = (-0.4 + i as f64 * 0.0027, -0.05 + j as f64 * 0.0031);
                    let want = value_noise_direct(x, y, cell, 99);
                    assert_eq!(
                        value_noise(x, y, cell, 99, &mut c).to_bits(),
                        want.to_bits(),
                        "{x} {y} {cell}"
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 64_000);
        // A whole bake of each kind equals the direct sum of octaves.
        for kind in [TextureKind::Plaster, TextureKind::Concrete, TextureKind::Speckled] {
            let t = Texture::bake(kind, 0.3, 7, [-1.0, 0.0], [0.3, 0.1], 0.002);
            let (w, _) = t.dims();
            let octaves: &[(f64, f32)] = match kind {
                TextureKind::Plaster => &[(0.5, 0.35), (0.12, 0.3), (0.03, 0.2), (0.008, 0.15)],
                TextureKind::Concrete => &[(0.4, 0.25), (0.08, 0.25), (0.02, 0.25), (0.006, 0.25)],
                TextureKind::Speckled => &[(0.3, 0.15), (0.05, 0.15), (0.01, 0.2)],
            };
            // Texels without a speckle or chip (those are added on top, unchanged): the smooth part matches.
            let mut same = 0;
            for (n, &texel) in t.texels().iter().enumerate() {
                let (i, j) = (n % w, n / w);
                let (x, y) = (-1.0 + (i as f64 + 0.5) * 0.002, (j as f64 + 0.5) * 0.002);
                let mut v = 0.0f32;
                for (k, &(cell, amp)) in octaves.iter().enumerate() {
                    v += amp * value_noise_direct(x, y, cell, 7u64.wrapping_add(k as u64 * 7919));
                }
                same += ((1.0 + 0.3f32 * v).max(0.05).to_bits() == texel.to_bits()) as usize;
            }
            let n = t.texels().len();
            // Plaster has nothing on top; concrete's speckles are 2 %, the vinyl's chips 40 % of its cells.
            let want = match kind {
                TextureKind::Plaster => n,
                TextureKind::Concrete => n * 95 / 100,
                TextureKind::Speckled => n * 40 / 100,
            };
            assert!(same >= want, "{kind:?}: {same} of {n}");
        }
    }
}
