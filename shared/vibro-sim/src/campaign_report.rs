//! What `vibrocomp sim` reports of a campaign: each condition's measured VE beside the
//! exact (MODEL.md section 6) and published (section 5) models, and the files written.

use serde::Serialize;

use crate::{ConditionSummary, Scenario};

/// One condition of a campaign report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConditionReport {
    pub id: String,
    /// Tilt of the table, deg.
    pub angle_deg: f64,
    /// Gravity in the unit's axes `[OA, PA, IA]`, g.
    pub a_l_unit_g: [f64; 3],
    /// Vibration direction (`Direction::name`).
    pub direction: String,
    pub tone_freq_hz: Option<f64>,
    pub tone_amplitude_g: Option<f64>,
    /// RMS of the random part per axis `[OA, PA, IA]`, g.
    pub sigma_unit_g: [f64; 3],
    /// The VE measured as MODEL.md section 8 does, and its standard error, g.
    pub measured_ve_g: f64,
    pub measured_ve_sigma_g: f64,
    pub exact_ve_g: f64,
    pub published_ve_g: f64,
    /// `(measured - exact)/sigma` ([`ConditionSummary::z_exact`]).
    pub z_exact: f64,
    /// The tilt check of MODEL.md section 8.
    pub drift_accepted: bool,
}

impl From<&ConditionSummary> for ConditionReport {
    fn from(s: &ConditionSummary) -> Self {
        ConditionReport {
            id: s.condition.id.clone(),
            angle_deg: s.condition.angle_deg,
            a_l_unit_g: s.condition.a_l_unit_g,
            direction: s.condition.direction.name().to_string(),
            tone_freq_hz: s.condition.tone.map(|t| t.freq_hz),
            tone_amplitude_g: s.condition.tone_amplitude_g,
            sigma_unit_g: s.sigma_unit_g(),
            measured_ve_g: s.measurement.ve_g,
            measured_ve_sigma_g: s.measurement.ve_sigma_g,
            exact_ve_g: s.exact_ve_g,
            published_ve_g: s.published_ve_g,
            z_exact: s.z_exact,
            drift_accepted: s.drift_accepted,
        }
    }
}

/// A campaign's report: the scenario, each condition, and the tables written.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CampaignReport {
    pub scenario: String,
    pub file: String,
    pub seed: u64,
    /// The passport of the unit under test, as the scenario names it.
    pub passport: String,
    /// [`crate::effect_labels`].
    pub effects: Vec<String>,
    /// Wall-clock time of the run, s.
    pub elapsed_s: f64,
    pub conditions: Vec<ConditionReport>,
    pub summary_csv: Option<String>,
    pub lab_csv: Option<String>,
    pub positions_csv: Option<String>,
}

impl CampaignReport {
    /// The report of `scenario`'s campaign run in `elapsed_s`; the table paths are
    /// left empty for the caller to fill in. `None` for a flight.
    pub fn new(
        scenario: &Scenario,
        summaries: &[ConditionSummary],
        elapsed_s: f64,
    ) -> Option<CampaignReport> {
        let campaign = scenario.campaign()?;
        Some(CampaignReport {
            scenario: scenario.name.clone(),
            file: scenario.file.clone(),
            seed: scenario.seed,
            passport: campaign.passport_source.clone(),
            effects: crate::effect_labels(scenario),
            elapsed_s,
            conditions: summaries.iter().map(ConditionReport::from).collect(),
            summary_csv: None,
            lab_csv: None,
            positions_csv: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flight_has_no_campaign_report() {
        let flight = crate::resolve_scenario("cyclone-4-short").unwrap();
        assert!(CampaignReport::new(&flight, &[], 1.0).is_none());
        let campaign = crate::resolve_scenario("ten-positions").unwrap();
        let report = CampaignReport::new(&campaign, &[], 2.5).unwrap();
        assert_eq!(report.scenario, campaign.name);
        assert_eq!(report.elapsed_s, 2.5);
        assert!(report.conditions.is_empty() && report.lab_csv.is_none());
    }
}
