//! JSON Schemas of the exported messages (MCAP `jsonschema` encoding), written out by hand so
//! that Foxglove knows every field, and the JSON form of each message (the serde form of the
//! wire type plus `host_t_us`). Foxglove's well-known `foxglove.PoseInFrame` and `foxglove.Log`
//! are given in their published JSON Schema form, so Foxglove's 3D and Log panels take them.

use serde_json::{Value, json};
use subnav_wire::{RawSample, Uplink};

fn num() -> Value {
    // f32 NaN ("no value yet") serialises as null.
    json!({"type": ["number", "null"]})
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
    let required: Vec<&str> = fields.iter().map(|(k, _)| *k).collect();
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
    let required: Vec<&str> = props.keys().map(|k| k.as_str()).collect();
    json!({"$schema": "http://json-schema.org/draft-07/schema#", "title": title, "type": "object", "properties": props, "required": required})
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
                ("covariance_m2ps2", json!({"type": ["array", "null"], "items": num(), "minItems": 9, "maxItems": 9})),
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
