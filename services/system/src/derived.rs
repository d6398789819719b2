//! The services' configurations with a rig's sensor chain and an extended model put
//! in (`vibrocomp up --rig RIG.toml --model MODEL.toml`): the text of each
//! configuration with those keys replaced ([`estimator_text`], [`compensator_text`]),
//! written into a private folder ([`DerivedConfigs`]) whose files the services are
//! started with ([`derive`] does it all, every input checked first), so that a restarted service (and the recorder, which attaches them)
//! reads exactly what the first one did.
//!
//! Files rather than flags on the services: the compensator reloads its configuration
//! file when it or a file it names changes, and a reload must not drop what `up` was
//! told. The derived compensator file names its triad, passports and model by absolute
//! paths (resolved as the compensator resolves them, next to the original file first),
//! so that a change to one of them is still reloaded; a change to the original
//! configuration file itself is not (restart `up` to take it).
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! let rig = vibro_config::load_rig("rig.toml".as_ref())?;
//! let estimator = vibro_system::derived::estimator_text(
//!     &std::fs::read_to_string("config/services/estimator.toml")?,
//!     &rig.sensors,
//! )?;
//! let configs = vibro_system::derived::DerivedConfigs::write(Some(&estimator), None)?;
//! println!("{:?}", configs.estimator());
//! # Ok(())
//! # }
//! ```

use anyhow::Context;
use std::path::{Path, PathBuf};
use toml::{Table, Value};
use vibro_config::rig::SensorChain;
use vibro_service::ServiceConfig;

/// The estimator's configuration text with the chain's sensitivity, AC corner and delay
/// in `[estimator]` (`sensitivity_raw_per_g`, `ac_corner_hz`, `delay_s`), and its rate
/// (`sample_rate_hz`) when the rig file states one: the estimator keeps out blocks at
/// another rate than its own.
///
/// `full_scale_g` (when given) is rescaled by the old sensitivity over the new one: the
/// input range is the acquisition's, in volts, and a more sensitive sensor reaches it
/// at fewer g.
pub fn estimator_text(base: &str, chain: &SensorChain) -> anyhow::Result<String> {
    let mut table: Table = toml::from_str(base).context("parsing the estimator's configuration")?;
    let est = table
        .get_mut("estimator")
        .and_then(Value::as_table_mut)
        .context("the estimator's configuration has no [estimator] table")?;
    let old: Option<Vec<f64>> = est
        .get("sensitivity_raw_per_g")
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(number).collect());
    if let (Some(old), Some(fs)) = (
        old.filter(|o| o.len() == 3),
        est.get("full_scale_g").and_then(Value::as_array),
    ) {
        let fs: Vec<f64> = fs.iter().filter_map(number).collect();
        if fs.len() == 3 {
            let scaled: [f64; 3] =
                std::array::from_fn(|i| fs[i] * (old[i] / chain.sensitivity_v_per_g[i]).abs());
            est.insert("full_scale_g".into(), floats(&scaled));
        }
    }
    est.insert(
        "sensitivity_raw_per_g".into(),
        floats(&chain.sensitivity_v_per_g),
    );
    match chain.ac_corner_hz {
        Some(fc) => {
            est.insert("ac_corner_hz".into(), Value::Float(fc));
        }
        None => {
            est.remove("ac_corner_hz");
        }
    }
    est.insert("delay_s".into(), Value::Float(chain.delay_s));
    if let Some(rate_hz) = chain.rate_hz {
        est.insert("sample_rate_hz".into(), Value::Float(rate_hz));
    }
    Ok(toml::to_string(&table)?)
}

/// The compensator's configuration text with the chain in `[sensors]`
/// (`sensitivity_v_per_g`, `ac_corner_hz`, 0 for a DC-coupled chain, `delay_s`) and
/// `model` set to `model`, its relative `triad`, `passports` and `model` made absolute
/// where they name a file next to `base_dir` (the original file's folder), as the
/// compensator looks them up.
pub fn compensator_text(
    base: &str,
    base_dir: Option<&Path>,
    chain: Option<&SensorChain>,
    model: Option<&Path>,
) -> anyhow::Result<String> {
    let mut table: Table =
        toml::from_str(base).context("parsing the compensator's configuration")?;
    let here = |value: &str| -> Option<String> {
        let p = base_dir?.join(value);
        p.is_file()
            .then(|| std::path::absolute(&p).unwrap_or(p))
            .map(|p| p.display().to_string())
    };
    for key in ["triad", "model"] {
        if let Some(abs) = table.get(key).and_then(Value::as_str).and_then(here) {
            table.insert(key.into(), Value::String(abs));
        }
    }
    if let Some(list) = table.get_mut("passports").and_then(Value::as_array_mut) {
        for v in list.iter_mut() {
            if let Some(abs) = v.as_str().and_then(here) {
                *v = Value::String(abs);
            }
        }
    }
    if let Some(chain) = chain {
        let sensors = table
            .entry("sensors")
            .or_insert_with(|| Value::Table(Table::new()));
        let sensors = sensors
            .as_table_mut()
            .context("the compensator's configuration: sensors is not a table")?;
        sensors.insert(
            "sensitivity_v_per_g".into(),
            floats(&chain.sensitivity_v_per_g),
        );
        sensors.insert(
            "ac_corner_hz".into(),
            Value::Float(chain.ac_corner_hz.unwrap_or(0.0)),
        );
        sensors.insert("delay_s".into(), Value::Float(chain.delay_s));
    }
    if let Some(model) = model {
        let abs = std::path::absolute(model).unwrap_or_else(|_| model.to_path_buf());
        table.insert("model".into(), Value::String(abs.display().to_string()));
    }
    Ok(toml::to_string(&table)?)
}

fn number(v: &Value) -> Option<f64> {
    v.as_float().or_else(|| v.as_integer().map(|i| i as f64))
}

fn floats(v: &[f64]) -> Value {
    Value::Array(v.iter().map(|x| Value::Float(*x)).collect())
}

/// The derived configuration files, in a folder of their own (mode 0700, a fresh
/// name in the temporary folder) that is removed when this is dropped.
#[derive(Debug)]
pub struct DerivedConfigs {
    dir: PathBuf,
    estimator: Option<PathBuf>,
    compensator: Option<PathBuf>,
}

impl DerivedConfigs {
    /// Writes the texts given (`estimator.toml`, `compensator.toml`) into a new private
    /// folder, by the file rule (`vibro_files`).
    pub fn write(estimator: Option<&str>, compensator: Option<&str>) -> anyhow::Result<Self> {
        let dir = private_dir()?;
        let mut out = Self {
            dir,
            estimator: None,
            compensator: None,
        };
        for (name, text, slot) in [
            ("estimator.toml", estimator, &mut out.estimator),
            ("compensator.toml", compensator, &mut out.compensator),
        ] {
            if let Some(text) = text {
                let path = out.dir.join(name);
                vibro_files::write_bytes(&path, false, text.as_bytes())
                    .with_context(|| format!("writing {}", path.display()))?;
                *slot = Some(path);
            }
        }
        Ok(out)
    }

    /// The estimator's derived configuration, if one was written.
    pub fn estimator(&self) -> Option<&Path> {
        self.estimator.as_deref()
    }

    /// The compensator's derived configuration, if one was written.
    pub fn compensator(&self) -> Option<&Path> {
        self.compensator.as_deref()
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for DerivedConfigs {
    fn drop(&mut self) {
        for f in [&self.estimator, &self.compensator].into_iter().flatten() {
            let _ = std::fs::remove_file(f);
        }
        let _ = std::fs::remove_dir(&self.dir);
    }
}

/// A new folder only this user can enter: `mkdir` (never through a link, failing if the
/// name exists) under a name made of the pid, the time and a counter.
fn private_dir() -> anyhow::Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    let base = std::env::temp_dir();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let mut last = None;
    for k in 0..100u32 {
        let dir = base.join(format!(
            "vibrocomp-up-{}-{nanos:09}-{k}",
            std::process::id()
        ));
        match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(dir),
            Err(e) => {
                return Err(e).with_context(|| format!("creating the folder {}", dir.display()))
            }
        }
    }
    anyhow::bail!(
        "could not create a private folder in {} (last tried {:?})",
        base.display(),
        last
    )
}

/// Checks the services' configurations as given, then `--rig` and `--model`, and with
/// either writes the configurations that carry them ([`DerivedConfigs`]) and checks
/// those as the services will load them. Every error names the file, key, value and
/// rule; nothing has started yet.
pub fn derive(
    estimator_config: Option<&Path>,
    compensator_config: Option<&Path>,
    rig_file: Option<&Path>,
    model: Option<&Path>,
) -> anyhow::Result<Option<DerivedConfigs>> {
    use vibro_compensator::Config as Compensator;
    use vibro_estimator::Config as Estimator;
    let estimator = base_config::<Estimator>(estimator_config)?;
    let compensator = base_config::<Compensator>(compensator_config)?;
    // The rig file's and the model's problems at once.
    let mut problems = Vec::new();
    let rig = match rig_file.map(rig_chain) {
        Some(Ok(chain)) => Some(chain),
        Some(Err(e)) => {
            problems.push(format!("{e:#}"));
            None
        }
        None => None,
    };
    if let Some(path) = model {
        if let Err(e) = vibro_effects::LabModel::load(path) {
            problems.push(format!("--model {}: {e}", path.display()));
        }
    }
    if !problems.is_empty() {
        anyhow::bail!("{}", problems.join("\n"));
    }
    if rig.is_none() && model.is_none() {
        return Ok(None);
    }
    let estimator_derived = match &rig {
        Some(chain) => Some(estimator_text(&estimator.text, chain).with_context(|| {
            format!(
                "applying --rig to the estimator's configuration {}",
                estimator.name
            )
        })?),
        None => None,
    };
    let compensator_derived = compensator_text(
        &compensator.text,
        compensator.dir.as_deref(),
        rig.as_ref(),
        model,
    )
    .with_context(|| {
        format!(
            "applying --rig/--model to the compensator's configuration {}",
            compensator.name
        )
    })?;
    let derived = DerivedConfigs::write(estimator_derived.as_deref(), Some(&compensator_derived))?;
    let given = |what: &str, name: &str| {
        let mut from = vec![format!("{what} {name}")];
        from.extend(rig_file.map(|p| format!("--rig {}", p.display())));
        if what == "compensator" {
            from.extend(model.map(|p| format!("--model {}", p.display())));
        }
        from.join(" with ")
    };
    if let Some(p) = derived.estimator() {
        Estimator::load(p).with_context(|| given("estimator", &estimator.name))?;
    }
    if let Some(p) = derived.compensator() {
        Compensator::load(p).with_context(|| given("compensator", &compensator.name))?;
    }
    Ok(Some(derived))
}

/// A service's configuration as given (or the default one), checked, with its text.
struct BaseConfig {
    text: String,
    /// Where its relative paths are looked up first.
    dir: Option<PathBuf>,
    /// The file, or `... (shipped)`.
    name: String,
}

fn base_config<C: ServiceConfig>(given: Option<&Path>) -> anyhow::Result<BaseConfig> {
    let default = Path::new(C::DEFAULT_CONFIG_PATH);
    let path = match given {
        Some(p) => Some(p),
        None => default.is_file().then_some(default),
    };
    match path {
        Some(p) => {
            drop(C::load(p)?);
            Ok(BaseConfig {
                text: vibro_service::read_config_file(p)?,
                dir: p.parent().map(Path::to_path_buf),
                name: p.display().to_string(),
            })
        }
        None => {
            drop(C::shipped()?);
            Ok(BaseConfig {
                text: C::shipped_text().to_string(),
                dir: None,
                name: format!("{} (shipped)", C::DEFAULT_CONFIG_PATH),
            })
        }
    }
}

/// The rig file's sensor chain (`vibro_config::rig`, the parser `log import --rig`
/// uses), checked against the compensator's rules for a chain as well.
fn rig_chain(path: &Path) -> anyhow::Result<vibro_config::rig::SensorChain> {
    let rig = vibro_config::load_rig(path).with_context(|| format!("--rig {}", path.display()))?;
    let s = rig.sensors;
    let problems = vibro_waveform::SensorChain {
        sensitivity_v_per_g: s.sensitivity_v_per_g,
        ac_corner_hz: s.ac_corner_hz.unwrap_or(0.0),
        delay_s: s.delay_s,
    }
    .problems();
    if !problems.is_empty() {
        let list: Vec<String> = problems.iter().map(|p| format!("sensors.{p}")).collect();
        anyhow::bail!("--rig {}: {}", rig.file, list.join("; "));
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CHAIN: SensorChain = SensorChain {
        sensitivity_v_per_g: [0.01, -0.01, 0.02],
        ac_corner_hz: None,
        delay_s: 0.00156,
        delay_stated: true,
        rate_hz: None,
    };

    #[test]
    fn the_estimator_takes_the_chain_and_keeps_its_volt_range() {
        let base = "prefix = \"a/\"\n[estimator]\nsample_rate_hz = 1000.0\n\
            sensitivity_raw_per_g = [0.1, 0.1, 0.1]\nac_corner_hz = 0.5\n\
            full_scale_g = [100.0, 100.0, 100.0]\n";
        let t: Table = toml::from_str(&estimator_text(base, &CHAIN).unwrap()).unwrap();
        let e = t["estimator"].as_table().unwrap();
        let f =
            |k: &str| -> Vec<f64> { e[k].as_array().unwrap().iter().filter_map(number).collect() };
        assert_eq!(f("sensitivity_raw_per_g"), [0.01, -0.01, 0.02]);
        // 10 V over the new sensitivities.
        let fs = f("full_scale_g");
        for (got, want) in fs.iter().zip([1000.0, 1000.0, 500.0]) {
            assert!((got - want).abs() < 1e-9, "{fs:?}");
        }
        assert!(e.get("ac_corner_hz").is_none());
        assert_eq!(e["delay_s"].as_float(), Some(0.00156));
        assert_eq!(t["prefix"].as_str(), Some("a/"));
        assert_eq!(e["sample_rate_hz"].as_float(), Some(1000.0));
        let rated = SensorChain {
            rate_hz: Some(6400.0),
            ..CHAIN
        };
        let t: Table = toml::from_str(&estimator_text(base, &rated).unwrap()).unwrap();
        assert_eq!(t["estimator"]["sample_rate_hz"].as_float(), Some(6400.0));
    }

    #[test]
    fn the_compensator_takes_the_chain_the_model_and_absolute_paths() {
        let dir = std::env::temp_dir().join(format!("derived-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("t.toml"), "x").unwrap();
        let base = "mode = \"exact\"\ntriad = \"t.toml\"\n\
            passports = [\"AK-1\", \"t.toml\", \"AK-3\"]\n[sensors]\nac_corner_hz = 0.5\n";
        let model = Path::new("m/model.toml");
        let text = compensator_text(base, Some(&dir), Some(&CHAIN), Some(model)).unwrap();
        let t: Table = toml::from_str(&text).unwrap();
        let abs = dir.join("t.toml").display().to_string();
        assert_eq!(t["triad"].as_str(), Some(abs.as_str()));
        let p = t["passports"].as_array().unwrap();
        assert_eq!(p[0].as_str(), Some("AK-1"));
        assert_eq!(p[1].as_str(), Some(abs.as_str()));
        let m = t["model"].as_str().unwrap();
        assert!(
            Path::new(m).is_absolute() && m.ends_with("m/model.toml"),
            "{m}"
        );
        let s = t["sensors"].as_table().unwrap();
        assert_eq!(s["ac_corner_hz"].as_float(), Some(0.0));
        assert_eq!(s["delay_s"].as_float(), Some(0.00156));
        let configs = DerivedConfigs::write(None, Some(&text)).unwrap();
        let written = configs.compensator().unwrap().to_path_buf();
        assert_eq!(std::fs::read_to_string(&written).unwrap(), text);
        let folder = configs.dir().to_path_buf();
        drop(configs);
        assert!(!folder.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
