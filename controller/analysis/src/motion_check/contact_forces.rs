//! The ground forces that carry a motion: the wrench the floating base needs, split over the sole
//! points in contact, each force inside its friction cone — a small second-order-cone program per
//! frame (Clarabel). Where the feet cannot carry the wrench (a body pulled up, leaning beyond its
//! feet, moving in the air other than falling), the residual says by how much.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};

/// Weight of the forces' own size against the wrench error: small, so that among the splits that
/// carry the wrench exactly the smallest forces (spread over every point) win.
const SPREAD: f64 = 1e-4;

/// The split of one frame's base wrench.
#[derive(Debug, Clone, PartialEq)]
pub struct Split {
    /// Force at each contact point, world frame, N.
    pub forces: Vec<[f64; 3]>,
    /// What the forces leave of the base's six generalised forces (free joint: world-frame force,
    /// N; body-frame moment, N·m).
    pub residual: [f64; 6],
}

/// Splits the base's generalised forces `wrench` over contact points. `columns[3·i + axis]` is
/// what a unit force along world `axis` at point `i` adds to the base's six generalised forces;
/// `friction` is the points' Coulomb coefficient. No contact point: the whole wrench is residual.
pub fn split(columns: &[[f64; 6]], wrench: [f64; 6], friction: f64) -> Split {
    let n = columns.len();
    let points = n / 3;
    if points == 0 {
        return Split {
            forces: Vec::new(),
            residual: wrench,
        };
    }
    // ½ fᵀPf + qᵀf with P = 2(AᵀA + εI), q = −2Aᵀb: least squares on the wrench, plus spread.
    let dot = |a: &[f64; 6], b: &[f64; 6]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut colptr = Vec::with_capacity(n + 1);
    let (mut rowval, mut nzval) = (Vec::new(), Vec::new());
    colptr.push(0);
    for j in 0..n {
        for i in 0..=j {
            let mut v = 2.0 * dot(&columns[i], &columns[j]);
            if i == j {
                v += 2.0 * SPREAD;
            }
            rowval.push(i);
            nzval.push(v);
        }
        colptr.push(rowval.len());
    }
    let p = CscMatrix::new(n, n, colptr, rowval, nzval);
    let q: Vec<f64> = columns.iter().map(|c| -2.0 * dot(c, &wrench)).collect();
    // Cone of each point: s = (μ f_z, f_x, f_y) in the second-order cone, s = −A f.
    let mut colptr = Vec::with_capacity(n + 1);
    let (mut rowval, mut nzval) = (Vec::new(), Vec::new());
    colptr.push(0);
    for j in 0..n {
        let (point, axis) = (j / 3, j % 3);
        let (row, value) = match axis {
            0 => (1, -1.0),
            1 => (2, -1.0),
            _ => (0, -friction),
        };
        rowval.push(3 * point + row);
        nzval.push(value);
        colptr.push(rowval.len());
    }
    let a = CscMatrix::new(n, n, colptr, rowval, nzval);
    let b = vec![0.0; n];
    let cones = vec![SupportedConeT::SecondOrderConeT(3); points];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(100)
        .build()
        .expect("the settings are complete");
    let solved = DefaultSolver::new(&p, &q, &a, &b, &cones, settings)
        .ok()
        .and_then(|mut solver| {
            solver.solve();
            matches!(
                solver.solution.status,
                SolverStatus::Solved | SolverStatus::AlmostSolved
            )
            .then(|| solver.solution.x.clone())
        });
    let x = solved.unwrap_or_else(|| vec![0.0; n]);
    let mut residual = wrench;
    for (c, f) in columns.iter().zip(&x) {
        for (r, v) in residual.iter_mut().zip(c) {
            *r -= v * f;
        }
    }
    Split {
        forces: x.chunks_exact(3).map(|f| [f[0], f[1], f[2]]).collect(),
        residual,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Columns of a point at `(x, y, 0)` for a base at the origin whose wrench is (force, moment
    /// about the origin), both in the world frame.
    fn columns(points: &[[f64; 2]]) -> Vec<[f64; 6]> {
        let mut out = Vec::new();
        for p in points {
            let r = [p[0], p[1], 0.0];
            for axis in 0..3 {
                let mut f = [0.0; 3];
                f[axis] = 1.0;
                let m = [
                    r[1] * f[2] - r[2] * f[1],
                    r[2] * f[0] - r[0] * f[2],
                    r[0] * f[1] - r[1] * f[0],
                ];
                out.push([f[0], f[1], f[2], m[0], m[1], m[2]]);
            }
        }
        out
    }

    #[test]
    fn a_weight_between_two_feet_is_shared_by_its_lever() {
        // 100 N held 0.05 m from the left foot and 0.15 m from the right: 75 N and 25 N.
        let c = columns(&[[0.0, 0.1], [0.0, -0.1]]);
        let s = split(&c, [0.0, 0.0, 100.0, 100.0 * 0.05, 0.0, 0.0], 0.8);
        assert!((s.forces[0][2] - 75.0).abs() < 0.5, "{:?}", s.forces);
        assert!((s.forces[1][2] - 25.0).abs() < 0.5, "{:?}", s.forces);
        assert!(s.residual.iter().all(|r| r.abs() < 0.5), "{:?}", s.residual);
    }

    #[test]
    fn feet_cannot_pull_or_slide_beyond_friction() {
        let c = columns(&[[0.0, 0.0]]);
        // Pulled up: no force, the whole wrench is left over.
        let up = split(&c, [0.0, 0.0, -50.0, 0.0, 0.0, 0.0], 0.8);
        assert!(
            up.forces[0][2].abs() < 0.5 && (up.residual[2] + 50.0).abs() < 0.5,
            "{up:?}"
        );
        // Pushed sideways harder than friction allows: the cone's edge, the rest left over.
        let side = split(&c, [100.0, 0.0, 100.0, 0.0, 0.0, 0.0], 0.5);
        let [fx, fy, fz] = side.forces[0];
        assert!((fx * fx + fy * fy).sqrt() <= 0.5 * fz + 0.5, "{side:?}");
        assert!(side.residual[0] > 20.0, "{side:?}");
    }
}
