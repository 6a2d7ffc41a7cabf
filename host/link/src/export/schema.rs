//! JSON Schemas of the exported messages (MCAP `jsonschema` encoding), written out by hand so
//! that Foxglove knows every field, and the JSON form of each message (the serde form of the
//! wire type plus `host_t_us`). Foxglove's well-known `foxglove.PoseInFrame` and `foxglove.Log`
//! are given in their published JSON Schema form, so Foxglove's 3D and Log panels take them.
//!
//! A value that is not a number (yet) is never sent as JSON `null` to Foxglove: [`omit_unknown`]
//! leaves the field out and names it in the message's `no_value` object with why (`"aligning"`,
//! `"no fix"`, ...), so a panel plots a gap, not a zero or a parse error. The schemas say so: the
//! numeric fields are numbers, not required. The CSV export keeps the serde form (empty cells).

use serde_json::{Value, json};
use subnav_wire::{RawSample, Uplink};

fn num() -> Value {
    // A NaN ("no value yet") is left out of the Foxglove form and named in `no_value`.
    json!({"type": "number"})
}
fn int() -> Value {
    json!({"type": "integer"})
}
fn arr(n: usize) -> Value {
    json!({"type": "array", "items": num(), "minItems": n, "maxItems": n})
}
/// A nested object (no `host_t_us`, no title): one aid source's status.
fn aid_status() -> Value {
    let fields = [
        ("t_us", int()),
        ("nis", num()),
        ("test_ratio", num()),
        ("noise_var", num()),
        ("fused", json!({"type": "boolean"})),
        ("fused_count", int()),
        ("refused_count", int()),
        ("resets", int()),
        ("last_fused_us", int()),
    ];
    let props: serde_json::Map<String, Value> = fields.iter().map(|(k, v)| ((*k).to_string(), v.clone())).collect();
    let required: Vec<&str> = fields.iter().filter(|(_, v)| !may_be_omitted(v)).map(|(k, _)| *k).collect();
    json!({"type": "object", "properties": props, "required": required})
}
/// Every aid source's status, by name (`subnav_wire::AidStatuses`).
fn aid_statuses() -> Value {
    let props: serde_json::Map<String, Value> = subnav_wire::AidSource::ALL.iter().map(|s| (s.name().to_string(), aid_status())).collect();
    let required: Vec<&str> = subnav_wire::AidSource::ALL.iter().map(|s| s.name()).collect();
    json!({"type": "object", "properties": props, "required": required})
}
fn obj(title: &str, fields: &[(&str, Value)]) -> Value {
    let mut props = serde_json::Map::new();
    props.insert("host_t_us".into(), int());
    for (k, v) in fields {
        props.insert((*k).into(), v.clone());
    }
    let required: Vec<String> = props.iter().filter(|(_, v)| !may_be_omitted(v)).map(|(k, _)| k.clone()).collect();
    props.insert("no_value".into(), no_value_schema());
    json!({"$schema": "http://json-schema.org/draft-07/schema#", "title": title, "type": "object", "properties": props, "required": required})
}

/// Whether [`omit_unknown`] may leave a field with this schema out: numbers, arrays of numbers and
/// free-form values (which may hold a `None`).
pub fn may_be_omitted(s: &Value) -> bool {
    let number = |t: &Value| t == "number";
    number(&s["type"]) || (s["type"] == "array" && number(&s["items"]["type"])) || (s.get("type").is_none() && s.get("oneOf").is_none())
}

/// The `no_value` field: each field left out of the message (dotted path) and why.
pub fn no_value_schema() -> Value {
    json!({"type": "object", "description": "Fields left out because they have no value, and why (e.g. \"aligning\")",
           "additionalProperties": {"type": "string"}, "minProperties": 1})
}

/// Takes every `null` (a NaN, or a `None`) out of `v`: an object's null field, or an array field
/// with a null element, is removed, and if any was, `v` gets `no_value: {path: why(path)}`. Objects
/// nested in objects and arrays are searched too (paths `aid.dvl.nis`, `entities.0.x`).
pub fn omit_unknown(v: &mut Value, why: impl Fn(&str) -> &'static str) {
    let mut gone = Vec::new();
    take_nulls("", v, &mut gone);
    if let (false, Value::Object(o)) = (gone.is_empty(), v) {
        o.insert(
            "no_value".into(),
            Value::Object(
                gone.into_iter()
                    .map(|p| {
                        let w = why(&p);
                        (p, json!(w))
                    })
                    .collect(),
            ),
        );
    }
}

fn take_nulls(prefix: &str, v: &mut Value, gone: &mut Vec<String>) {
    let path = |k: &str| if prefix.is_empty() { k.to_string() } else { format!("{prefix}.{k}") };
    match v {
        Value::Object(o) => {
            let keys: Vec<String> = o.keys().cloned().collect();
            for k in keys {
                let drop = match &o[&k] {
                    Value::Null => true,
                    Value::Array(a) => a.iter().any(Value::is_null),
                    _ => false,
                };
                if drop {
                    o.remove(&k);
                    gone.push(path(&k));
                } else if let Some(x) = o.get_mut(&k) {
                    take_nulls(&path(&k), x, gone);
                }
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter_mut().enumerate() {
                take_nulls(&path(&i.to_string()), x, gone);
            }
        }
        _ => {}
    }
}

/// Why a field of a navigation solution in this mode has no value.
pub fn nav_why(mode: subnav_wire::NavMode) -> &'static str {
    match mode {
        subnav_wire::NavMode::Uninitialised => "uninitialised",
        subnav_wire::NavMode::Aligning => "aligning",
        _ => "not finite",
    }
}

/// Why field `path` of an uplink message has no value.
pub fn uplink_why(m: &Uplink, path: &str) -> &'static str {
    match m {
        Uplink::Nav(n) => nav_why(n.mode),
        Uplink::Compass(c) if c.heading_rad.is_none() => "no fix",
        Uplink::Health(_) if path.starts_with("aid.") => "not measured yet",
        Uplink::Raw(RawSample::Dvl(_)) if path == "covariance_m2ps2" => "not reported by the DVL",
        Uplink::Raw(RawSample::Dvl(d)) if !d.valid => "DVL invalid",
        Uplink::Boot(_) | Uplink::Record(_) | Uplink::Ack(_) => "none",
        _ => "not finite",
    }
}

/// The Foxglove form of an uplink message: [`message_json`] without nulls ([`omit_unknown`]).
pub fn foxglove_json(m: &Uplink, t_host_us: u64) -> Value {
    let mut v = message_json(m, t_host_us);
    omit_unknown(&mut v, |p| uplink_why(m, p));
    v
}
/// A serde externally tagged enum: a variant name, or `{variant: {...}}` for variants with data.
fn tagged(variants: &[&str]) -> Value {
    json!({"oneOf": [{"type": "string", "enum": variants}, {"type": "object", "minProperties": 1, "maxProperties": 1}]})
}

/// The uplink message kinds (as `Uplink::kind`) in export order.
pub const KINDS: [&str; 12] =
    ["boot", "nav", "raw.imu", "raw.polarization", "raw.depth", "raw.dvl", "compass", "health", "fault", "ack", "camera.trigger", "record"];

/// Schema name and JSON Schema of a message kind.
pub fn for_kind(kind: &str) -> Option<(String, Value)> {
    let t = int();
    let s = match kind {
        "boot" => obj(
            "subnav.Boot",
            &[
                ("t_us", t),
                ("protocol_version", int()),
                ("schema_fingerprint", int()),
                ("firmware_version", json!({"type": "array", "items": int()})),
                ("board", tagged(&["QemuMps2An386", "Stm32F405"])),
                ("calibration", json!({"type": "object"})),
                ("reset_cause", tagged(&["PowerOn", "Pin", "Brownout", "Software", "Watchdog"])),
            ],
        ),
        "nav" => obj(
            "subnav.NavSolution",
            &[
                ("t_us", t),
                ("mode", tagged(&["Uninitialised", "Aligning", "Inertial", "Aided"])),
                ("pos_ned_m", arr(3)),
                ("vel_ned_mps", arr(3)),
                ("att_nb_wxyz", arr(4)),
                ("sigma_pos_m", arr(3)),
                ("sigma_vel_mps", arr(3)),
                ("sigma_att_rad", arr(3)),
                ("cov_ne_m2", num()),
            ],
        ),
        "raw.imu" => obj("subnav.ImuSample", &[("t_us", t), ("gyro_radps", arr(3)), ("accel_mps2", arr(3)), ("temp_c", num())]),
        "raw.polarization" => obj(
            "subnav.PolarizationSample",
            &[("t_us", t), ("unit", int()), ("counts", json!({"type": "array", "items": int(), "minItems": 4, "maxItems": 4}))],
        ),
        "raw.depth" => obj("subnav.DepthSample", &[("t_us", t), ("pressure_pa", num()), ("temp_c", num()), ("depth_m", num())]),
        "raw.dvl" => obj(
            "subnav.DvlSample",
            &[
                ("t_us", t),
                ("rx_us", int()),
                ("tracking", tagged(&["Bottom", "Water"])),
                ("valid", json!({"type": "boolean"})),
                ("vel_dvl_mps", arr(3)),
                ("fom_mps", num()),
                ("altitude_m", num()),
                ("covariance_m2ps2", arr(9)),
            ],
        ),
        "compass" => obj(
            "subnav.CompassReport",
            &[
                ("t_us", t),
                ("heading_rad", num()),
                ("sigma_heading_rad", num()),
                ("sun_rel_azimuth_rad", num()),
                ("sun_elevation_rad", num()),
                ("no_fix_reason", int()),
                ("units_used", int()),
            ],
        ),
        "health" => obj(
            "subnav.FilterHealth",
            &[
                ("t_us", t),
                ("aid", aid_statuses()),
                ("imu_q_scale", num()),
                ("lambda", num()),
                ("q_diag", arr(5)),
                ("pd_repairs", int()),
                ("cov_unrepairable", int()),
                ("gate_rejects", int()),
                ("nonfinite_rejects", int()),
                ("late_fused", int()),
                ("late_refused", int()),
                ("heading_resets", int()),
                ("position_resets", int()),
                ("cpu_load_permille", int()),
            ],
        ),
        "fault" => obj(
            "subnav.Fault",
            &[
                ("t_us", t),
                ("source", tagged(&["Imu", "Depth", "Dvl", "Camera", "Link", "Filter", "Scheduler", "Store", "Polarization"])),
                (
                    "kind",
                    tagged(&[
                        "BusNack",
                        "BusTimeout",
                        "BusOther",
                        "BadCrc",
                        "IdentityMismatch",
                        "Stuck",
                        "Saturated",
                        "NonFinite",
                        "CorruptFrame",
                        "Overrun",
                        "TelemetryDropped",
                        "Occluded",
                        "Malformed",
                        "Invalid",
                        "TooOld",
                        "FromFuture",
                    ]),
                ),
                ("count", int()),
            ],
        ),
        "ack" => obj("subnav.CommandAck", &[("seq", int()), ("result", json!({"type": "object"}))]),
        "camera.trigger" => obj("subnav.CameraTrigger", &[("t_us", t), ("frame", int())]),
        "record" => obj("subnav.RecordReport", &[("t_us", t), ("key", json!({})), ("stored", json!({}))]),
        _ => return None,
    };
    let name = s["title"].as_str().unwrap_or(kind).to_string();
    Some((name, s))
}

/// The JSON form of a message (the inner struct's serde form plus `host_t_us`).
pub fn message_json(m: &Uplink, t_host_us: u64) -> Value {
    let inner = match m {
        Uplink::Boot(x) => serde_json::to_value(x),
        Uplink::Nav(x) => serde_json::to_value(x),
        Uplink::Raw(RawSample::Imu(x)) => serde_json::to_value(x),
        Uplink::Raw(RawSample::Polarization(x)) => serde_json::to_value(x),
        Uplink::Raw(RawSample::Depth(x)) => serde_json::to_value(x),
        Uplink::Raw(RawSample::Dvl(x)) => serde_json::to_value(x),
        Uplink::Compass(x) => serde_json::to_value(x),
        Uplink::Health(x) => serde_json::to_value(x),
        Uplink::Fault(x) => serde_json::to_value(x),
        Uplink::Ack(x) => serde_json::to_value(x),
        Uplink::Trigger(x) => serde_json::to_value(x),
        Uplink::Record(x) => serde_json::to_value(x),
    };
    let mut v = inner.unwrap_or(Value::Null);
    if let Value::Object(o) = &mut v {
        o.insert("host_t_us".into(), json!(t_host_us));
    }
    v
}

fn time() -> Value {
    json!({"type": "object", "title": "time", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}})
}

/// `foxglove.PoseInFrame` (JSON Schema form).
pub fn foxglove_pose_in_frame() -> Value {
    let xyz = |title: &str| json!({"title": title, "type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}});
    json!({
        "title": "foxglove.PoseInFrame",
        "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "frame_id": {"type": "string"},
            "pose": {"title": "foxglove.Pose", "type": "object", "properties": {
                "position": xyz("foxglove.Vector3"),
                "orientation": {"title": "foxglove.Quaternion", "type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}, "w": {"type": "number"}}}
            }}
        }
    })
}

/// `foxglove.Log` (JSON Schema form). Level: 0 UNKNOWN, 1 DEBUG, 2 INFO, 3 WARNING, 4 ERROR, 5 FATAL.
pub fn foxglove_log() -> Value {
    json!({
        "title": "foxglove.Log",
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": time(),
            "level": {"title": "foxglove.LogLevel", "type": "integer", "oneOf": [
                {"title": "UNKNOWN", "const": 0}, {"title": "DEBUG", "const": 1}, {"title": "INFO", "const": 2},
                {"title": "WARNING", "const": 3}, {"title": "ERROR", "const": 4}, {"title": "FATAL", "const": 5}]},
            "message": {"type": "string"},
            "name": {"type": "string"},
            "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0}
        }
    })
}

/// Foxglove log level of a defmt level name.
pub fn foxglove_level(level: Option<&str>) -> u8 {
    match level.map(|l| l.to_ascii_lowercase()) {
        Some(l) if l == "trace" || l == "debug" => 1,
        Some(l) if l == "info" => 2,
        Some(l) if l == "warn" => 3,
        Some(l) if l == "error" => 4,
        _ => 0,
    }
}

/// `{sec, nsec}` of a time in µs.
pub fn stamp(t_us: u64) -> Value {
    json!({"sec": t_us / 1_000_000, "nsec": (t_us % 1_000_000) * 1000})
}
