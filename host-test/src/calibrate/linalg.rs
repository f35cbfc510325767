//! Small linear-algebra helpers over `nalgebra`: Levenberg–Marquardt, Wahba/Procrustes, polar decomposition.

use nalgebra::{DMatrix, DVector, Dyn, Matrix3, SVD, SymmetricEigen, U3, Vector3};

use super::{Mat3, Vec3};

/// `[[f64; 3]; 3]` (row-major) to a `Matrix3`.
pub fn mat3(m: &Mat3) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| m[r][c])
}

/// A `Matrix3` to `[[f64; 3]; 3]` (row-major).
pub fn arr3(m: &Matrix3<f64>) -> Mat3 {
    core::array::from_fn(|r| core::array::from_fn(|c| m[(r, c)]))
}

/// `[f64; 3]` to a `Vector3`.
pub fn vec3(v: &Vec3) -> Vector3<f64> {
    Vector3::new(v[0], v[1], v[2])
}

/// A `Vector3` to `[f64; 3]`.
pub fn arrv(v: &Vector3<f64>) -> Vec3 {
    [v[0], v[1], v[2]]
}

/// Iteration limit of the SVD and eigen decompositions (they never loop forever on bad input).
const MAX_NITER: usize = 1000;

/// SVD of a finite 3×3 matrix, `None` when it is not finite or the iteration does not converge.
pub fn svd3(m: Matrix3<f64>) -> Option<SVD<f64, U3, U3>> {
    if !m.iter().all(|x| x.is_finite()) {
        return None;
    }
    SVD::try_new(m, true, true, f64::EPSILON, MAX_NITER)
}

/// SVD of a finite dynamic matrix, `None` when it is not finite or the iteration does not converge.
pub fn svd(m: DMatrix<f64>, vectors: bool) -> Option<SVD<f64, Dyn, Dyn>> {
    if !m.iter().all(|x| x.is_finite()) {
        return None;
    }
    SVD::try_new(m, vectors, vectors, f64::EPSILON, MAX_NITER)
}

/// Rotation `R` (det +1) minimising `Σ w_k |R·from_k − to_k|²` (Wahba's problem, SVD solution). `None` when the
/// vectors do not determine a rotation (fewer than two independent directions) or are not finite.
pub fn wahba(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
    let b: Matrix3<f64> = from
        .iter()
        .zip(to)
        .fold(Matrix3::zeros(), |acc, (f, t)| acc + t * f.transpose());
    if !b.iter().all(|x| x.is_finite()) {
        return None;
    }
    let svd = svd3(b)?;
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    let mut sv: Vec<f64> = s.iter().copied().collect();
    sv.sort_by(|a, b| b.total_cmp(a));
    if sv[0] <= 0.0 || sv[1] <= 1e-9 * sv[0] {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t;
    Some(r)
}

/// Polar decomposition `m = R·P`, `R` a rotation, `P` symmetric; `None` when `m` is singular or not finite.
/// (For `det m < 0`, `R` is still a rotation and `P` has a negative eigenvalue.)
pub fn polar(m: &Matrix3<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    if !m.iter().all(|x| x.is_finite()) {
        return None;
    }
    let svd = svd3(*m)?;
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    if s.min() <= 1e-12 * s.max() {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    let dm = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    let r = u * dm * v_t;
    let p = r.transpose() * m;
    Some((r, (p + p.transpose()) * 0.5))
}

/// Symmetric positive-definite square root; `None` when `q` is not positive definite.
pub fn sqrt_spd(q: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let sym = (q + q.transpose()) * 0.5;
    if !sym.iter().all(|x| x.is_finite()) {
        return None;
    }
    let eig = SymmetricEigen::try_new(sym, f64::EPSILON, MAX_NITER)?;
    if eig.eigenvalues.iter().any(|&l| l <= 0.0) {
        return None;
    }
    let d = Matrix3::from_diagonal(&eig.eigenvalues.map(f64::sqrt));
    Some(eig.eigenvectors * d * eig.eigenvectors.transpose())
}

/// Angle between two vectors, radians (robust near 0 and π).
pub fn angle(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b))
}

/// Result of [`levenberg_marquardt`].
#[derive(Clone, Debug)]
pub struct LmResult {
    /// Parameters at the end.
    pub x: DVector<f64>,
    /// `½ Σ r²` at `x`.
    pub cost: f64,
    /// Iterations done.
    pub iterations: usize,
    /// The last Jacobian (at `x`).
    pub jacobian: DMatrix<f64>,
}

/// Levenberg–Marquardt with Marquardt's diagonal scaling. `eval(x)` returns residuals and Jacobian; `retract`
/// applies a step (plain addition, or a renormalisation for parameters on a manifold). Stops when the relative
/// decrease of the cost falls below `1e-14`, the step below `1e-12` relative, or after `max_iter` iterations.
/// Returns `None` only when the first evaluation is not finite.
pub fn levenberg_marquardt(
    x0: DVector<f64>,
    eval: impl Fn(&DVector<f64>) -> (DVector<f64>, DMatrix<f64>),
    retract: impl Fn(&DVector<f64>, &DVector<f64>) -> DVector<f64>,
    max_iter: usize,
) -> Option<LmResult> {
    let finite = |r: &DVector<f64>| r.iter().all(|v| v.is_finite());
    let mut x = x0;
    let (mut r, mut j) = eval(&x);
    if !finite(&r) || !j.iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut cost = 0.5 * r.norm_squared();
    let mut lambda = 1e-3;
    let mut it = 0;
    while it < max_iter {
        it += 1;
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let n = jtj.nrows();
        let diag_max = (0..n).map(|i| jtj[(i, i)]).fold(0.0, f64::max).max(1e-300);
        let mut improved = false;
        for _ in 0..30 {
            let mut a = jtj.clone();
            for i in 0..n {
                a[(i, i)] += lambda * jtj[(i, i)] + 1e-12 * diag_max;
            }
            if !a.iter().all(|v| v.is_finite()) {
                break;
            }
            let step = match a.clone().cholesky() {
                Some(ch) => ch.solve(&(-&g)),
                None => match svd(a, true).map(|s| s.solve(&(-&g), 1e-14)) {
                    Some(Ok(s)) => s,
                    _ => break,
                },
            };
            let xn = retract(&x, &step);
            let (rn, jn) = eval(&xn);
            let cn = 0.5 * rn.norm_squared();
            if finite(&rn) && cn <= cost {
                let rel = (cost - cn) / cost.max(1e-300);
                let small_step = step.norm() <= 1e-12 * (x.norm() + 1e-12);
                x = xn;
                r = rn;
                j = jn;
                cost = cn;
                lambda = (lambda / 3.0).max(1e-12);
                improved = true;
                if rel < 1e-14 || small_step {
                    return Some(LmResult {
                        x,
                        cost,
                        iterations: it,
                        jacobian: j,
                    });
                }
                break;
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                break;
            }
        }
        if !improved {
            break;
        }
    }
    Some(LmResult {
        x,
        cost,
        iterations: it,
        jacobian: j,
    })
}

/// Singular values of `j` divided by the largest (ascending); empty for an empty matrix.
pub fn relative_singular_values(j: &DMatrix<f64>) -> Vec<f64> {
    if j.is_empty() {
        return Vec::new();
    }
    let Some(svd) = svd(j.clone(), false) else {
        return vec![0.0];
    };
    let s = svd.singular_values;
    let max = s.max();
    let mut v: Vec<f64> = s.iter().map(|x| x / max.max(1e-300)).collect();
    v.sort_by(f64::total_cmp);
    v
}
