//! Exact area coverage of pixels by a convex polygon (box-filter anti-aliasing).
//!
//! Pixel `(i, j)` covers `[i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]` (pixel centres at integers).

/// Vertex capacity of a [`Poly`] (a 32-gon plus the vertices that clipping adds).
const CAP: usize = 40;

/// A small convex polygon with at most 40 vertices (a 32-gon plus the vertices that clipping adds).
#[derive(Clone, Copy, Debug)]
pub struct Poly {
    pts: [[f64; 2]; CAP],
    n: usize,
}

impl Poly {
    /// From vertices in order (either orientation).
    pub fn new(v: &[[f64; 2]]) -> Self {
        let mut p = Poly { pts: [[0.0; 2]; CAP], n: v.len().min(CAP) };
        p.pts[..p.n].copy_from_slice(&v[..p.n]);
        p
    }

    /// The vertices.
    pub fn vertices(&self) -> &[[f64; 2]] {
        &self.pts[..self.n]
    }

    /// Keeps the part where `a x + b y + c >= 0` (Sutherland-Hodgman).
    pub fn clip(&self, a: f64, b: f64, c: f64) -> Poly {
        let mut out = Poly { pts: [[0.0; 2]; CAP], n: 0 };
        if self.n == 0 {
            return out;
        }
        let f = |p: [f64; 2]| a * p[0] + b * p[1] + c;
        for k in 0..self.n {
            let p = self.pts[k];
            let q = self.pts[(k + 1) % self.n];
            let (fp, fq) = (f(p), f(q));
            if fp >= 0.0 {
                out.push(p);
            }
            if (fp >= 0.0) != (fq >= 0.0) {
                let t = fp / (fp - fq);
                out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
        out
    }

    fn push(&mut self, p: [f64; 2]) {
        if self.n < CAP {
            self.pts[self.n] = p;
            self.n += 1;
        }
    }

    /// Unsigned area.
    pub fn area(&self) -> f64 {
        let mut s = 0.0;
        for k in 0..self.n {
            let p = self.pts[k];
            let q = self.pts[(k + 1) % self.n];
            s += p[0] * q[1] - q[0] * p[1];
        }
        0.5 * s.abs()
    }

    /// x range of the intersection with the horizontal line `y`, or `None`.
    pub fn x_range_at(&self, y: f64) -> Option<(f64, f64)> {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for k in 0..self.n {
            let p = self.pts[k];
            let q = self.pts[(k + 1) % self.n];
            let (y0, y1) = (p[1].min(q[1]), p[1].max(q[1]));
            if y < y0 || y > y1 {
                continue;
            }
            let x = if (q[1] - p[1]).abs() < 1e-12 {
                lo = lo.min(p[0].min(q[0]));
                hi = hi.max(p[0].max(q[0]));
                continue;
            } else {
                p[0] + (y - p[1]) * (q[0] - p[0]) / (q[1] - p[1])
            };
            lo = lo.min(x);
            hi = hi.max(x);
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// Bounding box `(x_min, y_min, x_max, y_max)`.
    pub fn bounds(&self) -> (f64, f64, f64, f64) {
        let mut b = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in self.vertices() {
            b = (b.0.min(p[0]), b.1.min(p[1]), b.2.max(p[0]), b.3.max(p[1]));
        }
        b
    }
}

/// Fills `cov[i]` with the exact coverage of the pixels of row `j` by the convex polygon `poly`
/// (`cov` is cleared first). Returns the range of touched columns.
pub fn row_coverage(poly: &Poly, j: i64, cov: &mut [f32]) -> Option<(usize, usize)> {
    cov.fill(0.0);
    let (y0, y1) = (j as f64 - 0.5, j as f64 + 0.5);
    let strip = poly.clip(0.0, 1.0, -y0).clip(0.0, -1.0, y1);
    if strip.n < 3 || strip.area() <= 0.0 {
        return None;
    }
    let (xmin, _, xmax, _) = strip.bounds();
    let w = cov.len() as i64;
    let i0 = ((xmin + 0.5).floor() as i64).clamp(0, w - 1);
    let i1 = ((xmax - 0.5).ceil() as i64).clamp(0, w - 1);
    if i0 > i1 {
        return None;
    }
    // Fully covered columns: inside the polygon's span on both the strip's lines.
    let full = match (poly.x_range_at(y0), poly.x_range_at(y1)) {
        (Some((l0, r0)), Some((l1, r1))) => {
            let a = (l0.max(l1) + 0.5).ceil() as i64;
            let b = (r0.min(r1) - 0.5).floor() as i64;
            (a, b)
        }
        _ => (1, 0),
    };
    for i in i0..=i1 {
        cov[i as usize] = if i >= full.0 && i <= full.1 {
            1.0
        } else {
            let x0 = i as f64 - 0.5;
            let cell = strip.clip(1.0, 0.0, -x0).clip(-1.0, 0.0, x0 + 1.0);
            cell.area().clamp(0.0, 1.0) as f32
        };
    }
    Some((i0 as usize, i1 as usize))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_sums_to_the_area() {
        // A rotated quadrilateral: the coverage of all pixels sums to its area.
        let poly = Poly::new(&[[10.3, 5.2], [60.7, 9.9], [58.1, 30.4], [12.2, 25.75]]);
        let mut cov = vec![0.0f32; 80];
        let mut total = 0.0f64;
        for j in 0..40 {
            if row_coverage(&poly, j, &mut cov).is_some() {
                total += cov.iter().map(|&c| c as f64).sum::<f64>();
            }
        }
        assert!((total - poly.area()).abs() < 1e-3, "{total} vs {}", poly.area());
    }

    #[test]
    fn axis_aligned_edges_are_exact() {
        let poly = Poly::new(&[[2.25, 3.0], [7.0, 3.0], [7.0, 5.6], [2.25, 5.6]]);
        let mut cov = vec![0.0f32; 10];
        row_coverage(&poly, 3, &mut cov);
        assert_eq!(cov[2], 0.25 * 0.5);
        assert_eq!(cov[4], 0.5);
        row_coverage(&poly, 4, &mut cov);
        assert_eq!(cov[2], 0.25);
        assert_eq!(cov[4], 1.0);
        assert_eq!(cov[7], 0.5);
        assert_eq!(cov[8], 0.0);
    }
}
