//! A simulated flight (`vibro-sim`) as rig streams: into an MCAP log, live over
//! iceoryx2 at a multiple of real time, or both (`vibrocomp sim` on a flight, and the
//! first step of `vibrocomp demo`). The one module of this crate that knows the
//! simulator: [`crate::rig`] cuts its chunks into wire blocks as it would any
//! producer's.
//!
//! The log carries the scenario as metadata ([`SCENARIO_METADATA`]), the passports and
//! the scenario's text as attachments, and each enabled effect's table
//! ([`effect_metadata_name`]); it is written under a temporary name that takes the
//! final one only once finished (`crate::output::PartFile`). Offline generation loses
//! nothing: a full writer queue makes the flight wait.
//!
//! The mean error of each unit against the exact model is summed as the flight runs
//! (`vibro_sim::FlightStats`, MODEL.md sections 4 and 6).

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use serde::Serialize;
use vibro_mcap::{Recorder, RecorderOptions};
#[cfg(feature = "ipc")]
use vibro_msgs::ServiceNames;
use vibro_msgs::Stream;
use vibro_sim::{FlightStats, Scenario, Simulator, UnitReport};

use crate::attachments::{effect_metadata_name, LogExtras, SCENARIO_METADATA};
use crate::rig::{Packetizer, RigChunk, RigMessage, TruthSample};
#[cfg(feature = "ipc")]
use crate::Pace;
use crate::{topic, Error, Result};

/// What a flight made, and each unit's mean error against the exact model.
#[derive(Debug, Clone, Serialize)]
pub struct FlightReport {
    pub scenario: String,
    pub file: String,
    pub seed: u64,
    pub duration_s: f64,
    /// `vibro_sim::effect_labels`.
    pub effects: Vec<String>,
    /// Vibration-sensor samples per channel.
    pub sensor_samples: u64,
    /// Accelerometer output samples per unit.
    pub output_samples: u64,
    pub vib_blocks: u64,
    pub accel_blocks: u64,
    /// Vibration-sensor samples clipped by the ADC, per channel.
    pub sensor_clipped: [u64; 3],
    /// Wall-clock time of the generation, s.
    pub elapsed_s: f64,
    /// Simulated over wall-clock time.
    pub real_time_factor: f64,
    /// The log written, if any.
    pub out: Option<String>,
    /// The prefix of the live streams, if published (set by the caller).
    pub live_prefix: Option<String>,
    pub units: Vec<UnitReport>,
}

/// Where a flight goes besides its report.
pub struct FlightOutput<'a> {
    /// The MCAP log to write (it appears when finished).
    pub out: Option<&'a Path>,
    /// Publishers of the live streams, already opened.
    pub live: Option<LivePublishers>,
    /// Whether `out` may replace a file that appeared while the flight ran.
    pub force: bool,
}

/// Live publishers of the rig streams: none without the feature `ipc` (a build that
/// leaves iceoryx2 out writes flights into logs only).
#[cfg(not(feature = "ipc"))]
pub enum LivePublishers {}

#[cfg(not(feature = "ipc"))]
impl LivePublishers {
    fn publish(&mut self, _: RigMessage<'_>) -> Result<()> {
        match *self {}
    }
}

/// Live publishers of the rig streams, paced at a multiple of real time.
#[cfg(feature = "ipc")]
pub struct LivePublishers {
    _node: vibro_ipc::IpcNode,
    vib: vibro_ipc::StreamPublisher<vibro_msgs::VibBlock>,
    accel: vibro_ipc::StreamPublisher<vibro_msgs::AccelBlock>,
    truth: vibro_ipc::StreamPublisher<vibro_msgs::TruthBlock>,
    start: Instant,
    rate: f64,
}

#[cfg(feature = "ipc")]
impl LivePublishers {
    /// Opens the rig streams' publishers under `prefix`, paced at `rate` times real
    /// time (the rule of [`Pace::rate_problem`]).
    pub fn new(prefix: &str, rate: f64) -> Result<Self> {
        if let Some(rule) = Pace::rate_problem(rate) {
            return Err(Error::Option {
                name: "--rate",
                value: rate.to_string(),
                rule: rule.into(),
            });
        }
        let names = ServiceNames::new(prefix).map_err(|source| Error::Prefix {
            prefix: prefix.to_string(),
            source,
        })?;
        let node = vibro_ipc::create_node("vibrocomp-sim").map_err(Error::Node)?;
        let config = vibro_ipc::StreamConfig::default();
        let open = |s: Stream| (names.stream(s), names.event(s));
        let (vd, ve) = open(Stream::Vib);
        let (ad, ae) = open(Stream::Accel);
        let (td, te) = open(Stream::Truth);
        Ok(Self {
            vib: vibro_ipc::StreamPublisher::create(&node, &vd, &ve, &config)?,
            accel: vibro_ipc::StreamPublisher::create(&node, &ad, &ae, &config)?,
            truth: vibro_ipc::StreamPublisher::create(&node, &td, &te, &config)?,
            _node: node,
            start: Instant::now(),
            rate,
        })
    }

    /// Waits until the message's simulated time, scaled by `rate`, then publishes it
    /// stamped with the publish clock.
    fn publish(&mut self, msg: RigMessage<'_>) -> Result<()> {
        let due = Duration::from_nanos((msg.time_ns() as f64 / self.rate) as u64);
        if let Some(wait) = due.checked_sub(self.start.elapsed()) {
            std::thread::sleep(wait);
        }
        let now = vibro_ipc::now_ns();
        match msg {
            RigMessage::Vib(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.vib.publish(&b)?;
            }
            RigMessage::Accel(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.accel.publish(&b)?;
            }
            RigMessage::Truth(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.truth.publish(&b)?;
            }
        }
        Ok(())
    }
}

/// Runs a flight scenario into `output`; returns what it made and each unit's mean
/// error against the exact model.
///
/// `stop` is asked once per chunk, never per sample: a signal's name stops the flight
/// there, the log is finished with what was generated (a valid MCAP) and the result is
/// [`Error::Interrupted`]. `progress(done, total)` gets the output samples generated,
/// once before the first chunk and after each.
pub fn simulate_flight(
    scenario: &Scenario,
    output: FlightOutput<'_>,
    stop: &dyn Fn() -> Option<&'static str>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<FlightReport> {
    let FlightOutput {
        out,
        mut live,
        force,
    } = output;
    let effects_text = vibro_sim::effect_labels(scenario);
    let effects = vibro_sim::scenario_effects(scenario)?;
    let mut sim = Simulator::new(scenario, effects).map_err(Error::Simulator)?;
    let rates = scenario.rates;
    let names: Vec<String> = sim.unit_names().iter().map(|s| s.to_string()).collect();
    let total = sim.total_samples();
    let mut packetizer = Packetizer::new(rates.sensor_hz, rates.output_hz, 512, 32, 1);
    // Written under a temporary name, renamed to `out` once finished (README, "Files").
    let part = out.map(crate::output::PartFile::beside).transpose()?;
    let recorder = match (&part, out) {
        (Some(part), Some(path)) => Some(open_log(part.path(), path, scenario, &effects_text)?),
        _ => None,
    };
    progress(0, total.output);
    let mut stats = FlightStats::for_scenario(scenario, total.output);
    let started = Instant::now();
    let mut emit = |msg: RigMessage<'_>| -> Result<()> {
        if let Some(rec) = &recorder {
            write_blocking(rec, msg)?;
        }
        if let Some(live) = &mut live {
            live.publish(msg)?;
        }
        Ok(())
    };
    let mut interrupted = None;
    loop {
        if let Some(signal) = stop() {
            interrupted = Some(signal);
            break;
        }
        let Some(chunk) = sim.next_chunk()? else {
            break;
        };
        for (row, truth) in chunk.accel_v().iter().zip(chunk.truth()) {
            stats.push(row, truth);
        }
        let rig_chunk = RigChunk {
            sensor_first_index: chunk.sensor_first_index(),
            sensor_v: chunk.sensor_v(),
            output_first_index: chunk.output_first_index(),
            accel_v: chunk.accel_v(),
        };
        packetizer.push_chunk(rig_chunk, chunk.truth().iter().map(truth_sample), &mut emit)?;
        progress(stats.samples(), total.output);
    }
    packetizer.flush(&mut emit)?;
    if live.is_some() {
        // A subscriber's queued samples live in the publisher's shared memory: give
        // the consumers a moment to take the last blocks before the ports close.
        std::thread::sleep(Duration::from_millis(300));
    }
    let finished = match recorder {
        Some(rec) => Some(rec.finish().map_err(Error::FinishLog)?),
        None => None,
    };
    let n = stats.samples();
    // Finished, also when interrupted: a valid log of what was generated.
    if let (Some(part), Some(path)) = (part, out) {
        // Without `force`, an output that appeared while the flight was simulated is
        // refused, not replaced.
        part.commit(path, force)?;
    }
    if let Some(signal) = interrupted {
        let log = match (&finished, out) {
            (Some(f), Some(path)) => format!(
                "; {} is finished with the {} messages written so far",
                path.display(),
                f.messages
            ),
            _ => String::new(),
        };
        return Err(Error::Interrupted {
            signal,
            reached_s: n as f64 / rates.output_hz,
            duration_s: sim.duration_s(),
            log,
        });
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    let (vib_blocks, accel_blocks) = packetizer.blocks();
    let duration_s = sim.duration_s();
    Ok(FlightReport {
        scenario: scenario.name.clone(),
        file: scenario.file.clone(),
        seed: scenario.seed,
        duration_s,
        effects: effects_text,
        sensor_samples: total.sensor,
        output_samples: n,
        vib_blocks,
        accel_blocks,
        sensor_clipped: sim.sensor_clipped(),
        elapsed_s,
        real_time_factor: duration_s / elapsed_s.max(1e-9),
        out: out.map(|p| p.display().to_string()),
        live_prefix: None,
        units: stats.units(&names),
    })
}

/// The scenario's metadata record of a flight log: its name, file, seed, rates,
/// sensor, effects (`effects`, joined) and, for a flight, its length and units.
pub fn scenario_metadata(scenario: &Scenario, effects: &[String]) -> BTreeMap<String, String> {
    let rates = scenario.rates;
    let mut meta = BTreeMap::from([
        ("name".to_string(), scenario.name.clone()),
        ("file".to_string(), scenario.file.clone()),
        ("seed".to_string(), scenario.seed.to_string()),
        ("sensor_hz".to_string(), rates.sensor_hz.to_string()),
        ("internal_hz".to_string(), rates.internal_hz.to_string()),
        ("output_hz".to_string(), rates.output_hz.to_string()),
        (
            "sensor_sensitivity_v_per_g".to_string(),
            scenario.sensor.sensitivity_v_per_g.to_string(),
        ),
        (
            "sensor_ac_corner_hz".to_string(),
            scenario.sensor.ac_corner_hz.to_string(),
        ),
        ("effects".to_string(), effects.join("; ")),
    ]);
    if let Some(f) = scenario.flight() {
        meta.insert("duration_s".into(), f.duration_s.to_string());
        meta.insert("units".into(), f.triad.names.join(", "));
    }
    meta
}

/// Opens a recorder for a flight log, with the scenario as metadata and the passports
/// and scenario description as attachments.
/// `path` is where it is written (a temporary name), `shown` the log it becomes.
fn open_log(
    path: &Path,
    shown: &Path,
    scenario: &Scenario,
    effects: &[String],
) -> Result<Recorder> {
    let mut rec =
        Recorder::create(path, RecorderOptions::default()).map_err(|source| Error::CreateLog {
            path: shown.to_path_buf(),
            source,
        })?;
    for s in [Stream::Vib, Stream::Accel, Stream::Truth] {
        rec.add_channel(&topic(s), s.kind())?;
    }
    let meta = scenario_metadata(scenario, effects);
    let mut extras = LogExtras::generated();
    if let Some(f) = scenario.flight() {
        for (i, p) in f.triad.passports.iter().enumerate() {
            let text = toml::to_string(&p.to_spec()).map_err(Error::PassportToml)?;
            extras.passport(i, p.id(), text);
        }
    }
    extras.metadata(SCENARIO_METADATA, meta);
    for (i, e) in scenario.effects.iter().filter(|e| e.enabled).enumerate() {
        let mut m: BTreeMap<String, String> = e
            .params
            .iter()
            .map(|(k, v)| (k.clone(), v.to_string()))
            .collect();
        m.insert("kind".into(), e.kind.clone());
        if let Some(units) = &e.units {
            m.insert("units".into(), format!("{units:?}"));
        }
        extras.metadata(&effect_metadata_name(i), m);
    }
    // The scenario as written: its file, or the shipped text it was parsed from.
    let text = std::fs::read(&scenario.file).ok().or_else(|| {
        vibro_sim::scenario::EMBEDDED_SCENARIOS
            .iter()
            .find(|(_, file, _)| scenario.file == format!("{file} (embedded)"))
            .map(|(_, _, text)| text.as_bytes().to_vec())
    });
    if let Some(text) = text {
        extras.scenario_text(text);
    }
    extras.write_to(&rec)?;
    Ok(rec)
}

/// Writes one message to the log, waiting for room in the writer's queue (offline
/// generation must lose nothing).
fn write_blocking(rec: &Recorder, msg: RigMessage<'_>) -> Result<()> {
    let t = msg.time_ns();
    loop {
        let result = match msg {
            RigMessage::Vib(b) => rec.write(&topic(Stream::Vib), t, b.publish_ns, b.seq as u32, b),
            RigMessage::Accel(b) => {
                rec.write(&topic(Stream::Accel), t, b.publish_ns, b.seq as u32, b)
            }
            RigMessage::Truth(b) => {
                rec.write(&topic(Stream::Truth), t, b.publish_ns, b.seq as u32, b)
            }
        };
        match result {
            Err(vibro_mcap::Error::QueueFull { .. }) => {
                std::thread::sleep(Duration::from_micros(200))
            }
            other => return other.map_err(Into::into),
        }
    }
}

/// What the rig's truth stream carries of a sample's truth: each unit's IA component.
pub fn truth_sample(t: &vibro_sim::Truth) -> TruthSample {
    TruthSample {
        a_l_ia_g: [t.a_l_unit_g[0][2], t.a_l_unit_g[1][2], t.a_l_unit_g[2][2]],
        a_sensed_ia_g: [
            t.a_mean_unit_g[0][2],
            t.a_mean_unit_g[1][2],
            t.a_mean_unit_g[2][2],
        ],
        vib_error_ia_g: t.exact_ve_g,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_truth_stream_takes_each_units_ia_component() {
        let t = vibro_sim::Truth {
            a_l_unit_g: [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]],
            a_mean_unit_g: [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]],
            exact_mean_output_g: [0.0; 3],
            exact_ve_g: [1e-6, 2e-6, 3e-6],
        };
        let s = truth_sample(&t);
        assert_eq!(s.a_l_ia_g, [3.0, 6.0, 9.0]);
        assert_eq!(s.a_sensed_ia_g, [0.3, 0.6, 0.9]);
        assert_eq!(s.vib_error_ia_g, [1e-6, 2e-6, 3e-6]);
    }

    #[test]
    fn a_flights_metadata_names_its_scenario_and_units() {
        let scenario = vibro_sim::resolve_scenario("cyclone-4-short").unwrap();
        let meta = scenario_metadata(&scenario, &["a".into(), "b(x=1)".into()]);
        assert_eq!(meta["name"], scenario.name);
        assert_eq!(meta["seed"], scenario.seed.to_string());
        assert_eq!(meta["effects"], "a; b(x=1)");
        assert_eq!(meta["units"].split(", ").count(), 3);
    }

    #[test]
    fn a_flight_without_outputs_reports_every_sample() {
        let mut scenario = vibro_sim::resolve_scenario("cyclone-4-short").unwrap();
        if let vibro_sim::ScenarioKind::Flight(f) = &mut scenario.kind {
            f.duration_s = 0.25;
        }
        let output_hz = scenario.rates.output_hz;
        let mut last = (0, 0);
        let output = FlightOutput {
            out: None,
            live: None,
            force: false,
        };
        let report =
            simulate_flight(&scenario, output, &|| None, &mut |n, t| last = (n, t)).unwrap();
        // 0.25 s at the output rate, every one counted and reported.
        let expected = (0.25 * output_hz).round() as u64;
        assert_eq!(report.output_samples, expected);
        assert_eq!(last, (expected, expected));
        assert_eq!(report.units.len(), 3);
        // Blocks of 32 accelerometer samples, the last one partial.
        assert_eq!(report.accel_blocks, expected.div_ceil(32));
    }

    #[test]
    fn a_stopped_flight_says_where() {
        let scenario = vibro_sim::resolve_scenario("cyclone-4-short").unwrap();
        let output = FlightOutput {
            out: None,
            live: None,
            force: false,
        };
        let e = simulate_flight(&scenario, output, &|| Some("SIGINT"), &mut |_, _| {})
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("interrupted by SIGINT at simulated time 0.000 s of "),
            "{e}"
        );
    }
}
