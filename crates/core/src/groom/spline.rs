//! Natural cubic splines through a strand's control points, the strand
//! representation of the paper (Sec. 3): the stylizer moves control points
//! `p` and the renderer samples the spline through them.
//!
//! Parameterization: knots at cumulative chord length, `s_0 = 0`,
//! `s_{i+1} = s_i + |p_{i+1} - p_i|`. Natural end conditions (zero second
//! derivative at both ends). Per coordinate the second derivatives `M` solve
//! the tridiagonal system
//! `h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1} = 6 (d_i - d_{i-1})`
//! with `d_i = (p_{i+1} - p_i) / h_i`, by the Thomas algorithm.
//!
//! For fixed knots every sample is a fixed linear combination of the control
//! points; [`StrandSpline::basis_weights`] returns it, which is exactly the
//! Jacobian the renderer's backward needs to send gradients on spline samples
//! back to control points. The knots themselves depend on the points; the
//! gradient deliberately holds them fixed (the parameterization is treated as
//! a constant of each optimization step), as is usual for spline renderers.

use super::GroomError;

/// A natural cubic spline through a strand's control points.
#[derive(Clone, Debug)]
pub struct StrandSpline {
    points: Vec<[f64; 3]>,
    knots: Vec<f64>,
    /// Second derivative at each knot, per coordinate.
    second: Vec<[f64; 3]>,
}

/// Solves the natural-spline system for right-hand sides `rhs` (one per
/// interior knot) in place: `A x = rhs` with `A` the tridiagonal matrix of
/// the module notes. `A` is symmetric, which [`StrandSpline::basis_weights`]
/// relies on.
fn solve_tridiagonal(h: &[f64], rhs: &mut [f64]) {
    let m = rhs.len();
    if m == 0 {
        return;
    }
    // Interior row r (knot r+1): sub h[r], diag 2(h[r]+h[r+1]), super h[r+1].
    let mut c = vec![0.0; m];
    let mut diag = 2.0 * (h[0] + h[1]);
    c[0] = h[1] / diag;
    rhs[0] /= diag;
    for r in 1..m {
        diag = 2.0 * (h[r] + h[r + 1]) - h[r] * c[r - 1];
        c[r] = h[r + 1] / diag;
        rhs[r] = (rhs[r] - h[r] * rhs[r - 1]) / diag;
    }
    for r in (0..m - 1).rev() {
        rhs[r] -= c[r] * rhs[r + 1];
    }
}

impl StrandSpline {
    /// Fits the spline through `points` with chord-length knots. Needs at
    /// least two finite points and no two consecutive points equal (a zero
    /// chord would repeat a knot).
    pub fn new(points: &[[f32; 3]]) -> Result<Self, GroomError> {
        let p: Vec<[f64; 3]> = points.iter().map(|q| q.map(f64::from)).collect();
        let mut knots = Vec::with_capacity(p.len());
        let mut s = 0.0;
        for (i, q) in p.iter().enumerate() {
            if i > 0 {
                let d = (0..3).map(|a| (q[a] - p[i - 1][a]).powi(2)).sum::<f64>().sqrt();
                s += d;
            }
            knots.push(s);
        }
        Self::with_knots(points, &knots)
    }

    /// Fits the spline through `points` at given increasing `knots` (one per
    /// point). Used to evaluate moved control points with the knots of the
    /// original strand, the setting in which [`StrandSpline::basis_weights`]
    /// is the exact derivative.
    pub fn with_knots(points: &[[f32; 3]], knots: &[f64]) -> Result<Self, GroomError> {
        let err = |reason: String| GroomError::Spline { reason };
        if points.len() < 2 {
            return Err(err(format!("{} control point(s), need at least 2", points.len())));
        }
        if knots.len() != points.len() {
            return Err(err(format!("{} knots for {} points", knots.len(), points.len())));
        }
        if let Some(i) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(err(format!("control point {i} is not finite")));
        }
        if let Some(i) = knots.iter().position(|k| !k.is_finite()) {
            return Err(err(format!("knot {i} is not finite")));
        }
        if let Some(i) = (1..knots.len()).find(|&i| knots[i] <= knots[i - 1]) {
            return Err(err(format!("knot {i} does not increase (control points {} and {i} coincide?)", i - 1)));
        }
        let points: Vec<[f64; 3]> = points.iter().map(|q| q.map(f64::from)).collect();
        let n = points.len();
        let h: Vec<f64> = knots.windows(2).map(|w| w[1] - w[0]).collect();
        let mut second = vec![[0.0; 3]; n];
        for a in 0..3 {
            let mut rhs: Vec<f64> = (1..n - 1)
                .map(|i| {
                    6.0 * ((points[i + 1][a] - points[i][a]) / h[i] - (points[i][a] - points[i - 1][a]) / h[i - 1])
                })
                .collect();
            solve_tridiagonal(&h, &mut rhs);
            for (i, m) in rhs.into_iter().enumerate() {
                second[i + 1][a] = m;
            }
        }
        Ok(Self { points, knots: knots.to_vec(), second })
    }

    /// Knot values (cumulative chord length for [`StrandSpline::new`]).
    pub fn knots(&self) -> &[f64] {
        &self.knots
    }

    /// Parameter range end: the total chord length for [`StrandSpline::new`].
    pub fn length_param(&self) -> f64 {
        *self.knots.last().unwrap_or(&0.0)
    }

    /// Interval index `i` with `t` in `[s_i, s_{i+1}]`, and the local
    /// coordinate `w = (t - s_i) / h_i` in `[0, 1]` (`t` is clamped).
    fn locate(&self, t: f64) -> (usize, f64, f64) {
        let n = self.knots.len();
        let t = t.clamp(self.knots[0], self.knots[n - 1]);
        let i = match self.knots.partition_point(|&k| k <= t) {
            0 => 0,
            k => (k - 1).min(n - 2),
        };
        let h = self.knots[i + 1] - self.knots[i];
        (i, ((t - self.knots[i]) / h).clamp(0.0, 1.0), h)
    }

    /// Weights of `(p_i, p_{i+1}, M_i, M_{i+1})` in the sample at local `w`,
    /// or in its derivative with respect to `t` when `derivative`.
    fn local_weights(w: f64, h: f64, derivative: bool) -> [f64; 4] {
        let v = 1.0 - w;
        if derivative {
            [-1.0 / h, 1.0 / h, -(3.0 * v * v - 1.0) * h / 6.0, (3.0 * w * w - 1.0) * h / 6.0]
        } else {
            [v, w, (v * v * v - v) * h * h / 6.0, (w * w * w - w) * h * h / 6.0]
        }
    }

    fn combine(&self, t: f64, derivative: bool) -> [f32; 3] {
        let (i, w, h) = self.locate(t);
        let c = Self::local_weights(w, h, derivative);
        [0, 1, 2].map(|a| {
            (c[0] * self.points[i][a]
                + c[1] * self.points[i + 1][a]
                + c[2] * self.second[i][a]
                + c[3] * self.second[i + 1][a]) as f32
        })
    }

    /// Position at chord-length parameter `t` (clamped to the strand).
    pub fn eval(&self, t: f64) -> [f32; 3] {
        self.combine(t, false)
    }

    /// Derivative `dS/dt` at `t`; with chord-length knots its length is
    /// close to 1, so it doubles as the (unnormalized) tangent direction.
    pub fn tangent(&self, t: f64) -> [f32; 3] {
        self.combine(t, true)
    }

    /// Second derivative at every knot (zero at both ends: natural spline).
    pub fn second_derivatives(&self) -> Vec<[f32; 3]> {
        self.second.iter().map(|m| m.map(|x| x as f32)).collect()
    }

    /// `eval(t) = Σ w_j p_j` for fixed knots: the `(j, w_j)` pairs, one per
    /// control point (a natural spline has global support, though weights
    /// decay fast away from `t`). The same weights apply to each coordinate,
    /// so the gradient of a loss on the sample maps to control point `j` as
    /// `w_j * dL/dS`.
    pub fn basis_weights(&self, t: f64) -> Vec<(usize, f32)> {
        let n = self.points.len();
        let (i, w, h) = self.locate(t);
        let c = Self::local_weights(w, h, false);
        let mut weights = vec![0.0f64; n];
        weights[i] += c[0];
        weights[i + 1] += c[1];
        // M = A^{-1} B p, with B the second-difference rows of the module
        // notes; dM_k/dp = (A^{-1} e_k)^T B since A is symmetric.
        let mut g = vec![0.0; n.saturating_sub(2)];
        for (k, ck) in [(i, c[2]), (i + 1, c[3])] {
            if k >= 1 && k + 1 < n {
                g[k - 1] += ck;
            }
        }
        let hs: Vec<f64> = self.knots.windows(2).map(|w| w[1] - w[0]).collect();
        solve_tridiagonal(&hs, &mut g);
        for (r, &gr) in g.iter().enumerate() {
            // Interior row r (knot r+1) of 6 B.
            let k = r + 1;
            weights[k - 1] += gr * 6.0 / hs[k - 1];
            weights[k] -= gr * 6.0 * (1.0 / hs[k - 1] + 1.0 / hs[k]);
            weights[k + 1] += gr * 6.0 / hs[k];
        }
        weights.into_iter().enumerate().map(|(j, w)| (j, w as f32)).collect()
    }

    /// Arc length from the root to every one of `samples + 1` evenly spaced
    /// parameters (chord length underestimates arc length on curved
    /// strands, so resampling integrates the curve itself).
    fn arc_table(&self, samples: usize) -> (Vec<f64>, Vec<f64>) {
        let total = self.length_param();
        let ts: Vec<f64> = (0..=samples).map(|k| total * k as f64 / samples as f64).collect();
        let mut acc = vec![0.0; ts.len()];
        let mut prev = self.eval(0.0);
        for k in 1..ts.len() {
            let q = self.eval(ts[k]);
            let d = (0..3).map(|a| ((q[a] - prev[a]) as f64).powi(2)).sum::<f64>().sqrt();
            acc[k] = acc[k - 1] + d;
            prev = q;
        }
        (ts, acc)
    }

    /// Arc length of the spline (numerically, 64 samples per segment).
    pub fn arc_length(&self) -> f64 {
        let (_, acc) = self.arc_table(64 * (self.points.len() - 1));
        *acc.last().unwrap_or(&0.0)
    }

    /// Parameters of `n` points evenly spaced in arc length, root and tip
    /// included (so the renderer can pair [`StrandSpline::resample`] with
    /// [`StrandSpline::basis_weights`]).
    pub fn resample_params(&self, n: usize) -> Vec<f64> {
        match n {
            0 => return Vec::new(),
            1 => return vec![0.0],
            _ => {}
        }
        let (ts, acc) = self.arc_table(64 * (self.points.len() - 1));
        let total = *acc.last().unwrap_or(&0.0);
        (0..n)
            .map(|k| {
                let target = total * k as f64 / (n - 1) as f64;
                let j = acc.partition_point(|&a| a < target).clamp(1, acc.len() - 1);
                let span = acc[j] - acc[j - 1];
                let f = if span > 0.0 { ((target - acc[j - 1]) / span).clamp(0.0, 1.0) } else { 0.0 };
                ts[j - 1] + f * (ts[j] - ts[j - 1])
            })
            .collect()
    }

    /// `n` points evenly spaced along arc length, root and tip included.
    pub fn resample(&self, n: usize) -> Vec<[f32; 3]> {
        self.resample_params(n).into_iter().map(|t| self.eval(t)).collect()
    }
}
