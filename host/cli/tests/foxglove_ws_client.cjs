// The official Foxglove WebSocket protocol client (`@foxglove/ws-protocol`, npm, as Lichtblick and
// the ws-protocol ecosystem use it; `FoxgloveClient.SUPPORTED_SUBPROTOCOL` is
// "foxglove.websocket.v1") for the live-view test, with the `ws` package as its WebSocket and
// Ajv to validate every message against its channel's JSON Schema. Installed by `cargo xtask
// setup` into target/peers-node (tests/peers/node/package.json); NODE_PATH points there.
//
//   node foxglove_ws_client.cjs URL TIMEOUT_S
//
// Connects (retrying while the server starts), subscribes to every channel advertised, decodes
// each message with the channel's encoding and validates it, looks for a JSON null anywhere in it
// (a NaN must be left out and named with why in `no_value`), and prints one JSON summary line
// (the same fields as foxglove_client.py) when the server closes the connection.
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const Ajv = require("ajv");

const VALIDATE_PER_TOPIC = 200;
const [url, timeoutS] = [process.argv[2], Number(process.argv[3])];
const deadline = Date.now() + timeoutS * 1000;

const channels = new Map(); // channel id -> { topic, schemaName, validate }
const subs = new Map(); // subscription id -> channel id
const counts = {};
const validated = {};
const invalid = [];
const nulls = []; // "topic: path" of nulls found (the first few)
const noValue = {}; // topic -> {why: messages}
const errors = [];
const resubscribed = [];
let server = null;
let subprotocol = null;
let closedByServer = false;
let done = false;
const ajv = new Ajv({ strict: false, allErrors: false });
const decoder = new TextDecoder();

// The paths of every null in a decoded JSON message.
function nullPaths(v, path = "") {
  if (v === null) return [path];
  if (Array.isArray(v)) return v.flatMap((x, i) => nullPaths(x, `${path}.${i}`));
  if (typeof v === "object") return Object.entries(v).flatMap(([k, x]) => nullPaths(x, path ? `${path}.${k}` : k));
  return [];
}

function finish() {
  if (done) return;
  done = true;
  const topics = [...channels.values()];
  console.log(
    JSON.stringify({
      subprotocol,
      server: server && server.name,
      advertised: topics.map((c) => c.topic).sort(),
      schemas: Object.fromEntries(topics.map((c) => [c.topic, c.schemaName])),
      counts,
      validated,
      invalid,
      nulls,
      no_value: noValue,
      errors,
      resubscribed,
      closed_by_server: closedByServer,
    }),
  );
  process.exit(0);
}

function connect() {
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  let opened = false;
  ws.on("error", (e) => {
    if (!opened && Date.now() < deadline) {
      setTimeout(connect, 50);
    } else if (!done) {
      errors.push(`websocket: ${e.message}`);
    }
  });
  ws.on("open", () => {
    opened = true;
    subprotocol = ws.protocol;
  });
  const client = new FoxgloveClient({ ws });
  client.on("serverInfo", (info) => {
    server = info;
  });
  client.on("error", (e) => {
    if (opened) errors.push(String(e && e.message ? e.message : e));
  });
  client.on("status", (s) => {
    if (s.level < 2) return;
    // The foxglove crate (0.30.3) sends an advertisement before it records the channel as
    // advertised to this client, so a fast subscribe may be refused as an unknown channel:
    // retried once, as in foxglove_client.py; anything else is an error.
    const m = /^Unknown channel ID: (\d+)$/.exec(s.message || "");
    const cid = m ? Number(m[1]) : null;
    if (cid !== null && channels.has(cid) && !resubscribed.includes(cid)) {
      resubscribed.push(cid);
      for (const [sid, c] of subs) if (c === cid) subs.delete(sid);
      subs.set(client.subscribe(cid), cid);
    } else {
      errors.push(s.message);
    }
  });
  client.on("advertise", (chs) => {
    for (const ch of chs) {
      if (ch.encoding !== "json" || ch.schemaEncoding !== "jsonschema") {
        errors.push(`${ch.topic}: encoding ${ch.encoding}/${ch.schemaEncoding}`);
        continue;
      }
      let validate;
      try {
        validate = ajv.compile(JSON.parse(ch.schema));
      } catch (e) {
        errors.push(`${ch.topic}: schema: ${e.message}`);
        continue;
      }
      channels.set(ch.id, { topic: ch.topic, schemaName: ch.schemaName, validate });
      subs.set(client.subscribe(ch.id), ch.id);
    }
  });
  client.on("message", ({ subscriptionId, data }) => {
    const ch = channels.get(subs.get(subscriptionId));
    if (!ch) {
      errors.push(`message on unknown subscription ${subscriptionId}`);
      return;
    }
    counts[ch.topic] = (counts[ch.topic] || 0) + 1;
    if (counts[ch.topic] > VALIDATE_PER_TOPIC) return;
    let msg;
    try {
      msg = JSON.parse(decoder.decode(data));
    } catch (e) {
      if (invalid.length < 10) invalid.push(`${ch.topic}: not JSON: ${e.message}`);
      return;
    }
    for (const p of nullPaths(msg)) if (nulls.length < 10) nulls.push(`${ch.topic}: ${p}`);
    if (msg && typeof msg.no_value === "object" && msg.no_value !== null) {
      const whys = (noValue[ch.topic] = noValue[ch.topic] || {});
      for (const why of new Set(Object.values(msg.no_value))) whys[why] = (whys[why] || 0) + 1;
    }
    if (ch.validate(msg)) {
      validated[ch.topic] = (validated[ch.topic] || 0) + 1;
    } else if (invalid.length < 10) {
      invalid.push(`${ch.topic}: ${JSON.stringify(ch.validate.errors).slice(0, 300)}`);
    }
  });
  client.on("close", () => {
    if (opened) {
      closedByServer = true;
      finish();
    }
  });
}

setTimeout(finish, Math.max(0, deadline - Date.now()));
connect();
