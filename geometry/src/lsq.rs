//! Nonlinear least squares through the `levenberg-marquardt` crate (a port of
//! MINPACK's `lmder`), with a central-difference Jacobian so that each solver
//! states only its residuals.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use crate::GeometryError;

/// What a minimisation did.
#[derive(Debug, Clone)]
pub struct Report {
    /// Residual function evaluations (not counting the Jacobian's).
    pub evaluations: usize,
    /// Final `0.5 * |r|^2`.
    pub objective: f64,
    /// The crate's termination reason, as text.
    pub termination: String,
}

struct NumericProblem<F> {
    residual_fn: F,
    x: DVector<f64>,
}

impl<F> LeastSquaresProblem<f64, Dyn, Dyn> for NumericProblem<F>
where
    F: Fn(&DVector<f64>) -> Option<DVector<f64>>,
{
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        (self.residual_fn)(&self.x).filter(|r| r.iter().all(|v| v.is_finite()))
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        jacobian(&self.x, &self.residual_fn)
    }
}

/// The central-difference Jacobian of `residual_fn` at `x`; `None` where the
/// model is undefined or the Jacobian is not finite.
pub fn jacobian<F>(x: &DVector<f64>, residual_fn: F) -> Option<DMatrix<f64>>
where
    F: Fn(&DVector<f64>) -> Option<DVector<f64>>,
{
    let r0 = residual_fn(x)?;
    let mut jac = DMatrix::zeros(r0.len(), x.len());
    let mut probe = x.clone();
    for j in 0..x.len() {
        let h = 1e-6 * (1.0 + x[j].abs());
        probe[j] = x[j] + h;
        let plus = residual_fn(&probe)?;
        probe[j] = x[j] - h;
        let minus = residual_fn(&probe)?;
        probe[j] = x[j];
        if plus.len() != r0.len() || minus.len() != r0.len() {
            return None;
        }
        jac.set_column(j, &((plus - minus) / (2.0 * h)));
    }
    jac.iter().all(|v| v.is_finite()).then_some(jac)
}

/// Relative singular value (of the column-scaled Jacobian) under which a
/// direction of the parameters counts as not determined by the data. The
/// Jacobian is by central differences, and an exact symmetry of the model
/// (two mirror planes turning together about their common line with the
/// arm's base) showed at 2e-8 there; a direction a million times weaker
/// than the strongest has a sigma a million times larger, which is no
/// determination either.
const RANK_TOLERANCE: f64 = 1e-6;

/// Share of a parameter (squared, of a unit step in it) lying in the null
/// space above which it counts as not determined.
const UNSEEN_SHARE: f64 = 1e-6;

/// The uncertainty of a least-squares solution: the Gauss-Newton covariance
/// `s^2 (J^T J)^-1`, with `s^2 = |r|^2 / (m - rank)` the residual variance,
/// or a prior variance where the fit has no redundancy (`m = rank`).
#[derive(Debug, Clone, PartialEq)]
pub struct Covariance {
    /// Covariance of the parameters, in their units. Rows and columns of
    /// [`Covariance::undetermined`] parameters are zero.
    pub matrix: DMatrix<f64>,
    /// `s^2`, the residual variance per residual (the prior's if
    /// `redundancy` is 0).
    pub residual_variance: f64,
    /// Residuals beyond the determined parameters, `m - rank`.
    pub redundancy: usize,
    /// Parameters the data do not determine: every parameter that takes
    /// part in a null direction of the Jacobian.
    pub undetermined: Vec<usize>,
}

impl Covariance {
    /// The 1-sigma value of parameter `i`, or `None` if it is undetermined.
    pub fn sigma(&self, i: usize) -> Option<f64> {
        (!self.undetermined.contains(&i)).then(|| self.matrix[(i, i)].max(0.0).sqrt())
    }
}

/// The covariance of the parameters at a solution, from the Jacobian and the
/// residuals there. Columns are scaled to unit norm before the SVD so that
/// parameters of different units (mm, rad) do not pass for rank deficiency;
/// null directions are dropped (pseudo-inverse) and named. With no
/// redundancy the residuals say nothing of the noise, and
/// `prior_variance` scales the result instead.
pub fn covariance(
    jacobian: &DMatrix<f64>,
    residuals: &DVector<f64>,
    prior_variance: f64,
) -> Result<Covariance, GeometryError> {
    let (m, n) = jacobian.shape();
    if residuals.len() != m {
        return Err(GeometryError::Degenerate(format!(
            "{} residuals for a Jacobian of {m} rows",
            residuals.len()
        )));
    }
    // A column negligible next to the largest (the residuals do not move
    // with that parameter; what is left is rounding) stays null rather than
    // being scaled up into a direction of noise.
    let largest_column = jacobian.column_iter().map(|c| c.norm()).fold(0.0, f64::max);
    let scale = DVector::from_iterator(
        n,
        jacobian.column_iter().map(|c| {
            if c.norm() > RANK_TOLERANCE * largest_column {
                1.0 / c.norm()
            } else {
                0.0
            }
        }),
    );
    // Padded to at least n rows so that the SVD has n directions: with
    // fewer residuals than parameters the missing ones are null.
    let mut scaled = DMatrix::zeros(m.max(n), n);
    scaled
        .view_mut((0, 0), (m, n))
        .copy_from(&(jacobian * DMatrix::from_diagonal(&scale)));
    let svd = scaled.svd(false, true);
    let v_t = svd
        .v_t
        .ok_or(GeometryError::NonFinite("covariance decomposition"))?;
    let largest = svd.singular_values.max();
    let mut inverse = DMatrix::zeros(n, n);
    // How much of each parameter lies in the null space.
    let mut unseen = DVector::<f64>::zeros(n);
    let mut rank = 0;
    for (k, &value) in svd.singular_values.iter().enumerate() {
        let direction = v_t.row(k).transpose();
        if value > RANK_TOLERANCE * largest && value > 0.0 {
            rank += 1;
            inverse += &direction * direction.transpose() / (value * value);
        } else {
            unseen += direction.map(|v| v * v);
        }
    }
    // A parameter with any part in a null direction is not determined,
    // and neither is whatever it trades off against.
    let undetermined: Vec<usize> = (0..n).filter(|&i| unseen[i] > UNSEEN_SHARE).collect();
    let redundancy = m.saturating_sub(rank);
    let residual_variance = if redundancy == 0 {
        prior_variance
    } else {
        residuals.norm_squared() / redundancy as f64
    };
    let scale = DMatrix::from_diagonal(&scale);
    let mut matrix = &scale * inverse * &scale * residual_variance;
    for &i in &undetermined {
        matrix.row_mut(i).fill(0.0);
        matrix.column_mut(i).fill(0.0);
    }
    if !matrix.iter().all(|v| v.is_finite()) {
        return Err(GeometryError::NonFinite("parameter covariance"));
    }
    Ok(Covariance {
        matrix,
        residual_variance,
        redundancy,
        undetermined,
    })
}

/// Minimises `|residual_fn(x)|^2` from `x0`. `residual_fn` returns `None`
/// where the model is undefined (e.g. a point at zero depth); the optimiser
/// then backs off. Fails if the start is undefined or the result is not finite.
pub fn minimize<F>(
    x0: DVector<f64>,
    residual_fn: F,
) -> Result<(DVector<f64>, Report), GeometryError>
where
    F: Fn(&DVector<f64>) -> Option<DVector<f64>>,
{
    let problem = NumericProblem { residual_fn, x: x0 };
    if problem.residuals().is_none() {
        return Err(GeometryError::Degenerate(
            "the model is undefined at the initial estimate".into(),
        ));
    }
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    match report.termination {
        TerminationReason::Numerical(what) | TerminationReason::User(what) => {
            return Err(GeometryError::Degenerate(format!(
                "least squares failed: {what}"
            )));
        }
        TerminationReason::NoParameters
        | TerminationReason::NoResiduals
        | TerminationReason::WrongDimensions(_) => {
            return Err(GeometryError::Degenerate(format!(
                "least squares misuse: {:?}",
                report.termination
            )));
        }
        _ => {}
    }
    let x = problem.x;
    if !(x.iter().all(|v| v.is_finite()) && report.objective_function.is_finite()) {
        return Err(GeometryError::NonFinite("least-squares solution"));
    }
    Ok((
        x,
        Report {
            evaluations: report.number_of_evaluations,
            objective: report.objective_function,
            termination: format!("{:?}", report.termination),
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential_exactly() {
        let ts: Vec<f64> = (0..20).map(|i| f64::from(i) * 0.1).collect();
        let data: Vec<f64> = ts.iter().map(|t| 2.5 * (-1.3 * t).exp()).collect();
        let (x, report) = minimize(DVector::from_vec(vec![1.0, -0.5]), |p| {
            Some(DVector::from_iterator(
                ts.len(),
                ts.iter()
                    .zip(&data)
                    .map(|(t, y)| p[0] * (p[1] * t).exp() - y),
            ))
        })
        .unwrap();
        assert!(
            (x[0] - 2.5).abs() < 1e-9 && (x[1] + 1.3).abs() < 1e-9,
            "{x} {report:?}"
        );
    }

    /// A straight line fitted to noisy points: the covariance is the
    /// textbook one, and over many draws the errors divided by the stated
    /// sigmas have the RMS of a Student-t.
    #[test]
    fn a_line_fits_covariance_matches_the_textbook_and_the_spread() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let xs: Vec<f64> = (0..30).map(|i| f64::from(i) * 0.5).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.3).unwrap();
        let (mut z_slope, mut z_icpt) = (0.0, 0.0);
        let draws = 1500;
        for _ in 0..draws {
            let ys: Vec<f64> = xs
                .iter()
                .map(|x| 1.5 * x - 2.0 + noise.sample(&mut rng))
                .collect();
            let residual_fn = |p: &DVector<f64>| {
                Some(DVector::from_iterator(
                    xs.len(),
                    xs.iter().zip(&ys).map(|(x, y)| p[0] * x + p[1] - y),
                ))
            };
            let (p, _) = minimize(DVector::zeros(2), residual_fn).unwrap();
            let cov = covariance(
                &jacobian(&p, residual_fn).unwrap(),
                &residual_fn(&p).unwrap(),
                1.0,
            )
            .unwrap();
            // Textbook: var(slope) = s^2 / sum (x - mean)^2.
            let mean = xs.iter().sum::<f64>() / xs.len() as f64;
            let sxx: f64 = xs.iter().map(|x| (x - mean).powi(2)).sum();
            let textbook = cov.residual_variance / sxx;
            assert!((cov.matrix[(0, 0)] / textbook - 1.0).abs() < 1e-6);
            z_slope += ((p[0] - 1.5) / cov.sigma(0).unwrap()).powi(2);
            z_icpt += ((p[1] + 2.0) / cov.sigma(1).unwrap()).powi(2);
        }
        for z in [z_slope, z_icpt] {
            let rms = (z / f64::from(draws)).sqrt();
            // With s^2 estimated from 28 degrees of freedom the normalised
            // error is Student-t: its RMS is sqrt(28 / 26) = 1.038.
            assert!((0.97..1.11).contains(&rms), "normalised RMS {rms}");
        }
    }

    #[test]
    fn a_parameter_the_data_do_not_see_is_named() {
        // p[2] does not enter the model; p[0] and p[1] only as their sum
        // and difference with different weights.
        let residual_fn = |p: &DVector<f64>| {
            Some(DVector::from_vec(vec![
                p[0] + p[1] - 1.0,
                p[0] - p[1] - 0.5,
                2.0 * p[0] - 1.6,
                p[1] - 0.2,
            ]))
        };
        let p = DVector::from_vec(vec![0.8, 0.2, 7.0]);
        let cov = covariance(
            &jacobian(&p, residual_fn).unwrap(),
            &residual_fn(&p).unwrap(),
            1.0,
        )
        .unwrap();
        assert_eq!(cov.undetermined, vec![2]);
        assert_eq!(cov.sigma(2), None);
        assert!(cov.sigma(0).unwrap() > 0.0 && cov.sigma(1).unwrap() > 0.0);
    }

    #[test]
    fn parameters_seen_only_together_are_both_undetermined() {
        // Only p[0] + p[1] is seen; p[2] is well determined.
        let residual_fn = |p: &DVector<f64>| {
            Some(DVector::from_vec(vec![
                p[0] + p[1] - 1.0,
                2.0 * (p[0] + p[1]) - 2.1,
                p[2] - 0.3,
                p[2] - 0.32,
            ]))
        };
        let p = DVector::from_vec(vec![0.5, 0.52, 0.31]);
        let cov = covariance(
            &jacobian(&p, residual_fn).unwrap(),
            &residual_fn(&p).unwrap(),
            1.0,
        )
        .unwrap();
        assert_eq!(cov.undetermined, vec![0, 1]);
        assert!(cov.sigma(2).unwrap() > 0.0);
        // Fewer residuals than parameters: the rest are null directions.
        let short = |p: &DVector<f64>| Some(DVector::from_vec(vec![p[0] - 1.0, p[1] - 2.0]));
        let q = DVector::from_vec(vec![1.0, 2.0, 0.0]);
        let cov = covariance(&jacobian(&q, short).unwrap(), &short(&q).unwrap(), 1.0).unwrap();
        assert_eq!(cov.undetermined, vec![2]);
    }

    #[test]
    fn with_no_redundancy_the_prior_scales_it() {
        let residual_fn = |p: &DVector<f64>| Some(DVector::from_vec(vec![2.0 * p[0] - 1.0]));
        let p = DVector::from_vec(vec![0.5]);
        let cov = covariance(
            &jacobian(&p, residual_fn).unwrap(),
            &residual_fn(&p).unwrap(),
            4.0,
        )
        .unwrap();
        assert_eq!(cov.redundancy, 0);
        assert!((cov.matrix[(0, 0)] - 1.0).abs() < 1e-9, "4 / 2^2");
    }

    #[test]
    fn undefined_start_is_an_error() {
        assert!(minimize(DVector::from_vec(vec![1.0]), |_| None).is_err());
    }
}
