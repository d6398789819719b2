//! `lab add` as a request: the effects named, or those the diagnosis finds, or the
//! empirical correction, fitted to a table and added to a model (docs/lab.md). One
//! home for the rules the command line and the Python package share: `empirical`
//! alone and refitting, `--diagnosed` only when the diagnosis found an effect.

use crate::diagnose::{self, DiagnoseOptions};
use crate::{CampaignTable, EffectFit, EmpiricalFit, Error, LabModel, Result};

/// Which effects to add.
#[derive(Debug, Clone, PartialEq)]
pub enum Effects {
    /// These kinds of the lab's library (or `empirical` alone).
    Kinds(Vec<String>),
    /// Those the diagnosis of the same inputs finds (its stepwise search).
    Diagnosed,
}

/// What [`add`] made: the extended model, and the fit (physical effects) or the
/// correction (`empirical`).
#[derive(Debug, Clone)]
pub struct Added {
    pub model: LabModel,
    pub fit: Option<EffectFit>,
    pub empirical: Option<EmpiricalFit>,
}

/// Fits `effects` to `table` and adds them to `model` (refitting the model's own
/// effects jointly unless `freeze`). `options` runs the diagnosis of
/// [`Effects::Diagnosed`] (its progress included).
pub fn add(
    model: &LabModel,
    table: &CampaignTable,
    effects: &Effects,
    freeze: bool,
    options: &DiagnoseOptions,
) -> Result<Added> {
    let kinds: Vec<String> = match effects {
        Effects::Kinds(kinds) => kinds.clone(),
        Effects::Diagnosed => {
            let d = diagnose::diagnose(model, table, options)?;
            let kinds = diagnose::next_effects(&d);
            if kinds.is_empty() {
                return Err(Error::Invalid(format!(
                    "--diagnosed: the diagnosis of {} found no effect to add ({})",
                    table.path.display(),
                    crate::text::verdict_line(&d.verdict)
                )));
            }
            kinds
        }
    };
    let empirical = kinds.iter().any(|k| k == vibro_effects::empirical::KIND);
    if empirical && (kinds.len() != 1 || freeze) {
        return Err(Error::Invalid(
            "`empirical` is added alone and refits the model's effects beside it (no \
             --freeze): first add the physical effects, then `lab add empirical`"
                .into(),
        ));
    }
    if empirical {
        let Some((extended, e)) = diagnose::add_empirical(model, table)? else {
            return Err(Error::Invalid(format!(
                "{}: no empirical correction: no smooth function of the vibration and the \
                 flight acceleration predicts the residual out of sample (no set of terms, \
                 each lowering the leave-one-out chi-square by {}, brings it below {} of its \
                 value); nothing written",
                table.path.display(),
                crate::empirical::CV_SUPPORT,
                crate::empirical::OFFER_FRACTION
            )));
        };
        return Ok(Added {
            model: extended,
            fit: None,
            empirical: Some(e),
        });
    }
    let refs: Vec<&str> = kinds.iter().map(String::as_str).collect();
    let (extended, fit) =
        diagnose::add_effects_stoppable(model, table, &refs, freeze, &options.stop)?;
    Ok(Added {
        model: extended,
        fit: Some(fit),
        empirical: None,
    })
}
