//! The scenario's checks: every value against its declared range ([`super::limits`]), then the relations
//! between values; errors name the field.
use super::limits::Limit;
use super::*;

pub(super) fn check(ok: bool, field: &str, what: &str) -> Result<()> {
    if ok { Ok(()) } else { bail!("invalid value of `{field}`: {what}") }
}

/// One number (or array of numbers) of a scenario with its declared limit and the name a refusal gives it.
pub struct Ranged {
    /// The declaration.
    pub limit: Limit,
    /// The field as a refusal names it (the declared name, or an indexed one for shapes, gusts and faults).
    pub field: String,
    /// The values.
    pub values: Vec<f64>,
}

fn r(limit: Limit, values: &[f64]) -> Ranged {
    Ranged { limit, field: limit.name.to_string(), values: values.to_vec() }
}

fn r_at(limit: Limit, field: String, values: &[f64]) -> Ranged {
    Ranged { limit, field, values: values.to_vec() }
}

impl Scenario {
    /// Every number of the scenario outside the flight code's parameters, with its declared limit
    /// ([`super::limits`]).
    pub fn ranged_values(&self) -> Vec<Ranged> {
        use super::limits::*;
        let sc = &self.scene;
        let c = &self.forward_camera;
        let d = &self.down_camera;
        let m = &self.model;
        let i = &self.imu;
        let (l, mi, mm, w) = (&self.link, &self.mission, &self.mismatch, &self.wind);
        let mut v = vec![
            r(SCENE_LINE_X_START, &[sc.line_x_start_m]),
            r(SCENE_LINE_X_END, &[sc.line_x_end_m]),
            r(SCENE_LINE_Z_BOTTOM, &[sc.line_z_bottom_m]),
            r(SCENE_LINE_Z_TOP, &[sc.line_z_top_m]),
            r(SCENE_LINE_ALBEDO, &sc.line_albedo_rgb),
            r(SCENE_WALL_ALBEDO, &sc.wall_albedo_rgb),
            r(SCENE_FLOOR_ALBEDO, &sc.floor_albedo_rgb),
            r(SCENE_WALL_TEXTURE_CONTRAST, &[sc.wall_texture_contrast]),
            r(SCENE_FLOOR_TEXTURE_CONTRAST, &[sc.floor_texture_contrast]),
            r(SCENE_LIGHT_GAIN, &[sc.light_gain]),
            r(SCENE_LIGHT_GRADIENT, &sc.light_gradient_per_m),
            r(FORWARD_WIDTH, &[c.width_px as f64]),
            r(FORWARD_HEIGHT, &[c.height_px as f64]),
            r(FORWARD_FX, &[c.fx_px]),
            r(FORWARD_FY, &[c.fy_px]),
            r(FORWARD_CX, &[c.cx_px]),
            r(FORWARD_CY, &[c.cy_px]),
            r(FORWARD_DISTORTION, &c.distortion),
            r(FORWARD_MOUNT_OFFSET, &c.mount_offset_body_m),
            r(FORWARD_MOUNT_ROTATION, &c.mount_rotation_deg),
            r(FORWARD_NOISE, &[c.noise_sigma]),
            r(FORWARD_BLUR, &[c.blur_sigma_px]),
            r(FORWARD_EXPOSURE, &[c.exposure]),
            r(FORWARD_EXPOSURE_STEP, &[c.exposure_step]),
            r(FORWARD_VIGNETTING, &[c.vignetting]),
            r(FORWARD_JPEG_QUALITY, &[c.jpeg_quality as f64]),
            r(FORWARD_EXPOSURE_TIME, &[c.exposure_time_s]),
            r(FORWARD_LINE_DELAY, &[c.line_delay_s]),
            r(FORWARD_RATE, &[c.rate_hz]),
            r(FORWARD_LATENCY, &[c.latency_s]),
            r(FORWARD_LATENCY_JITTER, &[c.latency_jitter_s]),
            r(FORWARD_ANALYTIC_NOISE, &[c.analytic_noise_px]),
            r(DOWN_WIDTH, &[d.width_px as f64]),
            r(DOWN_HEIGHT, &[d.height_px as f64]),
            r(DOWN_FX, &[d.fx_px]),
            r(DOWN_FY, &[d.fy_px]),
            r(DOWN_CX, &[d.cx_px]),
            r(DOWN_CY, &[d.cy_px]),
            r(DOWN_MOUNT_OFFSET, &d.mount_offset_body_m),
            r(DOWN_MOUNT_ROTATION, &d.mount_rotation_deg),
            r(DOWN_RATE, &[d.rate_hz]),
            r(DOWN_LATENCY, &[d.latency_s]),
            r(DOWN_EXPOSURE_TIME, &[d.exposure_time_s]),
            r(DOWN_EXPOSURE, &[d.exposure]),
            r(DOWN_NOISE, &[d.noise_sigma]),
            r(DOWN_BLUR, &[d.blur_sigma_px]),
            r(DOWN_VIGNETTING, &[d.vignetting]),
            r(MODEL_MOTOR_TAU, &[m.motor_time_constant_s]),
            r(MODEL_LINEAR_DRAG, &[m.linear_drag_n_s_per_m]),
            r(MODEL_ROTOR_DRAG, &[m.rotor_drag_coeff]),
            r(MODEL_GROUND_EFFECT_RADIUS, &[m.ground_effect_rotor_radius_m]),
            r(MODEL_PHYSICS_STEP, &[m.physics_step_s]),
            r(MODEL_START_POSITION, &m.start_position_m),
            r(MODEL_START_YAW, &[m.start_yaw_deg]),
            r(IMU_RATE, &[i.rate_hz]),
            r(IMU_GYRO_NOISE, &[i.gyro_noise_density]),
            r(IMU_ACCEL_NOISE, &[i.accel_noise_density]),
            r(IMU_GYRO_BIAS, &[i.gyro_bias_sigma_rad_s]),
            r(IMU_ACCEL_BIAS, &[i.accel_bias_sigma_m_s2]),
            r(IMU_MAG_RATE, &[i.mag_rate_hz]),
            r(IMU_MAG_NOISE, &[i.mag_noise_rel]),
            r(IMU_MAG_FIELD, &i.mag_field_world),
            r(IMU_VIBRATION_ACCEL, &[i.vibration_accel_m_s2]),
            r(IMU_VIBRATION_GYRO, &[i.vibration_gyro_rad_s]),
            r(IMU_ACCEL_RANGE, &[i.accel_range_m_s2]),
            r(IMU_GYRO_RANGE, &[i.gyro_range_rad_s]),
            r(IMU_BARO_RATE, &[i.baro_rate_hz]),
            r(IMU_BARO_NOISE, &[i.baro_noise_m]),
            r(IMU_BARO_OFFSET, &[i.baro_offset_m]),
            r(IMU_BARO_DRIFT, &[i.baro_drift_m_per_sqrt_s]),
            r(IMU_DLPF, &[i.dlpf_hz]),
            r(LINK_LATENCY, &[l.latency_s]),
            r(LINK_HEARTBEAT, &[l.heartbeat_hz]),
            r(MISSION_CONTROL_RATE, &[mi.control_rate_hz]),
            r(MISSION_ARM_AT, &[mi.arm_at_s]),
            r(MISSION_TAKEOFF_AT, &[mi.takeoff_at_s]),
            r(MISSION_TRACK_AFTER_HOVER, &[mi.track_after_hover_s]),
            r(MISSION_MAX_DURATION, &[mi.max_duration_s]),
            r(MISMATCH_MASS, &[mm.mass_scale]),
            r(MISMATCH_INERTIA, &mm.inertia_scale),
            r(MISMATCH_THRUST, &[mm.thrust_coeff_scale]),
            r(MISMATCH_DRAG_TORQUE, &[mm.drag_torque_coeff_scale]),
            r(MISMATCH_MOTOR_TAU, &[mm.motor_time_constant_scale]),
            r(MISMATCH_FORWARD_MOUNT, &mm.forward_camera_mount_error_deg),
            r(MISMATCH_IMU, &mm.imu_misalignment_deg),
            r(WIND_MEAN, &w.mean_m_s),
            r(WIND_TURBULENCE, &[w.turbulence_sigma_m_s]),
        ];
        if w.turbulence_sigma_m_s != 0.0 {
            v.push(r(WIND_TURBULENCE_LENGTH, &[w.turbulence_length_m]));
        }
        for (k, shape) in sc.shapes.iter().enumerate() {
            let at = |name: &str| format!("scene.shapes[{k}].{name}");
            match shape {
                WallShape::Polygon { points_m, albedo_rgb } => {
                    let pts: Vec<f64> = points_m.iter().flatten().copied().collect();
                    v.push(r_at(SCENE_SHAPE_POINTS, at("points_m"), &pts));
                    v.push(r_at(SCENE_SHAPE_ALBEDO, at("albedo_rgb"), albedo_rgb));
                }
                WallShape::Disc { center_m, radius_m, albedo_rgb } => {
                    v.push(r_at(SCENE_SHAPE_CENTER, at("center_m"), center_m));
                    v.push(r_at(SCENE_SHAPE_RADIUS, at("radius_m"), &[*radius_m]));
                    v.push(r_at(SCENE_SHAPE_ALBEDO, at("albedo_rgb"), albedo_rgb));
                }
            }
        }
        for (k, g) in w.gusts.iter().enumerate() {
            let at = |name: &str| format!("wind.gusts[{k}].{name}");
            v.push(r_at(WIND_GUST_START, at("start_s"), &[g.start_s]));
            v.push(r_at(WIND_GUST_DURATION, at("duration_s"), &[g.duration_s]));
            v.push(r_at(WIND_GUST_VELOCITY, at("velocity_m_s"), &g.velocity_m_s));
        }
        for (k, f) in self.faults.iter().enumerate() {
            let at = |name: &str| format!("faults[{k}] ({}).{name}", f.kind.name());
            v.push(r_at(FAULT_START, at("start_s"), &[f.start_s]));
            v.push(r_at(FAULT_DURATION, at("duration_s"), &[f.duration_s]));
            let mut kind = |limit: Limit, name: &str, values: &[f64]| v.push(r_at(limit, at(name), values));
            match &f.kind {
                FaultKind::LinkCorruption { byte_error_rate } => {
                    kind(FAULT_BYTE_ERROR_RATE, "byte_error_rate", &[*byte_error_rate])
                }
                FaultKind::ImuSpike { rate_hz, accel_m_s2, gyro_rad_s } => {
                    kind(FAULT_SPIKE_RATE, "rate_hz", &[*rate_hz]);
                    kind(FAULT_SPIKE_ACCEL, "accel_m_s2", &[*accel_m_s2]);
                    kind(FAULT_SPIKE_GYRO, "gyro_rad_s", &[*gyro_rad_s]);
                }
                FaultKind::ImuBiasStep { gyro_rad_s, accel_m_s2 } => {
                    kind(FAULT_BIAS_STEP_GYRO, "gyro_rad_s", gyro_rad_s);
                    kind(FAULT_BIAS_STEP_ACCEL, "accel_m_s2", accel_m_s2);
                }
                FaultKind::GyroSaturation { limit_rad_s } => {
                    kind(FAULT_GYRO_SATURATION, "limit_rad_s", &[*limit_rad_s])
                }
                FaultKind::MagDisturbance { heading_offset_deg, field_scale } => {
                    kind(FAULT_MAG_HEADING, "heading_offset_deg", &[*heading_offset_deg]);
                    kind(FAULT_MAG_SCALE, "field_scale", &[*field_scale]);
                }
                FaultKind::MotorDegradation { motor, thrust_scale } => {
                    kind(FAULT_DEGRADED_MOTOR, "motor", &[*motor as f64]);
                    kind(FAULT_DEGRADED_THRUST, "thrust_scale", &[*thrust_scale]);
                }
                FaultKind::MotorLoss { motor } => kind(FAULT_LOST_MOTOR, "motor", &[*motor as f64]),
                FaultKind::VisionDropout
                | FaultKind::VisionFreeze
                | FaultKind::FlowDropout
                | FaultKind::LinkLoss
                | FaultKind::RcLoss => {}
            }
        }
        let b = &self.battery_model;
        v.extend([
            r(BATTERY_MODEL_CELLS, &[b.cells as f64]),
            r(BATTERY_MODEL_CAPACITY, &[b.capacity_mah]),
            r(BATTERY_MODEL_RESISTANCE, &[b.resistance_ohm]),
            r(BATTERY_MODEL_EFFICIENCY, &[b.drive_efficiency]),
            r(BATTERY_MODEL_IDLE_CURRENT, &[b.idle_current_a]),
            r(BATTERY_MODEL_CHARGE, &[b.initial_charge]),
            r(BATTERY_MODEL_RATE, &[b.rate_hz]),
            r(BATTERY_MODEL_VOLTAGE_NOISE, &[b.voltage_noise_v]),
            r(BATTERY_MODEL_CURRENT_NOISE, &[b.current_noise_a]),
        ]);
        let tx = &self.transmitter;
        v.push(r(TRANSMITTER_FRAME_RATE, &[tx.frame_rate_hz]));
        for (k, e) in tx.script.iter().enumerate() {
            let at = |name: &str| format!("transmitter.script[{k}].{name}");
            v.push(r_at(TRANSMITTER_AT, at("at_s"), &[e.at_s]));
            for (limit, name, stick) in [
                (TRANSMITTER_ROLL, "roll", e.roll),
                (TRANSMITTER_PITCH, "pitch", e.pitch),
                (TRANSMITTER_YAW, "yaw", e.yaw),
            ] {
                if let Some(x) = stick {
                    v.push(r_at(limit, at(name), &[x]));
                }
            }
            if let Some(x) = e.throttle {
                v.push(r_at(TRANSMITTER_THROTTLE, at("throttle"), &[x]));
            }
        }
        v
    }

    /// Checks every value against its declared range, then the relations between values, then the flight
    /// code's parameters; errors name the field.
    pub fn validate(&self) -> Result<()> {
        for v in self.ranged_values() {
            v.limit.check_as(&v.field, &v.values)?;
        }
        let sc = &self.scene;
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
        for (i, shape) in sc.shapes.iter().enumerate() {
            let (pts, _) = shape.polygon();
            check(
                pts.len() >= 3 && is_convex(&pts),
                &format!("scene.shapes[{i}]"),
                "points_m must be at least 3 points of a convex polygon",
            )?;
        }
        let c = &self.forward_camera;
        check(
            c.latency_jitter_s <= c.latency_s,
            "forward_camera.latency_jitter_s",
            "must lie in [0, latency_s]",
        )?;
        let d = &self.down_camera;
        check(
            d.latency_s + 1.0 / d.rate_hz <= 0.12,
            "down_camera.latency_s",
            "plus the frame interval must be at most 0.12 s (the flight code keeps 0.128 s of gyro history)",
        )?;
        check(
            d.exposure_time_s <= 1.0 / d.rate_hz,
            "down_camera.exposure_time_s",
            "must lie in [0, 1 / down_camera.rate_hz] (one frame interval)",
        )?;
        let m = &self.model;
        // The motors' decay must be resolved by the integrator (RK4 is stable for h / tau below 2.78; one
        // physics step per time constant keeps a margin), also for the simulated vehicle's mismatched motors.
        check(
            m.motor_time_constant_s * self.mismatch.motor_time_constant_scale >= m.physics_step_s,
            "model.motor_time_constant_s",
            "times mismatch.motor_time_constant_scale must be at least model.physics_step_s",
        )?;
        check(
            m.start_position_m[1] > 0.2,
            "model.start_position_m",
            "must be at least 0.2 m from the wall (y > 0.2)",
        )?;
        let steps_per = |hz: f64| 1.0 / (hz * m.physics_step_s);
        let whole = |x: f64| (x - x.round()).abs() < 1e-6 && x >= 1.0;
        let i = &self.imu;
        check(whole(steps_per(i.rate_hz)), "imu.rate_hz", "must divide the physics rate")?;
        check(
            i.dlpf_hz == 0.0 || (5.0..=0.5 * i.rate_hz).contains(&i.dlpf_hz),
            "imu.dlpf_hz",
            "must be 0 (off) or lie in [5 Hz, half the IMU rate]",
        )?;
        check(i.mag_rate_hz <= i.rate_hz, "imu.mag_rate_hz", "must lie in (0, imu.rate_hz]")?;
        check(i.baro_rate_hz <= i.rate_hz, "imu.baro_rate_hz", "must lie in [0, imu.rate_hz]")?;
        check(
            i.mag_field_world.iter().any(|v| *v != 0.0),
            "imu.mag_field_world",
            "must be finite and non-zero",
        )?;
        let mi = &self.mission;
        check(
            whole(steps_per(mi.control_rate_hz)),
            "mission.control_rate_hz",
            "must divide the physics rate",
        )?;
        check(
            mi.control_rate_hz <= i.rate_hz,
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
        check(mi.takeoff_at_s >= mi.arm_at_s, "mission.takeoff_at_s", "must not come before arm_at_s")?;
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
