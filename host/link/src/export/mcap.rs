//! MCAP export (the `mcap` crate's writer), JSON-encoded messages with JSON Schemas:
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/subnav/<kind>` (e.g. `/subnav/nav`, `/subnav/raw.imu`) | `subnav.<Type>` | every uplink message, one channel per kind present |
//! | `/subnav/pose` | `foxglove.PoseInFrame` | navigation solutions as poses in frame `ned` (Foxglove 3D panel) |
//! | `/subnav/log` | `foxglove.Log` | decoded defmt log lines (Foxglove Log panel) |
//! | `/subnav/link/corrupt` | `subnav.CorruptFrame` | corrupt uplink frames, with the error |
//!
//! The NED position goes to the pose as-is (x north, y east, z down) with the body->NED
//! quaternion; Foxglove draws it in the `ned` frame.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use anyhow::{Context, Result, anyhow};
use serde::Serialize;
use serde_json::json;
use subnav_wire::Uplink;

use super::TimeBase;
use super::schema::{self, foxglove_level, message_json, stamp};
use crate::record::session::Session;

/// What an export wrote: messages per topic.
#[derive(Debug, Clone, Default, Serialize)]
pub struct McapSummary {
    pub topics: BTreeMap<String, u64>,
    pub messages: u64,
}

struct Out<W: Write + Seek> {
    w: mcap::Writer<W>,
    channels: BTreeMap<String, u16>,
    seq: BTreeMap<u16, u32>,
    summary: McapSummary,
}

fn e(err: mcap::McapError) -> anyhow::Error {
    anyhow!("writing MCAP: {err}")
}

impl<W: Write + Seek> Out<W> {
    fn channel(&mut self, topic: &str, schema_name: &str, schema: &serde_json::Value) -> Result<u16> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let data = serde_json::to_vec(schema)?;
        let sid = self.w.add_schema(schema_name, "jsonschema", &data).map_err(e)?;
        let cid = self.w.add_channel(sid, topic, "json", &BTreeMap::new()).map_err(e)?;
        self.channels.insert(topic.to_string(), cid);
        Ok(cid)
    }

    fn write(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema: &serde_json::Value,
        t_us: u64,
        publish_us: u64,
        msg: &serde_json::Value,
    ) -> Result<()> {
        let cid = self.channel(topic, schema_name, schema)?;
        let seq = self.seq.entry(cid).or_insert(0);
        *seq += 1;
        let header = mcap::records::MessageHeader {
            channel_id: cid,
            sequence: *seq,
            log_time: t_us.saturating_mul(1000),
            publish_time: publish_us.saturating_mul(1000),
        };
        self.w.write_to_known_channel(&header, &serde_json::to_vec(msg)?).map_err(e)?;
        *self.summary.topics.entry(topic.to_string()).or_insert(0) += 1;
        self.summary.messages += 1;
        Ok(())
    }
}

/// Write `session` as MCAP to `out`. `progress` is called with (items done, items total).
pub fn write<W: Write + Seek>(session: &Session, out: W, time: TimeBase, mut progress: impl FnMut(u64, u64)) -> Result<McapSummary> {
    let w = mcap::WriteOptions::new().profile("").library(format!("subnav {}", env!("CARGO_PKG_VERSION"))).create(out).map_err(e)?;
    let mut o = Out { w, channels: BTreeMap::new(), seq: BTreeMap::new(), summary: McapSummary::default() };
    let pose_schema = schema::foxglove_pose_in_frame();
    let log_schema = schema::foxglove_log();
    let corrupt_schema = json!({"title": "subnav.CorruptFrame", "type": "object", "properties": {"host_t_us": {"type": "integer"}, "error": {"type": "string"}}, "required": ["host_t_us", "error"]});

    // Merge the streams in host-time order (each is already in order).
    enum Ev<'a> {
        Msg(&'a Uplink),
        Log(&'a crate::defmt_log::LogLine),
        Corrupt(&'a str),
    }
    let mut evs: Vec<(u64, usize, Ev)> = Vec::with_capacity(session.messages.len() + session.logs.len() + session.corrupt.len());
    for (i, m) in session.messages.iter().enumerate() {
        evs.push((m.t_host_us, i, Ev::Msg(&m.item)));
    }
    for (i, l) in session.logs.iter().enumerate() {
        evs.push((l.t_host_us, i, Ev::Log(&l.item)));
    }
    for (i, c) in session.corrupt.iter().enumerate() {
        evs.push((c.t_host_us, i, Ev::Corrupt(&c.item)));
    }
    evs.sort_by_key(|(t, i, ev)| (*t, matches!(ev, Ev::Log(_)), *i));
    let total = evs.len() as u64;

    let mut last_sensor_us = 0u64;
    for (k, (t_host, _, ev)) in evs.into_iter().enumerate() {
        if k % 4096 == 0 {
            progress(k as u64, total);
        }
        let sensor = match &ev {
            Ev::Msg(m) => m.t_us().unwrap_or(last_sensor_us),
            _ => last_sensor_us,
        };
        last_sensor_us = sensor;
        let t = match time {
            TimeBase::Host => t_host,
            TimeBase::Sensor => sensor,
        };
        match ev {
            Ev::Msg(m) => {
                let kind = m.kind();
                let (name, s) = schema::for_kind(kind).context("a message kind without a schema")?;
                o.write(&format!("/subnav/{kind}"), &name, &s, t, t_host, &message_json(m, t_host))?;
                if let Uplink::Nav(n) = m {
                    let [w, x, y, z] = n.att_nb_wxyz;
                    let pose = json!({
                        "timestamp": stamp(t),
                        "frame_id": "ned",
                        "pose": {"position": {"x": n.pos_ned_m[0], "y": n.pos_ned_m[1], "z": n.pos_ned_m[2]},
                                 "orientation": {"x": x, "y": y, "z": z, "w": w}}
                    });
                    o.write("/subnav/pose", "foxglove.PoseInFrame", &pose_schema, t, t_host, &pose)?;
                }
            }
            Ev::Log(l) => {
                let msg = json!({"timestamp": stamp(t), "level": foxglove_level(l.level.as_deref()), "message": l.message, "name": "firmware", "file": "", "line": 0});
                o.write("/subnav/log", "foxglove.Log", &log_schema, t, t_host, &msg)?;
            }
            Ev::Corrupt(c) => {
                o.write(
                    "/subnav/link/corrupt",
                    "subnav.CorruptFrame",
                    &corrupt_schema,
                    t,
                    t_host,
                    &json!({"host_t_us": t_host, "error": c}),
                )?;
            }
        }
    }
    progress(total, total);
    o.w.finish().map_err(e)?;
    Ok(o.summary)
}
