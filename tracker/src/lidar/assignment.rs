//! A global assignment of groups to tracks: the pairing of least total cost among those
//! with the most pairs within the gate (the Hungarian method in its shortest augmenting
//! path form, O(rows^2 columns)), in buffers kept between scans.

/// Cost of a pair outside the gate: larger than any sum of gated costs, so the method
/// pairs as many within the gate as it can before it weighs their costs.
const OUTSIDE: f64 = 1e9;

/// The assignment's buffers, sized once for `rows` by `columns` at most.
#[derive(Debug, Clone)]
pub struct Assignment {
    cost: Vec<f64>,
    columns: usize,
    /// Potentials of the rows and the columns, the row of each column (0: none), the
    /// column before each on the augmenting path, the least reduced cost to each column.
    row_potential: Vec<f64>,
    column_potential: Vec<f64>,
    row_of: Vec<usize>,
    way: Vec<usize>,
    least: Vec<f64>,
    used: Vec<bool>,
}

impl Assignment {
    /// Buffers for up to `rows` by `columns` costs.
    pub fn with_capacity(rows: usize, columns: usize) -> Assignment {
        let n = rows.max(columns) + 1;
        Assignment {
            cost: Vec::with_capacity(rows * columns),
            columns: 0,
            row_potential: Vec::with_capacity(n),
            column_potential: Vec::with_capacity(n),
            row_of: Vec::with_capacity(n),
            way: Vec::with_capacity(n),
            least: Vec::with_capacity(n),
            used: Vec::with_capacity(n),
        }
    }

    /// Pairs `rows` rows with `columns` columns, where `cost(r, c)` is `None` outside the
    /// gate; hands `pair(r, c)` every pair within it.
    pub fn solve(
        &mut self,
        rows: usize,
        columns: usize,
        cost: impl Fn(usize, usize) -> Option<f64>,
        mut pair: impl FnMut(usize, usize),
    ) {
        if rows == 0 || columns == 0 {
            return;
        }
        // The method wants no more rows than columns: transpose otherwise.
        let transposed = rows > columns;
        let (n, m) = if transposed {
            (columns, rows)
        } else {
            (rows, columns)
        };
        self.cost.clear();
        self.columns = m;
        for i in 0..n {
            for j in 0..m {
                let c = if transposed { cost(j, i) } else { cost(i, j) };
                self.cost.push(c.unwrap_or(OUTSIDE));
            }
        }
        self.hungarian(n, m);
        for j in 1..=m {
            let i = self.row_of[j];
            if i == 0 || self.cost[(i - 1) * m + (j - 1)] >= OUTSIDE {
                continue;
            }
            if transposed {
                pair(j - 1, i - 1);
            } else {
                pair(i - 1, j - 1);
            }
        }
    }

    /// The method on the `n` by `m` costs (`n <= m`), indices from 1.
    fn hungarian(&mut self, n: usize, m: usize) {
        let reset = |v: &mut Vec<f64>, len: usize| {
            v.clear();
            v.resize(len, 0.0);
        };
        reset(&mut self.row_potential, n + 1);
        reset(&mut self.column_potential, m + 1);
        self.row_of.clear();
        self.row_of.resize(m + 1, 0);
        self.way.clear();
        self.way.resize(m + 1, 0);
        for i in 1..=n {
            self.row_of[0] = i;
            let mut column = 0;
            self.least.clear();
            self.least.resize(m + 1, f64::INFINITY);
            self.used.clear();
            self.used.resize(m + 1, false);
            loop {
                self.used[column] = true;
                let row = self.row_of[column];
                let (mut delta, mut next) = (f64::INFINITY, 0);
                for j in 1..=m {
                    if self.used[j] {
                        continue;
                    }
                    let reduced = self.cost[(row - 1) * self.columns + (j - 1)]
                        - self.row_potential[row]
                        - self.column_potential[j];
                    if reduced < self.least[j] {
                        self.least[j] = reduced;
                        self.way[j] = column;
                    }
                    if self.least[j] < delta {
                        delta = self.least[j];
                        next = j;
                    }
                }
                for j in 0..=m {
                    if self.used[j] {
                        self.row_potential[self.row_of[j]] += delta;
                        self.column_potential[j] -= delta;
                    } else {
                        self.least[j] -= delta;
                    }
                }
                column = next;
                if self.row_of[column] == 0 {
                    break;
                }
            }
            while column != 0 {
                let before = self.way[column];
                self.row_of[column] = self.row_of[before];
                column = before;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(costs: &[&[Option<f64>]]) -> Vec<(usize, usize)> {
        let rows = costs.len();
        let columns = costs[0].len();
        let mut assignment = Assignment::with_capacity(rows, columns);
        let mut found = Vec::new();
        assignment.solve(rows, columns, |r, c| costs[r][c], |r, c| found.push((r, c)));
        found.sort();
        found
    }

    #[test]
    fn the_assignment_is_global_where_a_greedy_one_would_take_the_cheapest_pair_first() {
        // Greedy takes (0, 0) at 1 and leaves row 1 with 10: 11. The best is 2 + 3 = 5.
        let costs: [&[Option<f64>]; 2] = [&[Some(1.0), Some(2.0)], &[Some(3.0), Some(10.0)]];
        assert_eq!(pairs(&costs), [(0, 1), (1, 0)]);
    }

    #[test]
    fn pairs_outside_the_gate_are_never_made_and_rows_or_columns_may_go_unpaired() {
        let costs: [&[Option<f64>]; 3] = [&[None, Some(0.5)], &[None, Some(0.1)], &[None, None]];
        assert_eq!(pairs(&costs), [(1, 1)]);
        let wide: [&[Option<f64>]; 1] = [&[Some(4.0), None, Some(1.0)]];
        assert_eq!(pairs(&wide), [(0, 2)]);
    }
}
