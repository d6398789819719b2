//! A scenario as written in its TOML file: every table rejects unknown keys, and only
//! structural defaults are filled in here; [`super::Scenario`] checks every rule.

use serde::Deserialize;
use vibro_effects::EffectSpec;

/// The whole file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioRaw {
    /// Short name, used in reports.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: Option<String>,
    /// Seed of every random stream of the run.
    pub seed: u64,
    pub rates: RatesRaw,
    pub sensor: SensorRaw,
    /// A flight (exactly one of `flight` and `campaign`).
    #[serde(default)]
    pub flight: Option<FlightRaw>,
    /// A shake-table campaign.
    #[serde(default)]
    pub campaign: Option<CampaignRaw>,
    /// `[[effect]]` tables, applied in this order.
    #[serde(default)]
    pub effect: Vec<EffectSpec>,
}

/// `[rates]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RatesRaw {
    /// Vibration-sensor rate, Hz; default 25 600 Hz (RIG.md's common rig rate).
    #[serde(default)]
    pub sensor_hz: Option<f64>,
    /// Internal rate of the accelerometer physics, Hz: the sensor rate times a whole
    /// number; default the sensor rate.
    #[serde(default)]
    pub internal_hz: Option<f64>,
    /// Accelerometer output rate, Hz; `internal_hz / output_hz` must be a whole number.
    pub output_hz: f64,
}

/// `[sensor]`: the vibration sensor of each unit (all keys required: physical facts).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorRaw {
    pub sensitivity_v_per_g: f64,
    /// Corner of the AC coupling, Hz; 0 for a DC-coupled sensor.
    pub ac_corner_hz: f64,
    /// White noise referred to the input, g RMS.
    pub noise_g_rms: f64,
    pub adc_bits: u32,
    /// ADC full scale, V (codes span `-full_scale_v .. +full_scale_v`).
    pub full_scale_v: f64,
}

/// `[flight]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlightRaw {
    pub duration_s: f64,
    /// A triad file, or `default` for the shipped one.
    pub triad: String,
    /// Optional passport per unit (file or shipped id), replacing the triad's.
    #[serde(default)]
    pub passports: Option<Vec<String>>,
    /// `[[flight.profile]]`: the flight (apparent) acceleration, piecewise linear.
    pub profile: Vec<ProfilePointRaw>,
    /// `[[flight.tone]]`.
    #[serde(default)]
    pub tone: Vec<ToneRaw>,
    /// `[flight.random]`.
    #[serde(default)]
    pub random: Option<RandomRaw>,
}

/// One breakpoint of the flight acceleration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfilePointRaw {
    pub t_s: f64,
    /// Apparent acceleration in body axes `[x, y, z]`, g.
    pub accel_body_g: [f64; 3],
}

/// One tone in body axes.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToneRaw {
    pub freq_hz: f64,
    /// End frequency of a linear sweep over the whole flight.
    #[serde(default)]
    pub sweep_to_hz: Option<f64>,
    /// Amplitude (not RMS) per body axis, g.
    pub amplitude_g: [f64; 3],
    /// Phase per body axis, deg; default all 0 (in phase, as the papers assume).
    #[serde(default)]
    pub phase_deg: Option<[f64; 3]>,
}

/// One inline PSD band (the same shape for every axis).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BandRaw {
    pub f_lo_hz: f64,
    pub f_hi_hz: f64,
    pub psd_g2_per_hz: f64,
}

/// `[flight.random]`: broadband random vibration in body axes.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomRaw {
    /// One PSD table (file or shipped id) for every body axis: its `psd3_g2_per_hz`
    /// column is the PSD along the axis.
    #[serde(default)]
    pub psd_table: Option<String>,
    /// One table per body axis `[x, y, z]`.
    #[serde(default)]
    pub psd_tables: Option<[String; 3]>,
    /// Inline bands, the same shape on every axis.
    #[serde(default)]
    pub band: Option<Vec<BandRaw>>,
    /// Amplitude gain per band of the table (e.g. RIG.md's `psi_j`): the PSD is
    /// multiplied by its square. Only with a single table or inline bands.
    #[serde(default)]
    pub band_gain: Option<Vec<f64>>,
    /// Amplitude scale per body axis (PSD times its square); default 1.
    #[serde(default)]
    pub scale: Option<[f64; 3]>,
    /// Or: the RMS per body axis, g, the shape being kept.
    #[serde(default)]
    pub rms_g: Option<[f64; 3]>,
    /// Coherence matrix of the body axes; default independent axes.
    #[serde(default)]
    pub coherence: Option<[[f64; 3]; 3]>,
    /// Kurtosis per body axis, 3..30; default 3 (Gaussian).
    #[serde(default)]
    pub kurtosis: Option<[f64; 3]>,
    /// Segment of the non-Gaussian scale mixture, s; default 0.25 s.
    #[serde(default)]
    pub kurtosis_segment_s: Option<f64>,
    /// FIR resolution, Hz; default 1 Hz.
    #[serde(default)]
    pub filter_resolution_hz: Option<f64>,
}

/// `[campaign]`: a shake-table campaign on one unit.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRaw {
    /// The unit under test (file or shipped id).
    pub passport: String,
    /// Length of each still record, s (5 min in \[P2\]).
    pub still_s: f64,
    /// Length of the vibrating record, s (5 min in \[P2\]).
    pub vibrating_s: f64,
    /// Batches per record for the batch-means uncertainty; default 20.
    #[serde(default)]
    pub batches: Option<usize>,
    /// Tilt limit of the still-drift check, rad; default 1e-4 (\[P2\]).
    #[serde(default)]
    pub tilt_limit_rad: Option<f64>,
    /// Settling time left out of the measurement at the start of the vibrating record
    /// and of the second still record, s; default 0.
    #[serde(default)]
    pub settle_s: Option<f64>,
    /// `[[campaign.grid]]`: each a product of its lists, expanded in file order.
    pub grid: Vec<GridRaw>,
}

/// One grid of conditions: every combination of its lists.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridRaw {
    /// Angle of IA from the vertical in the vertical plane, deg.
    pub angle_deg: Vec<f64>,
    /// Where the rest of gravity goes: `oa` or `pa`.
    pub tilt_toward: String,
    /// Vibration directions in the unit frame: `ia`, `ia-oa-45`, `ia-pa-45`.
    pub direction: Vec<String>,
    /// Multiply the amplitude along 45-degree directions by sqrt(2), so that each of
    /// the two axes gets the full amplitude (MODEL.md section 9); default false.
    #[serde(default)]
    pub scale_45_by_sqrt2: Option<bool>,
    /// Tone amplitudes along the direction, g.
    #[serde(default)]
    pub tone_amplitude_g: Option<Vec<f64>>,
    /// Tone frequencies, Hz.
    #[serde(default)]
    pub tone_freq_hz: Option<Vec<f64>>,
    /// PSD tables (file or shipped id) of random runs: the `psd3_g2_per_hz` column is
    /// the PSD along the direction.
    #[serde(default)]
    pub psd_table: Option<Vec<String>>,
    /// Amplitude scales of the table along the direction; default `[1]`.
    #[serde(default)]
    pub random_scale: Option<Vec<f64>>,
    /// Or: RMS levels along the direction, g.
    #[serde(default)]
    pub random_rms_g: Option<Vec<f64>>,
    /// Kurtosis levels of the random part; default `[3]`.
    #[serde(default)]
    pub kurtosis: Option<Vec<f64>>,
    #[serde(default)]
    pub kurtosis_segment_s: Option<f64>,
    #[serde(default)]
    pub filter_resolution_hz: Option<f64>,
}
