//! The solver on exact observations: round trips, closed forms, observability, ambiguity.
use super::*;
use crate::observation::project_observation;

const CAM: CameraModel = CameraModel::PAPER_FORWARD;

fn camera_pose(pos: Vec3, att: Attitude) -> (Mat3, Vec3) {
    let r_wc = att.world_from_body().mul_mat(&BODY_FROM_FORWARD_CAMERA);
    (r_wc.transpose(), pos)
}

fn exact(target: &LineTarget, pos: Vec3, att: Attitude) -> LineObservation {
    let (r_cw, c) = camera_pose(pos, att);
    project_observation(&CAM, target, &r_cw, c, 3.0, 2.0, || 0.0).expect("line in view")
}

fn poses() -> Vec<(Vec3, Attitude)> {
    let mut v = Vec::new();
    for &x in &[0.0f32, 0.6, 1.15, 1.8, 2.3] {
        for &(y, z) in &[(1.0f32, 0.6f32), (1.3, 0.8), (1.6, 1.0)] {
            for &(r, p, yw) in &[(0.0f32, 0.0f32, 0.0f32), (3.0, -4.0, 7.0), (-5.0, 5.0, -10.0)] {
                v.push((
                    Vec3::new(x, y, z),
                    Attitude::new(geometry::deg(r), geometry::deg(p), geometry::deg(yw)),
                ));
            }
        }
    }
    v
}

#[test]
fn exact_round_trip_both_solvers() {
    let t = LineTarget::PAPER;
    let params = PoseParams::default();
    let mut checked = [0usize; 2];
    for (pos, att) in poses() {
        let obs = exact(&t, pos, att);
        let imu = AttitudeSource::Imu { roll: att.roll, pitch: att.pitch, sigma_rad: geometry::deg(0.5) };
        let sol = solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, imu, &params).unwrap();
        let err = sol.camera_position_m - pos;
        assert!(err.y.abs() < 1e-4 && err.z.abs() < 1e-4, "imu {pos:?} {att:?}: {err:?}");
        if obs.real_corners() > 0 {
            assert!(sol.x_observed, "{pos:?} {att:?} {sol:?} {obs:?}");
            assert!(err.x.abs() < 1e-4, "imu x {pos:?} {att:?}: {err:?}");
        } else {
            assert!(!sol.x_observed);
        }
        assert!((sol.camera_from_world.det() - 1.0).abs() < 1e-5);
        assert!((sol.attitude.yaw - att.yaw).abs() < 1e-4);
        checked[0] += 1;
        if obs.real_corners() == 4 {
            let sol = solve_pose(
                &obs,
                &CAM,
                &t,
                &CameraMount::FORWARD_AT_CENTRE,
                AttitudeSource::ImageOnly,
                &params,
            )
            .unwrap();
            let err = sol.camera_position_m - pos;
            assert!(err.norm() < 1e-4, "image {pos:?} {att:?}: {err:?}");
            assert!((sol.camera_from_world.det() - 1.0).abs() < 1e-5);
            let (r_cw, _) = camera_pose(pos, att);
            assert!(sol.camera_from_world.angle_to(&r_cw) < 1e-4);
            checked[1] += 1;
        }
    }
    assert!(checked[0] == 45 && checked[1] >= 5, "{checked:?}");
}

#[test]
fn closed_form_is_exact_on_exact_data() {
    let t = LineTarget::PAPER;
    let params = PoseParams { refine: false, check_ambiguity: false, ..PoseParams::default() };
    let pos = Vec3::new(1.15, 1.5, 0.8);
    let att = Attitude::new(geometry::deg(2.0), geometry::deg(-3.0), geometry::deg(2.0));
    let obs = exact(&t, pos, att);
    assert_eq!(obs.real_corners(), 4);
    let r_vp = rotation_from_vanishing_points(&obs).unwrap();
    let (r_cw, _) = camera_pose(pos, att);
    assert!(r_vp.angle_to(&r_cw) < 1e-4);
    assert!((r_vp.det() - 1.0).abs() < 1e-6);
    let sol = solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &params)
        .unwrap();
    assert!((sol.camera_position_m - pos).norm() < 2e-4, "{:?}", sol.camera_position_m);
}

#[test]
fn head_on_vanishing_points_at_infinity() {
    // Level, facing the wall, camera at the line's mid-height: both pairs of edges are parallel in the image.
    let t = LineTarget::PAPER;
    let pos = Vec3::new(1.15, 1.3, 1.0);
    let obs = exact(&t, pos, Attitude::default());
    let vx = obs.top.line().cross(obs.bottom.line());
    assert!(vx.z.abs() < 1e-6 * vx.norm(), "vanishing point should be at infinity: {vx:?}");
    let r = rotation_from_vanishing_points(&obs).unwrap();
    assert!((r.det() - 1.0).abs() < 1e-6);
    let (r_cw, _) = camera_pose(pos, Attitude::default());
    assert!(r.angle_to(&r_cw) < 1e-5);
    let sol = solve_pose(
        &obs,
        &CAM,
        &t,
        &CameraMount::FORWARD_AT_CENTRE,
        AttitudeSource::ImageOnly,
        &PoseParams::default(),
    )
    .unwrap();
    assert!((sol.camera_position_m - pos).norm() < 1e-4);
    assert!(
        sol.attitude.roll.abs() < 1e-5 && sol.attitude.pitch.abs() < 1e-5 && sol.attitude.yaw.abs() < 1e-5
    );
}

#[test]
fn no_end_in_view_reports_x_unknown() {
    // Close to the wall and yawed: neither end is in the image.
    let t = LineTarget::PAPER;
    let pos = Vec3::new(1.15, 0.5, 0.9);
    let obs = exact(&t, pos, Attitude::default());
    assert_eq!(obs.real_corners(), 0);
    let imu = AttitudeSource::Imu { roll: 0.0, pitch: 0.0, sigma_rad: 0.01 };
    let sol =
        solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, imu, &PoseParams::default()).unwrap();
    assert!(!sol.x_observed);
    assert!(sol.position_std_m.x.is_infinite());
    assert!((sol.camera_position_m.y - pos.y).abs() < 1e-4 && (sol.camera_position_m.z - pos.z).abs() < 1e-4);
    let r = solve_pose(
        &obs,
        &CAM,
        &t,
        &CameraMount::FORWARD_AT_CENTRE,
        AttitudeSource::ImageOnly,
        &PoseParams::default(),
    );
    assert_eq!(r.unwrap_err(), PoseError::Underdetermined);
}

#[test]
fn paper_line_height_depth_is_exact_only_when_fronto_parallel() {
    let t = LineTarget::PAPER;
    let params = PoseParams {
        translation: TranslationMethod::PaperLineHeight,
        refine: false,
        max_rms_px: 100.0,
        ..PoseParams::default()
    };
    let pos = Vec3::new(1.15, 1.5, 1.0);
    let obs = exact(&t, pos, Attitude::default());
    let sol = solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &params)
        .unwrap();
    assert!((sol.camera_position_m - pos).norm() < 1e-3);
    // Pitched by 8 degrees: the corner's depth from its apparent height is biased, least squares is not.
    let att = Attitude::new(geometry::deg(2.0), geometry::deg(8.0), geometry::deg(3.0));
    let obs = exact(&t, pos, att);
    assert_eq!(obs.real_corners(), 4);
    let paper =
        solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &params)
            .unwrap();
    let ls_params = PoseParams { refine: false, max_rms_px: 100.0, ..PoseParams::default() };
    let ls =
        solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &ls_params)
            .unwrap();
    let e_paper = (paper.camera_position_m - pos).norm();
    let e_ls = (ls.camera_position_m - pos).norm();
    assert!(e_paper > 10.0 * e_ls && e_paper > 1e-3, "paper {e_paper} ls {e_ls}");
}

#[test]
fn planar_ambiguity_resolved_by_gravity() {
    // A small rectangle far away and well above the camera: nearly affine, so two poses fit the image.
    let t = LineTarget { x_start_m: 0.0, x_end_m: 0.3, z_bottom_m: 3.7, z_top_m: 3.9 };
    let pos = Vec3::new(0.15, 10.0, 0.8);
    let level = Attitude::new(0.0, geometry::deg(-10.0), 0.0);
    let obs = exact(&t, pos, level);
    let params = PoseParams { max_rms_px: 5.0, max_std_m: f32::INFINITY, ..PoseParams::default() };
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let sol = solve_pose(&obs, &CAM, &t, &mount, AttitudeSource::ImageOnly, &params).unwrap();
    let alt = sol.alternative.expect("a second minimum");
    // Both poses explain the image to a small fraction of a pixel, and differ by a large rotation.
    assert!(sol.reprojection_rms_px < 0.05 && alt.reprojection_rms_px < 0.05, "{sol:?}");
    let tilt_between = sol.camera_from_world.angle_to(&alt.camera_from_world);
    assert!(tilt_between > geometry::deg(10.0), "{tilt_between}");
    // "Near level" picks the true (level) pose.
    let (r_true, _) = camera_pose(pos, level);
    assert!(sol.camera_from_world.angle_to(&r_true) < geometry::deg(0.5));
    assert!((sol.camera_position_m - pos).norm() < 0.05);
    assert!(sol.ambiguity_ratio < 1.5);

    // Now the vehicle really is pitched like the mirror: the image alone is fooled by "near level", the IMU
    // (gravity) is not.
    let pitched = Attitude::from_world_from_body(
        &alt.camera_from_world.transpose().mul_mat(&BODY_FROM_FORWARD_CAMERA.transpose()),
    );
    let obs = exact(&t, alt.camera_position_m, pitched);
    let img = solve_pose(&obs, &CAM, &t, &mount, AttitudeSource::ImageOnly, &params).unwrap();
    let imu = AttitudeSource::Imu { roll: pitched.roll, pitch: pitched.pitch, sigma_rad: geometry::deg(1.0) };
    let with_imu = solve_pose(&obs, &CAM, &t, &mount, imu, &params).unwrap();
    let (r_pitched, _) = camera_pose(alt.camera_position_m, pitched);
    assert!(with_imu.camera_from_world.angle_to(&r_pitched) < geometry::deg(0.5));
    assert!(img.camera_from_world.angle_to(&r_pitched) > geometry::deg(10.0));
}

/// The image-only costs (sigma-normalised) of the kept pose and of its alternative.
fn kept_and_alternative_costs(obs: &LineObservation, t: &LineTarget, sol: &PoseSolution) -> (f32, f32) {
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let sigma = pooled_sigma(obs, PoseParams::default().min_sigma_px / CAM.focal_px());
    let problem = Problem::new(obs, t, sigma, None, &mount, false);
    let cost = |r: &Mat3, c: Vec3| problem.cost(r, -r.mul_vec(c - t.center()));
    let alt = sol.alternative.expect("a second minimum");
    (cost(&sol.camera_from_world, sol.camera_position_m), cost(&alt.camera_from_world, alt.camera_position_m))
}

#[test]
fn when_only_one_minimum_fits_the_image_the_one_that_fits_is_kept() {
    // Costs more than 9 apart (the 3-sigma likelihood-ratio test fails): the smaller residual decides, whichever
    // minimum the refinement reached first. A far small target seen nearly affinely, where the first minimum
    // is the true pose, and a long line seen from afar with one end in view, which the image does not
    // determine and where the mirror is the better fit.
    let params = PoseParams { max_rms_px: 5.0, max_std_m: f32::INFINITY, ..PoseParams::default() };
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let views = [
        (
            LineTarget { x_start_m: 0.0, x_end_m: 0.3, z_bottom_m: 3.7, z_top_m: 3.9 },
            Vec3::new(0.15, 3.0, 0.8),
            Attitude::new(0.0, geometry::deg(-10.0), 0.0),
        ),
        (
            LineTarget { x_start_m: -8.0, x_end_m: 0.3, z_bottom_m: 3.7, z_top_m: 3.9 },
            Vec3::new(0.15, 8.0, 0.8),
            Attitude::new(0.0, geometry::deg(-30.0), geometry::deg(30.0)),
        ),
    ];
    for (i, (t, pos, att)) in views.iter().enumerate() {
        let obs = exact(t, *pos, *att);
        let sol = solve_pose(&obs, &CAM, t, &mount, AttitudeSource::ImageOnly, &params).unwrap();
        let alt = sol.alternative.expect("a second minimum");
        let (kept, other) = kept_and_alternative_costs(&obs, t, &sol);
        assert!(other - kept > 9.0, "view {i}: costs {kept} and {other}");
        assert!(sol.reprojection_rms_px < alt.reprojection_rms_px, "view {i}: {sol:?}");
        assert!(sol.ambiguity_ratio < 0.1, "view {i}: {}", sol.ambiguity_ratio);
        if i == 0 {
            let (r_true, _) = camera_pose(*pos, *att);
            assert!(sol.camera_from_world.angle_to(&r_true) < geometry::deg(0.1));
        }
    }
}

#[test]
fn when_both_minima_fit_the_image_gravity_decides_even_against_the_smaller_residual() {
    // The far, nearly affine view with 0.3 px of noise: both minima fit within 3 sigma, and the noise gives the
    // mirror the smaller residual. "Near level" keeps the true pose; the costs' sum is well above 9, so a test
    // on the sum instead of the difference would let the residual decide.
    let t = LineTarget { x_start_m: 0.0, x_end_m: 0.3, z_bottom_m: 3.7, z_top_m: 3.9 };
    let pos = Vec3::new(0.15, 6.0, 0.8);
    let att = Attitude::new(0.0, geometry::deg(-10.0), 0.0);
    let (r_cw, c) = camera_pose(pos, att);
    let mut rng = super::oracle_tests::Lcg(3u64.wrapping_mul(2654435761).wrapping_add(7));
    let obs =
        project_observation(&CAM, &t, &r_cw, c, 3.0, 2.0, move || 0.3 * rng.next()).expect("line in view");
    let params = PoseParams { max_rms_px: 5.0, max_std_m: f32::INFINITY, ..PoseParams::default() };
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let sol = solve_pose(&obs, &CAM, &t, &mount, AttitudeSource::ImageOnly, &params).unwrap();
    let alt = sol.alternative.expect("a second minimum");
    let (kept, other) = kept_and_alternative_costs(&obs, &t, &sol);
    assert!((kept - other).abs() < 9.0 && kept + other > 9.0, "costs {kept} and {other}");
    assert!(sol.reprojection_rms_px > alt.reprojection_rms_px && sol.ambiguity_ratio > 1.0, "{sol:?}");
    let tilt = |r: &Mat3| libm::acosf(mount.body_from_camera.mul_mat(r).mul_vec(Vec3::Z).z.clamp(-1.0, 1.0));
    assert!(tilt(&sol.camera_from_world) < tilt(&alt.camera_from_world));
    assert!(sol.camera_from_world.angle_to(&r_cw) < alt.camera_from_world.angle_to(&r_cw));
}

#[test]
fn a_mirror_that_refines_back_to_the_pose_is_no_alternative() {
    // The ordinary view: the mirror pose is computed and refined, and it either returns to the same minimum or
    // is implausible, so no alternative is reported and the ratio stays 0.
    let (pos, att) = (
        Vec3::new(1.0, 1.3, 0.8),
        Attitude::new(geometry::deg(3.0), geometry::deg(-4.0), geometry::deg(6.0)),
    );
    let (r_cw, c) = camera_pose(pos, att);
    assert!(mirror_pose(&r_cw, -r_cw.mul_vec(c - LineTarget::PAPER.center())).is_some());
    let obs = exact(&LineTarget::PAPER, pos, att);
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let sol =
        solve_pose(&obs, &CAM, &LineTarget::PAPER, &mount, AttitudeSource::ImageOnly, &PoseParams::default())
            .unwrap();
    assert!(sol.alternative.is_none() && sol.ambiguity_ratio == 0.0, "{sol:?}");
}

#[test]
fn a_band_read_thin_within_the_edge_error_is_covered_by_the_reported_spread() {
    // Both long edges moved inward by `EDGE_BIAS_PX` (optics blur moves them so: 0.02 px at 1.5 px of blur,
    // 0.03-0.05 px at 2 px, `a_blurred_band_keeps_its_edges` in detect.rs), seen from 2 m with both ends in
    // view, the IMU's tilt exact with a 0.5 deg sigma. The fit pitches the camera to make the band thin and z
    // moves with it. Measured: pitch -0.49 deg, z 17.3 mm off; reported z std 9.3 mm from the points alone,
    // 11.2 mm with the edge-common error (at 0.05 px: z 46 mm off, std 8.8 and 11.1 mm: not covered either
    // way, the error is then beyond the budget).
    let t = LineTarget::PAPER;
    let (pos, att) = (Vec3::new(0.6, 2.0, 0.8), Attitude::new(0.0, 0.0, 0.0));
    let mut obs = exact(&t, pos, att);
    let d = EDGE_BIAS_PX / CAM.focal_px();
    let (top, bottom) = (obs.top, obs.bottom);
    for (e, other) in [(&mut obs.top, &bottom), (&mut obs.bottom, &top)] {
        let inward = e.normal.dot(other.centroid - e.centroid).signum();
        e.centroid += e.normal * (inward * d);
    }
    let imu = AttitudeSource::Imu { roll: 0.0, pitch: 0.0, sigma_rad: geometry::deg(0.5) };
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let solve = |edge_bias_px: f32| {
        let params = PoseParams { edge_bias_px, ..PoseParams::default() };
        solve_pose(&obs, &CAM, &t, &mount, imu, &params).unwrap()
    };
    let z_sigmas = |sol: &PoseSolution| (sol.camera_position_m.z - pos.z).abs() / sol.position_std_m.z;
    let (points_only, with_bias) = (solve(0.0), solve(EDGE_BIAS_PX));
    // The same pose: the edge-common error widens the reported spread, it does not move the fit.
    assert_eq!(points_only.camera_position_m, with_bias.camera_position_m);
    for (name, sol) in [("points only", points_only), ("edge-common error", with_bias)] {
        eprintln!(
            "{name}: pitch {:.3} deg, z error {:.1} mm, z std {:.1} mm",
            geometry::to_deg(sol.attitude.pitch),
            1e3 * (sol.camera_position_m.z - pos.z),
            1e3 * sol.position_std_m.z,
        );
    }
    let widened = with_bias.position_std_m.z / points_only.position_std_m.z;
    assert!(widened > 1.15 && widened < 1.3, "z std {widened} times the points' alone");
    assert!(z_sigmas(&with_bias) <= 1.6, "{with_bias:?}");
}
