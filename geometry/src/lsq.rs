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
        let r0 = self.residuals()?;
        let mut jac = DMatrix::zeros(r0.len(), self.x.len());
        let mut x = self.x.clone();
        for j in 0..x.len() {
            let h = 1e-6 * (1.0 + self.x[j].abs());
            x[j] = self.x[j] + h;
            let plus = (self.residual_fn)(&x)?;
            x[j] = self.x[j] - h;
            let minus = (self.residual_fn)(&x)?;
            x[j] = self.x[j];
            jac.set_column(j, &((plus - minus) / (2.0 * h)));
        }
        jac.iter().all(|v| v.is_finite()).then_some(jac)
    }
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

    #[test]
    fn undefined_start_is_an_error() {
        assert!(minimize(DVector::from_vec(vec![1.0]), |_| None).is_err());
    }
}
