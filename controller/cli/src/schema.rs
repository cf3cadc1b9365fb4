//! `robodeploy schema`: the JSON Schema of robot.toml, the policy manifest, the mirror file and
//! calibration.toml, generated from the serde types the loaders read (so it cannot drift from
//! them), and the book's reference pages rendered from it.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result};
use serde_json::{Map, Value};

/// Which file's schema.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SchemaOf {
    /// robot.toml: joints, buses, IMU, start, safety, the trainer's physics.
    Robot,
    /// A policy manifest (policy.toml beside an ONNX file).
    Policy,
    /// A mirror file (`--mirror`): randomisation, scheduled faults, shoves, hardware truth.
    Mirror,
    /// calibration.toml beside a robot.toml (`calibrate` writes it).
    Calibration,
}

impl SchemaOf {
    fn what(self) -> &'static str {
        match self {
            Self::Robot => "robot.toml",
            Self::Policy => "policy manifest",
            Self::Mirror => "mirror file",
            Self::Calibration => "calibration.toml",
        }
    }
}

/// The format written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SchemaFormat {
    /// JSON Schema (draft 2020-12), for editors (taplo, VS Code's Even Better TOML) and validators.
    #[default]
    Json,
    /// A Markdown reference: every table, its fields, their types, defaults and meaning.
    Markdown,
}

/// `robodeploy schema`.
#[derive(Debug, clap::Args)]
pub struct SchemaArgs {
    /// The file whose schema to write.
    #[arg(value_enum)]
    pub of: SchemaOf,
    /// JSON Schema, or the Markdown reference the user guide carries.
    #[arg(long, value_enum, default_value_t)]
    pub format: SchemaFormat,
    /// Write here instead of standard output (a new file, or an existing one with --overwrite).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Replace --out's file where it exists (it is refused otherwise: `--out robot.toml` would
    /// put a schema where the robot's description was).
    #[arg(long, requires = "out")]
    pub overwrite: bool,
}

/// The schema of `of` as JSON.
pub fn schema(of: SchemaOf) -> Value {
    let mut schema = match of {
        SchemaOf::Robot => schemars::schema_for!(robots::RobotConfig),
        SchemaOf::Policy => schemars::schema_for!(policy::PolicyManifest),
        SchemaOf::Mirror => schemars::schema_for!(sim2real::config::MirrorConfig),
        SchemaOf::Calibration => schemars::schema_for!(robots::calibration::Calibration),
    }
    .to_value();
    if let Value::Object(root) = &mut schema {
        root.insert(
            "title".into(),
            Value::String(format!(
                "{} (robodeploy {})",
                of.what(),
                env!("CARGO_PKG_VERSION")
            )),
        );
    }
    schema
}

/// Runs `robodeploy schema`.
pub fn run(args: &SchemaArgs) -> Result<()> {
    let schema = schema(args.of);
    let text = match args.format {
        SchemaFormat::Json => {
            serde_json::to_string_pretty(&schema).context("writing the schema as JSON")? + "\n"
        }
        SchemaFormat::Markdown => markdown(args.of, &schema),
    };
    match &args.out {
        Some(path) if path.exists() && !args.overwrite => Err(crate::args::FlagError::new(
            "out",
            format!(" {}: the file exists; --overwrite replaces it", path.display()),
        )
        .into()),
        Some(path) => std::fs::write(path, text).with_context(|| format!("writing {}", path.display())),
        None => {
            std::io::Write::write_all(&mut std::io::stdout(), text.as_bytes()).context("writing the schema")
        }
    }
}

/// Renders `schema` as a reference page: the file's top level, then each table and choice it
/// refers to, in the order first met.
pub fn markdown(of: SchemaOf, schema: &Value) -> String {
    let empty = Map::new();
    let defs = schema.get("$defs").and_then(Value::as_object).unwrap_or(&empty);
    let mut page = format!(
        "# {} reference\n\nGenerated from the code by `robodeploy schema {} --format markdown`; the JSON Schema \
         for editors is `robodeploy schema {}`.\n\n",
        of.what(),
        of_name(of),
        of_name(of)
    );
    section(&mut page, &format!("The file ({})", of.what()), None, schema);
    let mut order: Vec<&str> = Vec::new();
    refs_in(schema, &mut order);
    let mut i = 0;
    while i < order.len() {
        if let Some(def) = defs.get(order[i]) {
            refs_in(def, &mut order);
        }
        i += 1;
    }
    for name in order {
        if let Some(def) = defs.get(name) {
            section(&mut page, name, Some(name), def);
        }
    }
    page
}

fn of_name(of: SchemaOf) -> &'static str {
    match of {
        SchemaOf::Robot => "robot",
        SchemaOf::Policy => "policy",
        SchemaOf::Mirror => "mirror",
        SchemaOf::Calibration => "calibration",
    }
}

/// The `$defs` names `value` refers to, appended to `order` once each.
fn refs_in<'a>(value: &'a Value, order: &mut Vec<&'a str>) {
    match value {
        Value::Object(map) => {
            if let Some(name) = map
                .get("$ref")
                .and_then(Value::as_str)
                .and_then(|r| r.strip_prefix("#/$defs/"))
                && !order.contains(&name)
            {
                order.push(name);
            }
            for (key, v) in map {
                if key != "$defs" {
                    refs_in(v, order);
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| refs_in(v, order)),
        _ => {}
    }
}

fn section(page: &mut String, title: &str, anchor: Option<&str>, def: &Value) {
    match anchor {
        Some(a) => {
            let _ = writeln!(page, "## {title} {{#{}}}\n", anchor_of(a));
        }
        None => {
            let _ = writeln!(page, "## {title}\n");
        }
    }
    if let Some(text) = def.get("description").and_then(Value::as_str) {
        let _ = writeln!(page, "{}\n", one_paragraph(text));
    }
    if let Some(props) = def.get("properties").and_then(Value::as_object) {
        let required: Vec<&str> = def
            .get("required")
            .and_then(Value::as_array)
            .map(|r| r.iter().filter_map(Value::as_str).collect())
            .unwrap_or_default();
        page.push_str("| field | type | default | meaning |\n|---|---|---|---|\n");
        for (name, prop) in props {
            let default = match prop.get("default") {
                // A table's default is its fields' own, listed where the table is.
                Some(Value::Object(_)) => "each field's".to_owned(),
                Some(Value::Null) => "none".to_owned(),
                Some(v) => format!("`{}`", compact(v)),
                None if required.contains(&name.as_str()) => "required".to_owned(),
                None => "optional".to_owned(),
            };
            let meaning = meaning_of(prop);
            let _ = writeln!(
                page,
                "| `{name}` | {} | {default} | {} |",
                type_of(prop),
                cell(&meaning)
            );
        }
        page.push('\n');
    }
    for key in ["oneOf", "anyOf"] {
        if let Some(choices) = def.get(key).and_then(Value::as_array) {
            page.push_str("One of:\n\n");
            for choice in choices {
                let meaning = meaning_of(choice);
                let _ = writeln!(
                    page,
                    "- {}{}{}",
                    choice_of(choice),
                    if meaning.is_empty() { "" } else { ": " },
                    meaning
                );
            }
            page.push('\n');
        }
    }
    if let Some(values) = def.get("enum").and_then(Value::as_array) {
        let _ = writeln!(page, "One of {}.\n", quoted(values).join(", "));
    }
}

/// What one choice of a `oneOf` is: a constant, a tagged table, or a type.
fn choice_of(choice: &Value) -> String {
    if let Some(c) = choice.get("const") {
        return format!("`{}`", compact(c));
    }
    if let Some(values) = choice.get("enum").and_then(Value::as_array) {
        return quoted(values).join(", ");
    }
    if let Some(props) = choice.get("properties").and_then(Value::as_object) {
        let fields: Vec<String> = props
            .iter()
            .map(|(name, p)| match p.get("const") {
                Some(c) => format!("`{name} = {}`", compact(c)),
                None => format!("`{name}`: {}", type_of(p)),
            })
            .collect();
        return fields.join(", ");
    }
    type_of(choice)
}

/// A field's type as a reader says it, with links to the tables it names.
fn type_of(prop: &Value) -> String {
    if let Some(name) = prop
        .get("$ref")
        .and_then(Value::as_str)
        .and_then(|r| r.strip_prefix("#/$defs/"))
    {
        return format!("[{name}](#{})", anchor_of(name));
    }
    for key in ["anyOf", "oneOf"] {
        if let Some(choices) = prop.get(key).and_then(Value::as_array) {
            let parts: Vec<String> = choices
                .iter()
                .filter(|c| c.get("type").and_then(Value::as_str) != Some("null"))
                .map(type_of)
                .collect();
            return parts.join(" or ");
        }
    }
    if let Some(values) = prop.get("enum").and_then(Value::as_array) {
        return quoted(values).join(" or ");
    }
    let types: Vec<&str> = match prop.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(ts)) => ts
            .iter()
            .filter_map(Value::as_str)
            .filter(|t| *t != "null")
            .collect(),
        _ => return "any".to_owned(),
    };
    let one = |t: &str| -> String {
        match t {
            "array" => match prop.get("items") {
                Some(items) => format!("list of {}", type_of(items)),
                None => match prop.get("prefixItems").and_then(Value::as_array) {
                    Some(items) => {
                        let each: Vec<String> = items.iter().map(type_of).collect();
                        format!("[{}]", each.join(", "))
                    }
                    None => "list".to_owned(),
                },
            },
            "object" => match prop.get("additionalProperties") {
                Some(v @ Value::Object(_)) => format!("table of {}", type_of(v)),
                _ => "table".to_owned(),
            },
            "integer" | "number" => {
                let mut s = t.to_owned();
                if let Some(min) = prop.get("minimum") {
                    let _ = write!(s, " ≥ {}", compact(min));
                }
                s
            }
            other => other.to_owned(),
        }
    };
    types.into_iter().map(one).collect::<Vec<_>>().join(" or ")
}

fn anchor_of(name: &str) -> String {
    name.to_ascii_lowercase()
}

fn compact(v: &Value) -> String {
    v.to_string()
}

/// What a schema node's doc comment says, on one line.
fn meaning_of(node: &Value) -> String {
    node.get("description")
        .and_then(Value::as_str)
        .map(one_paragraph)
        .unwrap_or_default()
}

/// Constants as a reader sees them: each in code quotes.
fn quoted(values: &[Value]) -> Vec<String> {
    values.iter().map(|v| format!("`{}`", compact(v))).collect()
}

/// Doc comments wrap at the source's width: one line here, so tables hold them; rustdoc's links
/// (`` [`name`] ``) read as plain code.
fn one_paragraph(text: &str) -> String {
    text.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace("[`", "`")
        .replace("`]", "`")
}

/// A table cell cannot hold a bare `|`.
fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}
