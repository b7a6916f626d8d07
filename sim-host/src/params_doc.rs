//! The flight parameters' reference page (docs/parameters.md), generated from their one declaration
//! ([`control_core::params::declared`]): name, default, range, unit and description of each. `sim-host params`
//! prints it; a test keeps the committed page equal to it, and checks that the declarations cover exactly the
//! fields a scenario's TOML has.
use anyhow::{Result, bail};
use control_core::declare::{ParamSpec, Range};
use control_core::params::{FlightParams, declared};

/// Every leaf of a TOML table as `(dotted name, value)`, in the table's order.
pub fn leaves(v: &toml::Value) -> Vec<(String, toml::Value)> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut Vec<(String, toml::Value)>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let name = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                    walk(&name, v, out);
                }
            }
            other => out.push((prefix.to_string(), other.clone())),
        }
    }
    let mut out = Vec::new();
    walk("", v, &mut out);
    out
}

/// The declared defaults as TOML values, by dotted name.
fn defaults() -> Result<Vec<(String, toml::Value)>> {
    Ok(leaves(&toml::Value::try_from(FlightParams::default())?))
}

/// An `f32` in its shortest form, with an exponent when small or large (`2.98e-6`).
fn num(v: f32) -> String {
    if v != 0.0 && (v.abs() < 1e-3 || v.abs() >= 1e5) { format!("{v:e}") } else { format!("{v}") }
}

/// A value as the page shows it: the `f32` the flight code holds, shortest form.
fn number(v: &toml::Value) -> String {
    match v {
        toml::Value::Float(f) => num(*f as f32),
        toml::Value::Integer(i) => i.to_string(),
        toml::Value::Boolean(b) => b.to_string(),
        toml::Value::Array(a) => format!("[{}]", a.iter().map(number).collect::<Vec<_>>().join(", ")),
        other => other.to_string(),
    }
}

fn range_text(r: &Range) -> String {
    let (l, h) = (num(r.lo), num(r.hi));
    if r.hi.is_infinite() {
        return if r.lo_open { format!("> {l}") } else { format!(">= {l}") };
    }
    let lo = if r.lo_open { format!("({l}") } else { format!("[{l}") };
    let hi = if r.hi_open { format!("{h})") } else { format!("{h}]") };
    format!("{lo}, {hi}")
}

fn section_of(spec: &ParamSpec) -> &str {
    spec.name.rsplit_once('.').map_or("(root)", |(s, _)| s)
}

/// The page, as docs/parameters.md holds it.
pub fn markdown() -> Result<String> {
    let defaults = defaults()?;
    let mut out = String::new();
    out.push_str(
        "# Flight parameters\n\n\
         Generated from the parameters' one declaration (`params_struct!` in `control-core/src/params.rs` and\n\
         `control-core/src/motion.rs`, see `control-core/src/declare.rs`) by `cargo run -p sim-host -- params >\n\
         docs/parameters.md`; a test keeps this page equal to it. Each parameter is a field of a scenario's\n\
         TOML under its dotted name (`[vehicle]` `mass_kg = 0.38`). A value outside its range is refused when\n\
         the scenario loads, with the field's name and the range; checks that relate several fields\n\
         (Routh-Hurwitz of the laws, one bound below another) follow the ranges and are stated in the\n\
         descriptions. Arrays: the range holds for every element. `(a, b]`: a excluded, b included.\n\
         Parameters that can be changed over the radio link: `control_core::params::ParamId`.\n",
    );
    let mut section = "";
    for spec in declared() {
        let s = section_of(spec);
        if s != section {
            section = s;
            out.push_str(&format!(
                "\n## `{s}`\n\n| name | type | default | range | unit | description |\n|---|---|---|---|---|---|\n"
            ));
        }
        let default = match defaults.iter().find(|(n, _)| n == spec.name) {
            Some((_, v)) => number(v),
            None => bail!("the declared parameter `{}` is not a field of the parameters' TOML", spec.name),
        };
        let short = spec.name.rsplit_once('.').map_or(spec.name, |(_, n)| n);
        let range = spec.range.as_ref().map_or("-".to_string(), range_text);
        let unit = if spec.unit.is_empty() { "-" } else { spec.unit };
        let doc = spec.doc.trim().replace('|', "\\|");
        out.push_str(&format!("| `{short}` | `{}` | {default} | {range} | {unit} | {doc} |\n", spec.ty));
    }
    out.push_str(
        "\n# Over the radio and MAVLink\n\n\
         The parameters a ground station reads and changes over the radio (`control_core::params::ParamId`),\n\
         with the short name a MAVLink ground control station shows (at most 16 characters, `param_id`) and the\n\
         index of `PARAM_VALUE` (docs/mavlink.md).\n\n\
         | index | MAVLink name | parameter |\n|---|---|---|\n",
    );
    for (i, id) in control_core::params::ParamId::ALL.iter().enumerate() {
        out.push_str(&format!("| {i} | `{}` | `{}` |\n", id.short_name(), id.name()));
    }
    out.push_str(
        "\n# Simulator values\n\n\
         The simulator's own values (scene, cameras, model, IMU, link, mission, mismatch, wind, faults), each\n\
         with its range declared once in `sim-host/src/scenario/limits.rs`. A scenario is refused when a value\n\
         lies outside, naming the field; the options that override a scenario value (`render --blur`, `--noise`,\n\
         `--light-gain`, `--light-gradient`, `--exposure-time`, `fly --duration`) have the same limits, since\n\
         they are checked as the scenario's field they set. Relations between values (a rate that divides the\n\
         physics rate, a latency plus a frame interval within the flight code's history) follow the ranges.\n\
         Entries of lists are named without their index (`faults.imu_spike.rate_hz`).\n\n",
    );
    out.push_str(&crate::scenario::limits::markdown_table());
    for (name, why) in crate::scenario::limits::UNRANGED {
        out.push_str(&format!("\nNot ranged: `{name}` ({why}).\n"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use control_core::params::FlightParams;

    #[test]
    fn the_declarations_cover_exactly_the_fields_of_the_toml() {
        let fields: Vec<String> = defaults().unwrap().into_iter().map(|(n, _)| n).collect();
        let declared: Vec<&str> = declared().map(|s| s.name).collect();
        for f in &fields {
            assert!(declared.contains(&f.as_str()), "`{f}` has no declaration");
        }
        for d in &declared {
            assert!(fields.iter().any(|f| f == d), "`{d}` is declared but is no field");
        }
    }

    /// The TOML of the paper's parameters with one leaf changed (its first element for an array).
    fn with_leaf(name: &str, value: f64) -> FlightParams {
        let mut v = toml::Value::try_from(FlightParams::paper()).unwrap();
        let mut t = &mut v;
        let parts: Vec<&str> = name.split('.').collect();
        for p in &parts[..parts.len() - 1] {
            t = t.get_mut(*p).unwrap();
        }
        let leaf = t.get_mut(parts[parts.len() - 1]).unwrap();
        let target = match leaf {
            toml::Value::Array(a) => &mut a[0],
            other => other,
        };
        *target = match target {
            toml::Value::Integer(_) => toml::Value::Integer(value as i64),
            _ => toml::Value::Float(value),
        };
        v.try_into().unwrap()
    }

    #[test]
    fn every_declared_range_refuses_just_outside_it_and_names_the_field() {
        let mut checked = 0;
        for spec in declared() {
            let Some(r) = spec.range else { continue };
            let integer = spec.ty == "u8" || spec.ty.starts_with("[u8;");
            let step = |b: f32| if integer { 1.0 } else { (b.abs() * 1e-3).max(1e-9) as f64 };
            let mut outside = vec![if r.lo_open { r.lo as f64 } else { r.lo as f64 - step(r.lo) }];
            if r.hi.is_finite() {
                outside.push(if r.hi_open { r.hi as f64 } else { r.hi as f64 + step(r.hi) });
            }
            for v in outside {
                // A u8 cannot hold a value below 0 or above 255: the type refuses those itself.
                if integer && !(0.0..=255.0).contains(&v) {
                    continue;
                }
                let e = with_leaf(spec.name, v).validate().unwrap_err();
                assert_eq!(e.field, spec.name, "{} = {v}: {e}", spec.name);
                checked += 1;
            }
        }
        assert!(checked > 150, "{checked}");
    }

    #[test]
    fn the_committed_page_is_the_generated_one() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/parameters.md");
        let committed = std::fs::read_to_string(path).expect("docs/parameters.md");
        let generated = markdown().unwrap();
        assert!(
            committed == generated,
            "docs/parameters.md is out of date: run `cargo run -p sim-host -- params > docs/parameters.md`"
        );
    }
}
