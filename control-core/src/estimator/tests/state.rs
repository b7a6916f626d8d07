//! The filter's bookkeeping: the reported covariance, health, the state history, the covariance propagation
//! against its equations, symmetrising, the spike filter and the refusal of samples.
use super::*;

#[test]
fn the_estimate_reports_the_covariance_it_holds() {
    let e = with_distinct_covariance();
    let s = e.estimate(42);
    let sd = |i: usize| e.cov[i][i].sqrt();
    assert_eq!(s.time_us, 42);
    assert_eq!(s.position_std_m, Vec3::new(sd(IP), sd(IP + 1), sd(IP + 2)));
    assert_eq!(s.velocity_std_m_s, Vec3::new(sd(IV), sd(IV + 1), sd(IV + 2)));
    assert_eq!(s.wind_std_m_s, [sd(IW), sd(IW + 1)]);
    // Yaw: the attitude error (body frame) projected on the world's vertical, u^T P u with u = R^T z.
    let r = e.q.to_mat3();
    let u = [r.m[2][0], r.m[2][1], r.m[2][2]];
    let mut var = 0.0f64;
    for a in 0..3 {
        for b in 0..3 {
            var += u[a] as f64 * e.cov[ITH + a][ITH + b] as f64 * u[b] as f64;
        }
    }
    assert!((s.yaw_std_rad as f64 - var.sqrt()).abs() < 1e-6, "{} {}", s.yaw_std_rad, var.sqrt());
    // Tilt: the larger of roll (its variance plus the bias across body y over g^2) and pitch (bias along x).
    let g2 = (GRAVITY * GRAVITY) as f64;
    let roll = e.cov[ITH][ITH] as f64 + e.cov[IBA + 1][IBA + 1] as f64 / g2;
    let pitch = e.cov[ITH + 1][ITH + 1] as f64 + e.cov[IBA][IBA] as f64 / g2;
    assert!((s.tilt_std_rad as f64 - roll.max(pitch).sqrt()).abs() < 1e-6);
    assert_eq!(s.tilt_std_rad, e.tilt_std_rad());
    // With roll's variance the larger one, the roll pair decides.
    let mut e2 = with_distinct_covariance();
    e2.cov[ITH][ITH] = 0.5;
    let roll = 0.5 + e2.cov[IBA + 1][IBA + 1] as f64 / g2;
    assert!((e2.tilt_std_rad() as f64 - roll.sqrt()).abs() < 1e-6);
}

#[test]
fn health_needs_every_state_and_variance_finite() {
    let e = with_distinct_covariance();
    assert!(e.is_healthy());
    let broken: [fn(&mut Estimator); 9] = [
        |e| e.p.y = f32::NAN,
        |e| e.v.z = f32::INFINITY,
        |e| e.q = Quat { w: f32::NAN, ..e.q },
        |e| e.bg.x = f32::NAN,
        |e| e.ba.y = f32::NAN,
        |e| e.w.x = f32::NAN,
        |e| e.cov[IV][IV] = f32::NAN,
        |e| e.cov[IW + 1][IW + 1] = -1e-6,
        |e| e.cov[IP][IP] = f32::INFINITY,
    ];
    for (k, f) in broken.iter().enumerate() {
        let mut b = with_distinct_covariance();
        f(&mut b);
        assert!(!b.is_healthy(), "case {k}");
    }
}

#[test]
fn the_history_keeps_one_snapshot_per_period_and_interpolates_between_them() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    assert!(e.state_at(0).is_none(), "an empty history");
    // Snapshots every 1 ms are offered: one per 2 ms is kept (a step within 1 % early counts as due).
    for k in 0..20u64 {
        e.p = Vec3::new(k as f32, 0.0, 0.0);
        e.v = Vec3::new(0.0, 2.0 * k as f32, 0.0);
        e.push_history(1000 + k * 1000);
    }
    assert_eq!(e.hist_len, 10);
    let times: std::vec::Vec<u64> = (0..e.hist_len).map(|k| e.history[k].time_us).collect();
    assert_eq!(times, (0..10).map(|k| 1000 + 2000 * k).collect::<std::vec::Vec<_>>());
    // 1 % early is due, 2 % early is not.
    let mut e2 = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    e2.push_history(10_000);
    e2.push_history(10_000 + 2000 - 20);
    assert_eq!(e2.hist_len, 2);
    e2.push_history(10_000 + 2000 - 20 + 2000 - 40);
    assert_eq!(e2.hist_len, 2);
    // Exact times read the snapshot; between two, position and velocity are interpolated linearly and the
    // attitude is the nearer one's.
    let s = e.state_at(5000).unwrap();
    assert_eq!((s.time_us, s.p.x, s.v.y), (5000, 4.0, 8.0));
    let s = e.state_at(5500).unwrap();
    assert_eq!(s.time_us, 5500);
    assert!((s.p.x - 4.5).abs() < 1e-6 && (s.v.y - 9.0).abs() < 1e-6, "{:?} {:?}", s.p, s.v);
    // Later than the newest, or earlier than the oldest: nothing.
    assert!(e.state_at(19_001).is_none());
    assert!(e.state_at(999).is_none());
    assert!(e.state_at(19_000).is_some() && e.state_at(1000).is_some());
    // Corrections made since a snapshot was stored apply to it when read.
    e.corr.p = Vec3::new(0.0, 0.0, 0.25);
    e.corr.v = Vec3::new(0.5, 0.0, 0.0);
    let s = e.state_at(5000).unwrap();
    assert_eq!((s.p.z, s.v.x), (0.25, 0.5));
}

#[test]
fn the_history_is_a_ring_of_its_newest_snapshots() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let n = HISTORY_LEN as u64 + 30;
    for k in 0..n {
        e.p = Vec3::new(k as f32, 0.0, 0.0);
        e.q = Quat::from_mat3(&Attitude::new(0.0, 0.0, k as f32 * 0.01).world_from_body());
        e.push_history(k * SNAPSHOT_EVERY_US);
    }
    assert_eq!(e.hist_len, HISTORY_LEN);
    let oldest = (n - HISTORY_LEN as u64) * SNAPSHOT_EVERY_US;
    assert!(e.state_at(oldest - 1).is_none());
    assert_eq!(e.state_at(oldest).unwrap().p.x, (n - HISTORY_LEN as u64) as f32);
    let newest = (n - 1) * SNAPSHOT_EVERY_US;
    assert_eq!(e.state_at(newest).unwrap().p.x, (n - 1) as f32);
    // Between two snapshots: the attitude of the nearer one.
    let t = 100 * SNAPSHOT_EVERY_US;
    let yaw = |t_us: u64| Attitude::from_world_from_body(&e.state_at(t_us).unwrap().q.to_mat3()).yaw;
    assert!((yaw(t + 900) - 1.00).abs() < 1e-5, "{}", yaw(t + 900));
    assert!((yaw(t + 1100) - 1.01).abs() < 1e-5, "{}", yaw(t + 1100));
    assert_eq!(e.attitude_at(t).map(|a| (a.yaw - 1.0).abs() < 1e-5), Some(true));
    let past = e.past_state(t + 1000).unwrap();
    assert_eq!(past.time_us, t + 1000);
    assert!((past.position_m.x - 100.5).abs() < 1e-5);
}

#[test]
fn a_snapshot_takes_only_the_corrections_made_after_it() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    // Corrections made before the snapshot are in its state already.
    e.corr = Corrections {
        p: Vec3::new(1.0, 0.0, 0.0),
        v: Vec3::new(0.0, 2.0, 0.0),
        th: Vec3::new(0.0, 0.0, 0.3),
    };
    e.push_history(1000);
    e.push_history(3000);
    e.corr.p.x += 0.25;
    e.corr.v.y += 0.5;
    e.corr.th.z += 0.1;
    let s = e.state_at(1000).unwrap();
    assert_eq!((s.p.x, s.v.y), (0.25, 0.5));
    let yaw = Attitude::from_world_from_body(&s.q.to_mat3()).yaw;
    let yaw0 = Attitude::from_world_from_body(&e.q.to_mat3()).yaw;
    assert!((wrap_pi(yaw - yaw0) - 0.1).abs() < 1e-5, "{}", wrap_pi(yaw - yaw0));
    // Exactly midway between two snapshots: the later one's attitude.
    e.q = Quat::from_mat3(&Attitude::new(0.0, 0.0, 0.5).world_from_body());
    e.corr = Corrections::default();
    e.push_history(5000);
    let mid = Attitude::from_world_from_body(&e.state_at(4000).unwrap().q.to_mat3()).yaw;
    assert!((mid - 0.5).abs() < 1e-5, "{mid}");
}

/// The covariance propagation written out densely: `P' = P + dt (F P + P F^T) + dt^2 F P F^T + Q dt`, then the
/// wind's walk and its cap (row and column scaled), in f64.
fn propagated_by_hand(e: &Estimator, dt: f64) -> [[f64; N]; N] {
    let r = e.q.to_mat3();
    let ra = r.mul_mat(&Mat3::skew(e.last_accel));
    let w = e.last_omega;
    let mut f = [[0.0f64; N]; N];
    for i in 0..3 {
        f[IP + i][IV + i] = 1.0;
        for k in 0..3 {
            f[IV + i][ITH + k] = -ra.m[i][k] as f64;
            f[IV + i][IBA + k] = -r.m[i][k] as f64;
        }
        f[ITH + i][IBG + i] = -1.0;
    }
    let (wx, wy, wz) = (w.x as f64, w.y as f64, w.z as f64);
    let minus_wx = [[0.0, wz, -wy], [-wz, 0.0, wx], [wy, -wx, 0.0]];
    for i in 0..3 {
        for k in 0..3 {
            f[ITH + i][ITH + k] = minus_wx[i][k];
        }
    }
    let p: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| e.cov[i][j] as f64));
    let mul = |a: &[[f64; N]; N], b: &[[f64; N]; N]| -> [[f64; N]; N] {
        core::array::from_fn(|i| core::array::from_fn(|j| (0..N).map(|k| a[i][k] * b[k][j]).sum()))
    };
    let ft: [[f64; N]; N] = core::array::from_fn(|i| core::array::from_fn(|j| f[j][i]));
    let fp = mul(&f, &p);
    let pft = mul(&p, &ft);
    let fpft = mul(&fp, &ft);
    let mut out: [[f64; N]; N] = core::array::from_fn(|i| {
        core::array::from_fn(|j| p[i][j] + dt * (fp[i][j] + pft[i][j]) + dt * dt * fpft[i][j])
    });
    let pr = &e.params;
    for (start, sigma) in
        [(IV, pr.accel_noise), (ITH, pr.gyro_noise), (IBG, pr.gyro_bias_walk), (IBA, pr.accel_bias_walk)]
    {
        for k in 0..3 {
            out[start + k][start + k] += (sigma as f64).powi(2) * dt;
        }
    }
    let cap = (pr.initial_wind_sigma_m_s as f64).powi(2);
    for k in 0..2 {
        let i = IW + k;
        out[i][i] += (pr.wind_walk_m_s as f64).powi(2) * dt;
        if out[i][i] > cap {
            let s = (cap / out[i][i]).sqrt();
            for j in 0..N {
                out[i][j] *= s;
                out[j][i] *= s;
            }
        }
    }
    out
}

#[test]
fn the_covariance_propagates_as_the_error_dynamics_state() {
    for case in 0..3 {
        let mut e = with_distinct_covariance();
        e.last_accel = Vec3::new(0.4, -0.7, 9.6);
        e.last_omega = Vec3::new(0.3, -0.5, 0.8);
        if case == 1 {
            // The wind's variance beyond its cap after the walk: scaled back to it.
            e.params.initial_wind_sigma_m_s = 1.5;
            let cap = e.params.initial_wind_sigma_m_s * e.params.initial_wind_sigma_m_s;
            e.cov[IW][IW] = cap * 0.999;
            e.cov[IW + 1][IW + 1] = cap * 1.5;
        }
        if case == 2 {
            e.q = Quat::from_mat3(&Attitude::new(-0.4, 0.1, -2.0).world_from_body());
        }
        let dt = 0.02;
        e.pending_dt = dt;
        let want = propagated_by_hand(&e, dt as f64);
        let len = e.hist_len;
        e.propagate_covariance(20_000);
        for i in 0..N {
            for j in 0..N {
                let tol = 1e-6 * want[i][j].abs().max(1e-3);
                assert!(
                    (e.cov[i][j] as f64 - want[i][j]).abs() < tol,
                    "case {case}: P[{i}][{j}] {} want {}",
                    e.cov[i][j],
                    want[i][j]
                );
            }
        }
        assert_eq!(e.hist_len, len + 1, "the state is stored");
        // The step is spent: another call adds nothing.
        let before = e.cov;
        e.propagate_covariance(22_000);
        assert_eq!(e.cov, before);
    }
}

#[test]
fn symmetrising_takes_the_mean_and_floors_the_variances() {
    let mut e = with_distinct_covariance();
    e.cov[IP][IV] = 0.3;
    e.cov[IV][IP] = 0.1;
    e.cov[IBA][IBA] = 0.0;
    e.cov[IW][IW] = -1.0;
    e.cov[IBG][IBG] = f32::NAN;
    let keep = e.cov[ITH][ITH];
    e.symmetrise();
    assert!((e.cov[IP][IV] - 0.2).abs() < 1e-7 && e.cov[IP][IV] == e.cov[IV][IP]);
    assert_eq!((e.cov[IBA][IBA], e.cov[IW][IW], e.cov[IBG][IBG]), (1e-12, 1e-12, 1e-12));
    assert_eq!(e.cov[ITH][ITH], keep);
}

/// The gyro x value the filter integrates for the middle of three samples (x, y, z at 1 ms), and whether it
/// counted a spike.
fn cleaned_middle(x: f32, y: f32, z: f32) -> (f32, bool) {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for (k, g) in [x, y, z].into_iter().enumerate() {
        let s = ImuSample {
            time_us: 1000 * (k as u64 + 1),
            gyro_rad_s: [g, 0.0, 0.0],
            accel_m_s2: [0.0, 0.0, GRAVITY],
        };
        assert!(e.predict(&s));
    }
    (e.last_omega.x, e.counters().imu_spikes == 1)
}

#[test]
fn a_spike_is_a_middle_sample_that_stands_out_from_two_agreeing_neighbours() {
    let lim = SPIKE_GYRO_RAD_S;
    // Above both, below both: replaced by the neighbours' mean, counted.
    assert_eq!(cleaned_middle(0.0, 1.0, 0.0), (0.0, true));
    assert_eq!(cleaned_middle(0.0, -1.0, 0.0), (0.0, true));
    assert_eq!(cleaned_middle(0.0, 1.0, 0.4), (0.2, true));
    // Neighbours that disagree by more than the threshold: a real change, passed.
    assert_eq!(cleaned_middle(0.0, 1.0, 0.6), (1.0, false));
    assert_eq!(cleaned_middle(0.6, 1.2, 0.0), (1.2, false));
    // At the thresholds: neighbours exactly `lim` apart agree; a sample exactly `lim` off is no spike.
    assert_eq!(cleaned_middle(0.0, 1.25, lim), (0.25, true));
    assert_eq!(cleaned_middle(0.0, lim, 0.0), (lim, false));
    assert_eq!(cleaned_middle(0.0, 1.0, 1.0 - lim), (1.0, false));
    // Measured from each neighbour: standing out from one only is no spike.
    assert_eq!(cleaned_middle(0.3, 0.75, 0.0), (0.75, false));
    assert_eq!(cleaned_middle(0.0, 0.75, 0.3), (0.75, false));
    assert_eq!(cleaned_middle(-0.3, -0.75, 0.0), (-0.75, false));
    // The accelerometer's own threshold, on its own axis.
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    for (k, az) in [GRAVITY, GRAVITY + 2.0 * SPIKE_ACCEL_M_S2, GRAVITY].into_iter().enumerate() {
        e.predict(&ImuSample {
            time_us: 1000 * (k as u64 + 1),
            gyro_rad_s: [0.0; 3],
            accel_m_s2: [0.0, 0.0, az],
        });
    }
    assert_eq!(e.counters().imu_spikes, 1);
    assert_eq!(e.last_accel.z, GRAVITY);
}

#[test]
fn samples_that_are_not_finite_or_not_newer_are_refused_and_a_held_gyro_is_counted() {
    let mut e = Estimator::new(EstimatorParams::default(), Vec3::ZERO);
    let at = |t: u64, g: [f32; 3], a: [f32; 3]| ImuSample { time_us: t, gyro_rad_s: g, accel_m_s2: a };
    let level = [0.0, 0.0, GRAVITY];
    assert!(e.predict(&at(1000, [0.0; 3], level)));
    assert!(!e.predict(&at(2000, [f32::NAN, 0.0, 0.0], level)), "a gyro NaN");
    assert!(!e.predict(&at(2000, [0.0; 3], [0.0, f32::INFINITY, 9.8])), "an accelerometer infinity");
    assert!(!e.predict(&at(1000, [0.0; 3], level)), "not newer");
    assert!(e.predict(&at(2000, [0.0; 3], level)));
    // A gyro axis held at exactly the same large value on consecutive samples (a saturated sensor) counts;
    // the same small value does not (a still gyro repeats its quantum), nor does a large one that changes.
    let big = CLIP_MIN_RATE_RAD_S * 2.0;
    assert!(e.predict(&at(3000, [0.0, big, 0.0], level)));
    assert!(e.predict(&at(4000, [0.0, big, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 1);
    assert!(e.predict(&at(5000, [0.0, big, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 2);
    assert!(e.predict(&at(6000, [0.0, big * 0.99, 0.0], level)));
    assert!(e.predict(&at(7000, [0.01, 0.0, 0.0], level)));
    assert!(e.predict(&at(8000, [0.01, 0.0, 0.0], level)));
    assert_eq!(e.counters().gyro_clipped, 2);
}

#[test]
fn the_accelerometer_bias_estimate_stays_within_its_limit() {
    // A correction that would take the bias beyond a MEMS part's offset is cut at the limit, per axis and in
    // both directions; one within it is applied in full.
    let mut e = with_distinct_covariance();
    let lim = e.params.accel_bias_limit_m_s2;
    let mut dx = [0.0; N];
    (dx[IBA], dx[IBA + 1], dx[IBA + 2]) = (5.0, -5.0, 0.25 * lim);
    e.inject(&dx);
    assert_eq!(e.ba, Vec3::new(lim, -lim, 0.25 * lim));
    e.inject(&dx);
    assert_eq!(e.ba.z, 0.5 * lim);
}
