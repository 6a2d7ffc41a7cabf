//! MCAP export (the `mcap` crate's writer), JSON-encoded messages with JSON Schemas, on the
//! topics of [`super::topics`] (the same ones the live server publishes): every uplink message on
//! `/subnav/<kind>`, the pose, its covariance, the trajectory, compass fixes, the filter's
//! health, faults and defmt logs as `foxglove.Log`, corrupt frames. A recording holds no truth
//! and no map, so those topics are only live (or in `subnav export --foxglove`).

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use anyhow::{Context, Result, anyhow};
use serde::Serialize;

use super::topics::{Msg, Projector, schema_of};
use super::{Event, TimeBase};
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

/// The MCAP error with its cause (an I/O error names the file: "No space left on device").
fn e(err: mcap::McapError) -> anyhow::Error {
    match &err {
        mcap::McapError::Io(io) => anyhow!("writing MCAP: {io}"),
        _ => anyhow!("writing MCAP: {err}"),
    }
}

impl<W: Write + Seek> Out<W> {
    fn channel(&mut self, topic: &str) -> Result<u16> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let (schema_name, schema) = schema_of(topic).with_context(|| format!("the topic {topic} has no schema"))?;
        let data = serde_json::to_vec(&schema)?;
        let sid = self.w.add_schema(&schema_name, "jsonschema", &data).map_err(e)?;
        let cid = self.w.add_channel(sid, topic, "json", &BTreeMap::new()).map_err(e)?;
        self.channels.insert(topic.to_string(), cid);
        Ok(cid)
    }

    fn write(&mut self, m: &Msg) -> Result<()> {
        let (topic, t_us, publish_us, msg) = (m.topic.as_str(), m.t_us, m.publish_us, &m.json);
        let cid = self.channel(topic)?;
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
    let mut projector = Projector::new(time);
    let mut msgs = Vec::new();

    let evs = super::events(session);
    let total = evs.len() as u64;

    for (k, (t_host, ev)) in evs.into_iter().enumerate() {
        if k % 4096 == 0 {
            progress(k as u64, total);
        }
        msgs.clear();
        match ev {
            Event::Msg(m) => projector.uplink(t_host, m, &mut msgs),
            Event::Log(l) => projector.log(t_host, l, &mut msgs),
            Event::Corrupt(c) => projector.corrupt(t_host, c, &mut msgs),
        }
        for m in &msgs {
            o.write(m)?;
        }
    }
    progress(total, total);
    o.w.finish().map_err(e)?;
    Ok(o.summary)
}
