//! One CSV file per message kind (`nav.csv`, `health.csv`, `raw.imu.csv`, ...) plus `log.csv`
//! and `corrupt.csv`. Columns are the message's JSON fields flattened (`pos_ned_m.0`,
//! `source.Polarization.unit`); a column missing in a row (another enum variant) is left empty.
//! Written by hand: the `csv` crate would only quote fields, which [`field`] does.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde_json::Value;

use super::schema::message_json;
use crate::record::session::Session;

fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, String)>) {
    let key = |k: &str| if prefix.is_empty() { k.to_string() } else { format!("{prefix}.{k}") };
    match v {
        Value::Object(o) => {
            for (k, x) in o {
                flatten(&key(k), x, out);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                flatten(&key(&i.to_string()), x, out);
            }
        }
        Value::Null => out.push((prefix.to_string(), String::new())),
        Value::String(s) => out.push((prefix.to_string(), s.clone())),
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

/// A CSV field, quoted when it needs to be.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

struct Table {
    columns: Vec<String>,
    rows: Vec<BTreeMap<String, String>>,
}

impl Table {
    fn new() -> Self {
        Self { columns: vec![], rows: vec![] }
    }
    fn push(&mut self, v: &Value) {
        let mut cells = vec![];
        flatten("", v, &mut cells);
        let mut row = BTreeMap::new();
        for (k, x) in cells {
            if !self.columns.contains(&k) {
                self.columns.push(k.clone());
            }
            row.insert(k, x);
        }
        self.rows.push(row);
    }
    fn text(&self) -> String {
        let mut s = self.columns.iter().map(|c| field(c)).collect::<Vec<_>>().join(",");
        s.push('\n');
        for r in &self.rows {
            let line: Vec<String> = self.columns.iter().map(|c| field(r.get(c).map(String::as_str).unwrap_or(""))).collect();
            s.push_str(&line.join(","));
            s.push('\n');
        }
        s
    }
}

/// Write the CSV files into `dir` (created if missing); returns (file, rows) per file written.
pub fn write(session: &Session, dir: &Path) -> Result<Vec<(PathBuf, u64)>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut tables: BTreeMap<String, Table> = BTreeMap::new();
    for m in &session.messages {
        tables.entry(m.item.kind().to_string()).or_insert_with(Table::new).push(&message_json(&m.item, m.t_host_us));
    }
    for l in &session.logs {
        let v =
            serde_json::json!({"host_t_us": l.t_host_us, "level": l.item.level, "timestamp": l.item.timestamp, "message": l.item.message});
        tables.entry("log".into()).or_insert_with(Table::new).push(&v);
    }
    for c in &session.corrupt {
        tables.entry("corrupt".into()).or_insert_with(Table::new).push(&serde_json::json!({"host_t_us": c.t_host_us, "error": c.item}));
    }
    let mut written = vec![];
    for (name, t) in &tables {
        let p = dir.join(format!("{name}.csv"));
        crate::output::write_atomic(&p, t.text().as_bytes())?;
        written.push((p, t.rows.len() as u64));
    }
    Ok(written)
}
