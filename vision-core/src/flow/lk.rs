//! Pyramidal Lucas-Kanade (Bouguet 2000): one level's iterations, with or without a brightness gain and
//! offset, and a point tracked down the pyramid.
use super::*;

/// Reused buffers of one Lucas-Kanade window (kept in the workspace: filling fresh zeroed arrays on every call
/// cost more than the tracking's arithmetic).
pub(super) struct LkScratch {
    big: [f32; (MAX_WIN + 2) * (MAX_WIN + 2)],
    tpl: [f32; MAX_WIN * MAX_WIN],
    gxs: [f32; MAX_WIN * MAX_WIN],
    gys: [f32; MAX_WIN * MAX_WIN],
    cur: [f32; MAX_WIN * MAX_WIN],
}

impl LkScratch {
    pub(super) const fn new() -> Self {
        Self {
            big: [0.0; (MAX_WIN + 2) * (MAX_WIN + 2)],
            tpl: [0.0; MAX_WIN * MAX_WIN],
            gxs: [0.0; MAX_WIN * MAX_WIN],
            gys: [0.0; MAX_WIN * MAX_WIN],
            cur: [0.0; MAX_WIN * MAX_WIN],
        }
    }
}

/// Lucas-Kanade at one level: refines the displacement `d` of the window centred at `p` from `a` to `b`.
pub(super) fn lk_level(
    a: &Pyramid,
    b: &Pyramid,
    l: usize,
    p: Vec2,
    mut d: Vec2,
    params: &FlowParams,
    sc: &mut LkScratch,
) -> Option<Vec2> {
    let LkScratch { big, tpl, gxs, gys, cur } = sc;
    let (la, lb) = (a.levels[l], b.levels[l]);
    let clamp = l > 0;
    let hw = params.window_half.min(MAX_WINDOW_HALF) as usize;
    let side = 2 * hw + 1;
    let n = side + 2;
    // The template with a one-sample border for the central-difference gradients.
    if !a.patch(&la, p.x - (hw + 1) as f32, p.y - (hw + 1) as f32, n, clamp, &mut big[..]) {
        return None;
    }
    let (mut gxx, mut gyy, mut gxy) = (0.0f32, 0.0f32, 0.0f32);
    for j in 0..side {
        let (up, mid, down) =
            (&big[j * n..(j + 1) * n], &big[(j + 1) * n..(j + 2) * n], &big[(j + 2) * n..(j + 3) * n]);
        for i in 0..side {
            let ix = 0.5 * (mid[i + 2] - mid[i]);
            let iy = 0.5 * (down[i + 1] - up[i + 1]);
            let k = j * side + i;
            tpl[k] = mid[i + 1];
            gxs[k] = ix;
            gys[k] = iy;
            gxx += ix * ix;
            gyy += iy * iy;
            gxy += ix * iy;
        }
    }
    let det = gxx * gyy - gxy * gxy;
    let area = (side * side) as f32;
    let (lmin, _, _) = geometry::solve::sym2_eigen(gxx, gxy, gyy);
    if !(det > 0.0) || lmin < params.min_eigen * area * 0.25 {
        // Too little texture at this scale: a coarse level passes the estimate on unchanged, the finest fails.
        return if l > 0 { Some(d) } else { None };
    }
    let inv = 1.0 / det;
    let mut last = f32::INFINITY;
    let m = side * side;
    let hwf = hw as f32;
    if params.gain_offset {
        return lk_gain_offset(b, &lb, clamp, p, d, params, hw, [gxx, gxy, gyy], sc);
    }
    for _ in 0..params.max_iterations {
        let (x0, y0) = (p.x + d.x - hwf, p.y + d.y - hwf);
        if !b.patch(&lb, x0, y0, side, clamp, &mut cur[..]) {
            return None;
        }
        // Eight independent partial sums (vectorisable without reassociating; the order is fixed, so the
        // result is the same on every machine).
        let (mut sx, mut sy) = ([0.0f32; 8], [0.0f32; 8]);
        for (((c, t), gx), gy) in
            cur[..m].chunks(8).zip(tpl[..m].chunks(8)).zip(gxs[..m].chunks(8)).zip(gys[..m].chunks(8))
        {
            for i in 0..c.len() {
                let e = c[i] - t[i];
                sx[i] += e * gx[i];
                sy[i] += e * gy[i];
            }
        }
        let (bx, by) = (sx.iter().sum::<f32>(), sy.iter().sum::<f32>());
        let step = Vec2::new(-(gyy * bx - gxy * by) * inv, -(gxx * by - gxy * bx) * inv);
        d += step;
        last = step.norm();
        // A coarse level only seeds the next: a twentieth of its pixel is enough there.
        if last < if l > 0 { params.epsilon_px.max(0.05) } else { params.epsilon_px } {
            return Some(d);
        }
    }
    // Not converged within the limit: a coarse level only seeds the next one, and the quantised coarse images
    // often creep; at the finest level a track still moving by more than a tenth of a pixel is not trusted.
    if l > 0 || last < 0.1 { Some(d) } else { None }
}

/// [`lk_level`]'s iterations with a brightness gain and offset between the windows estimated with the
/// displacement: `b(x + d) = (1 + g) a(x) + o`. Vignetting (a brightness that stays with the camera while the
/// floor moves under it), an exposure step between frames and uneven light all break plain Lucas-Kanade's
/// brightness constancy, and what they leave is read as motion. The template (`sc.tpl`) and its gradients
/// (`sc.gxs`, `sc.gys`, with their sums `g = [gxx, gxy, gyy]`) are filled by the caller.
#[allow(clippy::too_many_arguments)]
fn lk_gain_offset(
    b: &Pyramid,
    lb: &Level,
    clamp: bool,
    p: Vec2,
    mut d: Vec2,
    params: &FlowParams,
    hw: usize,
    g: [f32; 3],
    sc: &mut LkScratch,
) -> Option<Vec2> {
    let LkScratch { tpl, gxs, gys, cur, .. } = sc;
    let side = 2 * hw + 1;
    let m = side * side;
    let hwf = hw as f32;
    // The gain acts on the template less its mean, so that it is orthogonal to the offset.
    let mean = tpl[..m].iter().sum::<f32>() / m as f32;
    let (mut gxt, mut gyt, mut gx1, mut gy1, mut tt) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for k in 0..m {
        let t = tpl[k] - mean;
        gxt += gxs[k] * t;
        gyt += gys[k] * t;
        gx1 += gxs[k];
        gy1 += gys[k];
        tt += t * t;
    }
    // Normal matrix of the residual's Jacobian [gx, gy, -(t - mean), -1].
    let h = [
        [g[0], g[1], -gxt, -gx1],
        [g[1], g[2], -gyt, -gy1],
        [-gxt, -gyt, tt, 0.0],
        [-gx1, -gy1, 0.0, m as f32],
    ];
    let mut hinv = [[0.0f32; 4]; 4];
    if !geometry::solve::spd_inverse(&h, &mut hinv, 4) {
        return None;
    }
    let (mut gain, mut offset) = (0.0f32, 0.0f32);
    let mut last = f32::INFINITY;
    for _ in 0..params.max_iterations {
        if !b.patch(lb, p.x + d.x - hwf, p.y + d.y - hwf, side, clamp, &mut cur[..]) {
            return None;
        }
        let (mut sx, mut sy, mut st, mut s1) = ([0.0f32; 8], [0.0f32; 8], [0.0f32; 8], [0.0f32; 8]);
        for (((c, t), gx), gy) in
            cur[..m].chunks(8).zip(tpl[..m].chunks(8)).zip(gxs[..m].chunks(8)).zip(gys[..m].chunks(8))
        {
            for i in 0..c.len() {
                let tc = t[i] - mean;
                let e = c[i] - t[i] - gain * tc - offset;
                sx[i] += e * gx[i];
                sy[i] += e * gy[i];
                st[i] += e * tc;
                s1[i] += e;
            }
        }
        let jte = [
            sx.iter().sum::<f32>(),
            sy.iter().sum::<f32>(),
            -st.iter().sum::<f32>(),
            -s1.iter().sum::<f32>(),
        ];
        let mut step = [0.0f32; 4];
        for (r, row) in step.iter_mut().zip(&hinv) {
            *r = -(row[0] * jte[0] + row[1] * jte[1] + row[2] * jte[2] + row[3] * jte[3]);
        }
        d += Vec2::new(step[0], step[1]);
        gain += step[2];
        offset += step[3];
        last = libm::sqrtf(step[0] * step[0] + step[1] * step[1]);
        if last < if clamp { params.epsilon_px.max(0.05) } else { params.epsilon_px } {
            return Some(d);
        }
    }
    if clamp || last < 0.1 { Some(d) } else { None }
}

/// Pyramidal Lucas-Kanade of the point `p` (level 0) from `a` to `b`, starting from `guess` (level 0).
/// At most `max_levels` levels are used (the finest ones): a guess from the whole-frame search is already within
/// a pixel of the coarsest level but one.
pub(super) fn track(
    a: &Pyramid,
    b: &Pyramid,
    p: Vec2,
    guess: Vec2,
    max_levels: usize,
    params: &FlowParams,
    sc: &mut LkScratch,
) -> Option<Vec2> {
    let levels = a.n.min(b.n).min(max_levels).max(1);
    let top = levels - 1;
    let s = (1 << top) as f32;
    let mut d = guess * (1.0 / s);
    for l in (0..levels).rev() {
        let scale = (1 << l) as f32;
        let pl = Vec2::new((p.x + 0.5) / scale - 0.5, (p.y + 0.5) / scale - 0.5);
        d = lk_level(a, b, l, pl, d, params, sc)?;
        if l > 0 {
            d = d * 2.0;
        }
    }
    // Beyond what the pyramid can reach from the guess, a result is not trusted.
    let reach = (params.window_half as f32 + 1.0) * (1 << levels) as f32;
    ((d - guess).norm() <= reach).then_some(d)
}
