//! The task the TCP must follow — the full 6-D pose, or the 5-D printing task — and the task's
//! Yoshikawa manipulability with its analytic gradient.
//!
//! The printing task leaves the rotation about the nozzle axis free (004 Section II-A: printing is a
//! redundant task). Its Jacobian keeps the three linear rows and projects the angular rows onto the
//! two tool axes perpendicular to the nozzle (TCP x and y, with z along the nozzle):
//! J₅ = [J_v; b₁ᵀJ_ω; b₂ᵀJ_ω], b_k = R_BT e_k. √det(J₅J₅ᵀ) does not depend on which perpendicular pair
//! is used, so it is the manipulability of the 5-D task itself.
//!
//! Gradient: ∂w/∂q_i = w · tr(J⁺ ∂J/∂q_i) (from ∂ det M = det M · tr(M⁻¹ ∂M), M = JJᵀ), with ∂J/∂q_i the
//! kinematic Hessian slice of [`ChainState::jacobian_derivative`] plus, for the 5-D task, the turning
//! of b_k (∂b_k/∂q_i = ω_i × b_k). w·J⁺ = Σ_k (Π_{l≠k} σ_l) v_k u_kᵀ stays bounded as σ → 0, so the
//! gradient has no NaN at or near a singularity. The Hessian contraction is rearranged with the
//! triple-product identity into prefix and suffix sums, so it costs O(n) cross products, not O(n²).

use nalgebra::Vector3;

use super::fk::ChainState;
use super::model::{JointVector, MAX_JOINTS};
use super::svd::{MAX_TASK, Svd, identity_start, svd};

/// Which components of the TCP pose the arm must follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Task {
    /// Position and full orientation (6-D).
    Pose6,
    /// Position and nozzle direction; rotation about the nozzle axis (TCP z) is free (5-D).
    Print5,
}

impl Task {
    /// Number of task rows m.
    #[inline]
    pub(crate) fn dim(self) -> usize {
        match self {
            Task::Pose6 => 6,
            Task::Print5 => 5,
        }
    }
}

/// The m × n task Jacobian, stored by rows, with the angular row directions it used.
#[derive(Clone, Copy, Debug)]
pub struct TaskJacobian {
    /// The task.
    pub task: Task,
    /// Rows (task dimension).
    pub m: usize,
    /// Columns (joints).
    pub n: usize,
    /// Row r of the task Jacobian (entries past n are 0). Units: m per joint unit for rows 0–2, rad per
    /// joint unit for the rest.
    pub rows: [[f64; MAX_JOINTS]; MAX_TASK],
    /// Unit directions in the base frame onto which rows 3.. project the angular velocity.
    pub basis: [Vector3<f64>; 3],
}

impl TaskJacobian {
    /// The task Jacobian of `task` at the configuration `state` was computed for.
    pub fn new(state: &ChainState, task: Task) -> Self {
        let r = state.tcp.rotation.matrix();
        let basis = match task {
            Task::Pose6 => [Vector3::x(), Vector3::y(), Vector3::z()],
            Task::Print5 => [r.column(0).into_owned(), r.column(1).into_owned(), Vector3::zeros()],
        };
        let m = task.dim();
        let mut rows = [[0.0; MAX_JOINTS]; MAX_TASK];
        for j in 0..state.n {
            let (lin, ang) = (state.lin(j), state.ang(j));
            rows[0][j] = lin.x;
            rows[1][j] = lin.y;
            rows[2][j] = lin.z;
            for k in 0..m - 3 {
                rows[3 + k][j] = basis[k].dot(&ang);
            }
        }
        TaskJacobian { task, m, n: state.n, rows, basis }
    }

    /// Projects a 6-D quantity (linear part, angular part) onto the task rows.
    #[inline]
    pub fn project(&self, lin: &Vector3<f64>, ang: &Vector3<f64>) -> [f64; MAX_TASK] {
        let mut out = [0.0; MAX_TASK];
        out[0] = lin.x;
        out[1] = lin.y;
        out[2] = lin.z;
        for k in 0..self.m - 3 {
            out[3 + k] = self.basis[k].dot(ang);
        }
        out
    }

    /// Zeroes column `j` (a joint taken out of the solve).
    #[inline]
    pub(crate) fn remove_column(&mut self, j: usize) {
        for row in self.rows.iter_mut() {
            row[j] = 0.0;
        }
    }

    /// SVD from a cold start.
    pub fn svd(&self) -> Svd {
        svd(&self.rows, self.m, self.n, &identity_start())
    }
}

/// Manipulability √det(J Jᵀ) of `task` at `state`.
pub fn manipulability(state: &ChainState, task: Task) -> f64 {
    TaskJacobian::new(state, task).svd().manipulability()
}

/// ∂w/∂q (per rad or per m) of the task manipulability w, given the task Jacobian and its SVD.
pub fn manipulability_gradient(state: &ChainState, tj: &TaskJacobian, s: &Svd) -> JointVector {
    let (m, n) = (tj.m, tj.n);
    // c_k = Π_{l≠k} σ_l, so that w·J⁺ = Σ_k c_k v_k u_kᵀ without dividing by σ.
    let mut c = [0.0; MAX_TASK];
    for (k, ck) in c.iter_mut().enumerate().take(m) {
        *ck = (0..m).filter(|&l| l != k).map(|l| s.sigma[l]).product();
    }
    // a[j][r] = (w J⁺)[j][r]; split into the linear weight lv_j and the angular weight lw_j = Σ_k a[j][3+k] b_k.
    let mut lv = [Vector3::zeros(); MAX_JOINTS];
    let mut lw = [Vector3::zeros(); MAX_JOINTS];
    // g_k = Σ_j a[j][3+k] J_ω,j, for the turning of b_k in the 5-D task.
    let mut g = [Vector3::zeros(); 3];
    for j in 0..n {
        let mut a = [0.0; MAX_TASK];
        for k in 0..m {
            let ck_vkj = c[k] * s.v[k][j];
            if ck_vkj != 0.0 {
                for (r, ar) in a.iter_mut().enumerate().take(m) {
                    *ar += ck_vkj * s.u[k][r];
                }
            }
        }
        lv[j] = Vector3::new(a[0], a[1], a[2]);
        let ang = state.ang(j);
        for k in 0..m - 3 {
            lw[j] += tj.basis[k] * a[3 + k];
            g[k] += ang * a[3 + k];
        }
    }
    // Turning-basis term: Σ_k (ω_i × b_k)·g_k = ω_i · h with h = Σ_k b_k × g_k (zero for the 6-D task,
    // whose basis is fixed).
    let mut h = Vector3::zeros();
    if tj.task == Task::Print5 {
        for k in 0..m - 3 {
            h += tj.basis[k].cross(&g[k]);
        }
    }
    // grad_i = Σ_j lv_j·(ω_min(i,j) × v_max(i,j)) + Σ_{j>i} lw_j·(ω_i × ω_j) + ω_i·h
    //        = ω_i·(Σ_{j≥i} v_j × lv_j + Σ_{j>i} ω_j × lw_j + h) + v_i·(Σ_{j<i} lv_j × ω_j).
    let mut suffix = [Vector3::zeros(); MAX_JOINTS + 1];
    for j in (0..n).rev() {
        suffix[j] = suffix[j + 1] + state.lin(j).cross(&lv[j]) + state.ang(j).cross(&lw[j]);
    }
    let mut grad = JointVector::zeros();
    let mut prefix = Vector3::zeros();
    for i in 0..n {
        let (vi, wi) = (state.lin(i), state.ang(i));
        // suffix[i] holds ω_i × lw_i, which is not part of Σ_{j>i}; ω_i·(ω_i × lw_i) = 0, so it drops out.
        grad[i] = wi.dot(&(suffix[i] + h)) + vi.dot(&prefix);
        prefix += lv[i].cross(&wi);
    }
    grad
}
