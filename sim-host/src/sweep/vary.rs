//! `VARY.toml`: the distributions a sweep draws each run's scenario from.
//!
//! ```toml
//! [vary]                      # scenario fields by dotted path
//! "mismatch.mass_scale" = { uniform = [0.85, 1.15] }
//! "mismatch.inertia_scale" = { uniform = [0.8, 1.2] }      # an array field: each element drawn alone
//! "imu.gyro_noise_density" = { uniform = [0.5, 3.0], scale = true }   # times the scenario's value
//! "forward_camera.latency_s" = { normal = [0.08, 0.02], min = 0.03, max = 0.15 }
//! "scene.floor_texture" = { choice = ["concrete", "speckled"] }
//! "wind.mean_m_s" = { horizontal = [0.0, 1.5] }          # a speed from the range, a random direction
//!
//! [[faults]]                  # added to every run, their numbers drawn like the fields above
//! kind = "mag_disturbance"
//! start_s = 0.0
//! duration_s = 1000.0
//! heading_offset_deg = { uniform = [-45.0, 45.0] }
//! field_scale = 1.0
//!
//! [[one_fault_of]]            # one of these per run, chosen with equal weights
//! kind = "vision_dropout"
//! start_s = { uniform = [10.0, 40.0] }
//! duration_s = { uniform = [0.5, 2.0] }
//! ```
//!
//! Every draw comes from the run's own stream (seeded from the sweep's seed and the run index), so a run
//! is the same whether the sweep runs whole, sharded, or alone (`sim-host fly --vary VARY.toml --run K`).
use crate::rng::SimRng;
use crate::scenario::Scenario;
use anyhow::{Context, Result, bail};
use toml::Value;

/// The sweep's distributions.
#[derive(Clone, Debug)]
pub struct Vary {
    fields: Vec<(String, Value)>,
    faults: Vec<toml::Table>,
    one_fault_of: Vec<toml::Table>,
}

/// What was drawn for one run: the column names and values (for `runs.csv`) and the scenario.
#[derive(Clone, Debug)]
pub struct Draw {
    /// `(column, value)`, in the file's order.
    pub values: Vec<(String, String)>,
    /// The run's scenario.
    pub scenario: Scenario,
}

/// The keys a distribution table may have.
const DISTRIBUTION_KEYS: &[&str] =
    &["uniform", "normal", "choice", "horizontal", "min", "max", "scale", "also"];

fn is_distribution(v: &Value) -> bool {
    v.as_table()
        .is_some_and(|t| ["uniform", "normal", "choice", "horizontal"].iter().any(|k| t.contains_key(*k)))
}

fn pair(t: &toml::Table, key: &str, what: &str) -> Result<(f64, f64)> {
    let a = t.get(key).and_then(Value::as_array).filter(|a| a.len() == 2);
    let num = |v: &Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    match a.and_then(|a| Some((num(&a[0])?, num(&a[1])?))) {
        Some((x, y)) if x.is_finite() && y.is_finite() => Ok((x, y)),
        _ => bail!("{what}: `{key}` must be two numbers"),
    }
}

/// One number (or choice) drawn from a distribution table; `base` is the scenario's value for `scale`.
fn draw_one(t: &toml::Table, base: Option<f64>, rng: &mut SimRng, what: &str) -> Result<Value> {
    let scale = t.get("scale").and_then(Value::as_bool).unwrap_or(false);
    let clip = |x: f64| {
        let lo = t.get("min").and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)));
        let hi = t.get("max").and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)));
        x.max(lo.unwrap_or(f64::NEG_INFINITY)).min(hi.unwrap_or(f64::INFINITY))
    };
    let x = if t.contains_key("uniform") {
        let (a, b) = pair(t, "uniform", what)?;
        rng.range(a, b)
    } else if t.contains_key("normal") {
        let (m, s) = pair(t, "normal", what)?;
        m + s * rng.normal()
    } else if let Some(c) = t.get("choice") {
        let c = c
            .as_array()
            .filter(|c| !c.is_empty())
            .with_context(|| format!("{what}: `choice` must be a list"))?;
        let k = (rng.uniform() * c.len() as f64) as usize;
        return Ok(c[k.min(c.len() - 1)].clone());
    } else {
        bail!("{what}: a distribution needs `uniform`, `normal`, `choice` or `horizontal`");
    };
    let x = clip(x);
    Ok(Value::Float(if scale {
        x * base.with_context(|| format!("{what}: `scale` needs a numeric field"))?
    } else {
        x
    }))
}

fn as_f64(v: &Value) -> Option<f64> {
    v.as_float().or_else(|| v.as_integer().map(|i| i as f64))
}

fn cell(v: &Value) -> String {
    match v {
        Value::Float(f) => format!("{f}"),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

impl Vary {
    /// Parses a VARY.toml text.
    pub fn from_toml(text: &str) -> Result<Self> {
        let t: toml::Table = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        for k in t.keys() {
            if !["vary", "faults", "one_fault_of"].contains(&k.as_str()) {
                bail!("unknown section `{k}` (known: vary, faults, one_fault_of)");
            }
        }
        let fields = match t.get("vary") {
            Some(Value::Table(v)) => v.iter().map(|(k, v)| (k.clone(), v.clone())).collect(),
            Some(_) => bail!("`vary` must be a table of dotted field names"),
            None => Vec::new(),
        };
        let list = |name: &str| -> Result<Vec<toml::Table>> {
            match t.get(name) {
                None => Ok(Vec::new()),
                Some(Value::Array(a)) => a
                    .iter()
                    .map(|v| {
                        v.as_table().cloned().with_context(|| format!("`{name}` entries must be tables"))
                    })
                    .collect(),
                Some(_) => bail!("`{name}` must be an array of tables ([[{name}]])"),
            }
        };
        Ok(Self { fields, faults: list("faults")?, one_fault_of: list("one_fault_of")? })
    }

    /// Reads a VARY.toml file.
    pub fn load(path: &std::path::Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        Self::from_toml(&text).with_context(|| format!("in {}", path.display()))
    }

    /// Checks the file against a scenario: every path exists and every draw gives a valid scenario.
    pub fn check(&self, base: &Scenario) -> Result<()> {
        let mut rng = SimRng::stream(0, "vary-check");
        self.draw(base, &mut rng).map(|_| ())
    }

    /// Draws one run's scenario from `base`.
    pub fn draw(&self, base: &Scenario, rng: &mut SimRng) -> Result<Draw> {
        let mut doc = Value::try_from(base).context("the scenario as TOML")?;
        let mut values = Vec::new();
        for (path, dist) in &self.fields {
            let what = format!("vary.\"{path}\"");
            let slot = lookup(&mut doc, path).with_context(|| format!("{what}: no such scenario field"))?;
            let t = dist
                .as_table()
                .filter(|_| is_distribution(dist))
                .with_context(|| format!("{what}: expected a distribution such as {{ uniform = [a, b] }}"))?;
            if let Some(k) = t.keys().find(|k| !DISTRIBUTION_KEYS.contains(&k.as_str())) {
                bail!("{what}: unknown key `{k}` (known: {})", DISTRIBUTION_KEYS.join(", "));
            }
            if t.contains_key("horizontal") {
                let (a, b) = pair(t, "horizontal", &what)?;
                let speed = rng.range(a, b);
                let dir = rng.range(0.0, std::f64::consts::TAU);
                let v = [speed * dir.cos(), speed * dir.sin()];
                let arr = slot
                    .as_array_mut()
                    .filter(|a| a.len() >= 2)
                    .with_context(|| format!("{what}: `horizontal` needs a vector field"))?;
                arr[0] = Value::Float(v[0]);
                arr[1] = Value::Float(v[1]);
                values.push((format!("{path}.speed"), format!("{speed}")));
                values.push((format!("{path}.direction_deg"), format!("{}", dir.to_degrees())));
            } else if let Some(also) = t.get("also") {
                // One draw shared by several fields (e.g. every IMU noise and bias figure scaled alike).
                let also = also
                    .as_array()
                    .and_then(|a| {
                        a.iter().map(|v| v.as_str().map(str::to_string)).collect::<Option<Vec<_>>>()
                    })
                    .with_context(|| format!("{what}: `also` must be a list of field names"))?;
                let mut t = t.clone();
                t.remove("also");
                let unit = draw_one(
                    &t.clone().into_iter().filter(|(k, _)| k != "scale").collect(),
                    None,
                    rng,
                    &what,
                )?;
                let unit =
                    as_f64(&unit).with_context(|| format!("{what}: `also` needs a numeric distribution"))?;
                let scale = t.get("scale").and_then(Value::as_bool).unwrap_or(false);
                for p in std::iter::once(path.clone()).chain(also) {
                    let slot = lookup(&mut doc, &p)
                        .with_context(|| format!("{what}: no such scenario field `{p}`"))?;
                    let base = as_f64(slot).with_context(|| format!("{what}: `{p}` is not a number"))?;
                    let v = if scale { unit * base } else { unit };
                    values.push((p.clone(), format!("{v}")));
                    *slot = Value::Float(v);
                }
                if scale {
                    values.push((format!("{path}.scale"), format!("{unit}")));
                }
            } else if let Some(arr) = slot.as_array_mut() {
                for (i, e) in arr.iter_mut().enumerate() {
                    let v = draw_one(t, as_f64(e), rng, &what)?;
                    values.push((format!("{path}[{i}]"), cell(&v)));
                    *e = v;
                }
            } else {
                let v = draw_one(t, as_f64(slot), rng, &what)?;
                values.push((path.clone(), cell(&v)));
                *slot = v;
            }
        }
        let mut faults: Vec<Value> = Vec::new();
        for (i, f) in self.faults.iter().enumerate() {
            faults.push(Value::Table(draw_fault(f, rng, &format!("faults[{i}]"), &mut values)?));
        }
        if !self.one_fault_of.is_empty() {
            let k =
                ((rng.uniform() * self.one_fault_of.len() as f64) as usize).min(self.one_fault_of.len() - 1);
            faults.push(Value::Table(draw_fault(&self.one_fault_of[k], rng, "fault", &mut values)?));
        }
        if !faults.is_empty()
            && let Some(t) = doc.as_table_mut()
        {
            let mut all = t.get("faults").and_then(Value::as_array).cloned().unwrap_or_default();
            all.extend(faults);
            t.insert("faults".into(), Value::Array(all));
        }
        let text = toml::to_string(&doc).context("the drawn scenario as TOML")?;
        let scenario = Scenario::from_toml(&text).context("the drawn scenario")?;
        Ok(Draw { values, scenario })
    }

    /// The column names a draw has, for the CSV header (a draw from any seed has the same; the fault
    /// columns are those of the longest fault table).
    pub fn columns(&self, base: &Scenario) -> Result<Vec<String>> {
        let mut rng = SimRng::stream(0, "vary-columns");
        let d = self.draw(base, &mut rng)?;
        let mut cols: Vec<String> =
            d.values.iter().map(|(k, _)| k.clone()).filter(|k| !k.starts_with("fault.")).collect();
        let mut fault_cols: Vec<String> = vec!["fault.kind".into()];
        for f in &self.one_fault_of {
            for k in f.keys() {
                let c = format!("fault.{k}");
                if !fault_cols.contains(&c) {
                    fault_cols.push(c);
                }
            }
        }
        if !self.one_fault_of.is_empty() {
            cols.extend(fault_cols);
        }
        Ok(cols)
    }
}

fn draw_fault(
    f: &toml::Table,
    rng: &mut SimRng,
    what: &str,
    values: &mut Vec<(String, String)>,
) -> Result<toml::Table> {
    let mut out = toml::Table::new();
    for (k, v) in f {
        let name = format!("{what}.{k}");
        let v = match v {
            Value::Table(t) if is_distribution(v) => draw_one(t, None, rng, &name)?,
            // A vector field: each element a number or a distribution of its own.
            Value::Array(a) if a.iter().any(is_distribution) => {
                let mut drawn = Vec::with_capacity(a.len());
                for (i, e) in a.iter().enumerate() {
                    drawn.push(match e {
                        Value::Table(t) if is_distribution(e) => {
                            draw_one(t, None, rng, &format!("{name}[{i}]"))?
                        }
                        other => other.clone(),
                    });
                }
                Value::Array(drawn)
            }
            other => other.clone(),
        };
        match &v {
            Value::Array(a) => {
                for (i, e) in a.iter().enumerate() {
                    values.push((format!("{name}[{i}]"), cell(e)));
                }
            }
            _ => values.push((name, cell(&v))),
        }
        out.insert(k.clone(), v);
    }
    Ok(out)
}

/// The value at a dotted path (`mismatch.mass_scale`, `forward_camera.latency_s`).
fn lookup<'a>(doc: &'a mut Value, path: &str) -> Option<&'a mut Value> {
    let mut v = doc;
    for part in path.split('.') {
        v = v.as_table_mut()?.get_mut(part)?;
    }
    Some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_reproducible_and_within_their_ranges() {
        let v = Vary::from_toml(
            r#"
[vary]
"mismatch.mass_scale" = { uniform = [0.85, 1.15] }
"mismatch.inertia_scale" = { uniform = [0.8, 1.2] }
"imu.gyro_noise_density" = { uniform = [0.5, 3.0], scale = true }
"wind.mean_m_s" = { horizontal = [0.0, 1.5] }
"scene.floor_texture" = { choice = ["concrete", "plaster"] }
[[one_fault_of]]
kind = "vision_dropout"
start_s = { uniform = [10.0, 20.0] }
duration_s = 1.0
[[one_fault_of]]
kind = "motor_degradation"
start_s = 5.0
duration_s = 100.0
motor = 2
thrust_scale = { uniform = [0.8, 1.0] }
"#,
        )
        .unwrap();
        let base = Scenario::paper();
        let draw = |seed| v.draw(&base, &mut SimRng::stream(seed, "vary")).unwrap();
        let (a, b) = (draw(3), draw(3));
        assert_eq!(a.values, b.values);
        assert_eq!(a.scenario, b.scenario);
        for seed in 0..50 {
            let d = draw(seed);
            let s = &d.scenario;
            assert!((0.85..=1.15).contains(&s.mismatch.mass_scale));
            assert!(s.mismatch.inertia_scale.iter().all(|x| (0.8..=1.2).contains(x)));
            let g = s.imu.gyro_noise_density / base.imu.gyro_noise_density;
            assert!((0.5..=3.0).contains(&g), "{g}");
            let w = s.wind.mean_m_s;
            assert!((w[0] * w[0] + w[1] * w[1]).sqrt() <= 1.5 && w[2] == 0.0);
            assert_eq!(s.faults.len(), 1);
        }
        // The path must exist and the result validate.
        assert!(Vary::from_toml("[vary]\n\"no.such\" = { uniform = [0, 1] }").unwrap().check(&base).is_err());
        assert!(
            Vary::from_toml("[vary]\n\"mismatch.mass_scale\" = { uniform = [0, 0.1] }")
                .unwrap()
                .check(&base)
                .is_err()
        );
        assert!(Vary::from_toml("[typo]\n").is_err());
    }
}
