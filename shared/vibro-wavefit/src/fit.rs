//! The model's free parameters fitted to the readings: weighted least squares over
//! every used reading of every run, Levenberg-Marquardt (Gauss-Newton with damping).
//!
//! - **Nuisance.** Each run and unit has its own offset and slope (a bias that differs
//!   from turn-on to turn-on and drifts): projected out of the residual and of the
//!   Jacobian's columns per run and unit (variable projection: exact for parameters
//!   that enter linearly). What the vibration changes is then measured against the
//!   run's own still parts, as MODEL.md section 8's shaker measurement does.
//! - **Derivatives** where they are cheap ([`crate::eval`]): a path or chain parameter
//!   through the linear response alone (central differences of a fold), an output
//!   effect's through the grid pass alone (forward differences, the signals reused).
//!   The rectified part's dependence on a path parameter (1e-4 of its linear
//!   response) is left out of the Jacobian: Gauss-Newton then solves `J~^T W r = 0`
//!   with `J~` within 1e-4 of `J`, an unbiased estimating equation whose root differs
//!   from the least-squares one by far less than its uncertainty, and the covariance
//!   below is that equation's.
//! - **Uncertainty.** The residual is not white: the sensors' noise reaches every
//!   prediction through the mount's resonance and the boxcar, correlated over several
//!   readings and across units. The covariance is the sandwich `A^-1 B A^-1` with `B`
//!   summed over blocks of `block_readings` consecutive readings of all units (a
//!   heteroscedasticity- and autocorrelation-consistent estimate): it states the
//!   scatter over repeats whether or not the noise is white (tested by pulls over
//!   repeated draws).

use crate::eval::{self, Built, Role, Signals};
use crate::prepare::PreparedRun;
use crate::{Error, Result};
use serde::Serialize;

/// A parameter the fit moves.
#[derive(Debug, Clone, Serialize)]
pub struct FreeParam {
    /// The effect's kind, or `sensor_chain` for the delay.
    pub kind: String,
    /// Its key in the effect's table (`delay_s` for the delay).
    pub name: String,
    /// Index of its effect in the problem's tables; `None` for the delay.
    pub effect: Option<usize>,
    /// Its typical magnitude (steps and damping are scaled by it).
    pub scale: f64,
    pub bounds: (f64, f64),
    pub role: Role,
}

/// The model under test: `[[effect]]` tables, the delay, and which values are free.
#[derive(Debug, Clone)]
pub struct Problem {
    pub tables: Vec<toml::Table>,
    pub delay_s: f64,
    pub free: Vec<FreeParam>,
}

impl Problem {
    /// The tables and delay at `x` (one value per free parameter).
    pub fn at(&self, x: &[f64]) -> (Vec<toml::Table>, f64) {
        let mut tables = self.tables.clone();
        let mut delay = self.delay_s;
        for (p, &v) in self.free.iter().zip(x) {
            match p.effect {
                Some(e) => {
                    if let Some(t) = tables.get_mut(e) {
                        t.insert(p.name.clone(), toml::Value::Float(v));
                    }
                }
                None => delay = v,
            }
        }
        (tables, delay)
    }

    /// The current values of the free parameters (from the tables and delay).
    pub fn values(&self) -> Vec<f64> {
        self.free
            .iter()
            .map(|p| match p.effect {
                Some(e) => self
                    .tables
                    .get(e)
                    .and_then(|t| t.get(&p.name))
                    .and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)))
                    .unwrap_or(0.0),
                None => self.delay_s,
            })
            .collect()
    }
}

/// Per unit, the noise of a reading's residual, g (weights `1 / sigma^2`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Noise {
    pub sigma_g: [f64; 3],
    /// Where it came from: the quiet readings (the sensors' and the readings' own noise,
    /// independent of the model's fit under vibration) or the fit's own residual.
    pub from_quiet: bool,
}

/// How a fit runs.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FitSettings {
    pub max_iterations: usize,
    /// Readings per block of the sandwich covariance and the lack-of-fit test.
    pub block_readings: usize,
    pub threads: usize,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            max_iterations: 30,
            block_readings: 64,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }
}

/// One run's prediction, and its derivatives by the free parameters.
pub struct RunEval {
    /// Per reading, each unit's predicted reading, g (NaN where not evaluated).
    pub pred_g: Vec<[f64; 3]>,
    pub jac: Vec<Vec<[f64; 3]>>,
    /// The parts of the prediction (for a caller that holds `rest` fixed).
    pub rest_g: Vec<[f64; 3]>,
}

/// Whether a parameter point's `rest` is computed or taken as given (the cheap
/// objective of a path effect's multi-start: its rectified part barely moves).
#[derive(Clone, Copy)]
pub enum Rest<'a> {
    Compute,
    Fixed(&'a [Vec<[f64; 3]>]),
}

fn step(p: &FreeParam, x: f64) -> f64 {
    let h = 1e-4 * p.scale.abs().max(1e-12);
    // Stay inside the bounds.
    h.min(0.5 * (p.bounds.1 - p.bounds.0)).max(1e-15) * if x + h > p.bounds.1 { -1.0 } else { 1.0 }
}

/// Evaluates one run at `x`, with the Jacobian when `jacobian`.
pub fn eval_run(
    run: &PreparedRun,
    problem: &Problem,
    x: &[f64],
    jacobian: bool,
    rest: Option<&[[f64; 3]]>,
) -> Result<RunEval> {
    let (tables, delay) = problem.at(x);
    let mut built = Built::new(&tables, &run.passports, delay)?;
    let stat = eval::static_part(run);
    let linear = eval::linear_part(run, &built)?;
    let mut sig: Option<std::sync::Arc<Signals>> = None;
    let rest_g: Vec<[f64; 3]> = match rest {
        Some(r) => r.to_vec(),
        None => {
            let s = eval::signals_cached(run, &tables, &built)?;
            let r = eval::rest_part(run, &s, &mut built);
            sig = Some(s);
            r
        }
    };
    let pred_g: Vec<[f64; 3]> = (0..run.j)
        .map(|r| std::array::from_fn(|u| stat[r][u] + linear[r][u] + rest_g[r][u]))
        .collect();
    let mut jac = Vec::new();
    if jacobian {
        for (q, p) in problem.free.iter().enumerate() {
            let h = step(p, x[q]);
            let mut xp = x.to_vec();
            xp[q] += h;
            let (tp, dp) = problem.at(&xp);
            let col: Vec<[f64; 3]> = match p.role {
                Role::Path => {
                    // Forward differences: the linear response is smooth in its
                    // parameters, and an O(h) = 1e-4 relative error in a Jacobian column
                    // moves Gauss-Newton's steps, not its fixed point.
                    let lp = eval::linear_part(run, &Built::new(&tp, &run.passports, dp)?)?;
                    lp.iter()
                        .zip(&linear)
                        .map(|(a, b)| std::array::from_fn(|u| (a[u] - b[u]) / h))
                        .collect()
                }
                Role::Output => match &sig {
                    Some(s) => {
                        let mut bp = Built::new(&tp, &run.passports, dp)?;
                        let rp = eval::rest_part(run, s, &mut bp);
                        rp.iter()
                            .zip(&rest_g)
                            .map(|(a, b)| std::array::from_fn(|u| (a[u] - b[u]) / h))
                            .collect()
                    }
                    None => vec![[0.0; 3]; run.j],
                },
            };
            jac.push(col);
        }
    }
    Ok(RunEval {
        pred_g,
        jac,
        rest_g,
    })
}

/// Every run evaluated (on `threads` threads).
pub fn eval_all(
    runs: &[PreparedRun],
    problem: &Problem,
    x: &[f64],
    jacobian: bool,
    rest: Rest<'_>,
    threads: usize,
) -> Result<Vec<RunEval>> {
    let threads = threads.clamp(1, runs.len().max(1));
    let mut out: Vec<Option<Result<RunEval>>> = (0..runs.len()).map(|_| None).collect();
    std::thread::scope(|scope| {
        let chunks: Vec<_> = out.chunks_mut(runs.len().div_ceil(threads)).collect();
        let mut start = 0;
        for chunk in chunks {
            let first = start;
            start += chunk.len();
            scope.spawn(move || {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    let i = first + k;
                    let r = match rest {
                        Rest::Compute => None,
                        Rest::Fixed(f) => f.get(i).map(|v| v.as_slice()),
                    };
                    *slot = Some(eval_run(&runs[i], problem, x, jacobian, r));
                }
            });
        }
    });
    out.into_iter()
        .map(|o| o.unwrap_or_else(|| Err(Error::Numeric("a run was not evaluated".into()))))
        .collect()
}

/// The residual of every used reading with each run's and unit's offset and slope
/// projected out, and the same projection of the Jacobian's columns.
pub struct Projected {
    /// Per run, per reading, per unit: the residual, g (NaN where the reading is not
    /// used).
    pub residual_g: Vec<Vec<[f64; 3]>>,
    /// Per run and unit, the offset (at the run's middle) and slope (g/s) taken out.
    pub nuisance: Vec<[(f64, f64); 3]>,
    /// Per run, per parameter, per reading, per unit.
    pub jac: Vec<Vec<Vec<[f64; 3]>>>,
}

/// Projects each run's residual and Jacobian on the complement of `[1, t]` per unit.
pub fn project(runs: &[PreparedRun], evals: Vec<RunEval>) -> Projected {
    let mut residual_g = Vec::with_capacity(runs.len());
    let mut nuisance = Vec::with_capacity(runs.len());
    let mut jac = Vec::with_capacity(runs.len());
    for (run, ev) in runs.iter().zip(evals) {
        let mut res: Vec<[f64; 3]> = (0..run.j)
            .map(|r| {
                std::array::from_fn(|u| {
                    if run.used[r] {
                        run.readings_g[r][u] - ev.pred_g[r][u]
                    } else {
                        f64::NAN
                    }
                })
            })
            .collect();
        let mut nu = [(0.0, 0.0); 3];
        let mut cols = ev.jac;
        for u in 0..3 {
            let idx: Vec<usize> = (0..run.j).filter(|&r| run.used[r]).collect();
            if idx.len() < 3 {
                continue;
            }
            let nf = idx.len() as f64;
            let tm = idx.iter().map(|&r| run.t_s[r]).sum::<f64>() / nf;
            let stt: f64 = idx.iter().map(|&r| (run.t_s[r] - tm).powi(2)).sum();
            let take = |v: &mut Vec<[f64; 3]>| -> (f64, f64) {
                let mean = idx.iter().map(|&r| v[r][u]).sum::<f64>() / nf;
                let slope = if stt > 0.0 {
                    idx.iter()
                        .map(|&r| (run.t_s[r] - tm) * v[r][u])
                        .sum::<f64>()
                        / stt
                } else {
                    0.0
                };
                for &r in &idx {
                    v[r][u] -= mean + slope * (run.t_s[r] - tm);
                }
                (mean, slope)
            };
            nu[u] = take(&mut res);
            for c in cols.iter_mut() {
                take(c);
            }
        }
        residual_g.push(res);
        nuisance.push(nu);
        jac.push(cols);
    }
    Projected {
        residual_g,
        nuisance,
        jac,
    }
}

/// Sums over the used readings: `chi2`, `A = J^T W J`, `g = J^T W r`, and per block
/// `g_b` (the sandwich's meat).
struct Normal {
    chi2: f64,
    a: Vec<Vec<f64>>,
    g: Vec<f64>,
    meat: Vec<Vec<f64>>,
    n: usize,
}

fn normal(runs: &[PreparedRun], pr: &Projected, noise: &Noise, block: usize) -> Normal {
    let p = pr.jac.first().map_or(0, |c| c.len());
    let w = noise.sigma_g.map(|s| 1.0 / (s * s));
    let mut nm = Normal {
        chi2: 0.0,
        a: vec![vec![0.0; p]; p],
        g: vec![0.0; p],
        meat: vec![vec![0.0; p]; p],
        n: 0,
    };
    for (ri, run) in runs.iter().enumerate() {
        let res = &pr.residual_g[ri];
        let cols = &pr.jac[ri];
        let mut gb = vec![0.0; p];
        for r in 0..run.j {
            if run.used[r] {
                for u in 0..3 {
                    let e = res[r][u];
                    nm.chi2 += w[u] * e * e;
                    nm.n += 1;
                    for a in 0..p {
                        let ja = cols[a][r][u];
                        nm.g[a] += w[u] * ja * e;
                        gb[a] += w[u] * ja * e;
                        for b in 0..=a {
                            nm.a[a][b] += w[u] * ja * cols[b][r][u];
                        }
                    }
                }
            }
            if (r + 1) % block == 0 || r + 1 == run.j {
                for a in 0..p {
                    for b in 0..p {
                        nm.meat[a][b] += gb[a] * gb[b];
                    }
                }
                gb.iter_mut().for_each(|x| *x = 0.0);
            }
        }
    }
    for a in 0..p {
        for b in 0..a {
            nm.a[b][a] = nm.a[a][b];
        }
    }
    nm
}

/// Solves `m x = b` by Gaussian elimination with partial pivoting; `None` if singular.
pub fn solve(m: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let mut a: Vec<Vec<f64>> = m
        .iter()
        .zip(b)
        .map(|(row, &v)| {
            let mut r = row.clone();
            r.push(v);
            r
        })
        .collect();
    for c in 0..n {
        let piv = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[piv][c].abs() <= 1e-300 || a[piv][c].is_nan() {
            return None;
        }
        a.swap(c, piv);
        for r in c + 1..n {
            let f = a[r][c] / a[c][c];
            for k in c..=n {
                a[r][k] -= f * a[c][k];
            }
        }
    }
    let mut x = vec![0.0; n];
    for c in (0..n).rev() {
        let s: f64 = (c + 1..n).map(|k| a[c][k] * x[k]).sum();
        x[c] = (a[c][n] - s) / a[c][c];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The inverse of a small symmetric positive matrix; `None` if singular.
pub fn invert(m: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = m.len();
    let cols: Option<Vec<Vec<f64>>> = (0..n)
        .map(|c| {
            let e: Vec<f64> = (0..n).map(|r| if r == c { 1.0 } else { 0.0 }).collect();
            solve(m, &e)
        })
        .collect();
    let cols = cols?;
    Some(
        (0..n)
            .map(|r| (0..n).map(|c| cols[c][r]).collect())
            .collect(),
    )
}

/// A fitted model.
#[derive(Debug, Clone, Serialize)]
pub struct Fit {
    pub params: Vec<FreeParam>,
    pub x: Vec<f64>,
    /// Standard uncertainties from the sandwich covariance.
    pub sigma: Vec<f64>,
    /// The same from `A^-1` alone (white noise of the stated level).
    pub sigma_white: Vec<f64>,
    pub correlation: Vec<Vec<f64>>,
    pub chi2: f64,
    /// Used readings times units.
    pub n: usize,
    pub noise: Noise,
    pub iterations: usize,
    pub evaluations: usize,
    pub converged: bool,
    /// The errors-in-variables step applied after convergence, per parameter
    /// (`eval::sensor_noise_chi2`).
    pub eiv_correction: Vec<f64>,
    /// Per run, per reading, per unit, the residual (NaN where not used).
    #[serde(skip)]
    pub residual_g: Vec<Vec<[f64; 3]>>,
    /// Per run, the rectified part at the fit (for a cheap objective around it).
    #[serde(skip)]
    pub rest_g: Vec<Vec<[f64; 3]>>,
}

/// [`evaluate`]'s result: chi2, the projected residuals, per run the rectified part.
pub type Evaluated = (f64, Projected, Vec<Vec<[f64; 3]>>);

/// Evaluates the model at `x` without fitting: residuals and chi2.
pub fn evaluate(
    runs: &[PreparedRun],
    problem: &Problem,
    x: &[f64],
    noise: &Noise,
    settings: &FitSettings,
    rest: Rest<'_>,
) -> Result<Evaluated> {
    let evals = eval_all(runs, problem, x, false, rest, settings.threads)?;
    let rest_g: Vec<Vec<[f64; 3]>> = evals.iter().map(|e| e.rest_g.clone()).collect();
    let pr = project(runs, evals);
    let nm = normal(runs, &pr, noise, settings.block_readings);
    Ok((nm.chi2, pr, rest_g))
}

/// Fits the free parameters from `x0` by Levenberg-Marquardt.
pub fn fit(
    runs: &[PreparedRun],
    problem: &Problem,
    x0: &[f64],
    noise: &Noise,
    settings: &FitSettings,
    rest: Rest<'_>,
) -> Result<Fit> {
    let p = problem.free.len();
    let clamp = |x: &mut Vec<f64>| {
        for (v, q) in x.iter_mut().zip(&problem.free) {
            *v = v.clamp(q.bounds.0, q.bounds.1);
        }
    };
    let mut x = x0.to_vec();
    clamp(&mut x);
    let mut evaluations = 0;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = p == 0;
    let (mut nm, mut pr, mut rest_g) = {
        let evals = eval_all(runs, problem, &x, true, rest, settings.threads)?;
        evaluations += 1;
        let rest_g: Vec<Vec<[f64; 3]>> = evals.iter().map(|e| e.rest_g.clone()).collect();
        let pr = project(runs, evals);
        (
            normal(runs, &pr, noise, settings.block_readings),
            pr,
            rest_g,
        )
    };
    while !converged && iterations < settings.max_iterations {
        iterations += 1;
        let mut damped = nm.a.clone();
        let top = (0..p).map(|i| nm.a[i][i]).fold(0.0f64, f64::max);
        for i in 0..p {
            // A parameter the evaluation does not move (an output effect's, with the
            // rectified part held) stays where it is.
            let floor = if nm.a[i][i] > 0.0 { 1e-12 * top } else { 1.0 };
            damped[i][i] +=
                lambda * nm.a[i][i].max(floor) + if nm.a[i][i] > 0.0 { 0.0 } else { 1.0 };
        }
        let Some(delta) = solve(&damped, &nm.g) else {
            lambda *= 10.0;
            if lambda > 1e10 {
                break;
            }
            continue;
        };
        let mut xt: Vec<f64> = x.iter().zip(&delta).map(|(a, d)| a + d).collect();
        clamp(&mut xt);
        let (chi2_t, _, _) = evaluate(runs, problem, &xt, noise, settings, rest)?;
        evaluations += 1;
        if chi2_t.is_finite() && chi2_t <= nm.chi2 {
            // Converged when no parameter moves by a fiftieth of its (white-noise)
            // uncertainty: far below what the sandwich states.
            let small = match invert(&nm.a) {
                Some(inv) => {
                    (0..p).all(|i| (xt[i] - x[i]).abs() <= 0.02 * inv[i][i].max(0.0).sqrt())
                }
                None => false,
            };
            let rel = (nm.chi2 - chi2_t) / nm.chi2.max(1e-300);
            x = xt;
            lambda = (lambda / 3.0).max(1e-9);
            let evals = eval_all(runs, problem, &x, true, rest, settings.threads)?;
            evaluations += 1;
            rest_g = evals.iter().map(|e| e.rest_g.clone()).collect();
            pr = project(runs, evals);
            nm = normal(runs, &pr, noise, settings.block_readings);
            if small || rel < 1e-9 {
                converged = true;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e10 {
                // No step lowers chi2: at the minimum to the model's precision.
                converged = true;
            }
        }
    }
    // Errors in variables (`eval::sensor_noise_chi2`): the step from the least-squares
    // root to the minimum of `chi2 - E(theta)`, `A^-1 grad(E) / 2`, over the path
    // parameters (E does not depend on the others).
    let mut eiv_correction = vec![0.0; p];
    if converged && matches!(rest, Rest::Compute) {
        if let (Some(inv), Ok(e0)) = (invert(&nm.a), noise_chi2(runs, problem, &x, noise)) {
            let mut grad = vec![0.0; p];
            for (q, par) in problem.free.iter().enumerate() {
                if par.role != Role::Path || e0 == 0.0 {
                    continue;
                }
                let h = step(par, x[q]);
                let mut xp = x.clone();
                xp[q] += h;
                if let Ok(e1) = noise_chi2(runs, problem, &xp, noise) {
                    grad[q] = (e1 - e0) / h;
                }
            }
            for i in 0..p {
                eiv_correction[i] = 0.5 * (0..p).map(|k| inv[i][k] * grad[k]).sum::<f64>();
            }
            if eiv_correction.iter().any(|d| *d != 0.0) {
                let mut xc: Vec<f64> = x.iter().zip(&eiv_correction).map(|(a, d)| a + d).collect();
                clamp(&mut xc);
                let evals = eval_all(runs, problem, &xc, true, rest, settings.threads)?;
                evaluations += 1;
                rest_g = evals.iter().map(|e| e.rest_g.clone()).collect();
                pr = project(runs, evals);
                nm = normal(runs, &pr, noise, settings.block_readings);
                x = xc;
            }
        }
    }
    let (sigma, sigma_white, correlation) = match invert(&nm.a) {
        Some(inv) => {
            let cov: Vec<Vec<f64>> = (0..p)
                .map(|i| {
                    (0..p)
                        .map(|j| {
                            (0..p)
                                .map(|a| {
                                    (0..p)
                                        .map(|b| inv[i][a] * nm.meat[a][b] * inv[b][j])
                                        .sum::<f64>()
                                })
                                .sum()
                        })
                        .collect()
                })
                .collect();
            let sigma: Vec<f64> = (0..p).map(|i| cov[i][i].max(0.0).sqrt()).collect();
            let corr = (0..p)
                .map(|i| {
                    (0..p)
                        .map(|j| cov[i][j] / (sigma[i] * sigma[j]).max(1e-300))
                        .collect()
                })
                .collect();
            (
                sigma,
                (0..p).map(|i| inv[i][i].max(0.0).sqrt()).collect(),
                corr,
            )
        }
        None => (
            vec![f64::INFINITY; p],
            vec![f64::INFINITY; p],
            vec![vec![f64::NAN; p]; p],
        ),
    };
    Ok(Fit {
        params: problem.free.clone(),
        x,
        sigma,
        sigma_white,
        correlation,
        chi2: nm.chi2,
        n: nm.n,
        noise: *noise,
        iterations,
        evaluations,
        converged,
        eiv_correction,
        residual_g: pr.residual_g,
        rest_g,
    })
}

/// `sum over runs of eval::sensor_noise_chi2` at `x`.
fn noise_chi2(runs: &[PreparedRun], problem: &Problem, x: &[f64], noise: &Noise) -> Result<f64> {
    let (tables, delay) = problem.at(x);
    let w = noise.sigma_g.map(|s| 1.0 / (s * s));
    let mut total = 0.0;
    for run in runs {
        let built = Built::new(&tables, &run.passports, delay)?;
        total += eval::sensor_noise_chi2(run, &built, w)?;
    }
    Ok(total)
}

/// The noise of each unit's residual: from the quiet readings when the runs have
/// enough of them (at least 200 per unit), else from every used reading.
pub fn noise_of(runs: &[PreparedRun], residual_g: &[Vec<[f64; 3]>]) -> Noise {
    let collect = |quiet: bool| -> [(f64, usize); 3] {
        std::array::from_fn(|u| {
            let mut s = 0.0;
            let mut n = 0;
            for (run, res) in runs.iter().zip(residual_g) {
                for r in 0..run.j {
                    if run.used[r] && (!quiet || run.quiet[r]) && res[r][u].is_finite() {
                        s += res[r][u] * res[r][u];
                        n += 1;
                    }
                }
            }
            (s, n)
        })
    };
    let q = collect(true);
    let from_quiet = q.iter().all(|&(_, n)| n >= 200);
    let src = if from_quiet { q } else { collect(false) };
    Noise {
        sigma_g: src.map(|(s, n)| (s / n.max(1) as f64).sqrt().max(1e-15)),
        from_quiet,
    }
}

/// How the residual under vibration compares with the quiet readings' (the noise).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LackOfFit {
    /// Mean of `(r / sigma)^2` over the vibrating readings (1 for a right model).
    pub chi2_per_reading_vibrating: f64,
    /// The same over the quiet readings (1 by construction when the noise came from
    /// them).
    pub chi2_per_reading_quiet: f64,
    /// `(vibrating - quiet) / standard error`, the standard errors from block means
    /// (correlation-consistent): above 3, the model misses something.
    pub z: f64,
    /// The residual's correlation inflation: the variance of a block's mean over the
    /// white-noise one, from the quiet readings (the vibrating ones when there are
    /// none), 1 for white noise.
    pub inflation: f64,
    pub vibrating: usize,
    pub quiet: usize,
}

/// The lack-of-fit statistics of residuals under `noise`.
pub fn lack_of_fit(
    runs: &[PreparedRun],
    residual_g: &[Vec<[f64; 3]>],
    noise: &Noise,
    block: usize,
) -> LackOfFit {
    // Per block (run, consecutive readings, all units): mean z^2 and mean z.
    let mut blocks: [Vec<(f64, f64, usize)>; 2] = [Vec::new(), Vec::new()];
    let (mut zz, mut nn) = ([0.0; 2], [0usize; 2]);
    let mut z_single: Vec<f64> = Vec::new();
    for (run, res) in runs.iter().zip(residual_g) {
        let mut acc = [(0.0, 0.0, 0usize); 2];
        for r in 0..run.j {
            if run.used[r] {
                let c = usize::from(run.quiet[r]);
                for u in 0..3 {
                    let z = res[r][u] / noise.sigma_g[u];
                    if z.is_finite() {
                        acc[c].0 += z * z;
                        acc[c].1 += z;
                        acc[c].2 += 1;
                        zz[c] += z * z;
                        nn[c] += 1;
                        if c == 1 {
                            z_single.push(z);
                        }
                    }
                }
            }
            if (r + 1) % block == 0 || r + 1 == run.j {
                for c in 0..2 {
                    if acc[c].2 > 0 {
                        blocks[c].push(acc[c]);
                    }
                    acc[c] = (0.0, 0.0, 0);
                }
            }
        }
    }
    let mean_se = |b: &[(f64, f64, usize)]| -> (f64, f64) {
        let tot: usize = b.iter().map(|x| x.2).sum();
        if tot == 0 || b.len() < 2 {
            return (f64::NAN, f64::NAN);
        }
        let mean = b.iter().map(|x| x.0).sum::<f64>() / tot as f64;
        // Ratio estimator's variance over blocks.
        let var: f64 = b
            .iter()
            .map(|x| (x.0 - mean * x.2 as f64).powi(2))
            .sum::<f64>()
            / (b.len() - 1) as f64
            * b.len() as f64
            / (tot as f64).powi(2);
        (mean, var.sqrt())
    };
    let (mv, sv) = mean_se(&blocks[0]);
    let (mq, sq) = mean_se(&blocks[1]);
    let z = if mq.is_finite() {
        (mv - mq) / (sv * sv + sq * sq).sqrt()
    } else {
        (mv - 1.0) / sv
    };
    // Inflation: block sums of z against their white-noise variance, over the quiet
    // readings, or the vibrating ones when there are no quiet ones.
    let c = if blocks[1].len() >= 10 { 1 } else { 0 };
    let inflation = {
        let b = &blocks[c];
        let tot: usize = b.iter().map(|x| x.2).sum();
        if b.len() >= 10 && tot > 0 {
            let var_z = zz[c] / nn[c].max(1) as f64;
            let v: f64 = b.iter().map(|x| x.1 * x.1).sum::<f64>() / tot as f64;
            (v / var_z.max(1e-300)).max(1.0)
        } else {
            1.0
        }
    };
    LackOfFit {
        chi2_per_reading_vibrating: mv,
        chi2_per_reading_quiet: mq,
        z,
        inflation,
        vibrating: nn[0],
        quiet: nn[1],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_and_inverts() {
        let m = vec![vec![4.0, 1.0], vec![1.0, 3.0]];
        let x = solve(&m, &[1.0, 2.0]).unwrap();
        assert!((4.0 * x[0] + x[1] - 1.0).abs() < 1e-14);
        assert!((x[0] + 3.0 * x[1] - 2.0).abs() < 1e-14);
        let inv = invert(&m).unwrap();
        assert!((inv[0][0] - 3.0 / 11.0).abs() < 1e-15);
        assert!(solve(&[vec![0.0]], &[1.0]).is_none());
    }
}
