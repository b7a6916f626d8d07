//! Camera pose from one [`LineObservation`] (paper eq. 1-14, with the known traps fixed).
//!
//! **Rotation**, two ways:
//! - *image only* (the paper's eq. 1-2): the vanishing direction of the long edges `V_x = l1 x l2` and of the
//!   short edges `V_y = m1 x m2`, both as homogeneous directions in normalised coordinates (so a vanishing
//!   point at infinity, seen head-on, is an ordinary direction `(x, y, 0)`), each sign fixed from the image
//!   direction in which the edge runs, then `R` re-orthonormalised by polar decomposition;
//! - *IMU-aided*: roll and pitch from the IMU, yaw from the vanishing direction of the two long edges alone
//!   (a 2x2 eigenproblem), because the 10 cm short edges make `V_y` poorly conditioned.
//!
//! **Translation**: linear least squares over every observed edge given `R` (each image line back-projects to
//! a plane through the camera centre that must contain its 3-D edge), or, as an option, the paper's depth from
//! the line's apparent height at a corner (`Z_A = f l / h`, eq. 13-14).
//!
//! **Refinement**: Levenberg-Marquardt on the sum of squared distances of all sub-pixel edge points to the
//! projected model edges (through [`EdgeStats`], so the cost is exact and independent of the number of points),
//! plus, when an IMU attitude is given, a prior on the gravity direction with the IMU's uncertainty.
//!
//! **Ambiguity**: a planar target has a second, mirrored pose (the target's normal reflected about the line of
//! sight). The solver refines that mirror too; when both fit, the gravity direction decides (the IMU's when
//! given, otherwise "the vehicle is near level").
//!
//! **Observability**: with no end of the line in view, `x` along the line is unobservable and reported as such.
//! With one end, `x` is reported only when its standard deviation (from the Gauss-Newton covariance) is below
//! [`PoseParams::max_x_std_m`].
use crate::camera::CameraModel;
use crate::observation::{EdgeStats, LineObservation};
use crate::target::{Corner, Edge, LineTarget};
use geometry::frames::{Attitude, BODY_FROM_FORWARD_CAMERA};
use geometry::solve::{cholesky_solve, spd_inverse};
use geometry::{Mat3, Vec2, Vec3};

/// Where the camera sits on the vehicle.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CameraMount {
    /// `R_BC`: camera axes in the body frame.
    pub body_from_camera: Mat3,
    /// Camera centre in the body frame (m).
    pub offset_body_m: Vec3,
}

impl CameraMount {
    /// Forward camera at the vehicle's centre, looking along the body's x axis.
    pub const FORWARD_AT_CENTRE: CameraMount =
        CameraMount { body_from_camera: BODY_FROM_FORWARD_CAMERA, offset_body_m: Vec3::ZERO };
    /// Downward camera at the vehicle's centre, looking along the body's -z axis, image top forward.
    pub const DOWN_AT_CENTRE: CameraMount =
        CameraMount { body_from_camera: geometry::frames::BODY_FROM_DOWN_CAMERA, offset_body_m: Vec3::ZERO };
}

/// Where the rotation comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AttitudeSource {
    /// The image alone (the paper's vanishing points).
    ImageOnly,
    /// Roll and pitch of the vehicle from the IMU (radians) with their standard deviation.
    Imu {
        /// Roll (rad).
        roll: f32,
        /// Pitch (rad).
        pitch: f32,
        /// Standard deviation of roll and pitch (rad).
        sigma_rad: f32,
    },
}

/// How the translation of the closed-form solution is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TranslationMethod {
    /// Linear least squares over all observed edges given the rotation.
    LeastSquares,
    /// The paper's scaled-orthographic depth from the line's height at one corner (needs a real corner).
    PaperLineHeight,
}

/// Default of [`PoseParams::edge_bias_px`] (px).
pub const EDGE_BIAS_PX: f32 = 0.02;

/// Solver options.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PoseParams {
    /// Translation of the closed-form solution.
    pub translation: TranslationMethod,
    /// Refine by minimising the reprojection error (recommended; the closed form alone is biased).
    pub refine: bool,
    /// Refine the mirrored pose too and report the ambiguity ratio.
    pub check_ambiguity: bool,
    /// Lower bound of the per-point edge noise used for weights and covariance (px).
    pub min_sigma_px: f32,
    /// Standard deviation of an error common to all points of one edge (px), in the reported covariance:
    /// optics blur, JPEG and clipping move a whole edge, which the scatter of its points about their line
    /// does not show, so an edge's offset is taken as known to no better than this (with the points' own
    /// `sigma / sqrt(n)`). Without it the reported spread covered 83 % of y errors with 1.5 px of blur
    /// (docs/camera-effects.md); 0 gives the points alone. The fit itself is to the points.
    pub edge_bias_px: f32,
    /// `x` is reported as unknown when its standard deviation exceeds this (m).
    pub max_x_std_m: f32,
    /// Solutions whose reprojection RMS exceeds this are rejected (px).
    pub max_rms_px: f32,
    /// Accepted distance from the camera to the line's centre (m).
    pub distance_range_m: [f32; 2],
    /// Levenberg-Marquardt iteration limit.
    pub max_iterations: u8,
    /// A pose whose `y` or `z` standard deviation exceeds this is rejected as under-determined (m): with
    /// one end in view and no attitude, pitch and altitude are nearly interchangeable.
    pub max_std_m: f32,
}

impl Default for PoseParams {
    fn default() -> Self {
        Self {
            translation: TranslationMethod::LeastSquares,
            refine: true,
            check_ambiguity: true,
            min_sigma_px: 0.1,
            edge_bias_px: EDGE_BIAS_PX,
            max_x_std_m: 0.02,
            max_rms_px: 1.0,
            distance_range_m: [0.2, 20.0],
            max_iterations: 30,
            max_std_m: 0.1,
        }
    }
}

/// Why no pose was returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PoseError {
    /// Bad input (non-finite values, invalid target or attitude).
    InvalidInput,
    /// The two long edges are (numerically) the same line.
    DegenerateEdges,
    /// Image-only rotation needs both ends of the line in view.
    NeedBothEnds,
    /// The solution puts the line behind the camera or outside the accepted distance range.
    Implausible,
    /// The best pose still leaves a large reprojection error: the shape is not the known line.
    ReprojectionTooLarge,
    /// The least-squares system is singular.
    Singular,
    /// The image alone does not determine the pose: no end of the line in view, or one end and a covariance
    /// above [`PoseParams::max_std_m`] (pitch and altitude nearly interchangeable).
    Underdetermined,
}

impl PoseError {
    /// A short human-readable explanation.
    pub fn describe(&self) -> &'static str {
        match self {
            PoseError::InvalidInput => "invalid input (non-finite values, invalid target or attitude)",
            PoseError::DegenerateEdges => "the two long edges coincide",
            PoseError::NeedBothEnds => "the image-only rotation needs both ends of the line in view",
            PoseError::Implausible => "the solution puts the line behind the camera or out of range",
            PoseError::ReprojectionTooLarge => {
                "reprojection error too large: the red shape is not the known line"
            }
            PoseError::Singular => "the least-squares system is singular",
            PoseError::Underdetermined => {
                "the image alone cannot fix pitch and altitude here (no end, or one end, of the line in view): give an attitude"
            }
        }
    }

    /// A stable identifier (snake case) for logs and JSON.
    pub fn code(&self) -> &'static str {
        match self {
            PoseError::InvalidInput => "invalid_input",
            PoseError::DegenerateEdges => "degenerate_edges",
            PoseError::NeedBothEnds => "need_both_ends",
            PoseError::Implausible => "implausible",
            PoseError::ReprojectionTooLarge => "reprojection_too_large",
            PoseError::Singular => "singular",
            PoseError::Underdetermined => "underdetermined",
        }
    }
}

/// A pose of the camera and the vehicle, with its quality figures.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PoseSolution {
    /// Camera centre in the world frame (m). Its `x` is meaningless when `x_observed` is false.
    pub camera_position_m: Vec3,
    /// Vehicle centre in the world frame (m).
    pub vehicle_position_m: Vec3,
    /// Whether `x` (along the line) is observed.
    pub x_observed: bool,
    /// `R_CW`: world axes in camera coordinates (the paper's `R = [V_x V_y V_z]`, world to camera).
    pub camera_from_world: Mat3,
    /// Vehicle attitude implied by the rotation and the mount.
    pub attitude: Attitude,
    /// Standard deviation of the camera position (m), from the Gauss-Newton covariance.
    pub position_std_m: Vec3,
    /// Standard deviation of the yaw (rad), from the same covariance.
    pub yaw_std_rad: f32,
    /// RMS distance of the edge points from the projected model edges (px).
    pub reprojection_rms_px: f32,
    /// Number of real corners (corners of the ends in view).
    pub real_corners: u8,
    /// Reprojection RMS of this pose over that of the mirrored pose: 0 when the mirror is not a distinct
    /// minimum, near 1 when the image alone cannot tell them apart and gravity decided.
    pub ambiguity_ratio: f32,
    /// Levenberg-Marquardt iterations used.
    pub iterations: u8,
    /// The other local minimum of the planar pose (the mirror), when it is distinct.
    pub alternative: Option<AlternativePose>,
}

/// The mirrored solution of a planar pose.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize, postcard_schema::Schema))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlternativePose {
    /// Camera centre in the world frame (m).
    pub camera_position_m: Vec3,
    /// `R_CW` of the alternative.
    pub camera_from_world: Mat3,
    /// Its reprojection RMS (px).
    pub reprojection_rms_px: f32,
}

const MAX_RES: usize = 14;
const NP: usize = 6;

#[derive(Clone, Copy)]
struct EdgeTerm {
    stats: EdgeStats,
    /// Edge end points relative to the target centre (world axes).
    p1: Vec3,
    p2: Vec3,
}

/// The pose problem, parametrised as the target in the camera frame: `R_CW` and `t`, the target centre's
/// camera coordinates (so the camera centre is `-R_CW^T t` relative to the target centre). Perturbations
/// are `R_CW <- exp(-[d]x) R_CW` (a rotation about the target centre, camera axes) and `t <- t + dt`.
/// Unlike perturbing the camera about its own centre, this keeps the weakly observed tilt of the thin line
/// a single well-scaled direction that f32 resolves.
#[derive(Clone, Copy)]
struct Problem {
    edges: [Option<EdgeTerm>; 4],
    /// 1 / sigma in normalised units: residuals are in units of sigma.
    inv_sigma: f32,
    /// Gravity prior: measured up-direction in body coordinates and its sigma.
    prior: Option<(Vec3, f32)>,
    body_from_camera: Mat3,
    /// With no end in view, `t` may not move along the line (unobservable): 5 parameters.
    fix_x: bool,
    /// Standard deviation of an error common to all points of an edge (normalised units; see
    /// [`PoseParams::edge_bias_px`]).
    edge_bias: f32,
}

/// Columns of the translation parameters: all of `t`, or the two directions across the line.
fn t_basis(r_cw: &Mat3, fix_x: bool) -> [Vec3; 3] {
    if !fix_x {
        return [Vec3::X, Vec3::Y, Vec3::Z];
    }
    let ax = r_cw.mul_vec(Vec3::X);
    let b1 = ax.cross(Vec3::Z).normalized().unwrap_or(Vec3::Y);
    let b2 = ax.cross(b1);
    [b1, b2, Vec3::ZERO]
}

/// Per-point edge noise (normalised units) pooled over the edges (each edge's line fit uses two degrees of
/// freedom), with a floor.
fn pooled_sigma(obs: &LineObservation, floor: f32) -> f32 {
    let (mut ss, mut dof) = (0.0f32, 0.0f32);
    for (_, s) in edges_of(obs) {
        ss += s.count as f32 * s.rms * s.rms;
        dof += (s.count as f32 - 2.0).max(1.0);
    }
    libm::sqrtf(ss / dof.max(1.0)).max(floor)
}

impl Problem {
    /// The problem of an observation: each observed edge with its model end points relative to the target
    /// centre.
    fn new(
        obs: &LineObservation,
        target: &LineTarget,
        sigma: f32,
        prior: Option<(Vec3, f32)>,
        mount: &CameraMount,
        fix_x: bool,
    ) -> Self {
        let origin = target.center();
        let mut edges: [Option<EdgeTerm>; 4] = [None, None, None, None];
        for (e, s) in edges_of(obs) {
            let (p1, p2) = target.edge_points(e);
            edges[e as usize] = Some(EdgeTerm { stats: s, p1: p1 - origin, p2: p2 - origin });
        }
        Problem {
            edges,
            inv_sigma: 1.0 / sigma,
            prior,
            body_from_camera: mount.body_from_camera,
            fix_x,
            edge_bias: 0.0,
        }
    }

    /// The same problem with an edge-common error of `edge_bias` (normalised units) on each edge's offset.
    fn with_edge_bias(self, edge_bias: f32) -> Self {
        Problem { edge_bias, ..self }
    }

    fn n_params(&self) -> usize {
        if self.fix_x { 5 } else { 6 }
    }

    /// Residuals and Jacobian. Returns the number of residuals.
    fn eval(
        &self,
        r_cw: &Mat3,
        t: Vec3,
        res: &mut [f32; MAX_RES],
        jac: Option<&mut [[f32; NP]; MAX_RES]>,
    ) -> usize {
        let basis = t_basis(r_cw, self.fix_x);
        let np = self.n_params();
        let mut n = 0;
        let mut jrows = [[0.0f32; NP]; MAX_RES];
        for e in self.edges.iter().flatten() {
            let a1 = r_cw.mul_vec(e.p1);
            let a2 = r_cw.mul_vec(e.p2);
            let x1 = a1 + t;
            let x2 = a2 + t;
            let l = x1.cross(x2);
            let rho = libm::sqrtf(l.x * l.x + l.y * l.y).max(1e-20);
            let nv = Vec2::new(l.x / rho, l.y / rho);
            let d = l.z / rho;
            let s = &e.stats;
            let sq_n = libm::sqrtf(s.count as f32);
            let n0 = s.normal;
            let t0 = n0.perp();
            let k = self.inv_sigma;
            // The offset at the centroid is known to sigma / sqrt(n) from the points' scatter, and to no
            // better than the edge-common error: its residual is scaled to the two together.
            let kb = k * self.edge_bias;
            let a0 = 1.0 / libm::sqrtf(1.0 + s.count as f32 * kb * kb);
            let vals = [
                a0 * sq_n * (nv.dot(s.centroid) + d) * k,
                sq_n * s.spread * nv.dot(t0) * k,
                sq_n * s.rms * nv.dot(n0) * k,
            ];
            // Gradients with respect to l = (lx, ly, lz): dn/d(lx,ly) = (I - n n^T)/rho,
            // dd/d(lx,ly) = -d n / rho, dd/dlz = 1/rho.
            let g2 = |a: Vec2, extra: Vec2, scale: f32, dz: f32| -> Vec3 {
                let v = (a - nv * nv.dot(a) + extra) * (scale / rho);
                Vec3::new(v.x, v.y, dz)
            };
            let grads = [
                g2(s.centroid, nv * (-d), a0 * sq_n * k, a0 * sq_n * k / rho),
                g2(t0, Vec2::ZERO, sq_n * s.spread * k, 0.0),
                g2(n0, Vec2::ZERO, sq_n * s.rms * k, 0.0),
            ];
            let dx = x1 - x2;
            let c12 = x2.dot(a1) - x1.dot(a2);
            for g in grads.iter() {
                res[n] = vals[n % 3];
                // dl/dd = (x2.a1 - x1.a2) I - a1 x2^T + a2 x1^T ; dl/dt = [x1 - x2]x
                let jd = *g * c12 - x2 * g.dot(a1) + x1 * g.dot(a2);
                let jt = g.cross(dx);
                let mut row = [jd.x, jd.y, jd.z, 0.0, 0.0, 0.0];
                for (i, b) in basis.iter().enumerate().take(np - 3) {
                    row[3 + i] = jt.dot(*b);
                }
                jrows[n] = row;
                n += 1;
            }
        }
        if let Some((up_meas, sigma)) = self.prior {
            let w = r_cw.mul_vec(Vec3::Z);
            let up = self.body_from_camera.mul_vec(w);
            let inv = 1.0 / sigma;
            // d(up) = R_BC [w]x d
            let m = self.body_from_camera.mul_mat(&Mat3::skew(w));
            for (i, (val, meas)) in [(up.x, up_meas.x), (up.y, up_meas.y)].into_iter().enumerate() {
                res[n] = (val - meas) * inv;
                let r = m.row(i) * inv;
                jrows[n] = [r.x, r.y, r.z, 0.0, 0.0, 0.0];
                n += 1;
            }
        }
        if let Some(j) = jac {
            j[..n].copy_from_slice(&jrows[..n]);
        }
        n
    }

    /// Applies a parameter step.
    fn apply(&self, r_cw: &Mat3, t: Vec3, step: &[f32; NP]) -> (Mat3, Vec3) {
        let basis = t_basis(r_cw, self.fix_x);
        let dr = Vec3::new(step[0], step[1], step[2]);
        let mut dt = Vec3::ZERO;
        for (i, b) in basis.iter().enumerate().take(self.n_params() - 3) {
            dt += *b * step[3 + i];
        }
        (Mat3::exp_so3(-dr).mul_mat(r_cw), t + dt)
    }

    fn cost(&self, r_cw: &Mat3, t: Vec3) -> f32 {
        let mut res = [0.0; MAX_RES];
        let n = self.eval(r_cw, t, &mut res, None);
        res[..n].iter().map(|v| v * v).sum()
    }

    /// Mean squared point-to-line distance over all edge points (normalised units squared; of a problem
    /// without an edge-common error).
    fn image_mse(&self, r_cw: &Mat3, t: Vec3) -> f32 {
        let mut res = [0.0; MAX_RES];
        let n_edges = self.edges.iter().flatten().count();
        self.eval(r_cw, t, &mut res, None);
        let total: f32 = res[..3 * n_edges].iter().map(|v| v * v).sum();
        let count: u32 = self.edges.iter().flatten().map(|e| e.stats.count as u32).sum();
        total / (self.inv_sigma * self.inv_sigma) / count.max(1) as f32
    }

    /// Normal matrix `J^T J` and gradient `J^T r` at a pose.
    fn normal_equations(&self, r_cw: &Mat3, t: Vec3) -> ([[f32; NP]; NP], [f32; NP]) {
        let np = self.n_params();
        let mut res = [0.0; MAX_RES];
        let mut jac = [[0.0; NP]; MAX_RES];
        let n = self.eval(r_cw, t, &mut res, Some(&mut jac));
        let mut h = [[0.0f32; NP]; NP];
        let mut g = [0.0f32; NP];
        for i in 0..n {
            for a in 0..np {
                g[a] += jac[i][a] * res[i];
                for b in 0..np {
                    h[a][b] += jac[i][a] * jac[i][b];
                }
            }
        }
        (h, g)
    }

    /// Levenberg-Marquardt from `(r_cw, t)`. Returns the refined pose and the iterations used.
    fn refine(&self, mut r_cw: Mat3, mut t: Vec3, max_it: u8) -> (Mat3, Vec3, u8) {
        let np = self.n_params();
        let mut lambda = 1e-3f32;
        let mut cost = self.cost(&r_cw, t);
        let mut it = 0u8;
        while it < max_it {
            it += 1;
            let (h, g) = self.normal_equations(&r_cw, t);
            // Jacobi scaling: solve (S H S + lambda I) y = -S g, step = S y, with S = diag(1/sqrt(H_ii)).
            let scale = jacobi_scale(&h, np);
            let mut improved = false;
            let mut converged = false;
            for _ in 0..10 {
                let mut a = [[0.0f32; NP]; NP];
                let mut step = [0.0f32; NP];
                for i in 0..np {
                    for j in 0..np {
                        a[i][j] = h[i][j] * scale[i] * scale[j];
                    }
                    a[i][i] += lambda;
                    step[i] = -g[i] * scale[i];
                }
                if !cholesky_solve(&mut a, &mut step, np) {
                    lambda *= 10.0;
                    continue;
                }
                for i in 0..np {
                    step[i] *= scale[i];
                }
                let (r_new, t_new) = self.apply(&r_cw, t, &step);
                let cost_new = self.cost(&r_new, t_new);
                let size = step[..np].iter().map(|v| v * v).sum::<f32>();
                // Below these, f32 cannot tell the costs apart (relative 1e-6) or the step is under a
                // micrometre and a microradian: converged. Without them the last iterations spent up to ten
                // trials each on rounding noise.
                if cost_new <= cost {
                    let rel = (cost - cost_new) / cost.max(1e-30);
                    r_cw = r_new;
                    t = t_new;
                    cost = cost_new;
                    lambda = (lambda * 0.25).max(1e-9);
                    improved = true;
                    converged = rel < 1e-6 || size < 1e-12;
                    break;
                }
                if size < 1e-12 || cost_new - cost <= 1e-6 * cost {
                    break;
                }
                lambda *= 8.0;
            }
            if !improved || converged {
                break;
            }
        }
        (r_cw.orthonormalized().unwrap_or(r_cw), t, it)
    }

    /// Covariance of the camera centre at a pose and the variance of its yaw (rotation about the world
    /// vertical); `None` when singular.
    fn center_covariance(&self, r_cw: &Mat3, t: Vec3) -> Option<([[f32; 3]; 3], f32)> {
        let np = self.n_params();
        let (mut h, _) = self.normal_equations(r_cw, t);
        let scale = jacobi_scale(&h, np);
        for i in 0..np {
            for j in 0..np {
                h[i][j] *= scale[i] * scale[j];
            }
        }
        let mut inv = [[0.0f32; NP]; NP];
        if !spd_inverse(&h, &mut inv, np) {
            return None;
        }
        // c = -R^T t: dc = R^T [t]x d - R^T dt.
        let basis = t_basis(r_cw, self.fix_x);
        let rt = r_cw.transpose();
        let a = rt.mul_mat(&Mat3::skew(t));
        let mut jc = [[0.0f32; NP]; 3];
        for row in 0..3 {
            for k in 0..3 {
                jc[row][k] = a.m[row][k];
            }
            for (i, b) in basis.iter().enumerate().take(np - 3) {
                jc[row][3 + i] = -rt.mul_vec(*b)[row];
            }
        }
        let mut cov = [[0.0f32; 3]; 3];
        for (i, ci) in cov.iter_mut().enumerate() {
            for (j, cij) in ci.iter_mut().enumerate() {
                let mut s = 0.0f32;
                for a in 0..np {
                    for b in 0..np {
                        s += jc[i][a] * inv[a][b] * scale[a] * scale[b] * jc[j][b];
                    }
                }
                *cij = s;
            }
        }
        // Yaw: the rotation parameters are camera-frame; the world vertical in camera axes is R_CW z.
        let a = r_cw.col(2);
        let mut yaw_var = 0.0f32;
        for i in 0..3 {
            for j in 0..3 {
                yaw_var += a[i] * inv[i][j] * scale[i] * scale[j] * a[j];
            }
        }
        Some((cov, yaw_var))
    }
}

fn jacobi_scale(h: &[[f32; NP]; NP], np: usize) -> [f32; NP] {
    let mut scale = [1.0f32; NP];
    for i in 0..np {
        scale[i] = if h[i][i] > 0.0 { 1.0 / libm::sqrtf(h[i][i]) } else { 1.0 };
    }
    scale
}

/// Vanishing direction (camera frame) of two image lines, with its sign chosen so that moving along it from
/// the image point `from` moves the image point along `image_dir`.
fn vanishing_direction(l1: Vec3, l2: Vec3, from: Vec2, image_dir: Vec2) -> Option<Vec3> {
    let d = l1.cross(l2).normalized()?;
    let motion = Vec2::new(d.x - from.x * d.z, d.y - from.y * d.z);
    Some(if motion.dot(image_dir) < 0.0 { -d } else { d })
}

/// Image direction (normalised coordinates) in which world +x runs along the line.
fn x_direction_in_image(obs: &LineObservation) -> (Vec2, Vec2) {
    match (obs.start_end, obs.finish_end) {
        (Some(s), Some(f)) => (s.centroid, f.centroid - s.centroid),
        (Some(s), None) => (s.centroid, Vec2::new(-1.0, 0.0)),
        (None, Some(f)) => (f.centroid, Vec2::new(-1.0, 0.0)),
        (None, None) => (obs.top.centroid, Vec2::new(-1.0, 0.0)),
    }
}

/// The paper's rotation (eq. 1-2) from the two vanishing points, with homogeneous directions, sign fixes
/// and polar re-orthonormalisation. Returns `R_CW`.
pub fn rotation_from_vanishing_points(obs: &LineObservation) -> Result<Mat3, PoseError> {
    let (Some(start), Some(finish)) = (obs.start_end, obs.finish_end) else {
        return Err(PoseError::NeedBothEnds);
    };
    let (from, dir) = x_direction_in_image(obs);
    let vx = vanishing_direction(obs.top.line(), obs.bottom.line(), from, dir)
        .ok_or(PoseError::DegenerateEdges)?;
    let up_img = Vec2::new(0.0, -1.0);
    let vz = vanishing_direction(start.line(), finish.line(), start.centroid, up_img)
        .ok_or(PoseError::DegenerateEdges)?;
    let vy = vz.cross(vx);
    Mat3::from_cols(vx, vy, vz).orthonormalized().ok_or(PoseError::DegenerateEdges)
}

/// IMU-aided rotation: roll and pitch of the vehicle given, yaw from the vanishing direction of the long
/// edges. Returns `R_CW`.
pub fn rotation_from_imu(
    obs: &LineObservation,
    mount: &CameraMount,
    roll: f32,
    pitch: f32,
) -> Result<Mat3, PoseError> {
    // World +x in camera coordinates is B (sin yaw, cos yaw, 0), B = R_CB Rx(roll)^T Ry(pitch)^T.
    let b = mount
        .body_from_camera
        .transpose()
        .mul_mat(&Mat3::rot_x(roll).transpose())
        .mul_mat(&Mat3::rot_y(pitch).transpose());
    let mut s = [[0.0f32; 2]; 2];
    for l in [obs.top.line(), obs.bottom.line()] {
        let g = b.tmul_vec(l);
        s[0][0] += g.x * g.x;
        s[0][1] += g.x * g.y;
        s[1][1] += g.y * g.y;
    }
    let (_, _, v) = geometry::solve::sym2_eigen(s[0][0], s[0][1], s[1][1]);
    let mut yaw = libm::atan2f(v[0], v[1]);
    // Sign: world +x must run along the line's image direction.
    let d = b.mul_vec(Vec3::new(v[0], v[1], 0.0));
    let (from, dir) = x_direction_in_image(obs);
    if Vec2::new(d.x - from.x * d.z, d.y - from.y * d.z).dot(dir) < 0.0 {
        yaw = geometry::wrap_pi(yaw + core::f32::consts::PI);
    }
    let r_wb = Attitude::new(roll, pitch, yaw).world_from_body();
    Ok(r_wb.mul_mat(&mount.body_from_camera).transpose())
}

/// Camera centre by linear least squares over the observed edges, given `R_CW`. With no end in view the
/// system is rank 2 and `x` is held at `x_hint`. Coordinates are relative to `origin` (for conditioning).
fn translation_least_squares(
    r_cw: &Mat3,
    obs: &LineObservation,
    target: &LineTarget,
    origin: Vec3,
    x_hint: f32,
) -> Result<Vec3, PoseError> {
    let r_wc = r_cw.transpose();
    let mut a = [[0.0f32; 3]; 3];
    let mut b = [0.0f32; 3];
    let fix_x = obs.start_end.is_none() && obs.finish_end.is_none();
    for (edge, stats) in edges_of(obs) {
        let (p1, p2) = target.edge_points(edge);
        let n = r_wc.mul_vec(stats.line());
        let Some(n) = n.normalized() else { continue };
        for p in [p1 - origin, p2 - origin] {
            let rhs = n.dot(p);
            let nv = n.to_array();
            for i in 0..3 {
                b[i] += nv[i] * rhs;
                for j in 0..3 {
                    a[i][j] += nv[i] * nv[j];
                }
            }
        }
    }
    if fix_x {
        let xh = x_hint - origin.x;
        let mut a2 = [[a[1][1], a[1][2]], [a[2][1], a[2][2]]];
        let mut b2 = [b[1] - a[1][0] * xh, b[2] - a[2][0] * xh];
        if !cholesky_solve(&mut a2, &mut b2, 2) {
            return Err(PoseError::Singular);
        }
        Ok(Vec3::new(xh, b2[0], b2[1]))
    } else {
        if !cholesky_solve(&mut a, &mut b, 3) {
            return Err(PoseError::Singular);
        }
        Ok(Vec3::new(b[0], b[1], b[2]))
    }
}

/// The paper's translation (eq. 13-14): depth of a real corner from the line's apparent height there
/// (`Z_A = f l / h`, scaled orthographic), then `T = (Z_A / f) Oa`. Coordinates relative to `origin`.
fn translation_paper(
    r_cw: &Mat3,
    obs: &LineObservation,
    target: &LineTarget,
    origin: Vec3,
) -> Result<Vec3, PoseError> {
    // Reference corner: the lower corner of an end in view (A, else D); the height is measured along that end.
    let (corner, end) = match (obs.start_end, obs.finish_end) {
        (Some(s), _) => (Corner::A, s),
        (None, Some(f)) => (Corner::D, f),
        _ => return Err(PoseError::NeedBothEnds),
    };
    let (long_a, long_b) = (obs.bottom, obs.top);
    let meet = |l: &EdgeStats| {
        let p = l.line().cross(end.line());
        if p.z.abs() < 1e-12 { None } else { Some(Vec2::new(p.x / p.z, p.y / p.z)) }
    };
    let a = meet(&long_a).ok_or(PoseError::DegenerateEdges)?;
    let b = meet(&long_b).ok_or(PoseError::DegenerateEdges)?;
    let h = (a - b).norm();
    if !(h > 1e-6) {
        return Err(PoseError::DegenerateEdges);
    }
    let z_a = target.height_m() / h;
    let t = Vec3::new(a.x * z_a, a.y * z_a, z_a);
    Ok(target.corner(corner) - origin - r_cw.tmul_vec(t))
}

fn edges_of(obs: &LineObservation) -> impl Iterator<Item = (Edge, EdgeStats)> {
    [
        (Edge::Top, Some(obs.top)),
        (Edge::Bottom, Some(obs.bottom)),
        (Edge::StartEnd, obs.start_end),
        (Edge::FinishEnd, obs.finish_end),
    ]
    .into_iter()
    .filter_map(|(e, s)| s.map(|s| (e, s)))
}

fn valid_stats(s: &EdgeStats) -> bool {
    s.centroid.x.is_finite()
        && s.centroid.y.is_finite()
        && s.normal.x.is_finite()
        && s.normal.y.is_finite()
        && s.spread.is_finite()
        && s.rms.is_finite()
        && s.count >= 2
}

/// Mirror of a pose: the target rotated about its centre so that its normal is reflected about the line
/// of sight (the second minimum of a planar pose). `t` is unchanged.
fn mirror_pose(r_cw: &Mat3, t: Vec3) -> Option<Mat3> {
    let s = t.normalized()?;
    let n = r_cw.mul_vec(Vec3::Y);
    let n2 = s * (2.0 * n.dot(s)) - n;
    let axis = n.cross(n2);
    let sin = axis.norm();
    let angle = libm::atan2f(sin, n.dot(n2));
    if angle < 1e-3 {
        return None;
    }
    Some(Mat3::exp_so3(axis * (angle / sin)).mul_mat(r_cw))
}

/// Solves the pose of the camera (and vehicle) from one observation.
pub fn solve_pose(
    obs: &LineObservation,
    camera: &CameraModel,
    target: &LineTarget,
    mount: &CameraMount,
    source: AttitudeSource,
    params: &PoseParams,
) -> Result<PoseSolution, PoseError> {
    if !target.is_valid() || !edges_of(obs).all(|(_, s)| valid_stats(&s)) {
        return Err(PoseError::InvalidInput);
    }
    let origin = target.center();
    let f_px = camera.focal_px();
    let n_ends = obs.start_end.is_some() as u8 + obs.finish_end.is_some() as u8;
    let fix_x = n_ends == 0;
    // Initial rotation.
    let (r0, prior) = match source {
        AttitudeSource::ImageOnly => {
            if n_ends == 0 {
                return Err(PoseError::Underdetermined);
            }
            let r = match rotation_from_vanishing_points(obs) {
                Ok(r) => r,
                // One end only: start from "level" and let the refinement (and the covariance) decide.
                Err(PoseError::NeedBothEnds) => rotation_from_imu(obs, mount, 0.0, 0.0)?,
                Err(e) => return Err(e),
            };
            (r, None)
        }
        AttitudeSource::Imu { roll, pitch, sigma_rad } => {
            if !(roll.is_finite() && pitch.is_finite() && sigma_rad > 0.0) {
                return Err(PoseError::InvalidInput);
            }
            let r = rotation_from_imu(obs, mount, roll, pitch)?;
            let up = Attitude::new(roll, pitch, 0.0).world_from_body().tmul_vec(Vec3::Z);
            (r, Some((up, sigma_rad)))
        }
    };
    // Initial translation (relative to the target centre).
    let x_hint = origin.x;
    let c0 = match params.translation {
        TranslationMethod::LeastSquares => translation_least_squares(&r0, obs, target, origin, x_hint)?,
        TranslationMethod::PaperLineHeight => translation_paper(&r0, obs, target, origin)?,
    };
    let sigma = pooled_sigma(obs, params.min_sigma_px / f_px);
    // The fit is to the points; the edge-common error enters the reported covariance only. (Weighing the
    // edges against the IMU's tilt with it as well moved the single frames' tilt toward the IMU's, but in
    // flight that prior is the estimator's own attitude, which the fixes correct: the loop's z error grew by
    // 3-5 mm on the webcam scenario and one seed of five reached 29 mm, docs/camera-effects.md.)
    let problem = Problem::new(obs, target, sigma, prior, mount, fix_x);
    let with_bias = problem.with_edge_bias(params.edge_bias_px.max(0.0) / f_px);
    let image_only = Problem { prior: None, ..problem };

    let t0 = -r0.mul_vec(c0);
    let (mut r, mut t, mut iterations) = (r0, t0, 0u8);
    if params.refine {
        (r, t, iterations) = problem.refine(r0, t0, params.max_iterations);
    }
    let mut ambiguity_ratio = 0.0f32;
    let mut alternative = None;
    if params.check_ambiguity
        && params.refine
        && let Some(rm) = mirror_pose(&r, t)
    {
        let (rm, tm, _) = image_only.refine(rm, t, params.max_iterations);
        let primary_ok = plausible(&image_only, &r, t);
        if r.angle_to(&rm) > geometry::deg(1.0) && plausible(&image_only, &rm, tm) {
            let rms_p = libm::sqrtf(image_only.image_mse(&r, t));
            let rms_m = libm::sqrtf(image_only.image_mse(&rm, tm));
            // Gravity reference: the IMU's up direction, else "near level".
            let up_ref = prior.map_or(Vec3::Z, |p| p.0);
            let tilt = |rr: &Mat3| {
                let up = mount.body_from_camera.mul_mat(rr).mul_vec(Vec3::Z);
                libm::acosf(geometry::clamp_finite(up.dot(up_ref), -1.0, 1.0))
            };
            // Both fit the image (likelihood-ratio test on the sigma-normalised costs, 3 sigma): gravity
            // decides. With an IMU prior the primary solution already used gravity.
            let both_fit = (image_only.cost(&rm, tm) - image_only.cost(&r, t)).abs() < 9.0;
            let take_mirror = !primary_ok
                || (prior.is_none() && if both_fit { tilt(&rm) < tilt(&r) } else { rms_m < rms_p });
            let (rms_keep, rms_other) = if take_mirror { (rms_m, rms_p) } else { (rms_p, rms_m) };
            let (r_other, t_other) = if take_mirror { (r, t) } else { (rm, tm) };
            if take_mirror {
                r = rm;
                t = tm;
            }
            ambiguity_ratio = if rms_other > 0.0 { (rms_keep / rms_other).min(1e3) } else { 1.0 };
            alternative = Some(AlternativePose {
                camera_position_m: origin - r_other.tmul_vec(t_other),
                camera_from_world: r_other,
                reprojection_rms_px: rms_other * f_px,
            });
        }
    }
    if !r.is_finite() || !t.is_finite() || !plausible(&image_only, &r, t) {
        return Err(PoseError::Implausible);
    }
    let dist = t.norm();
    if !(dist >= params.distance_range_m[0] && dist <= params.distance_range_m[1]) {
        return Err(PoseError::Implausible);
    }
    let rms_px = libm::sqrtf(image_only.image_mse(&r, t)) * f_px;
    if rms_px > params.max_rms_px {
        return Err(PoseError::ReprojectionTooLarge);
    }
    let std = |v: f32| if v.is_finite() && v >= 0.0 { libm::sqrtf(v) } else { f32::INFINITY };
    let cov = with_bias.center_covariance(&r, t);
    let (mut position_std_m, yaw_std_rad) = match cov {
        Some((c, yv)) => (Vec3::new(std(c[0][0]), std(c[1][1]), std(c[2][2])), std(yv)),
        None => (Vec3::new(f32::INFINITY, f32::INFINITY, f32::INFINITY), f32::INFINITY),
    };
    if fix_x {
        position_std_m.x = f32::INFINITY;
    }
    if params.refine && !(position_std_m.y <= params.max_std_m && position_std_m.z <= params.max_std_m) {
        return Err(PoseError::Underdetermined);
    }
    let x_observed = !fix_x && (!params.refine || position_std_m.x <= params.max_x_std_m);
    let c = -r.tmul_vec(t);
    let camera_position_m = c + origin;
    let r_wb = r.transpose().mul_mat(&mount.body_from_camera.transpose());
    let vehicle_position_m = camera_position_m - r_wb.mul_vec(mount.offset_body_m);
    Ok(PoseSolution {
        camera_position_m,
        vehicle_position_m,
        x_observed,
        camera_from_world: r,
        attitude: Attitude::from_world_from_body(&r_wb),
        position_std_m,
        yaw_std_rad,
        reprojection_rms_px: rms_px,
        real_corners: obs.real_corners(),
        ambiguity_ratio,
        iterations,
        alternative,
    })
}

/// True when the target is in front of the camera and the camera on the painted side of the wall (the wall's
/// normal is world +y; from behind, a mirrored pose can fit the image as well).
fn plausible(p: &Problem, r_cw: &Mat3, t: Vec3) -> bool {
    in_front(p, r_cw, t) && (-r_cw.tmul_vec(t)).y > 0.0
}

/// True when every model edge end point is in front of the camera.
fn in_front(p: &Problem, r_cw: &Mat3, t: Vec3) -> bool {
    p.edges.iter().flatten().all(|e| (r_cw.mul_vec(e.p1) + t).z > 0.01 && (r_cw.mul_vec(e.p2) + t).z > 0.01)
}

#[cfg(test)]
mod oracle_tests;
#[cfg(test)]
mod tests;
