//! The one definition of subnav's Foxglove topics: names, schemas (JSON Schema, `json` message
//! encoding) and the messages each event of a dive becomes. Both the MCAP export
//! ([`super::mcap`]) and the live WebSocket server ([`crate::live_view`]) take their channels from
//! [`schema_of`] and their messages from a [`Projector`], so a recording opened as MCAP and a dive
//! watched live show the same topics with the same fields.
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/subnav/<kind>` (e.g. `/subnav/nav`, `/subnav/raw.imu`) | `subnav.<Type>` | every uplink message as decoded (see [`schema::KINDS`]) |
//! | `/subnav/pose` | `foxglove.PoseInFrame` | the navigation solution as a pose in frame `ned` |
//! | `/subnav/pose/covariance` | `subnav.PoseCovariance` | the pose with its NED position covariance and the 1-sigma figures |
//! | `/subnav/trajectory` | `foxglove.SceneUpdate` | the trajectory so far (one line strip per second of dive) and the 3-sigma ellipsoid |
//! | `/subnav/truth/pose` | `foxglove.PoseInFrame` | the simulator's true pose (simulated runs only) |
//! | `/subnav/truth/error` | `subnav.TruthError` | heading and position error against the truth, with the filter's sigmas |
//! | `/subnav/compass/fix` | `subnav.CompassFix` | the compass's heading fixes in degrees (reports without a fix are left out) |
//! | `/subnav/health/summary` | `subnav.HealthSummary` | NIS, test ratios (NIS / gate), fading lambda, Q and R diagonals |
//! | `/subnav/faults` | `foxglove.Log` | fault reports as log entries (Foxglove Log panel) |
//! | `/subnav/log` | `foxglove.Log` | decoded defmt log lines |
//! | `/subnav/link/corrupt` | `subnav.CorruptFrame` | corrupt uplink frames, with the error |
//! | `/subnav/map` | `foxglove.SceneUpdate` | the topological map's nodes and the accepted loop closures (runs with the map in the loop) |
//!
//! No message carries a JSON `null`: a value that is not a number yet (NaN while aligning, no
//! fix, an aid not measured yet) is left out and named with why in the message's `no_value`
//! ([`schema::omit_unknown`]); a pose that is not a number is not published.
//!
//! Frame `ned`: x north, y east, z down, metres; the pose's orientation is the body->NED
//! quaternion. Foxglove's well-known schemas are given in their JSON Schema form with the fields
//! subnav fills.

use serde_json::{Value, json};
use subnav_core::ukf::wrap_deg;
use subnav_wire::{NavMode, NavSolution, Uplink};

use super::TimeBase;
use super::schema::{self, foxglove_json, foxglove_level, nav_why, no_value_schema, omit_unknown, stamp};

pub const POSE: &str = "/subnav/pose";
pub const COVARIANCE: &str = "/subnav/pose/covariance";
pub const TRAJECTORY: &str = "/subnav/trajectory";
pub const TRUTH_POSE: &str = "/subnav/truth/pose";
pub const TRUTH_ERROR: &str = "/subnav/truth/error";
pub const COMPASS_FIX: &str = "/subnav/compass/fix";
pub const HEALTH_SUMMARY: &str = "/subnav/health/summary";
pub const FAULTS: &str = "/subnav/faults";
pub const LOG: &str = "/subnav/log";
pub const CORRUPT: &str = "/subnav/link/corrupt";
pub const MAP: &str = "/subnav/map";

/// The frame every pose and scene entity is drawn in.
pub const FRAME: &str = "ned";

/// Seconds of dive per trajectory segment.
const SEGMENT_US: u64 = 1_000_000;

/// The topic of an uplink message kind.
pub fn uplink_topic(kind: &str) -> String {
    format!("/subnav/{kind}")
}

/// Schema name and JSON Schema of a topic (`None` for a topic subnav does not publish).
pub fn schema_of(topic: &str) -> Option<(String, Value)> {
    let named = |name: &str, s: Value| Some((name.to_string(), s));
    match topic {
        POSE | TRUTH_POSE => named("foxglove.PoseInFrame", schema::foxglove_pose_in_frame()),
        COVARIANCE => named("subnav.PoseCovariance", pose_covariance_schema()),
        TRAJECTORY | MAP => named("foxglove.SceneUpdate", scene_update_schema()),
        TRUTH_ERROR => named("subnav.TruthError", truth_error_schema()),
        COMPASS_FIX => named("subnav.CompassFix", compass_fix_schema()),
        HEALTH_SUMMARY => named("subnav.HealthSummary", health_summary_schema()),
        FAULTS | LOG => named("foxglove.Log", schema::foxglove_log()),
        CORRUPT => named("subnav.CorruptFrame", corrupt_schema()),
        t => schema::for_kind(t.strip_prefix("/subnav/")?),
    }
}

/// One message on one topic.
#[derive(Debug, Clone, PartialEq)]
pub struct Msg {
    pub topic: String,
    /// Log time, µs (host or sensor time, as the [`Projector`]'s time base says).
    pub t_us: u64,
    /// Publish time: the host time the event was received, µs.
    pub publish_us: u64,
    pub json: Value,
}

/// A map node (id, NE position, m) and an accepted loop closure (the node it recognised and
/// the vehicle's estimated NE position at the image's time). The map is horizontal: both are
/// drawn at the vehicle's latest depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapNode {
    pub id: usize,
    pub pos_ne_m: [f64; 2],
}
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapClosure {
    pub t_us: u64,
    pub node_ne_m: [f64; 2],
    pub estimate_ne_m: [f64; 2],
}

/// Turns a dive's events (uplink messages, log lines, corrupt frames, truth, map) into the
/// messages of the topics above. Stateful: it keeps the sensor clock (for messages without their
/// own time), the latest solution (for the truth error) and the trajectory so far.
#[derive(Debug, Clone)]
pub struct Projector {
    time: TimeBase,
    last_sensor_us: u64,
    last_nav: Option<NavSolution>,
    /// Every trajectory point (t_us, NED m) so far, and where the current segment starts.
    path: Vec<(u64, [f64; 3])>,
    segment_start: usize,
    segment_t0_us: Option<u64>,
    segments: u64,
}

fn xyz(p: [f64; 3]) -> Value {
    json!({"x": p[0], "y": p[1], "z": p[2]})
}
fn identity_pose() -> Value {
    json!({"position": xyz([0.0; 3]), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}})
}
fn color(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({"r": r, "g": g, "b": b, "a": a})
}
fn f(x: f32) -> f64 {
    f64::from(x)
}
/// Yaw of a body->NED quaternion, rad.
pub fn yaw_rad(att_nb_wxyz: [f32; 4]) -> f64 {
    let [w, x, y, z] = att_nb_wxyz.map(f64::from);
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}
/// A finite number, or JSON null (a NaN "no value yet"), which [`omit_unknown`] then takes out.
fn num(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { Value::Null }
}

/// A scene entity with every list Foxglove's `SceneEntity` has (empty unless given).
fn entity(t_us: u64, id: &str, lines: Vec<Value>, spheres: Vec<Value>) -> Value {
    json!({
        "timestamp": stamp(t_us), "frame_id": FRAME, "id": id, "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": false,
        "metadata": [], "arrows": [], "cubes": [], "spheres": spheres, "cylinders": [], "lines": lines,
        "triangles": [], "texts": [], "models": []
    })
}
fn line_strip(points: &[[f64; 3]], thickness: f64, c: Value) -> Value {
    json!({"type": 0, "pose": identity_pose(), "thickness": thickness, "scale_invariant": true,
           "points": points.iter().map(|p| xyz(*p)).collect::<Vec<_>>(), "color": c, "colors": [], "indices": []})
}
fn sphere(center: [f64; 3], size: [f64; 3], c: Value) -> Value {
    json!({"pose": {"position": xyz(center), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}, "size": xyz(size), "color": c})
}

impl Projector {
    pub fn new(time: TimeBase) -> Self {
        Self { time, last_sensor_us: 0, last_nav: None, path: Vec::new(), segment_start: 0, segment_t0_us: None, segments: 0 }
    }

    fn t(&self, t_host_us: u64) -> u64 {
        match self.time {
            TimeBase::Host => t_host_us,
            TimeBase::Sensor => self.last_sensor_us,
        }
    }

    /// An uplink message received at host time `t_host_us`.
    pub fn uplink(&mut self, t_host_us: u64, m: &Uplink, out: &mut Vec<Msg>) {
        if let Some(ts) = m.t_us() {
            self.last_sensor_us = ts;
        }
        let t = self.t(t_host_us);
        let push =
            |out: &mut Vec<Msg>, topic: &str, json: Value| out.push(Msg { topic: topic.to_string(), t_us: t, publish_us: t_host_us, json });
        // A derived message without nulls: each left-out field and why.
        let push_omitting = |out: &mut Vec<Msg>, topic: &str, mut json: Value, why: &dyn Fn(&str) -> &'static str| {
            omit_unknown(&mut json, why);
            push(out, topic, json)
        };
        push(out, &uplink_topic(m.kind()), foxglove_json(m, t_host_us));
        match m {
            Uplink::Nav(n) => {
                self.last_nav = Some(*n);
                let [w, x, y, z] = n.att_nb_wxyz;
                let pose = json!({"position": {"x": n.pos_ned_m[0], "y": n.pos_ned_m[1], "z": n.pos_ned_m[2]},
                                  "orientation": {"x": x, "y": y, "z": z, "w": w}});
                // A pose only once it is a number (Foxglove's schema has no "no value").
                let pose_known = n.pos_ned_m.iter().chain(&n.att_nb_wxyz).all(|v| v.is_finite());
                if pose_known {
                    push(out, POSE, json!({"timestamp": stamp(t), "frame_id": FRAME, "pose": pose.clone()}));
                }
                let pose = if pose_known { pose } else { Value::Null };
                let why = |_: &str| nav_why(n.mode);
                let [sn, se, sd] = n.sigma_pos_m.map(f);
                let cne = f(n.cov_ne_m2);
                let cov = [sn * sn, cne, 0.0, cne, se * se, 0.0, 0.0, 0.0, sd * sd];
                push_omitting(
                    out,
                    COVARIANCE,
                    json!({
                        "timestamp": stamp(t), "frame_id": FRAME, "mode": format!("{:?}", n.mode), "pose": pose,
                        "covariance_ned_m2": cov.map(num), "sigma_pos_m": [num(sn), num(se), num(sd)],
                        "sigma_horizontal_m": num((sn * sn + se * se).sqrt()),
                        "heading_deg": num(yaw_rad(n.att_nb_wxyz).to_degrees()),
                        "sigma_heading_deg": num(f(n.sigma_att_rad[2]).to_degrees()),
                        "sigma_att_deg": n.sigma_att_rad.map(|s| num(f(s).to_degrees())),
                    }),
                    &why,
                );
                self.trajectory_point(t, n, out, t_host_us);
            }
            Uplink::Compass(c) => {
                if let Some(h) = c.heading_rad {
                    let nav = self.last_nav.map(|n| yaw_rad(n.att_nb_wxyz).to_degrees());
                    let nav_mode = self.last_nav.map(|n| n.mode);
                    let h_deg = f(h).to_degrees().rem_euclid(360.0);
                    let why = |p: &str| match (p, nav_mode) {
                        ("nav_heading_deg" | "innovation_deg", None) => "no solution yet",
                        ("nav_heading_deg" | "innovation_deg", Some(mode)) => nav_why(mode),
                        _ => "not finite",
                    };
                    push_omitting(
                        out,
                        COMPASS_FIX,
                        json!({
                            "timestamp": stamp(t), "heading_deg": num(h_deg), "sigma_heading_deg": num(f(c.sigma_heading_rad).to_degrees()),
                            "nav_heading_deg": nav.map_or(Value::Null, |x| num(x.rem_euclid(360.0))),
                            "innovation_deg": nav.map_or(Value::Null, |x| num(wrap_deg(h_deg - x))),
                            "units_used": c.units_used,
                        }),
                        &why,
                    );
                }
            }
            Uplink::Health(h) => {
                let mut aid = serde_json::Map::new();
                for src in subnav_wire::AidSource::ALL {
                    let a = h.aid.get(src);
                    aid.insert(
                        src.name().into(),
                        json!({"nis": num(f(a.nis)), "test_ratio": num(f(a.test_ratio)), "noise_var": num(f(a.noise_var)), "fused": a.fused,
                               "fused_count": a.fused_count, "refused_count": a.refused_count, "resets": a.resets}),
                    );
                }
                push_omitting(
                    out,
                    HEALTH_SUMMARY,
                    json!({
                        "timestamp": stamp(t), "aid": aid, "imu_q_scale": num(f(h.imu_q_scale)), "lambda": num(f(h.lambda)),
                        "q_diag": h.q_diag.map(|x| num(f(x))),
                        "gate_rejects": h.gate_rejects, "pd_repairs": h.pd_repairs, "cov_unrepairable": h.cov_unrepairable,
                        "nonfinite_rejects": h.nonfinite_rejects, "cpu_load_permille": h.cpu_load_permille,
                    }),
                    &|p: &str| if p.starts_with("aid.") { "not measured yet" } else { "not finite" },
                );
            }
            Uplink::Fault(x) => {
                let msg = format!("fault: {:?} {:?} (count {})", x.source, x.kind, x.count);
                push(out, FAULTS, json!({"timestamp": stamp(t), "level": 3, "message": msg, "name": "fault", "file": "", "line": 0}));
            }
            _ => {}
        }
    }

    fn trajectory_point(&mut self, t: u64, n: &NavSolution, out: &mut Vec<Msg>, t_host_us: u64) {
        let p = n.pos_ned_m.map(f);
        if n.mode == NavMode::Uninitialised || p.iter().any(|v| !v.is_finite()) {
            return;
        }
        self.path.push((t, p));
        let t0 = *self.segment_t0_us.get_or_insert(n.t_us);
        if n.t_us.saturating_sub(t0) < SEGMENT_US {
            return;
        }
        // The segment, from the last point of the previous one (so the strips join).
        let from = self.segment_start.saturating_sub(1);
        let pts: Vec<[f64; 3]> = self.path.get(from..).unwrap_or(&[]).iter().map(|(_, p)| *p).collect();
        let seg = entity(t, &format!("segment-{}", self.segments), vec![line_strip(&pts, 2.0, color(0.1, 0.6, 1.0, 1.0))], vec![]);
        let mut entities = vec![seg];
        let sigma = n.sigma_pos_m.map(f);
        if sigma.iter().all(|s| s.is_finite()) {
            let size = sigma.map(|s| 6.0 * s);
            entities.push(entity(t, "sigma3", vec![], vec![sphere(p, size, color(1.0, 0.6, 0.1, 0.3))]));
        }
        out.push(Msg { topic: TRAJECTORY.into(), t_us: t, publish_us: t_host_us, json: json!({"deletions": [], "entities": entities}) });
        self.segments += 1;
        self.segment_start = self.path.len();
        self.segment_t0_us = Some(n.t_us);
    }

    /// The whole trajectory so far as one scene update (entity `history`), for a viewer that
    /// joins during a dive; `None` before the first point.
    pub fn trajectory_history(&self) -> Option<Msg> {
        let (t_last, _) = self.path.last()?;
        let pts: Vec<[f64; 3]> = self.path.iter().map(|(_, p)| *p).collect();
        let t = *t_last;
        let e = entity(t, "history", vec![line_strip(&pts, 2.0, color(0.1, 0.6, 1.0, 1.0))], vec![]);
        Some(Msg { topic: TRAJECTORY.into(), t_us: t, publish_us: t, json: json!({"deletions": [], "entities": [e]}) })
    }

    /// A decoded defmt log line.
    pub fn log(&mut self, t_host_us: u64, l: &crate::defmt_log::LogLine, out: &mut Vec<Msg>) {
        let t = self.t(t_host_us);
        let json = json!({"timestamp": stamp(t), "level": foxglove_level(l.level.as_deref()), "message": l.message, "name": "firmware", "file": "", "line": 0});
        out.push(Msg { topic: LOG.into(), t_us: t, publish_us: t_host_us, json });
    }

    /// A corrupt uplink frame.
    pub fn corrupt(&mut self, t_host_us: u64, error: &str, out: &mut Vec<Msg>) {
        let t = self.t(t_host_us);
        out.push(Msg { topic: CORRUPT.into(), t_us: t, publish_us: t_host_us, json: json!({"host_t_us": t_host_us, "error": error}) });
    }

    /// The simulator's truth at sensor time `t_sensor_us`: NED position (m) and yaw (rad).
    pub fn truth(&mut self, t_host_us: u64, t_sensor_us: u64, pos_ned_m: [f64; 3], yaw_rad_true: f64, out: &mut Vec<Msg>) {
        let t = match self.time {
            TimeBase::Host => t_host_us,
            TimeBase::Sensor => t_sensor_us,
        };
        let (s, c) = (0.5 * yaw_rad_true).sin_cos();
        let pose = json!({"position": xyz(pos_ned_m), "orientation": {"x": 0.0, "y": 0.0, "z": s, "w": c}});
        out.push(Msg {
            topic: TRUTH_POSE.into(),
            t_us: t,
            publish_us: t_host_us,
            json: json!({"timestamp": stamp(t), "frame_id": FRAME, "pose": pose}),
        });
        let Some(n) = self.last_nav else { return };
        // The run's scoring (`crate::score`), epoch by epoch.
        let e = crate::score::epoch(&n, &crate::score::Truth { pos_ned_m, yaw_rad: yaw_rad_true });
        let mut json = json!({
            "timestamp": stamp(t), "nav_t_us": n.t_us, "mode": format!("{:?}", n.mode),
            "heading_error_deg": num(e.heading_err_deg),
            "sigma_heading_deg": num(e.sigma_heading_deg),
            "horizontal_error_m": num(e.horizontal_err_m), "sigma_horizontal_m": num(e.sigma_horizontal_m),
            "depth_error_m": num(e.err_ned_m[2]),
            "heading_converged": e.heading_converged,
        });
        omit_unknown(&mut json, |_| nav_why(n.mode));
        out.push(Msg { topic: TRUTH_ERROR.into(), t_us: t, publish_us: t_host_us, json });
    }

    /// The map as it is now: every node (spheres) and every accepted loop closure (a line from
    /// the vehicle's estimate to the node it recognised), replacing the previous map.
    pub fn map(&mut self, t_host_us: u64, nodes: &[MapNode], closures: &[MapClosure], out: &mut Vec<Msg>) {
        let t = self.t(t_host_us);
        let d = self.last_nav.map_or(0.0, |n| f(n.pos_ned_m[2])).max(0.0);
        let d = if d.is_finite() { d } else { 0.0 };
        let spheres: Vec<Value> =
            nodes.iter().map(|n| sphere([n.pos_ne_m[0], n.pos_ne_m[1], d], [1.0, 1.0, 1.0], color(0.2, 0.9, 0.3, 0.9))).collect();
        let lines: Vec<Value> = closures
            .iter()
            .map(|c| {
                let est = [c.estimate_ne_m[0], c.estimate_ne_m[1], d];
                let node = [c.node_ne_m[0], c.node_ne_m[1], d];
                json!({"type": 1, "pose": identity_pose(), "thickness": 1.0, "scale_invariant": true,
                       "points": [xyz(est), xyz(node)], "color": color(1.0, 0.2, 0.8, 1.0), "colors": [], "indices": []})
            })
            .collect();
        let e = vec![entity(t, "map-nodes", vec![], spheres), entity(t, "loop-closures", lines, vec![])];
        out.push(Msg { topic: MAP.into(), t_us: t, publish_us: t_host_us, json: json!({"deletions": [], "entities": e}) });
    }
}

/// A message schema: every field required but those [`omit_unknown`] may leave out (numbers and
/// the `pose` of a solution that is not a number yet), plus `no_value`.
fn base(title: &str, mut props: Value) -> Value {
    let required: Vec<String> = props
        .as_object()
        .map(|o| o.iter().filter(|(k, v)| *k != "pose" && !schema::may_be_omitted(v)).map(|(k, _)| k.clone()).collect())
        .unwrap_or_default();
    if let Some(o) = props.as_object_mut() {
        o.insert("no_value".into(), no_value_schema());
    }
    json!({"$schema": "http://json-schema.org/draft-07/schema#", "title": title, "type": "object", "properties": props, "required": required})
}
fn n() -> Value {
    json!({"type": "number"})
}
fn narr(k: usize) -> Value {
    json!({"type": "array", "items": n(), "minItems": k, "maxItems": k})
}
fn time_schema() -> Value {
    json!({"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}, "required": ["sec", "nsec"]})
}
fn vec3_schema() -> Value {
    json!({"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}, "required": ["x", "y", "z"]})
}
fn pose_schema() -> Value {
    json!({"type": "object", "properties": {"position": vec3_schema(), "orientation": {"type": "object",
        "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}, "w": {"type": "number"}}, "required": ["x", "y", "z", "w"]}},
        "required": ["position", "orientation"]})
}
fn color_schema() -> Value {
    json!({"type": "object", "properties": {"r": {"type": "number"}, "g": {"type": "number"}, "b": {"type": "number"}, "a": {"type": "number"}}, "required": ["r", "g", "b", "a"]})
}

fn pose_covariance_schema() -> Value {
    base(
        "subnav.PoseCovariance",
        json!({
            "timestamp": time_schema(), "frame_id": {"type": "string"}, "mode": {"type": "string"}, "pose": pose_schema(),
            "covariance_ned_m2": narr(9), "sigma_pos_m": narr(3), "sigma_horizontal_m": n(), "heading_deg": n(),
            "sigma_heading_deg": n(), "sigma_att_deg": narr(3),
        }),
    )
}
fn truth_error_schema() -> Value {
    base(
        "subnav.TruthError",
        json!({
            "timestamp": time_schema(), "nav_t_us": {"type": "integer"}, "mode": {"type": "string"}, "heading_error_deg": n(),
            "sigma_heading_deg": n(), "horizontal_error_m": n(), "sigma_horizontal_m": n(), "depth_error_m": n(),
            "heading_converged": {"type": "boolean", "description": "the yaw 1-sigma is within the scoring's convergence bound (subnav_link::score)"},
        }),
    )
}
fn compass_fix_schema() -> Value {
    base(
        "subnav.CompassFix",
        json!({
            "timestamp": time_schema(), "heading_deg": n(), "sigma_heading_deg": n(), "nav_heading_deg": n(), "innovation_deg": n(),
            "units_used": {"type": "integer"},
        }),
    )
}
/// Per aid source (by name): its latest NIS, test ratio (NIS / gate), noise variance, whether it
/// was fused, and its counts.
fn aid_summary_schema() -> Value {
    let int = json!({"type": "integer", "minimum": 0});
    let one = json!({"type": "object", "properties": {
        "nis": n(), "test_ratio": n(), "noise_var": n(), "fused": {"type": "boolean"},
        "fused_count": int, "refused_count": int, "resets": int,
    }});
    let props: serde_json::Map<String, Value> = subnav_wire::AidSource::ALL.iter().map(|s| (s.name().to_string(), one.clone())).collect();
    json!({"type": "object", "properties": props})
}
fn health_summary_schema() -> Value {
    let int = json!({"type": "integer", "minimum": 0});
    base(
        "subnav.HealthSummary",
        json!({
            "timestamp": time_schema(), "aid": aid_summary_schema(), "imu_q_scale": n(), "lambda": n(), "q_diag": narr(5),
            "gate_rejects": int, "pd_repairs": int, "cov_unrepairable": int, "nonfinite_rejects": int, "cpu_load_permille": int,
        }),
    )
}
fn corrupt_schema() -> Value {
    base("subnav.CorruptFrame", json!({"host_t_us": {"type": "integer"}, "error": {"type": "string"}}))
}

/// `foxglove.SceneUpdate` (JSON Schema form, with the entity fields subnav uses: line strips,
/// line lists and spheres; the other primitive lists are present and empty).
pub fn scene_update_schema() -> Value {
    let arr = |items: Value| json!({"type": "array", "items": items});
    let line = json!({"type": "object", "properties": {
        "type": {"type": "integer", "enum": [0, 1, 2]}, "pose": pose_schema(), "thickness": {"type": "number", "minimum": 0},
        "scale_invariant": {"type": "boolean"}, "points": arr(vec3_schema()), "color": color_schema(), "colors": arr(color_schema()),
        "indices": arr(json!({"type": "integer", "minimum": 0}))}, "required": ["type", "pose", "thickness", "scale_invariant", "points", "color"]});
    let sphere = json!({"type": "object", "properties": {"pose": pose_schema(), "size": vec3_schema(), "color": color_schema()}, "required": ["pose", "size", "color"]});
    let entity = json!({"type": "object", "title": "foxglove.SceneEntity", "properties": {
        "timestamp": time_schema(), "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_locked": {"type": "boolean"}, "metadata": arr(json!({"type": "object"})), "arrows": arr(json!({"type": "object"})),
        "cubes": arr(json!({"type": "object"})), "spheres": arr(sphere), "cylinders": arr(json!({"type": "object"})), "lines": arr(line),
        "triangles": arr(json!({"type": "object"})), "texts": arr(json!({"type": "object"})), "models": arr(json!({"type": "object"}))},
        "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "lines", "spheres"]});
    let deletion =
        json!({"type": "object", "properties": {"timestamp": time_schema(), "type": {"type": "integer"}, "id": {"type": "string"}}});
    json!({"$schema": "http://json-schema.org/draft-07/schema#", "title": "foxglove.SceneUpdate", "description": "An update to the entities displayed in a 3D scene",
           "type": "object", "properties": {"deletions": arr(deletion), "entities": arr(entity)}, "required": ["deletions", "entities"]})
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nav(t_us: u64, n_m: f32) -> Uplink {
        Uplink::Nav(NavSolution {
            t_us,
            mode: NavMode::Aided,
            pos_ned_m: [n_m, 0.0, 5.0],
            vel_ned_mps: [1.0, 0.0, 0.0],
            att_nb_wxyz: [1.0, 0.0, 0.0, 0.0],
            sigma_pos_m: [0.5, 0.4, 0.1],
            sigma_vel_mps: [0.1; 3],
            sigma_att_rad: [0.01; 3],
            cov_ne_m2: 0.01,
        })
    }

    #[test]
    fn every_topic_a_projector_writes_has_a_schema_and_trajectory_segments_join() {
        let mut p = Projector::new(TimeBase::Sensor);
        let mut out = Vec::new();
        for k in 0..25u64 {
            p.uplink(k, &nav(k * 100_000, k as f32), &mut out);
        }
        p.truth(30, 2_400_000, [24.5, 0.0, 5.0], 0.1, &mut out);
        p.map(31, &[MapNode { id: 1, pos_ne_m: [1.0, 2.0] }], &[], &mut out);
        for m in &out {
            assert!(schema_of(&m.topic).is_some(), "{} has no schema", m.topic);
        }
        let segs: Vec<&Msg> = out.iter().filter(|m| m.topic == TRAJECTORY).collect();
        // 2.4 s of solutions: segments closed at 1.0 s and 2.0 s; the second starts at the first's end.
        assert_eq!(segs.len(), 2);
        let pts = |m: &Msg| m.json["entities"][0]["lines"][0]["points"].as_array().unwrap().clone();
        assert_eq!(pts(segs[0]).len(), 11);
        assert_eq!(pts(segs[1]).first(), pts(segs[0]).last());
        // Truth error: nav 24 m north, truth 24.5 m; yaw 0 vs 0.1 rad.
        let e = out.iter().find(|m| m.topic == TRUTH_ERROR).unwrap();
        assert!((e.json["horizontal_error_m"].as_f64().unwrap() - 0.5).abs() < 1e-6);
        assert!((e.json["heading_error_deg"].as_f64().unwrap() + 0.1f64.to_degrees()).abs() < 1e-4);
        assert_eq!(p.trajectory_history().unwrap().json["entities"][0]["lines"][0]["points"].as_array().unwrap().len(), 25);
    }

    fn has_null(v: &Value) -> bool {
        match v {
            Value::Null => true,
            Value::Array(a) => a.iter().any(has_null),
            Value::Object(o) => o.values().any(has_null),
            _ => false,
        }
    }

    #[test]
    fn while_aligning_no_message_has_a_null_and_each_left_out_field_says_why() {
        let nan = f32::NAN;
        let aligning = NavSolution {
            t_us: 1_000,
            mode: NavMode::Aligning,
            pos_ned_m: [nan; 3],
            vel_ned_mps: [nan; 3],
            att_nb_wxyz: [nan; 4],
            sigma_pos_m: [nan; 3],
            sigma_vel_mps: [nan; 3],
            sigma_att_rad: [nan; 3],
            cov_ne_m2: nan,
        };
        let compass = subnav_wire::CompassReport {
            t_us: 1_000,
            heading_rad: Some(0.5),
            sigma_heading_rad: 0.01,
            sun_rel_azimuth_rad: nan,
            sun_elevation_rad: 0.3,
            no_fix_reason: 0,
            units_used: 4,
        };
        let no_fix = subnav_wire::CompassReport { heading_rad: None, sigma_heading_rad: nan, no_fix_reason: 3, ..compass };
        let health = subnav_wire::FilterHealth {
            t_us: 1_000,
            aid: subnav_wire::AidStatuses { depth: subnav_wire::AidStatus { nis: nan, ..Default::default() }, ..Default::default() },
            imu_q_scale: 1.0,
            lambda: nan,
            q_diag: [1e-6; 5],
            pd_repairs: 0,
            cov_unrepairable: 0,
            gate_rejects: 0,
            nonfinite_rejects: 0,
            late_fused: 0,
            late_refused: 0,
            heading_resets: 0,
            position_resets: 0,
            cpu_load_permille: 0,
        };
        let mut p = Projector::new(TimeBase::Sensor);
        let mut out = Vec::new();
        for m in [Uplink::Nav(aligning), Uplink::Compass(compass), Uplink::Compass(no_fix), Uplink::Health(health)] {
            p.uplink(1, &m, &mut out);
        }
        p.truth(2, 1_000, [0.0; 3], 0.0, &mut out);
        for m in &out {
            assert!(!has_null(&m.json), "{}: {}", m.topic, m.json);
            // Every field is in the schema, every required one is there.
            let (_, s) = schema_of(&m.topic).unwrap();
            for k in m.json.as_object().unwrap().keys() {
                assert!(s["properties"].get(k).is_some(), "{}: {k} not in its schema", m.topic);
            }
            for k in s["required"].as_array().into_iter().flatten() {
                assert!(m.json.get(k.as_str().unwrap()).is_some(), "{}: {k} missing: {}", m.topic, m.json);
            }
        }
        let on = |t: &str| out.iter().find(|m| m.topic == t).unwrap_or_else(|| panic!("no {t}")).json.clone();
        // No pose while aligning; the solution's numbers left out, each saying "aligning".
        assert!(out.iter().all(|m| m.topic != POSE));
        let nav = on("/subnav/nav");
        assert_eq!(nav["mode"], "Aligning");
        assert!(nav.get("pos_ned_m").is_none());
        for k in ["pos_ned_m", "vel_ned_mps", "att_nb_wxyz", "sigma_pos_m", "cov_ne_m2"] {
            assert_eq!(nav["no_value"][k], "aligning", "{nav}");
        }
        assert_eq!(on(COVARIANCE)["no_value"]["pose"], "aligning");
        assert_eq!(on(TRUTH_ERROR)["no_value"]["horizontal_error_m"], "aligning");
        let fix = on(COMPASS_FIX);
        assert_eq!(fix["heading_deg"].as_f64().unwrap().round(), 29.0);
        assert_eq!(fix["no_value"]["innovation_deg"], "aligning");
        let compass: Vec<Value> = out.iter().filter(|m| m.topic == "/subnav/compass").map(|m| m.json.clone()).collect();
        assert_eq!(compass[0]["no_value"]["sun_rel_azimuth_rad"], "not finite");
        assert_eq!(compass[1]["no_value"]["heading_rad"], "no fix");
        assert_eq!(compass[1]["no_fix_reason"], 3);
        assert_eq!(on("/subnav/health")["no_value"]["lambda"], "not finite");
        assert_eq!(on("/subnav/health")["no_value"]["aid.depth.nis"], "not measured yet");
        assert_eq!(on(HEALTH_SUMMARY)["no_value"]["aid.depth.nis"], "not measured yet");
        // The CSV form keeps the serde form (an empty cell).
        assert!(schema::message_json(&Uplink::Nav(aligning), 1)["pos_ned_m"][0].is_null());
    }
}
