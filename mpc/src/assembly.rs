//! The matrices of a conic program, written row by row in a fixed order (so the sparsity
//! never changes and only values are updated), in the states and inputs (sparse) or, with
//! a [`Condensing`], rewritten in the inputs alone.

use crate::layout::Layout;
use clarabel::algebra::CscMatrix;
use nalgebra::{DMatrix, DVector, Matrix4};

/// The rows of `A` and `b`, written in a fixed order; buffers are reused between steps.
/// Rows are given in stage-wise columns ([`Layout::z`], [`Layout::v`]); with a
/// [`Condensing`] they are rewritten in the inputs as they are appended.
#[derive(Debug, Default)]
pub struct Assembly {
    /// `(row, column, value)` of every structural entry of `A`, in a fixed order.
    pub entries: Vec<(usize, usize, f64)>,
    pub b: Vec<f64>,
    /// The objective's linear term `q` (empty: zero).
    pub q: Vec<f64>,
    /// Set for the condensed formulation.
    pub condensing: Option<Condensing>,
}

impl Assembly {
    /// Appends the row `sum(value * x[column]) + s = b`.
    pub fn row(&mut self, terms: impl IntoIterator<Item = (usize, f64)>, b: f64) {
        let r = self.b.len();
        let b = match &mut self.condensing {
            Some(condensing) => condensing.rewrite(r, terms, b, &mut self.entries),
            None => {
                self.entries
                    .extend(terms.into_iter().map(|(c, v)| (r, c, v)));
                b
            }
        };
        self.b.push(b);
    }

    /// Adds `value` to the objective's linear term at each stage-wise `column` (rewritten
    /// in the inputs when condensed: `T' q`). The term is written even when `terms` is
    /// empty, so a solver that tracked a reference before is given zeros.
    pub fn add_linear_cost(&mut self, l: &Layout, terms: &[(usize, f64)]) {
        if self.q.len() < l.base_variables() {
            self.q.resize(l.base_variables(), 0.0);
        }
        match &self.condensing {
            Some(condensing) => {
                for &(column, value) in terms {
                    let inputs = condensing.forced_transposed.column(column);
                    for (q, t) in self.q.iter_mut().zip(inputs.iter()) {
                        *q += value * t;
                    }
                }
            }
            None => {
                for &(column, value) in terms {
                    self.q[column] += value;
                }
            }
        }
    }
}

/// The states as affine functions of the inputs (eq. 52 rolled out): the stage-wise
/// vector is `T v + F z_0`, `z_i = A^i z_0 + sum_{j<i} A^(i-1-j) B v_j`. Rewrites rows
/// and the objective of the sparse formulation in the inputs `v` alone.
#[derive(Debug, Clone)]
pub struct Condensing {
    /// `T'` (inputs x stage-wise), so that each stage-wise column is contiguous.
    forced_transposed: DMatrix<f64>,
    /// `F` (stage-wise x 4).
    free: DMatrix<f64>,
    /// Upper triangle of `T' P T`, the objective's quadratic term in the inputs.
    hessian: CscMatrix<f64>,
    /// `G = T' P F`: the objective's linear term is `G z_0`.
    gradient_map: DMatrix<f64>,
    /// `F z_0` of the current step.
    free_response: DVector<f64>,
    /// Scratch for one row: its coefficients on the inputs and which are structural.
    coefficients: Vec<f64>,
    structural: Vec<bool>,
}

impl Condensing {
    /// `stagewise_hessian`: the upper triangle of the sparse formulation's `P`.
    pub fn new(
        l: &Layout,
        (forced, free): (DMatrix<f64>, DMatrix<f64>),
        stagewise_hessian: &CscMatrix<f64>,
    ) -> Condensing {
        let (rows, nv) = (l.stagewise(), 2 * l.horizon);
        let mut p = DMatrix::zeros(rows, rows);
        for col in 0..rows {
            for k in stagewise_hessian.colptr[col]..stagewise_hessian.colptr[col + 1] {
                let row = stagewise_hessian.rowval[k];
                p[(row, col)] = stagewise_hessian.nzval[k];
                p[(col, row)] = stagewise_hessian.nzval[k];
            }
        }
        let p_forced = &p * &forced;
        let hessian = forced.transpose() * &p_forced;
        let entries: Vec<(usize, usize, f64)> = (0..nv)
            .flat_map(|c| (0..=c).map(move |r| (r, c)))
            .map(|(r, c)| (r, c, hessian[(r, c)]))
            .filter(|e| e.2 != 0.0)
            .collect();
        Condensing {
            gradient_map: p_forced.transpose() * &free,
            forced_transposed: forced.transpose(),
            free,
            hessian: csc_with_positions(nv, nv, &entries).0,
            free_response: DVector::zeros(rows),
            coefficients: vec![0.0; nv],
            structural: vec![false; nv],
        }
    }

    /// Upper triangle of the objective's quadratic term in the inputs.
    pub fn hessian(&self) -> &CscMatrix<f64> {
        &self.hessian
    }

    /// Sets the step's `z_0`, and writes the objective's linear term `G z_0` into `q`.
    pub fn set_initial_state(&mut self, z0: [f64; 4], q: &mut Vec<f64>) {
        let z0 = nalgebra::Vector4::from(z0);
        self.free_response.gemv(1.0, &self.free, &z0, 0.0);
        q.resize(self.gradient_map.nrows(), 0.0);
        for (r, q) in q.iter_mut().enumerate() {
            *q = (0..4).map(|c| self.gradient_map[(r, c)] * z0[c]).sum();
        }
    }

    /// Appends to `entries` the row `sum(value * x_stagewise[column]) + s = b`, in the
    /// inputs, and returns its right-hand side `b - sum(value * (F z_0)[column])`.
    /// The structure comes from `T` alone, so it is the same every step.
    fn rewrite(
        &mut self,
        row: usize,
        terms: impl IntoIterator<Item = (usize, f64)>,
        b: f64,
        entries: &mut Vec<(usize, usize, f64)>,
    ) -> f64 {
        let mut b = b;
        let stagewise = self.free_response.len();
        for (column, value) in terms {
            if column >= stagewise {
                // A variable after the states and inputs (a decay slack, the stop
                // speed): it follows the inputs.
                entries.push((row, self.coefficients.len() + column - stagewise, value));
                continue;
            }
            b -= value * self.free_response[column];
            for (j, &t) in self.forced_transposed.column(column).iter().enumerate() {
                if t != 0.0 {
                    self.coefficients[j] += value * t;
                    self.structural[j] = true;
                }
            }
        }
        for j in 0..self.coefficients.len() {
            if std::mem::take(&mut self.structural[j]) {
                entries.push((row, j, std::mem::take(&mut self.coefficients[j])));
            }
        }
        b
    }

    /// The stage-wise vector `T v + F z_0` of the inputs `v` (the step's `z_0`).
    pub fn expand(&self, v: &[f64], stagewise: &mut [f64]) {
        for (r, out) in stagewise.iter_mut().enumerate() {
            *out = self.free_response[r]
                + v.iter()
                    .enumerate()
                    .map(|(j, v)| self.forced_transposed[(j, r)] * v)
                    .sum::<f64>();
        }
    }
}

/// Compressed-column matrix of `entries`, and for each entry its position in `nzval`
/// (so later values can be scattered into the same pattern).
pub fn csc_with_positions(
    rows: usize,
    cols: usize,
    entries: &[(usize, usize, f64)],
) -> (CscMatrix<f64>, Vec<usize>) {
    let mut order: Vec<usize> = (0..entries.len()).collect();
    order.sort_by_key(|&t| (entries[t].1, entries[t].0));
    let mut colptr = vec![0usize; cols + 1];
    let mut rowval = Vec::with_capacity(entries.len());
    let mut nzval = Vec::with_capacity(entries.len());
    let mut position = vec![0usize; entries.len()];
    for (nz, &t) in order.iter().enumerate() {
        let (r, c, v) = entries[t];
        colptr[c + 1] += 1;
        rowval.push(r);
        nzval.push(v);
        position[t] = nz;
    }
    for c in 0..cols {
        colptr[c + 1] += colptr[c];
    }
    (CscMatrix::new(rows, cols, colptr, rowval, nzval), position)
}

/// Upper triangle of the solver's `P`: the sparse formulation's, or its condensed form.
pub fn solver_hessian<'a>(
    assembly: &'a Assembly,
    stagewise: &'a CscMatrix<f64>,
) -> &'a CscMatrix<f64> {
    match &assembly.condensing {
        Some(condensing) => condensing.hessian(),
        None => stagewise,
    }
}

/// `p` with empty rows and columns appended up to `n`: the decay slacks and the terminal
/// rows' variables have no quadratic cost.
pub fn padded(p: &CscMatrix<f64>, n: usize) -> CscMatrix<f64> {
    let mut colptr = p.colptr.clone();
    colptr.resize(n + 1, p.nnz());
    CscMatrix::new(n, n, colptr, p.rowval.clone(), p.nzval.clone())
}

/// Upper triangle of `P` with `1/2 x'Px` = eq. (51),
/// `sum z_i'Q z_i + v_i'R v_i + z_N' Q_bar z_N`, on the stage-wise variables.
pub fn stagewise_hessian(
    l: &Layout,
    q_diag: [f64; 4],
    r_diag: [f64; 2],
    terminal_weight: &Matrix4<f64>,
) -> CscMatrix<f64> {
    let n = l.horizon;
    let mut entries = Vec::new();
    for i in 0..n {
        for (c, q) in q_diag.iter().enumerate() {
            entries.push((l.z(i, c), l.z(i, c), 2.0 * q));
        }
    }
    for c in 0..4 {
        for r in 0..=c {
            entries.push((l.z(n, r), l.z(n, c), 2.0 * terminal_weight[(r, c)]));
        }
    }
    for i in 0..n {
        for (c, r) in r_diag.iter().enumerate() {
            entries.push((l.v(i, c), l.v(i, c), 2.0 * r));
        }
    }
    csc_with_positions(l.stagewise(), l.stagewise(), &entries).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csc_positions_point_at_each_entry() {
        let entries = [(2, 1, 5.0), (0, 0, 1.0), (1, 1, 3.0), (0, 2, 7.0)];
        let (m, pos) = csc_with_positions(3, 3, &entries);
        for (t, &(_, _, v)) in entries.iter().enumerate() {
            assert_eq!(m.nzval[pos[t]], v);
        }
        assert_eq!(m.colptr, vec![0, 1, 3, 4]);
    }
}
