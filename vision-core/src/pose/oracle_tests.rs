//! Each step of the solver against its equations written out independently, in f64 where it matters: the
//! residuals against the point-to-line distances of the raw edge points, the Jacobian against finite
//! differences, the normal equations, the parameter step, the refinement's optimality, the covariance against
//! `J_c (J^T J)^-1 J_c^T` with a finite-difference `J_c`, the pooled noise, and what `solve_pose` reports.
use super::*;

const CAM: CameraModel = CameraModel::PAPER_FORWARD;
const TARGET: LineTarget = LineTarget::PAPER;

/// Which ends of the line the synthetic observation has.
#[derive(Clone, Copy, PartialEq)]
enum Ends {
    Both,
    StartOnly,
    FinishOnly,
    None,
}

/// An observation built from explicit edge points (normalised coordinates), which the tests keep.
struct Synthetic {
    obs: LineObservation,
    points: [Vec<[f64; 2]>; 4],
}

/// A small deterministic generator of noise in [-1, 1].
pub(super) struct Lcg(pub(super) u64);
impl Lcg {
    pub(super) fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }
}

fn camera_from_world(att: Attitude, mount: &CameraMount) -> Mat3 {
    att.world_from_body().mul_mat(&mount.body_from_camera).transpose()
}

/// Points along each edge seen by a camera at `c` with `R_CW`, moved across the edge by up to `noise_px`.
fn synthetic(r_cw: &Mat3, c: Vec3, noise_px: f32, ends: Ends, seed: u64) -> Synthetic {
    let mut rng = Lcg(seed);
    let f = CAM.focal_px();
    let mut stats = [None; 4];
    let mut points: [Vec<[f64; 2]>; 4] = Default::default();
    for e in Edge::ALL {
        let keep = match e {
            Edge::Top | Edge::Bottom => true,
            Edge::StartEnd => matches!(ends, Ends::Both | Ends::StartOnly),
            Edge::FinishEnd => matches!(ends, Ends::Both | Ends::FinishOnly),
        };
        if !keep {
            continue;
        }
        let (p1, p2) = TARGET.edge_points(e);
        let project = |p: Vec3| {
            let x = r_cw.mul_vec(p - c);
            Vec2::new(x.x / x.z, x.y / x.z)
        };
        let normal = (project(p2) - project(p1)).normalized().unwrap().perp();
        let n = if matches!(e, Edge::Top | Edge::Bottom) { 60 } else { 12 };
        let mut pts = Vec::new();
        for i in 0..n {
            let u = project(p1 + (p2 - p1) * ((i as f32 + 0.5) / n as f32));
            pts.push(u + normal * (noise_px * rng.next() / f));
        }
        stats[e as usize] = EdgeStats::from_points(pts.iter().copied());
        points[e as usize] = pts.iter().map(|p| [p.x as f64, p.y as f64]).collect();
    }
    let obs = LineObservation {
        top: stats[0].unwrap(),
        bottom: stats[1].unwrap(),
        start_end: stats[2],
        finish_end: stats[3],
    };
    Synthetic { obs, points }
}

/// The pose seen in most tests: 1.3 m from the wall, rolled, pitched and yawed, the whole line in view.
fn scene() -> (Vec3, Attitude) {
    (Vec3::new(1.0, 1.3, 0.8), Attitude::new(geometry::deg(3.0), geometry::deg(-4.0), geometry::deg(6.0)))
}

fn problem(s: &Synthetic, prior: Option<(Vec3, f32)>, fix_x: bool) -> Problem {
    let sigma = pooled_sigma(&s.obs, 0.1 / CAM.focal_px());
    Problem::new(&s.obs, &TARGET, sigma, prior, &CameraMount::FORWARD_AT_CENTRE, fix_x)
}

/// The problem's parameters (`R_CW`, target centre in camera coordinates) of a camera pose.
fn params_of(r_cw: &Mat3, c: Vec3) -> (Mat3, Vec3) {
    (*r_cw, r_cw.mul_vec(TARGET.center() - c))
}

/// Squared distance (f64) of image point `q` from the line through the projections of the model edge.
fn dist_sq(r_cw: &Mat3, t: Vec3, e: Edge, q: [f64; 2]) -> f64 {
    let (p1, p2) = TARGET.edge_points(e);
    let proj = |p: Vec3| {
        let x = r_cw.mul_vec(p - TARGET.center()) + t;
        [x.x as f64 / x.z as f64, x.y as f64 / x.z as f64]
    };
    let (a, b) = (proj(p1), proj(p2));
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let cross = dx * (q[1] - a[1]) - dy * (q[0] - a[0]);
    cross * cross / (dx * dx + dy * dy)
}

/// A pose near `(r, t)`: rotated by `rot` (rad, camera axes) and moved by `dt` (m).
fn perturbed(r: &Mat3, t: Vec3, rot: Vec3, dt: Vec3) -> (Mat3, Vec3) {
    (Mat3::exp_so3(rot).mul_mat(r), t + dt)
}

#[test]
fn the_edge_residuals_are_the_point_to_line_distances_of_every_edge_point() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    for (ends, seed) in [(Ends::Both, 1), (Ends::StartOnly, 2), (Ends::FinishOnly, 3), (Ends::None, 4)] {
        let s = synthetic(&r_true, pos, 0.6, ends, seed);
        let p = problem(&s, None, ends == Ends::None);
        let (r0, t0) = params_of(&r_true, pos);
        let (r, t) = perturbed(&r0, t0, Vec3::new(0.01, -0.02, 0.015), Vec3::new(0.02, -0.01, 0.03));
        let mut res = [0.0f32; MAX_RES];
        let n = p.eval(&r, t, &mut res, None);
        let edges: Vec<Edge> = Edge::ALL.into_iter().filter(|e| !s.points[*e as usize].is_empty()).collect();
        assert_eq!(n, 3 * edges.len());
        let sigma = 1.0 / p.inv_sigma as f64;
        for (k, e) in edges.iter().enumerate() {
            let expected: f64 = s.points[*e as usize].iter().map(|q| dist_sq(&r, t, *e, *q)).sum();
            let got: f64 = res[3 * k..3 * k + 3].iter().map(|v| (*v as f64 * sigma).powi(2)).sum();
            assert!((got - expected).abs() < 1e-3 * expected, "{ends:?} {e:?}: {got} vs {expected}");
        }
        // The cost is their sum in units of sigma, and the image MSE the mean over the points.
        let total: f64 = edges
            .iter()
            .map(|e| s.points[*e as usize].iter().map(|q| dist_sq(&r, t, *e, *q)).sum::<f64>())
            .sum();
        let count: usize = edges.iter().map(|e| s.points[*e as usize].len()).sum();
        let cost = p.cost(&r, t) as f64;
        assert!((cost * sigma * sigma - total).abs() < 1e-3 * total, "{cost} vs {total}");
        let mse = p.image_mse(&r, t) as f64;
        assert!((mse - total / count as f64).abs() < 1e-3 * mse, "{mse} vs {}", total / count as f64);
        // A gravity prior adds its own two residuals and changes neither the edges' nor the image MSE.
        let up = Vec3::new(0.05, -0.03, 1.0).normalized().unwrap();
        let with_prior = problem(&s, Some((up, 0.01)), ends == Ends::None);
        let mut res2 = [0.0f32; MAX_RES];
        assert_eq!(with_prior.eval(&r, t, &mut res2, None), n + 2);
        assert_eq!(res2[..n], res[..n]);
        assert_eq!(with_prior.image_mse(&r, t), p.image_mse(&r, t));
        let up_now = CameraMount::FORWARD_AT_CENTRE.body_from_camera.mul_vec(r.mul_vec(Vec3::Z));
        for (i, (now, meas)) in [(up_now.x, up.x), (up_now.y, up.y)].into_iter().enumerate() {
            let expected = (now - meas) / 0.01;
            assert!((res2[n + i] - expected).abs() < 1e-4 * expected.abs().max(1.0), "{res2:?}");
        }
    }
}

impl Ends {
    fn all() -> [(Ends, bool); 4] {
        [(Ends::Both, false), (Ends::StartOnly, false), (Ends::FinishOnly, false), (Ends::None, true)]
    }
}

impl core::fmt::Debug for Ends {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let name = match self {
            Ends::Both => "both ends",
            Ends::StartOnly => "start end",
            Ends::FinishOnly => "finish end",
            Ends::None => "no end",
        };
        f.write_str(name)
    }
}

#[test]
fn the_jacobian_is_the_derivative_of_the_residuals() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let up = Vec3::new(0.04, -0.06, 1.0).normalized().unwrap();
    for (ends, fix_x) in Ends::all() {
        for prior in [None, Some((up, 0.02))] {
            let s = synthetic(&r_true, pos, 0.5, ends, 9);
            let p = problem(&s, prior, fix_x);
            let (r0, t0) = params_of(&r_true, pos);
            let (r, t) = perturbed(&r0, t0, Vec3::new(-0.01, 0.02, 0.01), Vec3::new(0.01, 0.02, -0.02));
            let mut res = [0.0f32; MAX_RES];
            let mut jac = [[0.0f32; NP]; MAX_RES];
            let n = p.eval(&r, t, &mut res, Some(&mut jac));
            let np = p.n_params();
            for k in 0..np {
                let h = 1e-3;
                let mut step = [0.0f32; NP];
                step[k] = h;
                let (rp, tp) = p.apply(&r, t, &step);
                step[k] = -h;
                let (rm, tm) = p.apply(&r, t, &step);
                let (mut a, mut b) = ([0.0f32; MAX_RES], [0.0f32; MAX_RES]);
                p.eval(&rp, tp, &mut a, None);
                p.eval(&rm, tm, &mut b, None);
                let col_norm = (0..n).map(|i| (jac[i][k] as f64).powi(2)).sum::<f64>().sqrt();
                for i in 0..n {
                    let fd = (a[i] as f64 - b[i] as f64) / (2.0 * h as f64);
                    assert!(
                        (fd - jac[i][k] as f64).abs() < 2e-3 * col_norm + 0.05,
                        "{ends:?} prior {}: d res[{i}] / d p[{k}] = {} by finite differences, {} analytic",
                        prior.is_some(),
                        fd,
                        jac[i][k]
                    );
                }
                assert!(col_norm > 1.0, "{ends:?}: parameter {k} moves no residual");
            }
            // Columns beyond the parameters are zero.
            assert!((0..n).all(|i| jac[i][np..].iter().all(|v| *v == 0.0)));
        }
    }
}

#[test]
fn the_normal_equations_are_j_transpose_j_and_j_transpose_r() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r_true, pos, 0.5, Ends::StartOnly, 5);
    let p = problem(&s, Some((Vec3::Z, 0.01)), false);
    let (r0, t0) = params_of(&r_true, pos);
    let (r, t) = perturbed(&r0, t0, Vec3::new(0.01, 0.0, -0.01), Vec3::new(0.0, 0.02, 0.01));
    let mut res = [0.0f32; MAX_RES];
    let mut jac = [[0.0f32; NP]; MAX_RES];
    let n = p.eval(&r, t, &mut res, Some(&mut jac));
    let (h, g) = p.normal_equations(&r, t);
    for a in 0..NP {
        let ga: f64 = (0..n).map(|i| jac[i][a] as f64 * res[i] as f64).sum();
        assert!((g[a] as f64 - ga).abs() < 1e-4 * ga.abs().max(1.0), "g[{a}] = {} vs {ga}", g[a]);
        for b in 0..NP {
            let hab: f64 = (0..n).map(|i| jac[i][a] as f64 * jac[i][b] as f64).sum();
            assert!((h[a][b] as f64 - hab).abs() < 1e-4 * hab.abs().max(1.0), "H[{a}][{b}]");
        }
    }
}

#[test]
fn a_step_rotates_about_the_target_centre_and_moves_only_across_the_line_when_x_is_fixed() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r_true, pos, 0.5, Ends::None, 6);
    let (r, t) = params_of(&r_true, pos);
    let step = [0.01f32, -0.02, 0.03, 0.1, -0.2, 0.3];
    // All six parameters: t moves by the last three, R by exp(-d).
    let free = problem(&s, None, false);
    let (r1, t1) = free.apply(&r, t, &step);
    assert!((t1 - (t + Vec3::new(0.1, -0.2, 0.3))).norm() < 1e-6, "{t1:?}");
    assert!(r1.angle_to(&Mat3::exp_so3(Vec3::new(-0.01, 0.02, -0.03)).mul_mat(&r)) < 1e-6);
    // x fixed: five parameters, the move is perpendicular to the line's direction and as long as the step.
    let fixed = problem(&s, None, true);
    assert_eq!((free.n_params(), fixed.n_params()), (6, 5));
    let (r2, t2) = fixed.apply(&r, t, &step);
    let d = t2 - t;
    let along = r.mul_vec(Vec3::X);
    assert!(d.dot(along).abs() < 1e-6, "moved along the line: {d:?}");
    assert!((d.norm() - (0.1f32 * 0.1 + 0.2 * 0.2).sqrt()).abs() < 1e-6, "{d:?}");
    assert!(r2.angle_to(&r1) < 1e-6);
    // The two directions are orthonormal and the first lies in the camera's horizontal plane.
    let [b1, b2, b3] = t_basis(&r, true);
    assert!((b1.norm() - 1.0).abs() < 1e-6 && (b2.norm() - 1.0).abs() < 1e-6 && b3 == Vec3::ZERO);
    assert!(b1.dot(b2).abs() < 1e-6 && b1.z.abs() < 1e-6 && b1.dot(along).abs() < 1e-6);
}

#[test]
fn the_refinement_ends_at_a_minimum_of_the_cost() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    for (ends, fix_x) in Ends::all() {
        // Exact points and the true gravity: the true pose, from 2 degrees and 4 cm away.
        let up = CameraMount::FORWARD_AT_CENTRE.body_from_camera.mul_vec(r_true.mul_vec(Vec3::Z));
        let exact = synthetic(&r_true, pos, 0.0, ends, 0);
        let p = problem(&exact, Some((up, 0.01)), fix_x);
        let (r0, t0) = params_of(&r_true, pos);
        let start = perturbed(&r0, t0, Vec3::new(0.02, -0.03, 0.02), Vec3::new(0.0, 0.03, -0.02));
        let (r, t, it) = p.refine(start.0, start.1, 30);
        let c = -r.tmul_vec(t) + TARGET.center();
        assert!(
            r.angle_to(&r_true) < 2e-4 && (c.y - pos.y).abs() < 1e-4 && (c.z - pos.z).abs() < 1e-4,
            "{ends:?}: {c:?} after {it}"
        );
        if !fix_x {
            assert!((c.x - pos.x).abs() < 1e-3, "{ends:?}: {c:?}");
        }
        assert!((r.det() - 1.0).abs() < 1e-5 && (2..30).contains(&it), "{ends:?}: {it} iterations");
        // One iteration at most when told so, and it improves.
        let (r1, t1, it1) = p.refine(start.0, start.1, 1);
        assert_eq!(it1, 1);
        assert!(p.cost(&r1, t1) < 0.5 * p.cost(&start.0, start.1));
        // Noisy points, with a prior: no small move in any parameter lowers the cost at the result.
        let noisy = synthetic(&r_true, pos, 0.8, ends, 11);
        let p = problem(&noisy, Some((up, 0.01)), fix_x);
        let (r, t, _) = p.refine(start.0, start.1, 30);
        let best = p.cost(&r, t);
        for k in 0..p.n_params() {
            for h in [2e-4f32, -2e-4] {
                let mut step = [0.0f32; NP];
                step[k] = h;
                let (rk, tk) = p.apply(&r, t, &step);
                let ck = p.cost(&rk, tk);
                assert!(ck >= best * (1.0 - 1e-5), "{ends:?}: parameter {k} by {h} lowers {best} to {ck}");
            }
        }
    }
}

/// Inverse of a symmetric positive definite matrix by Gauss-Jordan elimination (f64).
fn inverse(mut a: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let n = a.len();
    let mut inv: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| (i == j) as u8 as f64).collect()).collect();
    for c in 0..n {
        let piv = a[c][c];
        for j in 0..n {
            a[c][j] /= piv;
            inv[c][j] /= piv;
        }
        for r in 0..n {
            if r != c {
                let f = a[r][c];
                for j in 0..n {
                    a[r][j] -= f * a[c][j];
                    inv[r][j] -= f * inv[c][j];
                }
            }
        }
    }
    inv
}

/// Covariance of the camera centre and the yaw variance written out: `J_c H^-1 J_c^T` with `H = J^T J` in
/// f64 and `J_c` by central differences of the camera centre through `apply`.
fn covariance_oracle(p: &Problem, r: &Mat3, t: Vec3) -> ([[f64; 3]; 3], f64) {
    let np = p.n_params();
    let mut res = [0.0f32; MAX_RES];
    let mut jac = [[0.0f32; NP]; MAX_RES];
    let n = p.eval(r, t, &mut res, Some(&mut jac));
    let h: Vec<Vec<f64>> = (0..np)
        .map(|a| (0..np).map(|b| (0..n).map(|i| jac[i][a] as f64 * jac[i][b] as f64).sum()).collect())
        .collect();
    let hinv = inverse(h);
    let centre = |r: &Mat3, t: Vec3| -r.tmul_vec(t);
    let mut jc = vec![[0.0f64; 3]; np];
    for (k, col) in jc.iter_mut().enumerate() {
        let mut step = [0.0f32; NP];
        step[k] = 1e-3;
        let (rp, tp) = p.apply(r, t, &step);
        step[k] = -1e-3;
        let (rm, tm) = p.apply(r, t, &step);
        let d = centre(&rp, tp) - centre(&rm, tm);
        *col = [d.x as f64 / 2e-3, d.y as f64 / 2e-3, d.z as f64 / 2e-3];
    }
    let mut cov = [[0.0f64; 3]; 3];
    for (i, row) in cov.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..np).map(|a| (0..np).map(|b| jc[a][i] * hinv[a][b] * jc[b][j]).sum::<f64>()).sum();
        }
    }
    // Yaw: a rotation by d (camera axes) turns the world by R^T d, whose vertical part is d . (R z).
    let a = r.mul_vec(Vec3::Z);
    let a = [a.x as f64, a.y as f64, a.z as f64];
    let yaw: f64 = (0..3).map(|i| (0..3).map(|j| a[i] * hinv[i][j] * a[j]).sum::<f64>()).sum();
    (cov, yaw)
}

#[test]
fn the_covariance_is_j_c_times_the_inverse_normal_matrix_times_j_c_transposed() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    for (ends, fix_x) in Ends::all() {
        let s = synthetic(&r_true, pos, 0.7, ends, 21);
        let up = CameraMount::FORWARD_AT_CENTRE.body_from_camera.mul_vec(r_true.mul_vec(Vec3::Z));
        let p = problem(&s, Some((up, 0.01)), fix_x);
        let (r0, t0) = params_of(&r_true, pos);
        let (r, t, _) = p.refine(r0, t0, 30);
        let (cov, yaw) = p.center_covariance(&r, t).expect("regular");
        let (expected, yaw_expected) = covariance_oracle(&p, &r, t);
        for i in 0..3 {
            for j in 0..3 {
                let scale = (expected[i][i] * expected[j][j]).sqrt();
                assert!(
                    (cov[i][j] as f64 - expected[i][j]).abs() < 2e-3 * scale,
                    "{ends:?}: cov[{i}][{j}] = {} vs {}",
                    cov[i][j],
                    expected[i][j]
                );
            }
        }
        assert!((yaw as f64 - yaw_expected).abs() < 2e-3 * yaw_expected, "{ends:?}: {yaw} vs {yaw_expected}");
    }
}

#[test]
fn the_noise_is_pooled_over_the_edges_with_a_floor() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r_true, pos, 0.9, Ends::Both, 31);
    let (ss, dof) = edges_of(&s.obs).fold((0.0f64, 0.0f64), |(ss, dof), (_, e)| {
        (ss + e.count as f64 * (e.rms as f64).powi(2), dof + (e.count as f64 - 2.0).max(1.0))
    });
    let expected = (ss / dof).sqrt();
    let got = pooled_sigma(&s.obs, 0.0) as f64;
    assert!((got - expected).abs() < 1e-5 * expected, "{got} vs {expected}");
    assert_eq!(pooled_sigma(&s.obs, 1.0), 1.0);
    // Two-point edges still count one degree of freedom each.
    let mut two = s.obs;
    two.top.count = 2;
    two.bottom.count = 2;
    two.start_end = None;
    two.finish_end = None;
    let expected =
        ((2.0 * (two.top.rms as f64).powi(2) + 2.0 * (two.bottom.rms as f64).powi(2)) / 2.0).sqrt();
    assert!((pooled_sigma(&two, 0.0) as f64 - expected).abs() < 1e-5 * expected);
}

#[test]
fn the_imu_rotation_is_exact_for_any_yaw_and_a_tilted_camera() {
    // The camera pitched down by 15 degrees and rolled by 2 on its mount.
    let tilt = Mat3::rot_y(geometry::deg(15.0)).mul_mat(&Mat3::rot_x(geometry::deg(2.0)));
    let mount =
        CameraMount { body_from_camera: tilt.mul_mat(&BODY_FROM_FORWARD_CAMERA), offset_body_m: Vec3::ZERO };
    let mut checked = 0;
    for (ends, _) in Ends::all() {
        for (roll, pitch, yaw) in
            [(0.0f32, 0.0f32, 0.0f32), (4.0, -6.0, 25.0), (-5.0, 3.0, -30.0), (2.0, 8.0, 12.0)]
        {
            let att = Attitude::new(geometry::deg(roll), geometry::deg(pitch), geometry::deg(yaw));
            let r_cw = camera_from_world(att, &mount);
            // Camera 1.4 m in front of the line, at the line's height plus the tilt's view.
            let pos = Vec3::new(1.15, 1.4, 1.3);
            let s = synthetic(&r_cw, pos, 0.0, ends, 0);
            let r = rotation_from_imu(&s.obs, &mount, att.roll, att.pitch).unwrap();
            assert!(r.angle_to(&r_cw) < 1e-4, "{ends:?} {roll} {pitch} {yaw}: {} rad off", r.angle_to(&r_cw));
            checked += 1;
        }
    }
    assert_eq!(checked, 16);
}

#[test]
fn solve_pose_reports_the_vehicle_behind_an_offset_camera_and_its_covariance() {
    let offset = Vec3::new(0.08, -0.02, 0.03);
    let mount = CameraMount { body_from_camera: BODY_FROM_FORWARD_CAMERA, offset_body_m: offset };
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &mount);
    let s = synthetic(&r_true, pos, 0.6, Ends::Both, 41);
    let params = PoseParams { max_x_std_m: 1.0, ..PoseParams::default() };
    let imu = AttitudeSource::Imu { roll: att.roll, pitch: att.pitch, sigma_rad: 0.01 };
    let sol = solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &params).unwrap();
    let r_wb = att.world_from_body();
    let expected_vehicle = sol.camera_position_m - r_wb.mul_vec(offset);
    assert!((sol.vehicle_position_m - expected_vehicle).norm() < 1e-3, "{:?}", sol.vehicle_position_m);
    assert!((sol.camera_position_m - pos).norm() < 0.02, "{:?}", sol.camera_position_m);
    assert!(
        (sol.attitude.yaw - att.yaw).abs() < geometry::deg(0.5) && sol.x_observed && sol.real_corners == 4
    );
    // The reported spread is the covariance of the pose the solver returns, with the pooled sigma.
    let sigma = pooled_sigma(&s.obs, params.min_sigma_px / CAM.focal_px());
    let up = Attitude::new(att.roll, att.pitch, 0.0).world_from_body().tmul_vec(Vec3::Z);
    let p = Problem::new(&s.obs, &TARGET, sigma, Some((up, 0.01)), &mount, false)
        .with_edge_bias(params.edge_bias_px / CAM.focal_px());
    let r = sol.camera_from_world;
    let t = r.mul_vec(TARGET.center() - sol.camera_position_m);
    let (cov, yaw) = covariance_oracle(&p, &r, t);
    let std = sol.position_std_m;
    for (i, v) in [std.x, std.y, std.z].into_iter().enumerate() {
        assert!(
            (v as f64 - cov[i][i].sqrt()).abs() < 2e-3 * cov[i][i].sqrt(),
            "std[{i}] = {v} vs {}",
            cov[i][i].sqrt()
        );
    }
    assert!((sol.yaw_std_rad as f64 - yaw.sqrt()).abs() < 2e-3 * yaw.sqrt());
    // The RMS is the points' distance from the model edges, in pixels.
    let (total, count) = Edge::ALL.iter().fold((0.0f64, 0usize), |(tot, n), e| {
        let pts = &s.points[*e as usize];
        (tot + pts.iter().map(|q| dist_sq(&r, t, *e, *q)).sum::<f64>(), n + pts.len())
    });
    let rms_px = (total / count as f64).sqrt() * CAM.focal_px() as f64;
    assert!(
        (sol.reprojection_rms_px as f64 - rms_px).abs() < 1e-3 * rms_px,
        "{} vs {rms_px}",
        sol.reprojection_rms_px
    );
    // x is reported when its std is below the limit, not above.
    let just_below = PoseParams { max_x_std_m: std.x * 0.99, ..params };
    let just_above = PoseParams { max_x_std_m: std.x * 1.01, ..params };
    assert!(!solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &just_below).unwrap().x_observed);
    assert!(solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &just_above).unwrap().x_observed);
    // y and z beyond max_std_m: under-determined.
    let tight = PoseParams { max_std_m: std.y.min(std.z) * 0.99, ..params };
    assert_eq!(
        solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &tight).unwrap_err(),
        PoseError::Underdetermined
    );
    // Either one beyond is enough.
    assert!((std.y - std.z).abs() > 0.05 * std.y.max(std.z), "{std:?}");
    let between = PoseParams { max_std_m: 0.5 * (std.y + std.z), ..params };
    assert_eq!(
        solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &between).unwrap_err(),
        PoseError::Underdetermined
    );
    let loose = PoseParams { max_std_m: std.y.max(std.z) * 1.01, ..params };
    assert!(solve_pose(&s.obs, &CAM, &TARGET, &mount, imu, &loose).is_ok());
}

#[test]
fn solve_pose_refuses_what_it_cannot_trust_and_names_why() {
    let mount = CameraMount::FORWARD_AT_CENTRE;
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &mount);
    let s = synthetic(&r_true, pos, 0.6, Ends::Both, 51);
    let params = PoseParams::default();
    let imu = AttitudeSource::Imu { roll: att.roll, pitch: att.pitch, sigma_rad: 0.01 };
    let solve = |obs: &LineObservation, source, params: &PoseParams| {
        solve_pose(obs, &CAM, &TARGET, &mount, source, params)
    };
    let ok = solve(&s.obs, imu, &params).unwrap();
    let dist = (TARGET.center() - ok.camera_position_m).norm();
    // The distance range, both bounds.
    for range in [[0.2, dist * 0.98], [dist * 1.02, 20.0]] {
        let p = PoseParams { distance_range_m: range, ..params };
        assert_eq!(solve(&s.obs, imu, &p).unwrap_err(), PoseError::Implausible, "{range:?}");
    }
    assert!(
        solve(&s.obs, imu, &PoseParams { distance_range_m: [dist * 0.98, dist * 1.02], ..params }).is_ok()
    );
    // The reprojection limit, either side of the RMS.
    let rms = ok.reprojection_rms_px;
    let p = PoseParams { max_rms_px: rms * 0.99, ..params };
    assert_eq!(solve(&s.obs, imu, &p).unwrap_err(), PoseError::ReprojectionTooLarge);
    assert!(solve(&s.obs, imu, &PoseParams { max_rms_px: rms * 1.01, ..params }).is_ok());
    // Bad inputs.
    for source in [
        AttitudeSource::Imu { roll: f32::NAN, pitch: 0.0, sigma_rad: 0.01 },
        AttitudeSource::Imu { roll: 0.0, pitch: f32::INFINITY, sigma_rad: 0.01 },
        AttitudeSource::Imu { roll: 0.0, pitch: 0.0, sigma_rad: 0.0 },
        AttitudeSource::Imu { roll: 0.0, pitch: 0.0, sigma_rad: f32::NAN },
    ] {
        assert_eq!(solve(&s.obs, source, &params).unwrap_err(), PoseError::InvalidInput, "{source:?}");
    }
    let mut bad = s.obs;
    bad.top.count = 1;
    assert_eq!(solve(&bad, imu, &params).unwrap_err(), PoseError::InvalidInput);
    for field in 0..6 {
        let mut bad = s.obs;
        let e = bad.finish_end.as_mut().unwrap();
        match field {
            0 => e.centroid.x = f32::NAN,
            1 => e.centroid.y = f32::INFINITY,
            2 => e.normal.x = f32::NAN,
            3 => e.normal.y = f32::NAN,
            4 => e.spread = f32::NAN,
            _ => e.rms = f32::INFINITY,
        }
        assert_eq!(solve(&bad, imu, &params).unwrap_err(), PoseError::InvalidInput, "field {field}");
    }
    let invalid_target = LineTarget { x_end_m: TARGET.x_start_m, ..TARGET };
    assert_eq!(
        solve_pose(&s.obs, &CAM, &invalid_target, &mount, imu, &params).unwrap_err(),
        PoseError::InvalidInput
    );
    // Without refinement the closed form is returned as it is, with x reported.
    let closed = solve(&s.obs, imu, &PoseParams { refine: false, ..params }).unwrap();
    assert_eq!(closed.iterations, 0);
    assert!(closed.x_observed && ok.iterations > 0);
}

#[test]
fn every_error_has_its_own_code_and_explanation() {
    use PoseError::*;
    let all = [
        InvalidInput,
        DegenerateEdges,
        NeedBothEnds,
        Implausible,
        ReprojectionTooLarge,
        Singular,
        Underdetermined,
    ];
    let codes: Vec<&str> = all.iter().map(|e| e.code()).collect();
    assert_eq!(
        codes,
        [
            "invalid_input",
            "degenerate_edges",
            "need_both_ends",
            "implausible",
            "reprojection_too_large",
            "singular",
            "underdetermined"
        ]
    );
    let mut texts: Vec<&str> = all.iter().map(|e| e.describe()).collect();
    assert!(texts.iter().all(|t| t.len() > 15), "{texts:?}");
    texts.sort_unstable();
    texts.dedup();
    assert_eq!(texts.len(), all.len());
    assert!(Singular.describe().contains("singular") && Underdetermined.describe().contains("attitude"));
}

#[test]
fn the_jacobi_scale_is_one_over_the_root_of_each_positive_diagonal_element() {
    let mut h = [[0.0f32; NP]; NP];
    let diag = [4.0f32, 0.25, 0.0, -1.0, 100.0, 9.0];
    for i in 0..NP {
        h[i][i] = diag[i];
    }
    h[0][1] = 7.0;
    assert_eq!(jacobi_scale(&h, NP), [0.5, 2.0, 1.0, 1.0, 0.1, 1.0 / 3.0]);
    // Only the first `np` parameters are scaled.
    assert_eq!(jacobi_scale(&h, 5)[5], 1.0);
}

#[test]
fn the_line_runs_from_the_start_end_to_the_finish_end_else_leftward() {
    let (pos, att) = scene();
    let r_true = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let both = synthetic(&r_true, pos, 0.0, Ends::Both, 0).obs;
    let (s, f) = (both.start_end.unwrap().centroid, both.finish_end.unwrap().centroid);
    assert_eq!(x_direction_in_image(&both), (s, f - s));
    let start = synthetic(&r_true, pos, 0.0, Ends::StartOnly, 0).obs;
    assert_eq!(x_direction_in_image(&start), (s, Vec2::new(-1.0, 0.0)));
    let finish = synthetic(&r_true, pos, 0.0, Ends::FinishOnly, 0).obs;
    assert_eq!(x_direction_in_image(&finish), (f, Vec2::new(-1.0, 0.0)));
    let none = synthetic(&r_true, pos, 0.0, Ends::None, 0).obs;
    assert_eq!(x_direction_in_image(&none), (none.top.centroid, Vec2::new(-1.0, 0.0)));
    // Facing the wall, world +x runs to the image's left (docs/frames.md): the start end is right of the
    // finish end.
    assert!(f.x < s.x);
}

#[test]
fn a_vanishing_direction_points_where_the_image_moves() {
    // Two image lines through (0.5, 0) and (-0.5, 0) meeting at (0, -1): homogeneous lines x/0.5 - y... built
    // from points. The vanishing point is (0, -1, 1) up to scale.
    let line = |a: Vec2, b: Vec2| Vec3::new(a.x, a.y, 1.0).cross(Vec3::new(b.x, b.y, 1.0));
    let l1 = line(Vec2::new(0.5, 0.0), Vec2::new(0.0, -1.0));
    let l2 = line(Vec2::new(-0.5, 0.0), Vec2::new(0.0, -1.0));
    let from = Vec2::new(0.0, 0.0);
    let up = vanishing_direction(l1, l2, from, Vec2::new(0.0, -1.0)).unwrap();
    let down = vanishing_direction(l1, l2, from, Vec2::new(0.0, 1.0)).unwrap();
    assert!((up + down).norm() < 1e-6, "opposite image directions give opposite signs");
    // The image of `from + e d` moves toward the vanishing point (0, -1) for the upward choice.
    let e = 1e-3;
    let p = Vec3::new(from.x, from.y, 1.0) + up * e;
    assert!(p.y / p.z < 0.0, "{up:?}");
    let expected = Vec3::new(0.0, -1.0, 1.0).normalized().unwrap();
    assert!((up - expected).norm() < 1e-5 || (up + expected).norm() < 1e-5, "{up:?}");
    // Seen from a point off the axis, the sign still follows the motion of that point.
    let from = Vec2::new(0.3, 0.4);
    let d = vanishing_direction(l1, l2, from, Vec2::new(0.0, -1.0)).unwrap();
    let p = Vec3::new(from.x, from.y, 1.0) + d * e;
    assert!(p.y / p.z < from.y, "{d:?}");
    assert_eq!(vanishing_direction(l1, l1, from, Vec2::new(0.0, -1.0)), None);
}

#[test]
fn the_mirror_reflects_the_target_normal_about_the_line_of_sight() {
    let (pos, att) = scene();
    let r = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let t = r.mul_vec(TARGET.center() - pos);
    let rm = mirror_pose(&r, t).expect("a distinct mirror");
    let s = t.normalized().unwrap();
    let n = r.mul_vec(Vec3::Y);
    let expected = s * (2.0 * n.dot(s)) - n;
    let got = rm.mul_vec(Vec3::Y);
    assert!((got - expected).norm() < 1e-5, "{got:?} vs {expected:?}");
    assert!((rm.det() - 1.0).abs() < 1e-5);
    // The rotation is about the axis perpendicular to both normals: that axis is unchanged.
    let axis = n.cross(expected).normalized().unwrap();
    assert!((rm.mul_vec(r.transpose().mul_vec(axis)) - axis).norm() < 1e-5);
    // Seen along its normal, the target is its own mirror.
    let head_on = n * 1.5;
    assert!(mirror_pose(&r, head_on).is_none());
    assert!(mirror_pose(&r, Vec3::ZERO).is_none());
}

#[test]
fn a_pose_is_plausible_only_in_front_of_the_camera_and_on_the_painted_side() {
    let (pos, att) = scene();
    let r = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r, pos, 0.0, Ends::Both, 0);
    let p = problem(&s, None, false);
    let t = r.mul_vec(TARGET.center() - pos);
    assert!(plausible(&p, &r, t) && in_front(&p, &r, t));
    // Behind the camera.
    assert!(!in_front(&p, &r, -t) && !plausible(&p, &r, -t));
    // The camera behind the wall (y < 0), target still in front: the mirror image of the scene.
    let behind = Vec3::new(pos.x, -pos.y, pos.z);
    let r_behind = camera_from_world(
        Attitude::new(att.roll, att.pitch, att.yaw + core::f32::consts::PI),
        &CameraMount::FORWARD_AT_CENTRE,
    );
    let t_behind = r_behind.mul_vec(TARGET.center() - behind);
    assert!(in_front(&p, &r_behind, t_behind) && !plausible(&p, &r_behind, t_behind));
    // Each end point must be at least 1 cm in front; one corner at 5 mm fails.
    let mut near = t;
    let zmin = p
        .edges
        .iter()
        .flatten()
        .flat_map(|e| [r.mul_vec(e.p1).z, r.mul_vec(e.p2).z])
        .fold(f32::INFINITY, f32::min);
    near.z = 0.005 - zmin;
    assert!(!in_front(&p, &r, near));
    near.z = 0.02 - zmin;
    assert!(in_front(&p, &r, near));
}

#[test]
fn the_paper_depth_uses_the_finish_end_when_the_start_is_out_of_view() {
    let (pos, _) = scene();
    let level = Attitude::default();
    let r = camera_from_world(level, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r, pos, 0.0, Ends::FinishOnly, 0);
    let c = translation_paper(&r, &s.obs, &TARGET, TARGET.center()).unwrap() + TARGET.center();
    // Fronto-parallel and level: the scaled-orthographic depth is exact.
    assert!((c - pos).norm() < 1e-3, "{c:?}");
    let none = synthetic(&r, pos, 0.0, Ends::None, 0);
    assert_eq!(
        translation_paper(&r, &none.obs, &TARGET, TARGET.center()).unwrap_err(),
        PoseError::NeedBothEnds
    );
}

#[test]
fn the_paper_depth_is_the_line_height_over_its_image_at_the_end_corners() {
    // A yawed, rolled camera, so that in the image the end meets the long edges far from a right angle: the
    // meet points are then the projected corners A and B only if the homogeneous intersection is divided out.
    let pos = Vec3::new(0.6, 1.1, 0.85);
    let att = Attitude::new(geometry::deg(12.0), geometry::deg(-6.0), geometry::deg(28.0));
    let r = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let s = synthetic(&r, pos, 0.0, Ends::StartOnly, 0);
    let got = translation_paper(&r, &s.obs, &TARGET, TARGET.center()).unwrap() + TARGET.center();
    // By hand (f64): a and b the normalised images of A and B; depth z = H / |a - b| along a; the camera
    // centre is A less that ray rotated to the world.
    let proj = |p: Vec3| {
        let x = r.mul_vec(p - pos);
        [x.x as f64 / x.z as f64, x.y as f64 / x.z as f64]
    };
    let (a, b) = (proj(TARGET.corner(Corner::A)), proj(TARGET.corner(Corner::B)));
    let h = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let z = TARGET.height_m() as f64 / h;
    let ray = r.tmul_vec(Vec3::new((a[0] * z) as f32, (a[1] * z) as f32, z as f32));
    let want = TARGET.corner(Corner::A) - ray;
    assert!((got - want).norm() < 2e-4, "{got:?} {want:?}");
    // The ends meet the long edges well away from a right angle here (the test's point).
    let e = s.obs.start_end.unwrap().line();
    let l = s.obs.bottom.line();
    let sin = (l.x * e.y - l.y * e.x).abs() / ((l.x * l.x + l.y * l.y) * (e.x * e.x + e.y * e.y)).sqrt();
    assert!(sin < 0.995, "sin {sin}");
}

#[test]
fn the_ambiguity_ratio_is_the_kept_rms_over_the_other() {
    // The far, nearly affine view of `planar_ambiguity_resolved_by_gravity`, with noise.
    let t = LineTarget { x_start_m: 0.0, x_end_m: 0.3, z_bottom_m: 3.7, z_top_m: 3.9 };
    let pos = Vec3::new(0.15, 10.0, 0.8);
    let att = Attitude::new(0.0, geometry::deg(-10.0), 0.0);
    let r = camera_from_world(att, &CameraMount::FORWARD_AT_CENTRE);
    let obs = crate::observation::project_observation(&CAM, &t, &r, pos, 3.0, 2.0, {
        let mut rng = Lcg(5);
        move || 0.3 * rng.next()
    })
    .unwrap();
    let params = PoseParams { max_rms_px: 5.0, max_std_m: f32::INFINITY, ..PoseParams::default() };
    let sol = solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &params)
        .unwrap();
    let alt = sol.alternative.expect("a second minimum");
    let ratio = sol.reprojection_rms_px / alt.reprojection_rms_px;
    assert!((sol.ambiguity_ratio - ratio).abs() < 1e-3 * ratio, "{} vs {ratio}", sol.ambiguity_ratio);
    assert!(sol.ambiguity_ratio > 0.0);
    // The alternative's position is the camera centre of its own pose.
    assert!(
        alt.camera_position_m.is_finite() && (alt.camera_position_m - sol.camera_position_m).norm() > 0.01
    );
    // Without the check there is no alternative and the ratio is 0.
    let off = PoseParams { check_ambiguity: false, ..params };
    let sol =
        solve_pose(&obs, &CAM, &t, &CameraMount::FORWARD_AT_CENTRE, AttitudeSource::ImageOnly, &off).unwrap();
    assert!(sol.alternative.is_none() && sol.ambiguity_ratio == 0.0);
}
