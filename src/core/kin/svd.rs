//! Singular value decomposition of a small task Jacobian (m ≤ 6 rows, n ≤ 8 columns) by one-sided
//! Jacobi rotations (Hestenes), on the stack, with a fixed sweep cap so its cost per tick is bounded.
//!
//! Why not nalgebra's SVD: this one is generic over the row count at run time (6-D pose and 5-D
//! printing tasks share it), computes tiny singular values to high *relative* accuracy (which is what
//! the singularity damping and the manipulability gradient look at), and can start from the previous
//! tick's left vectors, which makes it converge in one or two sweeps while the arm moves smoothly.
//! The result does not depend on the start, beyond the last bits; the controller always passes the
//! same start for the same history, so replay stays bit-exact.

use super::model::MAX_JOINTS;

/// Largest task dimension.
pub(crate) const MAX_TASK: usize = 6;

/// J = Σ_k σ_k u_k v_kᵀ, k < m, with σ sorted from largest to smallest.
#[derive(Clone, Copy, Debug)]
pub struct Svd {
    /// Rows of the decomposed matrix (task dimension).
    pub m: usize,
    /// Columns (joints).
    pub n: usize,
    /// Singular values, descending; entries ≥ m are 0.
    pub sigma: [f64; MAX_TASK],
    /// Left singular vectors: `u[k]` is u_k (length m).
    pub u: [[f64; MAX_TASK]; MAX_TASK],
    /// Right singular vectors: `v[k]` is v_k (length n); zero where σ_k = 0.
    pub v: [[f64; MAX_JOINTS]; MAX_TASK],
    /// Jacobi sweeps used.
    pub sweeps: u32,
}

/// Sweep cap: one-sided Jacobi converges quadratically, and 6 × 8 problems from a cold start need
/// 5–7 sweeps; 30 is never reached in practice but bounds the tick.
const MAX_SWEEPS: u32 = 30;

/// Dot product with four partial sums in a fixed order: the same bits on every run, and a quarter of
/// the dependency chain of a plain left-to-right sum, which is what bounds the Jacobi sweep.
#[inline]
fn dot(a: &[f64; MAX_JOINTS], b: &[f64; MAX_JOINTS]) -> f64 {
    let mut s = [0.0; 4];
    for k in 0..MAX_JOINTS {
        s[k % 4] += a[k] * b[k];
    }
    (s[0] + s[2]) + (s[1] + s[3])
}

/// The identity start for [`svd`].
pub fn identity_start() -> [[f64; MAX_TASK]; MAX_TASK] {
    let mut w = [[0.0; MAX_TASK]; MAX_TASK];
    for (k, row) in w.iter_mut().enumerate() {
        row[k] = 1.0;
    }
    w
}

/// |x| = |2γ / (β − α)| below which a rotation's angle comes from its series ([`rotation`]).
const SMALL_ANGLE: f64 = 1e-4;

/// |x| below which, for every pair, a sweep takes all its angles at once from the same columns (a
/// Jacobi–Newton step, which leaves off-diagonal terms of the order of x²): the warm-started ticks of
/// a moving arm, whose first sweep sees x ≈ 1e-4 and whose second ≈ 1e-8.
const SIMULTANEOUS: f64 = 1e-2;

/// The order of the column pairs in a sweep, per m: a round-robin tournament (the circle method), so
/// that the pairs of a round touch disjoint columns. In the row-cyclic order (0,1), (0,2), … every
/// rotation waits for the last one's square roots and divisions; here the three rotations of a round
/// are independent and the processor overlaps them (about a third of the sweep's latency at m = 6).
/// Convergence is the same (every pair once a sweep, quadratic once near diagonal).
const PAIR_ORDERS: [[(u8, u8); 15]; MAX_TASK + 1] = {
    let mut orders = [[(0u8, 0u8); 15]; MAX_TASK + 1];
    let mut m = 2;
    while m <= MAX_TASK {
        // An even number of players, one of them a dummy when m is odd.
        let players = m + m % 2;
        let mut count = 0;
        let mut round = 0;
        while round < players - 1 {
            let mut i = 0;
            while i < players / 2 {
                let a = if i == 0 { players - 1 } else { (round + i) % (players - 1) };
                let b = (round + players - 1 - i) % (players - 1);
                if a < m && b < m {
                    orders[m][count] = if a < b { (a as u8, b as u8) } else { (b as u8, a as u8) };
                    count += 1;
                }
                i += 1;
            }
            round += 1;
        }
        m += 1;
    }
    orders
};

/// Whether columns with squared norms α, β and inner product γ are not yet orthogonal to working
/// precision (the one-sided Jacobi criterion |γ| ≤ 1e-15·√(αβ), which keeps small singular values
/// accurate relative to themselves).
#[inline]
fn needs_rotation(alpha: f64, beta: f64, gamma: f64) -> bool {
    gamma != 0.0 && gamma.abs() > 1e-15 * (alpha * beta).sqrt()
}

/// The rotation that makes two columns orthogonal: (tan θ, cos θ).
/// tan θ = sgn ζ / (|ζ| + √(1 + ζ²)) with ζ = (β − α) / 2γ (Rutishauser's choice, |θ| ≤ π/4), i.e.
/// t = x / (1 + √(1 + x²)) with x = sgn(β − α)·2γ / |β − α|, and cos θ = 1 / √(1 + t²).
#[inline]
fn rotation(alpha: f64, beta: f64, gamma: f64) -> (f64, f64) {
    let tau = beta - alpha;
    let two_gamma = if tau >= 0.0 { 2.0 * gamma } else { -2.0 * gamma };
    let (t, c) = if two_gamma.abs() < SMALL_ANGLE * tau.abs() {
        // A small rotation, as every one is near convergence or from the last tick's vectors: the
        // series t = x/2 − x³/8 and cos θ = 1 − t²/2 are exact to rounding for |x| < 1e-4 (the next
        // terms, x⁵/16 and 3t⁴/8, are below half an ulp) and save two square roots and a division.
        let x = two_gamma / tau.abs();
        let t = 0.5 * x - 0.125 * x * x * x;
        (t, 1.0 - 0.5 * t * t)
    } else {
        let t = two_gamma / (tau.abs() + (tau * tau + two_gamma * two_gamma).sqrt());
        (t, 1.0 / (1.0 + t * t).sqrt())
    };
    (t, c)
}

/// Rotates columns p and q of B and of W by (c, s), over their whole fixed length (the entries past
/// n in B and past m in W are zero and stay so).
#[inline(always)]
fn rotate_pair(b: &mut [[f64; MAX_JOINTS]; MAX_TASK], w: &mut [[f64; MAX_TASK]; MAX_TASK], p: usize, q: usize, c: f64, s: f64) {
    for j in 0..MAX_JOINTS {
        let (x, y) = (b[p][j], b[q][j]);
        b[p][j] = c * x - s * y;
        b[q][j] = s * x + c * y;
    }
    for r in 0..MAX_TASK {
        let (x, y) = (w[p][r], w[q][r]);
        w[p][r] = c * x - s * y;
        w[q][r] = s * x + c * y;
    }
}

/// Decomposes the m × n matrix whose rows are `rows[..m]` (entries past n must be 0).
/// `start` is an orthogonal m × m matrix (columns `start[k]`) to begin from: the identity, or the
/// left vectors `u` of a previous, nearby decomposition.
pub fn svd(rows: &[[f64; MAX_JOINTS]; MAX_TASK], m: usize, n: usize, start: &[[f64; MAX_TASK]; MAX_TASK]) -> Svd {
    debug_assert!(m <= MAX_TASK && n <= MAX_JOINTS);
    // Columns of Jᵀ W: b_k = Σ_r W[r][k] · row_r. Orthogonalising them gives Jᵀ W = V Σ, so J = W Σ Vᵀ.
    let mut w = *start;
    // Entries past m are zero (so rotating whole columns of W, a fixed length, changes nothing there).
    for column in w.iter_mut().take(m) {
        for x in column.iter_mut().skip(m) {
            *x = 0.0;
        }
    }
    let mut b = [[0.0; MAX_JOINTS]; MAX_TASK];
    for k in 0..m {
        for r in 0..m {
            let c = w[k][r];
            if c != 0.0 {
                for j in 0..MAX_JOINTS {
                    b[k][j] += c * rows[r][j];
                }
            }
        }
    }
    let mut norms = [0.0; MAX_TASK];
    for k in 0..m {
        norms[k] = dot(&b[k], &b[k]);
    }
    let mut sweeps = 0;
    let pairs = &PAIR_ORDERS[m][..m * m.saturating_sub(1) / 2];
    while sweeps < MAX_SWEEPS {
        sweeps += 1;
        // Every pair's inner product from the same columns: independent of each other, so the
        // processor computes them side by side.
        let mut gammas = [0.0; 15];
        for (g, &(p, q)) in gammas.iter_mut().zip(pairs) {
            *g = dot(&b[p as usize], &b[q as usize]);
        }
        let (mut rotate, mut near_diagonal) = (false, true);
        for (&gamma, &(p, q)) in gammas.iter().zip(pairs) {
            let (alpha, beta) = (norms[p as usize], norms[q as usize]);
            if needs_rotation(alpha, beta, gamma) {
                rotate = true;
                near_diagonal &= 2.0 * gamma.abs() < SIMULTANEOUS * (beta - alpha).abs();
            }
        }
        if !rotate {
            break;
        }
        if near_diagonal {
            // Every angle from the columns as they were (a Jacobi–Newton step): the rotations are
            // still exact, so J = W·Bᵀ holds, and what the stale angles leave off the diagonal is of
            // the order of the angles squared, for the next pass. The angles' divisions and roots are
            // independent of each other here, not one chain through the sweep.
            let mut angles = [(1.0, 0.0); 15];
            for ((angle, &gamma), &(p, q)) in angles.iter_mut().zip(&gammas).zip(pairs) {
                let (alpha, beta) = (norms[p as usize], norms[q as usize]);
                if needs_rotation(alpha, beta, gamma) {
                    let (t, c) = rotation(alpha, beta, gamma);
                    *angle = (c, t);
                }
            }
            for (&(c, t), &(p, q)) in angles.iter().zip(pairs) {
                if t != 0.0 {
                    rotate_pair(&mut b, &mut w, p as usize, q as usize, c, c * t);
                }
            }
            for k in 0..m {
                norms[k] = dot(&b[k], &b[k]);
            }
        } else {
            // Far from diagonal (a cold start): the classic sweep, each angle from the columns as the
            // last rotation left them.
            for &(p, q) in pairs {
                let (p, q) = (p as usize, q as usize);
                let (alpha, beta) = (norms[p], norms[q]);
                let gamma = dot(&b[p], &b[q]);
                if !needs_rotation(alpha, beta, gamma) {
                    continue;
                }
                let (t, c) = rotation(alpha, beta, gamma);
                rotate_pair(&mut b, &mut w, p, q, c, c * t);
                // The rotation moves t·γ of squared norm from column p to column q (Hestenes); the
                // exact norms are taken again at the end, so drift cannot reach the singular values.
                norms[p] = alpha - t * gamma;
                norms[q] = beta + t * gamma;
            }
        }
    }
    for k in 0..m {
        norms[k] = dot(&b[k], &b[k]);
    }
    let mut out = Svd { m, n, sigma: [0.0; MAX_TASK], u: [[0.0; MAX_TASK]; MAX_TASK], v: [[0.0; MAX_JOINTS]; MAX_TASK], sweeps };
    // Sort by descending σ (insertion sort over at most 6 entries; ties keep their order).
    let mut order = [0usize, 1, 2, 3, 4, 5];
    for i in 1..m {
        let mut k = i;
        while k > 0 && norms[order[k - 1]] < norms[order[k]] {
            order.swap(k - 1, k);
            k -= 1;
        }
    }
    for (dst, &src) in order[..m].iter().enumerate() {
        let s = norms[src].sqrt();
        out.sigma[dst] = s;
        out.u[dst] = w[src];
        if s > 0.0 {
            for j in 0..n {
                out.v[dst][j] = b[src][j] / s;
            }
        }
    }
    out
}

impl Svd {
    /// Smallest singular value σ_{m−1}.
    #[inline]
    pub fn sigma_min(&self) -> f64 {
        if self.m == 0 { 0.0 } else { self.sigma[self.m - 1] }
    }

    /// Yoshikawa manipulability √det(J Jᵀ) = Π σ_k.
    #[inline]
    pub fn manipulability(&self) -> f64 {
        self.sigma[..self.m].iter().product()
    }

    /// Condition number σ_max / σ_min (∞ at a singularity).
    pub fn condition(&self) -> f64 {
        if self.sigma_min() > 0.0 { self.sigma[0] / self.sigma_min() } else { f64::INFINITY }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reconstruct(s: &Svd, r: usize, c: usize) -> f64 {
        (0..s.m).map(|k| s.sigma[k] * s.u[k][r] * s.v[k][c]).sum()
    }

    /// Every pair once a sweep, and the pairs of a round (m / 2 in a row, rounded down) disjoint.
    #[test]
    fn the_pair_order_is_a_round_robin() {
        for m in 2..=MAX_TASK {
            let pairs = &PAIR_ORDERS[m][..m * (m - 1) / 2];
            let mut seen = [[false; MAX_TASK]; MAX_TASK];
            for &(p, q) in pairs {
                assert!(p < q && (q as usize) < m, "m = {m}: {p}, {q}");
                assert!(!seen[p as usize][q as usize], "m = {m}: ({p}, {q}) twice");
                seen[p as usize][q as usize] = true;
            }
            for round in pairs.chunks(m / 2) {
                let mut used = [false; MAX_TASK];
                for &(p, q) in round {
                    assert!(!used[p as usize] && !used[q as usize], "m = {m}: round {round:?} shares a column");
                    used[p as usize] = true;
                    used[q as usize] = true;
                }
            }
        }
    }

    #[test]
    fn decomposes_a_known_matrix() {
        let mut rows = [[0.0; MAX_JOINTS]; MAX_TASK];
        let mut seed = 12345u64;
        for r in rows.iter_mut() {
            for x in r.iter_mut().take(7) {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                *x = ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
            }
        }
        for m in [5, 6] {
            let s = svd(&rows, m, 7, &identity_start());
            for r in 0..m {
                for c in 0..7 {
                    assert!((reconstruct(&s, r, c) - rows[r][c]).abs() < 1e-14);
                }
            }
            for a in 0..m {
                for b in 0..m {
                    let uu: f64 = (0..m).map(|r| s.u[a][r] * s.u[b][r]).sum();
                    let vv: f64 = (0..7).map(|j| s.v[a][j] * s.v[b][j]).sum();
                    let e = if a == b { 1.0 } else { 0.0 };
                    assert!((uu - e).abs() < 1e-14 && (vv - e).abs() < 1e-14);
                }
            }
            for k in 1..m {
                assert!(s.sigma[k - 1] >= s.sigma[k]);
            }
            // Warm start from the result converges at once.
            let again = svd(&rows, m, 7, &s.u);
            assert!(again.sweeps <= 2, "{}", again.sweeps);
            for k in 0..m {
                assert!((again.sigma[k] - s.sigma[k]).abs() < 1e-14);
            }
        }
    }

    #[test]
    fn rank_deficient_has_zero_singular_value_and_no_nan() {
        let mut rows = [[0.0; MAX_JOINTS]; MAX_TASK];
        rows[0][0] = 1.0;
        rows[1][1] = 2.0;
        rows[2] = rows[0]; // duplicate row
        let s = svd(&rows, 3, 2, &identity_start());
        assert_eq!(s.sigma[2], 0.0);
        assert!((s.sigma[0] - 2.0).abs() < 1e-15 && (s.sigma[1] - 2f64.sqrt()).abs() < 1e-15);
        assert!(s.v.iter().flatten().all(|x| x.is_finite()));
    }
}
