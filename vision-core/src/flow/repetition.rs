//! Does the floor repeat within the tracking's reach?
//!
//! On a floor that repeats (tiles, a grid, stripes), a displacement and the same displacement less one
//! repetition match equally well: shifted by more than half a repetition, Lucas-Kanade converges on the alias
//! and every track agrees on it, a confident wrong flow (measured before this check: a 10 px tiling shifted by
//! 5.5 px gave -4.5 px at quality 1.00). Nothing in the pair itself tells the truth from the alias, so the pair
//! is refused ([`super::NoFlowReason::RepeatingTexture`]).
//!
//! The check is the self-similarity of the earlier frame: the mean squared difference between the frame and
//! itself shifted by each offset `s` (on a grid of sample points), over the offsets up to the tracking's reach.
//! An aperiodic texture's difference rises from zero at `s = 0` to a plateau and has no other low minimum; a
//! repeating one dips back toward zero at each repetition. The frame repeats when some offset with
//! `|s|_inf >= 2` is a local minimum (among its eight neighbours) whose difference is below
//! `max_repetition_ratio` times the plateau (the median difference over the offsets). Repetitions of 2-6 px are
//! looked for on pyramid level 0, of 4-12 px on level 1, 8-24 px on level 2 and so on up the pyramid, and
//! longer ones, up to 2.5 times the tracking's reach (or the whole-frame search's, `flow::search`), on an image
//! half the size of the pyramid's coarsest level (a quarter of the cost of searching that level). Each level is
//! needed: a tiling of 40 px is 2.5 px on the coarse image of a five-level pyramid, blurred away there.
//!
//! A found repetition refuses the pair only when the flow is at least [`ALIAS_FRACTION`] of it: the alias of a
//! shift by `f` of a repetition is `1 - f` of it, while a small true motion on a floor that repeats far away
//! (or nearly repeats, as sums of a few sinusoids do) is kept.
use super::{FLOW_MAX_H, FLOW_MAX_W, FlowParams, Pyramid};
use geometry::Vec2;

/// Largest offset searched per axis, on any image (px of that image).
const MAX_R: usize = 24;
const SIDE: usize = 2 * MAX_R + 1;
/// Offsets searched on levels 0 and 1 (px of the level): repetitions shorter than this blur away on the
/// coarse image.
const FINE_R: usize = 6;
/// Spacing of the sample points: the image's width and height over these.
const POINTS: [usize; 2] = [12, 9];
/// A flow (less the predicted rotation) of at least this fraction of the repetition is refused: shifts of up
/// to 0.85 of a repetition are caught, and motions under 0.15 of it pass (a near-repetition 55 px away in a
/// sum of six sinusoids does not stop a 3 px flow).
pub(super) const ALIAS_FRACTION: f32 = 0.15;
/// The shortest repetition the search reports (level-0 px): offsets with `|s|_inf >= 2` on level 0.
pub(super) const MIN_OFFSET_PX: f32 = 2.0;
/// The coarse image of a one-level pyramid of the largest frame is a quarter of it.
const COARSE_LEN: usize = FLOW_MAX_W * FLOW_MAX_H / 4;

/// The search's buffers (about 38 KB; kept in the flow's workspace, not on the stack).
pub(super) struct Scratch {
    map: [u32; SIDE * SIDE],
    ring: [u32; SIDE * SIDE],
    coarse: [u8; COARSE_LEN],
}

impl Scratch {
    pub(super) const fn new() -> Self {
        Self { map: [0; SIDE * SIDE], ring: [0; SIDE * SIDE], coarse: [0; COARSE_LEN] }
    }
}

/// A repetition of the floor's texture found in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Repetition {
    /// The shortest offset found at which the frame matches itself (level-0 px).
    pub offset_px: Vec2,
    /// That offset's mean squared difference over the median one (0: a perfect repetition).
    pub ratio: f32,
}

/// One image searched: its pixels, size and scale to level 0.
#[derive(Clone, Copy)]
struct Image<'a> {
    data: &'a [u8],
    w: usize,
    h: usize,
    scale: usize,
}

/// The repetition of the pyramid's frame within the tracking's reach, if any.
pub(super) fn find(p: &Pyramid, params: &FlowParams, sc: &mut Scratch) -> Option<Repetition> {
    if !(params.max_repetition_ratio > 0.0) {
        return None;
    }
    let level = |l: usize| {
        let lv = p.levels[l];
        Image { data: &p.data[lv.off..lv.off + lv.w * lv.h], w: lv.w, h: lv.h, scale: 1 << l }
    };
    // The tracking reaches (window_half + 1) 2^levels px from its start. Shifted by d, more than half a
    // repetition P, the alias d - P is within that reach for every P up to twice the reach, and for somewhat
    // longer ones once d itself is beyond it: repetitions up to 2.5 times the reach are looked for.
    // The whole-frame search (`flow::search`) reaches further still, and finds an alias as readily.
    let lk_reach = (params.window_half.min(super::MAX_WINDOW_HALF) as usize + 1) << p.n;
    let reach = lk_reach.max(params.search_px.max(0.0) as usize);
    let top = level(p.n - 1);
    // The coarse image: 2x2 means of the coarsest level.
    let (cw, ch) = (top.w / 2, top.h / 2);
    for y in 0..ch {
        for x in 0..cw {
            let i = 2 * y * top.w + 2 * x;
            let s = top.data[i] as u16
                + top.data[i + 1] as u16
                + top.data[i + top.w] as u16
                + top.data[i + top.w + 1] as u16;
            sc.coarse[y * cw + x] = ((s + 2) / 4) as u8;
        }
    }
    let mut best: Option<Repetition> = None;
    // Every level (repetitions of 2-6 of its pixels), then the coarse image.
    for step in 0..=p.n {
        let (img, r) = if step < p.n {
            (level(step), FINE_R)
        } else {
            let scale = 2 * top.scale;
            let img = Image { data: &sc.coarse[..cw * ch], w: cw, h: ch, scale };
            (img, (5 * reach / 2).div_ceil(scale))
        };
        let Scratch { map, ring, .. } = sc;
        if let Some(rep) = search(img, r, params.max_repetition_ratio, map, ring)
            && best.is_none_or(|b| rep.offset_px.norm() < b.offset_px.norm())
        {
            best = Some(rep);
        }
    }
    best
}

/// The self-similarity search of one image with offsets up to `r` per axis: for each offset, the mean
/// squared difference over the sample points whose shifted position is inside the image too (the overlap
/// shrinks with the offset; an offset whose overlap holds fewer than 16 points is left out).
fn search(
    img: Image<'_>,
    r: usize,
    max_ratio: f32,
    map: &mut [u32; SIDE * SIDE],
    ring: &mut [u32; SIDE * SIDE],
) -> Option<Repetition> {
    let Image { data, w, h, scale } = img;
    let r = r.min(MAX_R).min(w.saturating_sub(8) / 2).min(h.saturating_sub(4) / 2);
    if r < 2 {
        return None;
    }
    let (sx, sy) = ((w / POINTS[0]).max(1), (h / POINTS[1]).max(1));
    let side = 2 * r + 1;
    // Mean squared difference (grey levels squared, 1/16 units) per offset; u32::MAX where not measured.
    map[..side * side].fill(u32::MAX);
    // Offsets in one half-plane; the other half is the same comparison seen from the other side.
    for dy in 0..=r {
        for dx in 0..side {
            if dy == 0 && dx <= r {
                continue;
            }
            let ox = dx as isize - r as isize;
            // Points x with 0 <= x + ox < w, and y with y + dy < h.
            let x0 = (-ox).max(0) as usize;
            let x1 = (w as isize - ox.max(0)) as usize;
            let (mut sum, mut n) = (0u64, 0u32);
            let mut y = sy / 2;
            while y + dy < h {
                let row = &data[y * w..(y + 1) * w];
                let shifted = &data[(y + dy) * w..(y + dy + 1) * w];
                let mut x = x0 + sx / 2;
                while x < x1 {
                    let d = row[x] as i32 - shifted[(x as isize + ox) as usize] as i32;
                    sum += (d * d) as u64;
                    n += 1;
                    x += sx;
                }
                y += sy;
            }
            if n >= 16 {
                let mean = (16 * sum / n as u64) as u32;
                map[(r + dy) * side + dx] = mean;
                map[(r - dy) * side + (side - 1 - dx)] = mean;
            }
        }
    }
    map[r * side + r] = 0;
    // The plateau: the median over the offsets outside the central 3x3.
    let mut n = 0;
    for dy in 0..side {
        for dx in 0..side {
            let v = map[dy * side + dx];
            if (dx.abs_diff(r) >= 2 || dy.abs_diff(r) >= 2) && v != u32::MAX {
                ring[n] = v;
                n += 1;
            }
        }
    }
    if n == 0 {
        return None;
    }
    let (_, plateau, _) = ring[..n].select_nth_unstable(n / 2);
    let plateau = *plateau;
    if plateau == 0 {
        return None;
    }
    let mut best: Option<(u32, usize, usize)> = None;
    for dy in 0..side {
        for dx in 0..side {
            if dx.abs_diff(r) < 2 && dy.abs_diff(r) < 2 {
                continue;
            }
            let v = map[dy * side + dx];
            if v as f32 >= max_ratio * plateau as f32 {
                continue;
            }
            let mut local_min = true;
            for (ex, ey) in [(0, 1), (1, 0), (1, 1), (1, 2), (2, 1), (0, 0), (0, 2), (2, 0), (2, 2)] {
                let (x, y) = ((dx + ex).wrapping_sub(1), (dy + ey).wrapping_sub(1));
                if (x, y) != (dx, dy) && x < side && y < side && map[y * side + x] < v {
                    local_min = false;
                }
            }
            let d2 = dx.abs_diff(r).pow(2) + dy.abs_diff(r).pow(2);
            if local_min && best.is_none_or(|(_, bx, by)| d2 < bx.abs_diff(r).pow(2) + by.abs_diff(r).pow(2))
            {
                best = Some((v, dx, dy));
            }
        }
    }
    let (v, dx, dy) = best?;
    let scale = scale as f32;
    Some(Repetition {
        offset_px: Vec2::new((dx as f32 - r as f32) * scale, (dy as f32 - r as f32) * scale),
        ratio: v as f32 / plateau as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Gray8View;

    const W: usize = 160;
    const H: usize = 120;

    /// A frame repeating every `px` pixels in x and `py` in y (a product of two periodic profiles, so its
    /// shortest repetition is the shorter of the two), plus `noise` grey levels of a fixed pseudo-random
    /// pattern that does not repeat.
    fn frame(px: usize, py: usize, noise: f32) -> Vec<u8> {
        let mut s = 0x1234_5678u32;
        let mut img = vec![0u8; W * H];
        for y in 0..H {
            for x in 0..W {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                let n = (s % 1000) as f32 / 1000.0 - 0.5;
                let a = core::f32::consts::TAU * (x % px) as f32 / px as f32;
                let b = core::f32::consts::TAU * (y % py) as f32 / py as f32;
                let v = 128.0 + 40.0 * (a.sin() + 0.5 * (2.0 * a).cos()) + 40.0 * b.sin() + noise * n;
                img[y * W + x] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    }

    fn found(img: &[u8], levels: usize, max_ratio: f32) -> Option<Repetition> {
        let mut p = Box::new(Pyramid::new());
        p.build(&Gray8View::packed(img, W, H).unwrap(), levels, false);
        let params = FlowParams { max_repetition_ratio: max_ratio, ..FlowParams::default() };
        find(&p, &params, &mut Scratch::new())
    }

    #[test]
    fn each_stage_finds_its_repetitions_exactly() {
        // Level 0 (2-6 px), level 1 (4-12 px) and the coarse image (beyond) each report the shortest
        // repetition at its exact offset (in level-0 pixels) and a ratio near 0.
        for (px, py, want) in [(4, 50, 4.0), (10, 48, 10.0), (28, 52, 28.0), (36, 44, 36.0)] {
            let rep = found(&frame(px, py, 0.0), 2, 0.25).unwrap_or_else(|| panic!("period {px}: none"));
            assert_eq!(rep.offset_px.y, 0.0, "period {px}: {rep:?}");
            assert_eq!(rep.offset_px.x.abs(), want, "period {px}: {rep:?}");
            assert!(rep.ratio < 0.05, "period {px}: {rep:?}");
        }
        // One pyramid level: level 0 and a half-size coarse image.
        let rep = found(&frame(24, 50, 0.0), 1, 0.25).unwrap();
        assert_eq!((rep.offset_px.x.abs(), rep.offset_px.y), (24.0, 0.0), "{rep:?}");
    }

    #[test]
    fn the_ratio_is_the_match_over_the_typical_difference() {
        // The same tiling with non-repeating noise: the match at the repetition is the noise's difference,
        // measured 0.125 of the typical one here; found below a ratio of 0.5, and not below its own ratio.
        let img = frame(10, 14, 100.0);
        let rep = found(&img, 2, 0.5).unwrap();
        assert_eq!(rep.offset_px.x.abs(), 10.0, "{rep:?}");
        assert!(rep.ratio > 0.1 && rep.ratio < 0.15, "{rep:?}");
        // Below that, only the coarse image's match remains (its 4x4 means average the noise out: measured
        // 20 px with a ratio of 0.044).
        let coarse = found(&img, 2, 0.1).unwrap();
        assert_eq!((coarse.offset_px.x.abs(), coarse.offset_px.y), (20.0, 0.0), "{coarse:?}");
        assert!(coarse.ratio < 0.06, "{coarse:?}");
        assert_eq!(found(&img, 2, 0.03), None);
        // Turned off, and a frame without texture: nothing.
        assert_eq!(found(&frame(10, 48, 0.0), 2, 0.0), None);
        assert_eq!(found(&[128u8; W * H], 2, 0.25), None);
    }
}
