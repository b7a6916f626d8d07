//! The flow field from the tracks: an affine fit with MAD rejection, then the inliers' statistics.
use super::*;

/// Median of a non-empty slice (mean of the middle two for even lengths); reorders the slice.
pub(super) fn median_of(v: &mut [f32]) -> f32 {
    let m = v.len();
    let (lo, hi, _) = v.select_nth_unstable_by(m / 2, |a, b| a.total_cmp(b));
    if m % 2 == 1 { *hi } else { 0.5 * (*hi + lo.iter().copied().fold(f32::NEG_INFINITY, f32::max)) }
}

/// Affine flow fit with MAD rejection, then the inliers' statistics. The fit's inliers and residual go to
/// `counts` (also when the pair is refused).
#[allow(clippy::too_many_arguments)]
pub(super) fn aggregate(
    tracks: &[(Vec2, Vec2)],
    selected: usize,
    camera: &CameraModel,
    params: &FlowParams,
    predicted_rotation: Vec3,
    inlier: &mut [bool; MAX_FEATURES],
    scratch: &mut [f32; MAX_FEATURES],
    counts: &mut PairCounts,
) -> Result<FlowStats, NoFlowReason> {
    let n = tracks.len();
    if n < params.min_tracks as usize {
        return Err(NoFlowReason::TooFewTracks);
    }
    let f = camera.focal_px();
    // Normalised positions and displacements.
    let mut pos = [Vec2::ZERO; MAX_FEATURES];
    let mut disp = [Vec2::ZERO; MAX_FEATURES];
    for (k, (p, d)) in tracks.iter().enumerate() {
        let a = camera.pixel_to_normalized(*p);
        pos[k] = a;
        disp[k] = camera.pixel_to_normalized(*p + *d) - a;
    }
    inlier[..n].fill(true);
    let mut res = [0.0f32; MAX_FEATURES];
    let mut model = [[0.0f32; 3]; 2];
    for _ in 0..3 {
        // Least squares of disp = c + A (pos - centroid) per axis, over the inliers.
        let m = inlier[..n].iter().filter(|k| **k).count();
        counts.inliers = m as u16;
        if m < params.min_tracks as usize {
            return Err(NoFlowReason::TooFewTracks);
        }
        let mut c = Vec2::ZERO;
        for k in (0..n).filter(|k| inlier[*k]) {
            c += pos[k];
        }
        c = c * (1.0 / m as f32);
        let mut h = [[0.0f32; 3]; 3];
        let mut g = [[0.0f32; 3]; 2];
        for k in (0..n).filter(|k| inlier[*k]) {
            let r = [1.0, pos[k].x - c.x, pos[k].y - c.y];
            for i in 0..3 {
                for j in 0..3 {
                    h[i][j] += r[i] * r[j];
                }
                g[0][i] += r[i] * disp[k].x;
                g[1][i] += r[i] * disp[k].y;
            }
        }
        for axis in 0..2 {
            let mut hh = h;
            let mut b = g[axis];
            // Regularise the slopes a little: with features in one region the affine terms are weak.
            hh[1][1] += 1e-6 * m as f32;
            hh[2][2] += 1e-6 * m as f32;
            if !geometry::solve::cholesky_solve(&mut hh, &mut b, 3) {
                return Err(NoFlowReason::TooFewTracks);
            }
            model[axis] = b;
        }
        let resid = |k: usize| {
            let r = [1.0, pos[k].x - c.x, pos[k].y - c.y];
            let px = model[0][0] * r[0] + model[0][1] * r[1] + model[0][2] * r[2];
            let py = model[1][0] * r[0] + model[1][1] * r[1] + model[1][2] * r[2];
            (disp[k] - Vec2::new(px, py)).norm()
        };
        for k in 0..n {
            res[k] = resid(k);
        }
        scratch[..n].copy_from_slice(&res[..n]);
        // The residual's norm is Rayleigh-distributed for Gaussian noise: median = 1.1774 sigma per axis.
        let sigma = median_of(&mut scratch[..n]) / 1.1774;
        let thresh = (params.outlier_sigmas * sigma).max(0.1 / f);
        let mut changed = false;
        for k in 0..n {
            let ok = res[k] <= thresh;
            changed |= ok != inlier[k];
            inlier[k] = ok;
        }
        if !changed {
            break;
        }
    }
    let idx = |k: &usize| inlier[*k];
    let m = (0..n).filter(idx).count();
    counts.inliers = m as u16;
    if m < params.min_tracks as usize {
        return Err(NoFlowReason::TooFewTracks);
    }
    let inv = 1.0 / m as f32;
    let mut mp = Vec2::ZERO;
    let mut sq = [0.0f32; 3];
    for k in (0..n).filter(idx) {
        mp += pos[k];
        sq[0] += pos[k].x * pos[k].x;
        sq[1] += pos[k].y * pos[k].y;
        sq[2] += pos[k].x * pos[k].y;
    }
    let mut rss = 0.0f32;
    for k in (0..n).filter(idx) {
        rss += res[k] * res[k];
    }
    // Medians per axis: of the displacement less the predicted rotational flow (normalised), and of the raw
    // displacement (pixels).
    let mut median = |value: &dyn Fn(usize) -> f32| {
        for (j, k) in (0..n).filter(idx).enumerate() {
            scratch[j] = value(k);
        }
        median_of(&mut scratch[..m])
    };
    // Each track's end point with the predicted rotation undone exactly: what remains is the translational
    // displacement `(p T_z - T_xy) / (Z - T_z)` of the point's start `p`.
    let rot = Quat::from_rotvec(predicted_rotation).to_mat3();
    let derot = |k: usize| match derotate_point(pos[k] + disp[k], &rot) {
        Some(q) => q - pos[k],
        None => disp[k] - rot_flow_at(pos[k].x, pos[k].y, predicted_rotation),
    };
    let flow = Vec2::new(median(&|k| derot(k).x), median(&|k| derot(k).y));
    let med = Vec2::new(median(&|k| tracks[k].1.x), median(&|k| tracks[k].1.y));
    let residual_rms = libm::sqrtf(rss * inv);
    counts.residual_px = residual_rms * f;
    let quality = m as f32 / selected.max(1) as f32;
    if quality < params.min_quality || residual_rms * f > params.max_residual_px {
        return Err(NoFlowReason::Inconsistent);
    }
    Ok(FlowStats {
        flow,
        predicted_rotation,
        mean_pos: mp * inv,
        mean_sq: sq.map(|v| v * inv),
        inliers: m as u16,
        selected: selected as u16,
        residual_rms,
        median_flow_px: med,
        quality,
    })
}
