//! What the forward camera's sensor does to the light the optics deliver: optical blur (a separable Gaussian,
//! row-wise), then per channel clipping at full scale, the tone curve (sRGB unless the scenario says
//! `forward_camera.response = "linear"`), sensor noise and 8-bit quantisation.
//!
//! Linear values are on the 0-255 scale (255 is the sensor's full scale). The tone curve is a table of the
//! encoded value every 1/64 grey level of linear light, read at the nearest entry (within 0.1 grey level of
//! the exact curve below 1 grey level of light, where sRGB's slope is 12.92, within 0.09 above and 0.023
//! above 10; tested), so the per-pixel cost is a table read, not a power.
use super::forward::{MAGIC, quantise};
use crate::imageio::RgbImage;
use rayon::prelude::*;
use vision_core::ToneCurve;

/// Table entries per grey level of linear light.
const STEPS: f32 = 64.0;
/// Entries: 0 ..= 255 grey levels in `STEPS`.
const ENTRIES: usize = 255 * STEPS as usize + 1;
/// The table's length: the next power of two, so that a masked index needs no bounds check (the entries
/// beyond `ENTRIES` are never read: indices are clamped to `ENTRIES - 1` first).
const TABLE_LEN: usize = ENTRIES.next_power_of_two();

/// The sensor's response from linear light to the encoded value before noise (0-255 scale).
pub(super) struct Response {
    /// `None` for a linear response (the value is kept as it is).
    table: Option<Box<[f32; TABLE_LEN]>>,
}

impl Response {
    pub(super) fn new(curve: ToneCurve) -> Self {
        let table = match curve {
            ToneCurve::Linear => None,
            _ => {
                let mut t = Box::new([255.0f32; TABLE_LEN]);
                for (i, o) in t.iter_mut().take(ENTRIES).enumerate() {
                    *o = 255.0 * curve.encode(i as f32 / (STEPS * 255.0));
                }
                Some(t)
            }
        };
        Self { table }
    }

    /// The encoded value of linear light `x` (0-255 scale; clipped at 0 and 255 by the curve): the table's
    /// nearest entry (the index rounded branch-free, as `quantise` does, so the loop vectorises but for the
    /// table read).
    #[cfg(test)]
    fn encode(t: &[f32; TABLE_LEN], x: f32) -> f32 {
        t[Self::index(x) as usize]
    }

    /// The table entry nearest to linear light `x`.
    #[inline(always)]
    #[allow(clippy::manual_clamp)]
    fn index(x: f32) -> u32 {
        // `max` first, so NaN reads as 0.
        let i = (x * STEPS).max(0.0).min(255.0 * STEPS);
        ((i + MAGIC).to_bits() & 0x007F_FFFF).min(ENTRIES as u32 - 1)
    }

    /// Encodes, adds noise (`sigma` times the table's standard-normal values) and quantises: `out[i]` from
    /// `linear[i]` and `noise[i]`.
    pub(super) fn finish(&self, linear: &[f32], noise: &[i8], sigma: f32, out: &mut [u8]) {
        match &self.table {
            None => {
                for ((o, &x), &n) in out.iter_mut().zip(linear).zip(noise) {
                    *o = quantise(x + sigma * n as f32);
                }
            }
            Some(t) => {
                // In three passes over chunks: the table indices and the noise with the quantisation are
                // vectorised; the table reads between them are one scalar load each (a vectorised gather
                // moves every index out of and every value into a vector register through the shuffle unit,
                // which made this loop the simulation's most expensive one). The same values either way.
                const CHUNK: usize = 256;
                let (mut idx, mut enc) = ([0u32; CHUNK], [0.0f32; CHUNK]);
                for ((xs, ns), os) in linear.chunks(CHUNK).zip(noise.chunks(CHUNK)).zip(out.chunks_mut(CHUNK))
                {
                    let n = xs.len().min(ns.len()).min(os.len());
                    for (k, &x) in idx[..n].iter_mut().zip(&xs[..n]) {
                        *k = Self::index(x);
                    }
                    for (e, &k) in enc[..n].iter_mut().zip(&idx[..n]) {
                        *e = t[k as usize & (TABLE_LEN - 1)];
                    }
                    for ((o, &e), &nv) in os[..n].iter_mut().zip(&enc[..n]).zip(&ns[..n]) {
                        *o = quantise(e + sigma * nv as f32);
                    }
                }
            }
        }
    }
}

/// The lens's light fall-off per pixel for the forward camera: `1 - vignetting` at the farthest corner,
/// quadratic in the distance from the principal point (the downward camera's model). None without it.
pub(super) fn vignette(c: &crate::scenario::ForwardCameraConfig) -> Option<Vec<f32>> {
    if c.vignetting <= 0.0 {
        return None;
    }
    let (w, h) = (c.width_px as usize, c.height_px as usize);
    let corner = |x: f64, y: f64| (x - c.cx_px).powi(2) + (y - c.cy_px).powi(2);
    let r2max = [(0.0, 0.0), (w as f64, 0.0), (0.0, h as f64), (w as f64, h as f64)]
        .iter()
        .map(|&(x, y)| corner(x, y))
        .fold(1e-9, f64::max);
    let mut out = Vec::with_capacity(w * h);
    for v in 0..h {
        for u in 0..w {
            out.push((1.0 - c.vignetting * corner(u as f64, v as f64) / r2max) as f32);
        }
    }
    Some(out)
}

/// The frame as a webcam's MJPEG delivers it: encoded at `quality` with 4:2:2 chroma (averaged), decoded by
/// the station's decoder (`ground_station::v4l2::decode_jpeg`).
pub(super) fn through_jpeg(img: &RgbImage, quality: u8) -> RgbImage {
    let mut jpeg = Vec::new();
    let mut enc = jpeg_encoder::Encoder::new(&mut jpeg, quality.clamp(1, 100));
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_2);
    enc.set_chroma_subsampling_method(jpeg_encoder::ChromaSubsamplingMethod::Average);
    // The encoder fails only on sizes beyond JPEG's 65535 or buffer writes to a Vec, neither possible for a
    // validated scenario; an empty result falls through to the decoder's error below.
    let encoded = enc.encode(&img.data, img.width as u16, img.height as u16, jpeg_encoder::ColorType::Rgb);
    match encoded
        .map_err(|e| e.to_string())
        .and_then(|()| ground_station::v4l2::decode_jpeg(&jpeg, 3).map_err(|e| format!("{e:?}")))
    {
        Ok((width, height, data)) => RgbImage { width, height, data },
        Err(e) => panic!("JPEG round trip of a {}x{} frame failed: {e}", img.width, img.height),
    }
}

/// Separable Gaussian blur of an interleaved RGB image of linear values (`w` by `h`), edges clamped: a row
/// pass and a column pass, each a sum of shifted rows (vectorised), rows on the thread pool. Every output
/// value is the same sum in the same order whatever the threads, so renders stay deterministic.
pub(super) fn gaussian_blur_rgb(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    let r = (3.0 * sigma).ceil() as usize;
    if r == 0 || w == 0 || h == 0 {
        return;
    }
    let mut k: Vec<f32> = (0..=2 * r)
        .map(|i| (-((i as f64 - r as f64).powi(2)) / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let row = 3 * w;
    // Rows: each row padded by r clamped pixels on both sides, then out = sum_t k[t] * padded[3 t ..].
    let mut tmp = vec![0.0f32; img.len()];
    tmp.par_chunks_mut(row).zip(img.par_chunks(row)).for_each_init(
        || vec![0.0f32; 3 * (w + 2 * r)],
        |pad, (out, src)| {
            for p in 0..r {
                pad[3 * p..3 * p + 3].copy_from_slice(&src[..3]);
                let q = r + w + p;
                pad[3 * q..3 * q + 3].copy_from_slice(&src[row - 3..]);
            }
            pad[3 * r..3 * (r + w)].copy_from_slice(src);
            out.fill(0.0);
            for (t, &kv) in k.iter().enumerate() {
                for (o, &p) in out.iter_mut().zip(&pad[3 * t..3 * t + row]) {
                    *o += kv * p;
                }
            }
        },
    );
    // Columns: output row y is the weighted sum of rows y - r ..= y + r (clamped).
    img.par_chunks_mut(row).enumerate().for_each(|(y, out)| {
        out.fill(0.0);
        for (t, &kv) in k.iter().enumerate() {
            let yy = (y + t).saturating_sub(r).min(h - 1);
            for (o, &p) in out.iter_mut().zip(&tmp[yy * row..(yy + 1) * row]) {
                *o += kv * p;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The direct per-pixel Gaussian (the renderer's earlier one), for comparison.
    fn reference_blur(img: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
        let r = (3.0 * sigma).ceil() as i64;
        let k: Vec<f64> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp()).collect();
        let s: f64 = k.iter().sum();
        let mut tmp = vec![0.0f64; img.len()];
        for y in 0..h {
            for x in 0..w {
                for ch in 0..3 {
                    tmp[3 * (y * w + x) + ch] = (0..k.len())
                        .map(|t| {
                            let xx = (x as i64 + t as i64 - r).clamp(0, w as i64 - 1) as usize;
                            k[t] / s * img[3 * (y * w + xx) + ch] as f64
                        })
                        .sum();
                }
            }
        }
        let mut out = vec![0.0f32; img.len()];
        for y in 0..h {
            for x in 0..w {
                for ch in 0..3 {
                    out[3 * (y * w + x) + ch] = (0..k.len())
                        .map(|t| {
                            let yy = (y as i64 + t as i64 - r).clamp(0, h as i64 - 1) as usize;
                            k[t] / s * tmp[3 * (yy * w + x) + ch]
                        })
                        .sum::<f64>() as f32;
                }
            }
        }
        out
    }

    #[test]
    fn the_row_wise_blur_is_the_gaussian_with_clamped_edges() {
        let (w, h) = (37, 23);
        let mut s = 7u64;
        let img: Vec<f32> = (0..3 * w * h).map(|_| (crate::rng::splitmix64(&mut s) % 256) as f32).collect();
        for sigma in [0.4, 1.0, 1.5, 3.0] {
            let mut fast = img.clone();
            gaussian_blur_rgb(&mut fast, w, h, sigma);
            let want = reference_blur(&img, w, h, sigma);
            let worst = fast.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(worst < 1e-3, "sigma {sigma}: worst difference {worst}");
        }
        // A flat image stays flat; a very small sigma (no taps) leaves the image as it is.
        let mut flat = vec![100.0f32; 3 * w * h];
        gaussian_blur_rgb(&mut flat, w, h, 2.0);
        assert!(flat.iter().all(|v| (v - 100.0).abs() < 1e-3));
        let mut same = img.clone();
        gaussian_blur_rgb(&mut same, w, h, 0.0);
        assert_eq!(same, img);
    }

    #[test]
    fn the_srgb_table_follows_the_curve_and_clips_per_channel() {
        let srgb = Response::new(ToneCurve::Srgb);
        let t = srgb.table.as_deref().unwrap();
        // The nearest entry is off by at most half a step (1/128 grey level) times the curve's slope: 12.92
        // below 0.8 grey levels of light, about 2.3 at 10 and 0.7 at 100 (measured 0.100 / 0.085 / 0.022 /
        // 0.006 grey levels below 1, 1-10, 10-100 and above).
        let mut worst = [0.0f32; 4];
        for i in 0..=255_000 {
            let x = i as f32 / 1000.0;
            let exact = 255.0 * ToneCurve::Srgb.encode(x / 255.0);
            let e = (Response::encode(t, x) - exact).abs();
            let band = [1.0, 10.0, 100.0].iter().filter(|&&b| x >= b).count();
            worst[band] = worst[band].max(e);
        }
        assert!(worst[0] <= 0.101 && worst[1] < 0.086 && worst[2] < 0.023 && worst[3] < 0.0061, "{worst:?}");
        let mut out = [0u8; 6];
        // Half the light is 186 in sRGB; above full scale a channel clips alone; NaN and negative read black.
        srgb.finish(&[127.5, 255.0, 400.0, 0.0, -5.0, f32::NAN], &[0; 6], 0.0, &mut out);
        assert_eq!(out, [188, 255, 255, 0, 0, 0]);
        let lin = Response::new(ToneCurve::Linear);
        // The noise table holds 32 per standard deviation: 2 grey levels of noise at +1 sigma.
        lin.finish(&[127.4, 255.0, 400.0, 0.0, -5.0, 3.0], &[0, 0, 0, 0, 0, 32], 2.0 / 32.0, &mut out);
        assert_eq!(out, [127, 255, 255, 0, 0, 5]);
    }
}
