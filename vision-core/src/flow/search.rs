//! The whole frame's displacement, searched on the pyramid's coarsest level before tracking.
//!
//! Lucas-Kanade converges from a guess within about the texture's correlation length at each level: on the
//! rendered floors, a 320x240 pyramid of four levels lost every pair moved by a third of the width (107 px,
//! 13 px on the 40x30 top level) although its nominal reach, `(window_half + 1) 2^levels`, is 176 px. OpenCV's
//! tracker with its defaults stops near 77 px on the same floors. A floor seen by a downward camera moves
//! nearly as one piece between frames, so one exhaustive search of the coarsest level for the displacement
//! that best matches the two frames gives every track a guess that Lucas-Kanade can take from there.
//!
//! The match is the zero-mean normalised cross-correlation over the overlap of the two images: it does not
//! depend on exposure (a gain and an offset between the frames), and normalising by the overlap keeps large
//! offsets, with their small overlaps, comparable with small ones. Offsets whose overlap is under
//! [`MIN_OVERLAP`] of the image are not considered. A search whose best correlation is under [`MIN_NCC`] gives
//! no guess (the prediction stays).
use super::{Level, Pyramid};
use geometry::Vec2;

/// Smallest overlap of an offset, as a fraction of the coarse image's area.
const MIN_OVERLAP: f32 = 0.3;
/// Smallest correlation of a match. The search's offsets are whole pixels of the coarsest level, so a motion
/// of half of one correlates at 0.39-0.52 where a whole one reaches 0.8-0.9 (rendered floors, 320x240, 40x30
/// top level); a wrong guess costs only its tracks, which Lucas-Kanade, the forward-backward check and the
/// flow field's fit then refuse.
const MIN_NCC: f32 = 0.25;

/// The displacement (level-0 px) from `a` to `b` that correlates best on their coarsest common level, searched
/// within `radius_px` (level-0 px, per axis) of `center_px` (level-0 px), or `None` without a clear match.
pub(super) fn whole_frame_shift(a: &Pyramid, b: &Pyramid, center_px: Vec2, radius_px: f32) -> Option<Vec2> {
    let top = a.n.min(b.n).checked_sub(1)?;
    let (la, lb) = (a.levels[top], b.levels[top]);
    if la.w != lb.w || la.h != lb.h {
        return None;
    }
    let scale = (1u32 << top) as f32;
    let r = libm::ceilf(radius_px / scale).clamp(0.0, 64.0) as i32;
    let (cx, cy) = (libm::roundf(center_px.x / scale) as i32, libm::roundf(center_px.y / scale) as i32);
    let (da, db) = (&a.data[la.off..la.off + la.w * la.h], &b.data[lb.off..lb.off + lb.w * lb.h]);
    let mut best: Option<(f32, i32, i32)> = None;
    for dy in cy - r..=cy + r {
        for dx in cx - r..=cx + r {
            if let Some(c) = ncc(da, db, &la, dx, dy)
                && best.is_none_or(|(bc, _, _)| c > bc)
            {
                best = Some((c, dx, dy));
            }
        }
    }
    let (c, dx, dy) = best?;
    (c >= MIN_NCC).then(|| Vec2::new(dx as f32 * scale, dy as f32 * scale))
}

/// Zero-mean normalised cross-correlation of `a` at `x` with `b` at `x + (dx, dy)` over their overlap.
fn ncc(a: &[u8], b: &[u8], l: &Level, dx: i32, dy: i32) -> Option<f32> {
    let (w, h) = (l.w as i32, l.h as i32);
    let (x0, x1) = (0.max(-dx), w.min(w - dx));
    let (y0, y1) = (0.max(-dy), h.min(h - dy));
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let n = ((x1 - x0) * (y1 - y0)) as f32;
    if n < MIN_OVERLAP * (w * h) as f32 || n < 16.0 {
        return None;
    }
    // Integer sums: exact, and in any order the same.
    let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0u64, 0u64, 0u64, 0u64, 0u64);
    for y in y0..y1 {
        let ra = &a[(y * w + x0) as usize..(y * w + x1) as usize];
        let rb = &b[((y + dy) * w + x0 + dx) as usize..((y + dy) * w + x1 + dx) as usize];
        let (mut s1, mut s2, mut s11, mut s22, mut s12) = (0u32, 0u32, 0u32, 0u32, 0u32);
        for (&p, &q) in ra.iter().zip(rb) {
            let (p, q) = (p as u32, q as u32);
            s1 += p;
            s2 += q;
            s11 += p * p;
            s22 += q * q;
            s12 += p * q;
        }
        sa += s1 as u64;
        sb += s2 as u64;
        saa += s11 as u64;
        sbb += s22 as u64;
        sab += s12 as u64;
    }
    let (ma, mb) = (sa as f64 / n as f64, sb as f64 / n as f64);
    let vab = sab as f64 / n as f64 - ma * mb;
    let va = saa as f64 / n as f64 - ma * ma;
    let vb = sbb as f64 / n as f64 - mb * mb;
    (va > 1e-6 && vb > 1e-6).then(|| (vab / libm::sqrt(va * vb)) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Gray8View;
    extern crate std;
    use std::boxed::Box;
    use std::vec::Vec;

    /// The flow tests' aperiodic lattice texture, sampled at `(x + dx, y + dy)`.
    fn texture(w: usize, h: usize, dx: i64, dy: i64) -> Vec<u8> {
        super::super::large_frame_tests::lattice_texture(w, h, dx as f32, dy as f32, 1.0, 0.0)
    }

    fn pyramid(img: &[u8], w: usize, h: usize, levels: usize) -> Box<Pyramid> {
        let mut p = Box::new(Pyramid::new());
        p.build(&Gray8View::packed(img, w, h).unwrap(), levels, false);
        p
    }

    #[test]
    fn the_correlation_is_one_for_the_same_image_under_any_gain_and_offset() {
        let (w, h) = (40usize, 30usize);
        let a = texture(w, h, 0, 0);
        let l = Level { w, h, off: 0 };
        assert_eq!(ncc(&a, &a, &l, 0, 0), Some(1.0));
        let brighter: Vec<u8> = a.iter().map(|&v| (v as u32 * 5 / 4 + 10) as u8).collect();
        assert!((ncc(&a, &brighter, &l, 0, 0).unwrap() - 1.0).abs() < 0.01);
        let inverted: Vec<u8> = a.iter().map(|&v| 255 - v).collect();
        assert!((ncc(&a, &inverted, &l, 0, 0).unwrap() + 1.0).abs() < 1e-6);
        // The second image shifted by (5, -3): matched there and only there.
        let b = texture(w, h, -5, 3);
        assert!((ncc(&a, &b, &l, 5, -3).unwrap() - 1.0).abs() < 1e-6);
        assert!(ncc(&a, &b, &l, 0, 0).unwrap() < 0.5 && ncc(&a, &b, &l, 4, -3).unwrap() < 0.95);
        // Overlaps under 30 % of the image, or of no texture, are not measured.
        assert!(ncc(&a, &b, &l, 30, 0).is_none() && ncc(&a, &b, &l, 0, 22).is_none());
        assert!(ncc(&a, &b, &l, 25, 0).is_some() && ncc(&a, &b, &l, 0, 18).is_some());
        assert!(ncc(&a, &b, &l, 40, 0).is_none() && ncc(&a, &b, &l, -40, 0).is_none());
        // A tiny image: at least 16 pixels of overlap as well.
        let (t, lt) = (texture(6, 6, 0, 0), Level { w: 6, h: 6, off: 0 });
        assert!(ncc(&t, &t, &lt, 2, 2).is_some() && ncc(&t, &t, &lt, 2, 3).is_none());
        let flat = std::vec![77u8; w * h];
        assert!(ncc(&a, &flat, &l, 0, 0).is_none() && ncc(&flat, &a, &l, 0, 0).is_none());
    }

    #[test]
    fn the_search_finds_the_shift_around_its_centre_within_its_radius() {
        let (w, h) = (320usize, 240usize);
        let a = texture(w, h, 0, 0);
        // The content moves by (96, -40) px: 12 and -5 px of the 40x30 coarsest level of four.
        let b = texture(w, h, -96, 40);
        let (pa, pb) = (pyramid(&a, w, h, 4), pyramid(&b, w, h, 4));
        let truth = Vec2::new(96.0, -40.0);
        for centre in [Vec2::ZERO, Vec2::new(60.0, -20.0), Vec2::new(130.0, -70.0)] {
            let found = whole_frame_shift(&pa, &pb, centre, 110.0).unwrap();
            assert_eq!(found, truth, "from {centre:?}");
        }
        // A small radius about a centre near the truth.
        assert_eq!(whole_frame_shift(&pa, &pb, Vec2::new(100.0, -48.0), 8.0), Some(truth));
        // A radius that does not reach the truth from the centre: not the truth.
        let found = whole_frame_shift(&pa, &pb, Vec2::ZERO, 60.0);
        assert!(found != Some(truth), "{found:?}");
        assert!(found.is_none_or(|f| f.x.abs() <= 64.0 && f.y.abs() <= 64.0), "{found:?}");
        // Frames of different sizes are not compared.
        let small = texture(160, 120, 0, 0);
        assert_eq!(whole_frame_shift(&pa, &pyramid(&small, 160, 120, 4), Vec2::ZERO, 110.0), None);
        let shorter = texture(w, 200, -96, 40);
        assert_eq!(whole_frame_shift(&pa, &pyramid(&shorter, w, 200, 4), Vec2::ZERO, 110.0), None);
        // A blank later frame correlates with nothing.
        let blank = std::vec![90u8; w * h];
        assert_eq!(whole_frame_shift(&pa, &pyramid(&blank, w, h, 4), Vec2::ZERO, 110.0), None);
    }
}
