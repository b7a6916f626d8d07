//! Tests of the flow at 160x120 (the defaults) and of its parts.
use super::*;

const W: usize = 160;
const H: usize = 120;

fn cam() -> CameraModel {
    CameraModel {
        width: W as u16,
        height: H as u16,
        fx: 139.0,
        fy: 139.0,
        cx: 79.5,
        cy: 59.5,
        distortion: Default::default(),
    }
}

/// A smooth random texture sampled at (x + dx, y + dy) with exact bilinear-free evaluation (sum of
/// sinusoids), so that sub-pixel shifts are exact.
fn texture(dx: f32, dy: f32, contrast: f32) -> Vec<u8> {
    let mut img = vec![0u8; W * H];
    let waves = [
        (0.31f32, 0.17f32, 0.0f32),
        (-0.13, 0.41, 1.0),
        (0.57, -0.23, 2.0),
        (0.07, 0.11, 0.5),
        (0.21, 0.29, 3.0),
        (-0.45, 0.06, 4.0),
    ];
    for y in 0..H {
        for x in 0..W {
            let (u, v) = (x as f32 + dx, y as f32 + dy);
            let mut s = 0.0;
            for (a, b, ph) in waves {
                s += (a * u + b * v + ph).sin();
            }
            img[y * W + x] = (128.0 + contrast * 20.0 * s).round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}

fn run(a: &[u8], b: &[u8], pred: Vec3) -> Result<FlowStats, NoFlowReason> {
    let mut ws = Box::new(FlowWorkspace::new());
    let va = Gray8View::packed(a, W, H).unwrap();
    let vb = Gray8View::packed(b, W, H).unwrap();
    flow_between(&va, &vb, &cam(), &FlowParams::default(), pred, &mut ws)
}

#[test]
fn sub_pixel_shift_is_recovered() {
    for &(sx, sy) in &[(0.37f32, -0.21f32), (1.6, 0.45), (-2.3, 3.1), (0.0, 0.0)] {
        // Content moves by (sx, sy): the next frame at x shows what the previous one showed at x - s.
        let a = texture(0.0, 0.0, 1.0);
        let b = texture(-sx, -sy, 1.0);
        let s = run(&a, &b, Vec3::ZERO).unwrap();
        let f = s.median_flow_px;
        assert!((f.x - sx).abs() < 0.05 && (f.y - sy).abs() < 0.05, "shift ({sx}, {sy}): measured {f:?}");
        let m = s.flow * 139.0;
        assert!((m.x - sx).abs() < 0.05 && (m.y - sy).abs() < 0.05, "robust flow {m:?}");
        assert!(s.quality > 0.8 && s.inliers >= 30, "{s:?}");
    }
}

#[test]
fn the_last_pair_s_tracks_are_kept_for_display() {
    let (sx, sy) = (1.25f32, -0.5f32);
    let (a, b) = (texture(0.0, 0.0, 1.0), texture(-sx, -sy, 1.0));
    let mut ws = Box::new(FlowWorkspace::new());
    let (va, vb) = (Gray8View::packed(&a, W, H).unwrap(), Gray8View::packed(&b, W, H).unwrap());
    let s = flow_between(&va, &vb, &cam(), &FlowParams::default(), Vec3::ZERO, &mut ws).unwrap();
    let tracks: Vec<_> = ws.last_tracks().collect();
    assert!(tracks.len() >= s.inliers as usize, "{} tracks, {} inliers", tracks.len(), s.inliers);
    assert_eq!(tracks.iter().filter(|t| t.2).count(), s.inliers as usize);
    for (p, d, ok) in &tracks {
        assert!(p.x >= 0.0 && p.x < W as f32 && p.y >= 0.0 && p.y < H as f32, "{p:?}");
        if *ok {
            assert!((d.x - sx).abs() < 0.1 && (d.y - sy).abs() < 0.1, "{d:?}");
        }
    }
    // A blank pair has none; a reset forgets them.
    let blank = texture(0.0, 0.0, 0.0);
    let vblank = Gray8View::packed(&blank, W, H).unwrap();
    assert!(flow_between(&va, &vb, &cam(), &FlowParams::default(), Vec3::ZERO, &mut ws).is_ok());
    assert!(add_frame(&vblank, &cam(), &FlowParams::default(), Vec3::ZERO, &mut ws).is_err());
    assert_eq!(ws.last_tracks().count(), 0);
    assert!(flow_between(&va, &vb, &cam(), &FlowParams::default(), Vec3::ZERO, &mut ws).is_ok());
    ws.reset();
    assert_eq!(ws.last_tracks().count(), 0);
}

#[test]
fn blank_floor_has_no_flow() {
    let a = texture(0.0, 0.0, 0.0);
    assert_eq!(run(&a, &a, Vec3::ZERO).unwrap_err(), NoFlowReason::NoTexture);
}

#[test]
fn shifts_beyond_reach_are_rejected() {
    // 2 levels, window 9: reach about (4 + 1) * 4 = 20 px from the guess. A 60 px jump of a periodic-ish texture must
    // not come back as a small wrapped flow.
    let a = texture(0.0, 0.0, 1.0);
    let b = texture(-60.0, 0.0, 1.0);
    match run(&a, &b, Vec3::ZERO) {
        Err(e) => assert!(
            matches!(
                e,
                NoFlowReason::TooFewTracks | NoFlowReason::Inconsistent | NoFlowReason::RepeatingTexture
            ),
            "{e:?}"
        ),
        Ok(s) => panic!("a 60 px shift gave a flow: {s:?}"),
    }
}

/// A floor that repeats every `period` px in x and y and at no shorter offset (its lattice is spanned by
/// (period, 0) and (0, period)), sampled at (x + dx, y + dy).
fn tiles(period: f32, dx: f32, dy: f32) -> Vec<u8> {
    let k = core::f32::consts::TAU / period;
    let mut img = vec![0u8; W * H];
    for y in 0..H {
        for x in 0..W {
            let (u, v) = (x as f32 + dx, y as f32 + dy);
            let s = (k * u).sin() + (k * v).sin() + 0.5 * (2.0 * k * (u + v) + 1.0).cos();
            img[y * W + x] = (128.0 + 35.0 * s).round().clamp(0.0, 255.0) as u8;
        }
    }
    img
}

#[test]
fn a_repeating_floor_gives_no_confident_wrong_flow() {
    // Shifted by 0.5-0.8 of its period, a tiled floor matches itself better at the alias (the shift less
    // a period) than anywhere near the truth: a tracker returns the alias with every track agreeing.
    // Refused, or at least below the flight code's quality gate (0.4), never a confident wrong flow.
    let (mut refused, mut right, mut other) = (0, 0, 0);
    for period in [10.0f32, 16.0, 24.0, 32.0, 40.0, 48.0] {
        for frac in [0.55f32, 0.65, 0.8] {
            for (ux, uy) in [(1.0f32, 0.0f32), (0.0, 1.0), (0.7, 0.7)] {
                let (sx, sy) = (frac * period * ux, frac * period * uy);
                let a = tiles(period, 0.0, 0.0);
                let b = tiles(period, -sx, -sy);
                match run(&a, &b, Vec3::ZERO) {
                    Err(NoFlowReason::RepeatingTexture) => refused += 1,
                    Err(_) => other += 1,
                    Ok(st) => {
                        let f = st.median_flow_px;
                        let wrong = (f.x - sx).abs() > 1.0 || (f.y - sy).abs() > 1.0;
                        right += usize::from(!wrong);
                        assert!(
                            !wrong || st.quality < 0.4,
                            "period {period}, shift ({sx}, {sy}): flow {f:?} with quality {}",
                            st.quality
                        );
                    }
                }
            }
        }
    }
    // Measured: 40 of the 54 pairs refused as repeating, the other 14 for too few tracks or inconsistent
    // tracks; before the check, aliases came back with quality 1.00.
    eprintln!("{refused} refused as repeating, {right} right, {other} refused otherwise");
    assert!(refused >= 40, "{refused} pairs refused as a repeating texture");
}

/// A tiling of `period` px (sums of sinusoids along both axes and a diagonal), sampled at `(x + d, y)`.
pub(super) fn tiling(w: usize, h: usize, period: f32, d: f32) -> Vec<u8> {
    let k = core::f32::consts::TAU / period;
    let mut img = vec![0u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 + d, y as f32);
            let s = (k * u).sin() + (k * v).sin() + 0.5 * (2.0 * k * (u + v) + 1.0).cos();
            img[y * w + x] = (128.0 + 35.0 * s).round() as u8;
        }
    }
    img
}

#[test]
fn repeating_floors_are_found_with_any_pyramid_depth_and_up_to_320x240() {
    // One to three pyramid levels, 160x120 and 320x240 frames: a 16 px tiling shifted by 0.65 of it.
    for (w, h) in [(160usize, 120usize), (320, 240)] {
        let (a, b) = (tiling(w, h, 16.0, 0.0), tiling(w, h, 16.0, -0.65 * 16.0));
        let camera = CameraModel { width: w as u16, height: h as u16, ..cam() };
        for levels in 1..=3u8 {
            let params = FlowParams { levels, ..FlowParams::default() };
            let mut ws = Box::new(FlowWorkspace::new());
            let (va, vb) = (Gray8View::packed(&a, w, h).unwrap(), Gray8View::packed(&b, w, h).unwrap());
            let r = flow_between(&va, &vb, &camera, &params, Vec3::ZERO, &mut ws);
            assert_eq!(r.err(), Some(NoFlowReason::RepeatingTexture), "{w}x{h}, {levels} levels");
            let rep = ws.repetition().unwrap();
            assert!((rep.offset_px.norm() - 16.0).abs() < 0.5 && rep.ratio < 0.1, "{rep:?}");
        }
    }
}

#[test]
fn natural_floors_are_not_taken_for_repeating_ones() {
    for contrast in [0.5f32, 1.0] {
        for &(sx, sy) in &[(0.4f32, 0.3f32), (3.0, -2.0), (-2.3, 3.1), (6.0, 0.0)] {
            let a = texture(0.0, 0.0, contrast);
            let b = texture(-sx, -sy, contrast);
            let s = run(&a, &b, Vec3::ZERO).unwrap_or_else(|e| panic!("({sx}, {sy}): {e:?}"));
            assert!((s.median_flow_px.x - sx).abs() < 0.1 && (s.median_flow_px.y - sy).abs() < 0.1);
        }
    }
}

#[test]
fn a_prediction_extends_the_reach() {
    // A 60 px shift is beyond the pyramid's reach without a guess; a guess 3 px off brings it back.
    let a = texture(0.0, 0.0, 1.0);
    let b = texture(60.0, -10.0, 1.0);
    let (va, vb) = (Gray8View::packed(&a, W, H).unwrap(), Gray8View::packed(&b, W, H).unwrap());
    let mut ws = Box::new(FlowWorkspace::new());
    ws.pyr[0].build(&va, 3, false);
    ws.pyr[1].build(&vb, 3, false);
    let params = FlowParams::default();
    let p = Vec2::new(110.0, 60.0);
    let truth = Vec2::new(-60.0, 10.0);
    let near = |d: Option<Vec2>| d.is_some_and(|d| (d - truth).norm() < 0.05);
    let mut sc = LkScratch::new();
    assert!(!near(track(&ws.pyr[0], &ws.pyr[1], p, Vec2::ZERO, MAX_LEVELS, &params, &mut sc)));
    let d = track(&ws.pyr[0], &ws.pyr[1], p, truth + Vec2::new(2.0, -2.0), MAX_LEVELS, &params, &mut sc);
    assert!(near(d), "{d:?}");
}

#[test]
fn velocity_from_translation_and_rotation() {
    // Level camera 1 m above the floor moving at 0.5 m/s along its x for 20 ms: translational flow
    // -0.01 (normalised) everywhere, plus a rotation whose flow the derotation must remove.
    let stats = FlowStats {
        flow: Vec2::ZERO,
        predicted_rotation: Vec3::new(0.012, -0.018, 0.0),
        mean_pos: Vec2::new(0.1, -0.05),
        mean_sq: [0.05, 0.03, -0.004],
        inliers: 40,
        selected: 48,
        residual_rms: 0.001,
        median_flow_px: Vec2::ZERO,
        quality: 0.8,
    };
    let rot = Vec3::new(0.01, -0.02, 0.005);
    let mut s = stats;
    // The tracker removed the flow of its predicted rotation; the velocity corrects for the difference.
    s.flow = Vec2::new(-0.01, 0.0) + stats.rotational_flow(rot - stats.predicted_rotation);
    let v = s.velocity(rot, 0.02, 1.0, Vec3::Z, 0.0, 0.0).unwrap();
    assert!((v.velocity_cam_m_s.x - 0.5).abs() < 1e-4 && v.velocity_cam_m_s.y.abs() < 1e-4, "{v:?}");
    assert!(v.std_m_s > 0.0);
    // Tilted floor: depth at the mean position differs from the range on the axis.
    let n = Vec3::new(0.2, 0.0, 0.98).normalized().unwrap();
    let v2 = s.velocity(rot, 0.02, 1.0, n, 0.0, 0.0).unwrap();
    assert!((v2.velocity_cam_m_s.x - 0.5).abs() > 0.005);
    assert!(s.velocity(rot, 0.0, 1.0, Vec3::Z, 0.0, 0.0).is_none());
}
