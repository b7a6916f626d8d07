//! The flow's image pyramids: level 0 optionally smoothed, then 2x2 means, in one fixed buffer; bilinear
//! patches at a shared sub-pixel offset.
use super::*;

/// One level's place in a pyramid's buffer.
#[derive(Clone, Copy)]
pub(super) struct Level {
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) off: usize,
}

/// One image pyramid in a fixed buffer.
pub(super) struct Pyramid {
    pub(super) data: [u8; FLOW_MAX_W * FLOW_MAX_H * 4 / 3 + 64],
    pub(super) levels: [Level; MAX_LEVELS],
    pub(super) n: usize,
}

impl Pyramid {
    pub(super) const fn new() -> Self {
        Self {
            data: [0; FLOW_MAX_W * FLOW_MAX_H * 4 / 3 + 64],
            levels: [Level { w: 0, h: 0, off: 0 }; MAX_LEVELS],
            n: 0,
        }
    }

    pub(super) fn build(&mut self, img: &Gray8View<'_>, levels: usize, presmooth: bool) {
        let (w, h) = (img.width(), img.height());
        self.levels[0] = Level { w, h, off: 0 };
        if presmooth && w >= 3 && h >= 3 {
            // Binomial [1 2 1] x [1 2 1] / 16, edges clamped: damps the content near the Nyquist frequency,
            // where bilinear interpolation's phase error biases sub-pixel tracking (measured on rendered
            // floors: 0.25 px shifts read 0.270 px without it, 0.264 px with it; OpenCV's tracker reads 0.263).
            let mut col = [0u16; FLOW_MAX_W];
            for y in 0..h {
                let (r0, r1, r2) = (img.row(y.saturating_sub(1)), img.row(y), img.row((y + 1).min(h - 1)));
                // Vertical pass, then horizontal (both vectorisable).
                for (((c, &a), &b), &d) in col[..w].iter_mut().zip(r0).zip(r1).zip(r2) {
                    *c = a as u16 + 2 * b as u16 + d as u16;
                }
                let out = &mut self.data[y * w..(y + 1) * w];
                for (o, t) in out[1..w - 1].iter_mut().zip(col[..w].windows(3)) {
                    *o = ((t[0] + 2 * t[1] + t[2] + 8) / 16) as u8;
                }
                out[0] = ((3 * col[0] + col[1] + 8) / 16) as u8;
                out[w - 1] = ((3 * col[w - 1] + col[w - 2] + 8) / 16) as u8;
            }
        } else {
            for y in 0..h {
                self.data[y * w..(y + 1) * w].copy_from_slice(img.row(y));
            }
        }
        let mut off = w * h;
        self.n = 1;
        for l in 1..levels {
            let p = self.levels[l - 1];
            let (lw, lh) = (p.w / 2, p.h / 2);
            if lw < 8 || lh < 8 {
                break;
            }
            for y in 0..lh {
                for x in 0..lw {
                    let i = p.off + 2 * y * p.w + 2 * x;
                    let s = self.data[i] as u16
                        + self.data[i + 1] as u16
                        + self.data[i + p.w] as u16
                        + self.data[i + p.w + 1] as u16;
                    self.data[off + y * lw + x] = ((s + 2) / 4) as u8;
                }
            }
            self.levels[l] = Level { w: lw, h: lh, off };
            off += lw * lh;
            self.n += 1;
        }
    }

    /// [`Pyramid::patch`] for a fixed size `N` (`M = N + 1` source samples per row), inside the image:
    /// horizontal interpolation once per source row, then the vertical blend.
    #[inline(always)]
    fn patch_n<const N: usize, const M: usize>(
        &self,
        at: usize,
        stride: usize,
        fx: f32,
        fy: f32,
        out: &mut [f32],
    ) {
        let d = &self.data;
        let hinterp = |start: usize| -> [f32; N] {
            let r: &[u8; M] = match d[start..start + M].try_into() {
                Ok(r) => r,
                Err(_) => return [0.0; N],
            };
            let mut o = [0.0f32; N];
            for i in 0..N {
                let (a, b) = (r[i] as f32, r[i + 1] as f32);
                o[i] = a + fx * (b - a);
            }
            o
        };
        let mut cur = hinterp(at);
        for (j, row) in out.chunks_exact_mut(N).take(N).enumerate() {
            let next = hinterp(at + (j + 1) * stride);
            for i in 0..N {
                row[i] = cur[i] + fy * (next[i] - cur[i]);
            }
            cur = next;
        }
    }

    /// A bilinear `n x n` patch of level `l` whose top-left sample is at `(x0, y0)`: every sample shares the
    /// same fractional offset, so the four weights are computed once. Outside the image: `false`, or, with
    /// `clamp`, edge-clamped samples (used on the coarse levels, where a window near the border would
    /// otherwise lose the track before level 0 decides).
    pub(super) fn patch(&self, l: &Level, x0: f32, y0: f32, n: usize, clamp: bool, out: &mut [f32]) -> bool {
        if !(x0.abs() < 1.0e6 && y0.abs() < 1.0e6) {
            return false;
        }
        let (xf, yf) = (libm::floorf(x0), libm::floorf(y0));
        let (fx, fy) = (x0 - xf, y0 - yf);
        let (xi, yi) = (xf as i32, yf as i32);
        let (w00, w01, w10, w11) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let d = &self.data;
        let inside = xi >= 0 && yi >= 0 && xi + (n as i32) < l.w as i32 && yi + (n as i32) < l.h as i32;
        if inside {
            let at = l.off + yi as usize * l.w + xi as usize;
            // Fixed sizes unroll and vectorise; the window sizes in use are odd, 3 to 15.
            match n {
                3 => self.patch_n::<3, 4>(at, l.w, fx, fy, out),
                5 => self.patch_n::<5, 6>(at, l.w, fx, fy, out),
                7 => self.patch_n::<7, 8>(at, l.w, fx, fy, out),
                9 => self.patch_n::<9, 10>(at, l.w, fx, fy, out),
                11 => self.patch_n::<11, 12>(at, l.w, fx, fy, out),
                13 => self.patch_n::<13, 14>(at, l.w, fx, fy, out),
                15 => self.patch_n::<15, 16>(at, l.w, fx, fy, out),
                17 => self.patch_n::<17, 18>(at, l.w, fx, fy, out),
                19 => self.patch_n::<19, 20>(at, l.w, fx, fy, out),
                21 => self.patch_n::<21, 22>(at, l.w, fx, fy, out),
                23 => self.patch_n::<23, 24>(at, l.w, fx, fy, out),
                25 => self.patch_n::<25, 26>(at, l.w, fx, fy, out),
                27 => self.patch_n::<27, 28>(at, l.w, fx, fy, out),
                29 => self.patch_n::<29, 30>(at, l.w, fx, fy, out),
                31 => self.patch_n::<31, 32>(at, l.w, fx, fy, out),
                33 => self.patch_n::<33, 34>(at, l.w, fx, fy, out),
                35 => self.patch_n::<35, 36>(at, l.w, fx, fy, out),
                37 => self.patch_n::<37, 38>(at, l.w, fx, fy, out),
                39 => self.patch_n::<39, 40>(at, l.w, fx, fy, out),
                41 => self.patch_n::<41, 42>(at, l.w, fx, fy, out),
                _ => {
                    for (j, row) in out.chunks_exact_mut(n).take(n).enumerate() {
                        let r0 = at + j * l.w;
                        let top = &d[r0..r0 + n + 1];
                        let bot = &d[r0 + l.w..r0 + l.w + n + 1];
                        for (i, o) in row.iter_mut().enumerate() {
                            *o = w00 * top[i] as f32
                                + w01 * top[i + 1] as f32
                                + w10 * bot[i] as f32
                                + w11 * bot[i + 1] as f32;
                        }
                    }
                }
            }
            true
        } else if clamp {
            let cx = |x: i32| x.clamp(0, l.w as i32 - 1) as usize;
            let cy = |y: i32| y.clamp(0, l.h as i32 - 1) as usize;
            for (j, row) in out.chunks_exact_mut(n).take(n).enumerate() {
                let (y0, y1) = (cy(yi + j as i32), cy(yi + j as i32 + 1));
                for (i, o) in row.iter_mut().enumerate() {
                    let (x0, x1) = (cx(xi + i as i32), cx(xi + i as i32 + 1));
                    let at = |x: usize, y: usize| d[l.off + y * l.w + x] as f32;
                    *o = w00 * at(x0, y0) + w01 * at(x1, y0) + w10 * at(x0, y1) + w11 * at(x1, y1);
                }
            }
            true
        } else {
            false
        }
    }
}
