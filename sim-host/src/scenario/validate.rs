//! The scenario's checks: every value against its range, errors naming the field.
use super::*;

/// The forward camera's largest Gaussian blur (px): the scenario's `forward_camera.blur_sigma_px` and
/// `sim-host render --camera forward --blur` share it.
pub const FORWARD_BLUR_MAX_PX: f64 = 5.0;
/// The downward camera's largest Gaussian blur (px), for `down_camera.blur_sigma_px` and `render --camera down`.
pub const DOWN_BLUR_MAX_PX: f64 = 1.0;

pub(super) fn check(ok: bool, field: &str, what: &str) -> Result<()> {
    if ok { Ok(()) } else { bail!("invalid value of `{field}`: {what}") }
}

pub(super) fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Scenario {
    /// Checks every value; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let sc = &self.scene;
        check(
            finite(&[sc.line_x_start_m, sc.line_x_end_m, sc.line_z_bottom_m, sc.line_z_top_m]),
            "scene.line_*",
            "must be finite",
        )?;
        check(
            sc.line_x_end_m > sc.line_x_start_m,
            "scene.line_x_end_m",
            "must be greater than line_x_start_m",
        )?;
        check(
            sc.line_z_top_m > sc.line_z_bottom_m,
            "scene.line_z_top_m",
            "must be greater than line_z_bottom_m",
        )?;
        check(sc.line_z_bottom_m >= 0.0, "scene.line_z_bottom_m", "must be above the floor (>= 0)")?;
        for (name, v) in [
            ("scene.line_albedo_rgb", &sc.line_albedo_rgb),
            ("scene.wall_albedo_rgb", &sc.wall_albedo_rgb),
            ("scene.floor_albedo_rgb", &sc.floor_albedo_rgb),
        ] {
            check(
                finite(v) && v.iter().all(|x| (0.0..=1.0).contains(x)),
                name,
                "albedos must lie in [0, 1]",
            )?;
        }
        check(
            (0.0..=1.0).contains(&sc.wall_texture_contrast),
            "scene.wall_texture_contrast",
            "must lie in [0, 1]",
        )?;
        check(
            (0.0..=1.0).contains(&sc.floor_texture_contrast),
            "scene.floor_texture_contrast",
            "must lie in [0, 1]",
        )?;
        check(sc.light_gain.is_finite() && sc.light_gain > 0.0, "scene.light_gain", "must be positive")?;
        check(finite(&sc.light_gradient_per_m), "scene.light_gradient_per_m", "must be finite")?;
        for (i, shape) in sc.shapes.iter().enumerate() {
            let field = format!("scene.shapes[{i}]");
            let (pts, albedo) = shape.polygon();
            check(
                finite(&albedo) && albedo.iter().all(|x| (0.0..=1.0).contains(x)),
                &field,
                "albedos must lie in [0, 1]",
            )?;
            if let WallShape::Disc { radius_m, .. } = shape {
                check(radius_m.is_finite() && *radius_m > 0.0, &field, "radius_m must be positive")?;
            }
            check(
                pts.len() >= 3 && pts.iter().all(|p| finite(p)) && is_convex(&pts),
                &field,
                "points_m must be at least 3 finite points of a convex polygon",
            )?;
        }
        let c = &self.forward_camera;
        check(
            c.width_px >= 16 && c.width_px as usize <= vision_core::detect::MAX_DETECT_DIM,
            "forward_camera.width_px",
            "must be 16..=1280",
        )?;
        check(
            c.height_px >= 16 && c.height_px as usize <= vision_core::detect::MAX_DETECT_DIM,
            "forward_camera.height_px",
            "must be 16..=1280",
        )?;
        check(c.fx_px.is_finite() && c.fx_px > 0.0, "forward_camera.fx_px", "must be positive")?;
        check(c.fy_px.is_finite() && c.fy_px > 0.0, "forward_camera.fy_px", "must be positive")?;
        check(c.cx_px.is_finite(), "forward_camera.cx_px", "must be finite")?;
        check(c.cy_px.is_finite(), "forward_camera.cy_px", "must be finite")?;
        check(finite(&c.distortion), "forward_camera.distortion", "must be finite")?;
        check(finite(&c.mount_offset_body_m), "forward_camera.mount_offset_body_m", "must be finite")?;
        check(
            finite(&c.mount_rotation_deg) && c.mount_rotation_deg.iter().all(|a| a.abs() <= 45.0),
            "forward_camera.mount_rotation_deg",
            "angles must lie within +-45 deg",
        )?;
        check(
            c.noise_sigma.is_finite() && c.noise_sigma >= 0.0,
            "forward_camera.noise_sigma",
            "must be >= 0",
        )?;
        check(
            c.blur_sigma_px.is_finite() && (0.0..=FORWARD_BLUR_MAX_PX).contains(&c.blur_sigma_px),
            "forward_camera.blur_sigma_px",
            &format!("must lie in [0, {FORWARD_BLUR_MAX_PX}] px"),
        )?;
        check(c.exposure.is_finite() && c.exposure > 0.0, "forward_camera.exposure", "must be positive")?;
        check(
            c.rate_hz.is_finite() && c.rate_hz > 0.0 && c.rate_hz <= 200.0,
            "forward_camera.rate_hz",
            "must lie in (0, 200] Hz",
        )?;
        check(
            c.latency_s.is_finite() && (0.0..=0.2).contains(&c.latency_s),
            "forward_camera.latency_s",
            "must lie in [0, 0.2] s (the estimator keeps 0.25 s)",
        )?;
        check(
            c.latency_jitter_s.is_finite() && c.latency_jitter_s >= 0.0 && c.latency_jitter_s <= c.latency_s,
            "forward_camera.latency_jitter_s",
            "must lie in [0, latency_s]",
        )?;
        check(
            c.analytic_noise_px.is_finite() && c.analytic_noise_px >= 0.0,
            "forward_camera.analytic_noise_px",
            "must be >= 0",
        )?;
        let d = &self.down_camera;
        check(
            d.width_px >= 32 && d.width_px as usize <= vision_core::flow::FLOW_MAX_W,
            "down_camera.width_px",
            "must be 32..=320",
        )?;
        check(
            d.height_px >= 32 && d.height_px as usize <= vision_core::flow::FLOW_MAX_H,
            "down_camera.height_px",
            "must be 32..=240",
        )?;
        check(d.fx_px.is_finite() && d.fx_px > 0.0, "down_camera.fx_px", "must be positive")?;
        check(d.fy_px.is_finite() && d.fy_px > 0.0, "down_camera.fy_px", "must be positive")?;
        check(d.cx_px.is_finite(), "down_camera.cx_px", "must be finite")?;
        check(d.cy_px.is_finite(), "down_camera.cy_px", "must be finite")?;
        check(
            finite(&d.mount_offset_body_m) && d.mount_offset_body_m.iter().all(|v| v.abs() <= 0.5),
            "down_camera.mount_offset_body_m",
            "must be finite and within 0.5 m of the centre",
        )?;
        check(
            finite(&d.mount_rotation_deg) && d.mount_rotation_deg.iter().all(|a| a.abs() <= 30.0),
            "down_camera.mount_rotation_deg",
            "angles must lie within +-30 deg",
        )?;
        check(
            d.rate_hz.is_finite() && (10.0..=400.0).contains(&d.rate_hz),
            "down_camera.rate_hz",
            "must lie in [10, 400] Hz",
        )?;
        check(
            d.latency_s.is_finite() && d.latency_s >= 0.0 && d.latency_s + 1.0 / d.rate_hz <= 0.12,
            "down_camera.latency_s",
            "plus the frame interval must be at most 0.12 s (the flight code keeps 0.128 s of gyro history)",
        )?;
        check(
            d.exposure_time_s.is_finite() && d.exposure_time_s >= 0.0 && d.exposure_time_s <= 1.0 / d.rate_hz,
            "down_camera.exposure_time_s",
            "must lie in [0, 1 / rate_hz]",
        )?;
        check(d.exposure.is_finite() && d.exposure > 0.0, "down_camera.exposure", "must be positive")?;
        check(d.noise_sigma.is_finite() && d.noise_sigma >= 0.0, "down_camera.noise_sigma", "must be >= 0")?;
        check(
            d.blur_sigma_px.is_finite() && (0.0..=DOWN_BLUR_MAX_PX).contains(&d.blur_sigma_px),
            "down_camera.blur_sigma_px",
            &format!("must lie in [0, {DOWN_BLUR_MAX_PX}] px"),
        )?;
        check(
            d.vignetting.is_finite() && (0.0..=0.9).contains(&d.vignetting),
            "down_camera.vignetting",
            "must lie in [0, 0.9]",
        )?;
        let m = &self.model;
        check(
            m.motor_time_constant_s.is_finite() && (1e-3..=1.0).contains(&m.motor_time_constant_s),
            "model.motor_time_constant_s",
            "must lie in [0.001, 1] s",
        )?;
        // The motors' decay must be resolved by the integrator (RK4 is stable for h / tau below 2.78; one
        // physics step per time constant keeps a margin), also for the simulated vehicle's mismatched motors.
        check(
            m.motor_time_constant_s * self.mismatch.motor_time_constant_scale >= m.physics_step_s,
            "model.motor_time_constant_s",
            "times mismatch.motor_time_constant_scale must be at least model.physics_step_s",
        )?;
        check(
            m.linear_drag_n_s_per_m.is_finite() && m.linear_drag_n_s_per_m >= 0.0,
            "model.linear_drag_n_s_per_m",
            "must be >= 0",
        )?;
        check(
            m.rotor_drag_coeff.is_finite() && (0.0..=1e-3).contains(&m.rotor_drag_coeff),
            "model.rotor_drag_coeff",
            "must lie in [0, 1e-3] N s^2/(m rad)",
        )?;
        check(
            m.ground_effect_rotor_radius_m.is_finite()
                && (0.0..=0.5).contains(&m.ground_effect_rotor_radius_m),
            "model.ground_effect_rotor_radius_m",
            "must lie in [0, 0.5] m",
        )?;
        check(
            m.physics_step_s.is_finite() && m.physics_step_s >= 1e-5 && m.physics_step_s <= 0.001,
            "model.physics_step_s",
            "must lie in [1e-5, 0.001] s",
        )?;
        check(finite(&m.start_position_m), "model.start_position_m", "must be finite")?;
        check(
            m.start_position_m[1] > 0.2,
            "model.start_position_m",
            "must be at least 0.2 m from the wall (y > 0.2)",
        )?;
        check(
            m.start_yaw_deg.is_finite() && m.start_yaw_deg.abs() <= 45.0,
            "model.start_yaw_deg",
            "must lie within +-45 deg",
        )?;
        let steps_per = |hz: f64| 1.0 / (hz * m.physics_step_s);
        let whole = |x: f64| (x - x.round()).abs() < 1e-6 && x >= 1.0;
        let i = &self.imu;
        check(
            i.rate_hz.is_finite() && whole(steps_per(i.rate_hz)),
            "imu.rate_hz",
            "must divide the physics rate",
        )?;
        for (name, v) in [
            ("imu.gyro_noise_density", i.gyro_noise_density),
            ("imu.accel_noise_density", i.accel_noise_density),
            ("imu.gyro_bias_sigma_rad_s", i.gyro_bias_sigma_rad_s),
            ("imu.accel_bias_sigma_m_s2", i.accel_bias_sigma_m_s2),
            ("imu.mag_noise_rel", i.mag_noise_rel),
        ] {
            check(v.is_finite() && v >= 0.0, name, "must be >= 0")?;
        }
        check(
            i.vibration_accel_m_s2.is_finite() && (0.0..=20.0).contains(&i.vibration_accel_m_s2),
            "imu.vibration_accel_m_s2",
            "must lie in [0, 20] m/s^2",
        )?;
        check(
            i.vibration_gyro_rad_s.is_finite() && (0.0..=2.0).contains(&i.vibration_gyro_rad_s),
            "imu.vibration_gyro_rad_s",
            "must lie in [0, 2] rad/s",
        )?;
        check(
            i.accel_range_m_s2.is_finite() && (20.0..=1000.0).contains(&i.accel_range_m_s2),
            "imu.accel_range_m_s2",
            "must lie in [20, 1000] m/s^2",
        )?;
        check(
            i.gyro_range_rad_s.is_finite() && (1.0..=100.0).contains(&i.gyro_range_rad_s),
            "imu.gyro_range_rad_s",
            "must lie in [1, 100] rad/s",
        )?;
        check(
            i.dlpf_hz.is_finite() && (i.dlpf_hz == 0.0 || (5.0..=0.5 * i.rate_hz).contains(&i.dlpf_hz)),
            "imu.dlpf_hz",
            "must be 0 (off) or lie in [5 Hz, half the IMU rate]",
        )?;
        check(
            i.mag_rate_hz.is_finite() && i.mag_rate_hz > 0.0 && i.mag_rate_hz <= i.rate_hz,
            "imu.mag_rate_hz",
            "must lie in (0, imu.rate_hz]",
        )?;
        check(
            finite(&i.mag_field_world) && i.mag_field_world.iter().any(|v| *v != 0.0),
            "imu.mag_field_world",
            "must be finite and non-zero",
        )?;
        let l = &self.link;
        check(
            l.latency_s.is_finite() && (0.0..=0.5).contains(&l.latency_s),
            "link.latency_s",
            "must lie in [0, 0.5] s",
        )?;
        check(l.heartbeat_hz.is_finite() && l.heartbeat_hz > 0.0, "link.heartbeat_hz", "must be positive")?;
        let mi = &self.mission;
        check(
            mi.control_rate_hz.is_finite() && whole(steps_per(mi.control_rate_hz)),
            "mission.control_rate_hz",
            "must divide the physics rate",
        )?;
        check(
            mi.control_rate_hz >= 100.0 && mi.control_rate_hz <= i.rate_hz,
            "mission.control_rate_hz",
            "must lie in [100 Hz, imu.rate_hz]",
        )?;
        // A control step (its link message to a firmware in the loop and its log record) carries at most
        // `MAX_IMU_PER_STEP` IMU samples: a slower control rate would lose samples.
        let per_step = (i.rate_hz / mi.control_rate_hz).ceil() as usize;
        check(
            per_step <= flight_core::fil::MAX_IMU_PER_STEP,
            "mission.control_rate_hz",
            &format!(
                "must be at least imu.rate_hz / {} = {} Hz (a control step carries at most {} IMU samples)",
                flight_core::fil::MAX_IMU_PER_STEP,
                i.rate_hz / flight_core::fil::MAX_IMU_PER_STEP as f64,
                flight_core::fil::MAX_IMU_PER_STEP
            ),
        )?;
        for (name, v) in [
            ("mission.arm_at_s", mi.arm_at_s),
            ("mission.takeoff_at_s", mi.takeoff_at_s),
            ("mission.track_after_hover_s", mi.track_after_hover_s),
        ] {
            check(v.is_finite() && v >= 0.0, name, "must be >= 0")?;
        }
        check(mi.takeoff_at_s >= mi.arm_at_s, "mission.takeoff_at_s", "must not come before arm_at_s")?;
        check(
            mi.max_duration_s.is_finite() && mi.max_duration_s > 0.0,
            "mission.max_duration_s",
            "must be positive",
        )?;
        self.mismatch.validate()?;
        self.wind.validate()?;
        for (i, f) in self.faults.iter().enumerate() {
            f.validate(i)?;
        }
        self.flight_params()
            .validate()
            .map_err(|e| anyhow::anyhow!("invalid value of `{}`: {}", e.field, e.problem))?;
        Ok(())
    }
}

impl Scenario {
    /// The fields the `analytic` camera mode cannot honour, set away from the built-in scenario's values: the
    /// analytic forward camera projects the line's edges with `forward_camera.analytic_noise_px` of edge noise
    /// (scaled by the light), the analytic flow tracks an ideal floor grid; neither renders textures, shapes,
    /// blur, gradients or sensor noise. `Sil::new` refuses such a scenario in that mode, naming each field.
    pub fn analytic_unmodelled(&self) -> Vec<String> {
        let p = Scenario::paper();
        let mut out = Vec::new();
        let mut differs = |name: &str, same: bool, why: &str| {
            if !same {
                out.push(format!("{name}: {why}"));
            }
        };
        let (sc, ps) = (&self.scene, &p.scene);
        differs("scene.shapes", sc.shapes.is_empty(), "the analytic camera projects the line alone");
        differs(
            "scene.wall_texture_contrast",
            sc.wall_texture_contrast == ps.wall_texture_contrast,
            "no texture is rendered",
        );
        differs(
            "scene.floor_texture_contrast",
            sc.floor_texture_contrast == ps.floor_texture_contrast,
            "the analytic flow tracks an ideal floor",
        );
        differs(
            "scene.floor_texture",
            sc.floor_texture == ps.floor_texture,
            "the analytic flow tracks an ideal floor",
        );
        differs(
            "scene.light_gradient_per_m",
            sc.light_gradient_per_m == ps.light_gradient_per_m,
            "only a uniform light gain is modelled",
        );
        let (fc, pf) = (&self.forward_camera, &p.forward_camera);
        differs("forward_camera.blur_sigma_px", fc.blur_sigma_px == pf.blur_sigma_px, "no image is rendered");
        differs(
            "forward_camera.noise_sigma",
            fc.noise_sigma == pf.noise_sigma,
            "set forward_camera.analytic_noise_px instead",
        );
        let (dc, pd) = (&self.down_camera, &p.down_camera);
        differs(
            "down_camera.noise_sigma",
            dc.noise_sigma == pd.noise_sigma,
            "the analytic flow's tracking noise is fixed",
        );
        differs("down_camera.blur_sigma_px", dc.blur_sigma_px == pd.blur_sigma_px, "no image is rendered");
        differs("down_camera.vignetting", dc.vignetting == pd.vignetting, "no image is rendered");
        differs(
            "down_camera.exposure_time_s",
            dc.exposure_time_s == pd.exposure_time_s,
            "no motion blur is modelled",
        );
        differs("down_camera.exposure", dc.exposure == pd.exposure, "no image is rendered");
        out
    }
}
