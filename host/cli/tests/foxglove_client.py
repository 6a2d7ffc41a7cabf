"""A Foxglove WebSocket protocol client (foxglove.websocket.v1) for the live-view tests.

Connects to URL (retrying while the server starts), subscribes to every channel advertised,
validates each message against its channel's JSON Schema (jsonschema), looks for a JSON null
anywhere in it (a NaN must be left out and named with why in `no_value`, never sent as null),
and prints one JSON summary line when the server closes the connection.

  python foxglove_client.py read URL TIMEOUT_S   # read everything until the server closes
  python foxglove_client.py stall URL TIMEOUT_S  # subscribe to what is advertised in the first
                                                 # second, then never read again (TIMEOUT_S)
  ... [SUBPROTOCOL]                              # offer only this subprotocol (default
                                                 # foxglove.sdk.v1; foxglove.websocket.v1 as
                                                 # ws-protocol clients and Lichtblick do)
"""

import json
import socket
import struct
import sys
import time
from urllib.parse import urlparse

import jsonschema
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

# The foxglove crate (0.30) names the classic Foxglove WebSocket protocol (ws-protocol
# "foxglove.websocket.v1": JSON advertisements, binary message frames) "foxglove.sdk.v1".
SUBPROTOCOL = "foxglove.sdk.v1"
VALIDATE_PER_TOPIC = 200


def null_paths(v, path=""):
    """The paths of every null in a decoded JSON message."""
    if v is None:
        return [path]
    if isinstance(v, dict):
        return [p for k, x in v.items() for p in null_paths(x, f"{path}.{k}" if path else k)]
    if isinstance(v, list):
        return [p for i, x in enumerate(v) for p in null_paths(x, f"{path}.{i}")]
    return []


def open_ws(url, deadline, rcvbuf=None, subprotocol=SUBPROTOCOL):
    u = urlparse(url)
    last = None
    while time.time() < deadline:
        try:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            if rcvbuf:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            s.connect((u.hostname, u.port))
            return connect(url, sock=s, subprotocols=[subprotocol], max_size=None, open_timeout=10)
        except OSError as e:
            last = e
            s.close()
            time.sleep(0.05)
    raise SystemExit(f"could not connect to {url}: {last}")


def main():
    mode, url, timeout_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
    subprotocol = sys.argv[4] if len(sys.argv) > 4 else SUBPROTOCOL
    deadline = time.time() + timeout_s
    ws = open_ws(url, deadline, rcvbuf=4096 if mode == "stall" else None, subprotocol=subprotocol)
    channels = {}  # channel id -> advertisement (+ validator)
    subs = {}  # subscription id -> channel id
    counts = {}
    validated = {}
    invalid = []
    nulls = []  # "topic: path" of nulls found (the first few)
    no_value = {}  # topic -> {why: messages}
    errors = []
    resubscribed = []  # channels refused as unknown right after their advertisement, subscribed again
    server = None
    next_sub = 1
    first_advert = None
    closed_by_server = False

    def subscribe(chs):
        nonlocal next_sub
        batch = []
        for ch in chs:
            if ch["encoding"] != "json" or ch.get("schemaEncoding") != "jsonschema":
                errors.append(f"{ch['topic']}: encoding {ch['encoding']}/{ch.get('schemaEncoding')}")
                continue
            schema = json.loads(ch["schema"])
            jsonschema.Draft7Validator.check_schema(schema)
            ch["validator"] = jsonschema.Draft7Validator(schema)
            channels[ch["id"]] = ch
            subs[next_sub] = ch["id"]
            batch.append({"id": next_sub, "channelId": ch["id"]})
            next_sub += 1
        if batch:
            ws.send(json.dumps({"op": "subscribe", "subscriptions": batch}))

    try:
        while time.time() < deadline:
            if mode == "stall" and first_advert is not None and time.time() > first_advert + 1.0:
                # Never read again: the server's outbox and the socket buffers fill up.
                time.sleep(max(0.0, deadline - time.time()))
                break
            try:
                msg = ws.recv(timeout=max(0.01, min(1.0, deadline - time.time())))
            except TimeoutError:
                continue
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "serverInfo":
                    server = op
                elif op["op"] == "advertise":
                    first_advert = first_advert or time.time()
                    subscribe(op["channels"])
                elif op["op"] == "status" and op.get("level", 0) >= 2:
                    # foxglove 0.30.3 sends an advertisement before it records the channel as
                    # advertised to this client (`advertise_channels` in connected_client.rs), so a
                    # subscribe that comes back fast enough is refused as an unknown channel. Retry
                    # such a channel once; anything else is an error.
                    text = op.get("message") or ""
                    prefix = "Unknown channel ID: "
                    cid = int(text[len(prefix):]) if text.startswith(prefix) and text[len(prefix):].isdigit() else None
                    if cid in channels and cid not in resubscribed:
                        resubscribed.append(cid)
                        for sid in [k for k, v in subs.items() if v == cid]:
                            del subs[sid]
                        subs[next_sub] = cid
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": next_sub, "channelId": cid}]}))
                        next_sub += 1
                    else:
                        errors.append(text)
                continue
            if msg[0] != 0x01:
                continue
            sub, _t_ns = struct.unpack_from("<IQ", msg, 1)
            ch = channels[subs[sub]]
            topic = ch["topic"]
            counts[topic] = counts.get(topic, 0) + 1
            # Validate the first messages of every topic (all of them would make this client the
            # slow one); count the rest.
            if counts[topic] > VALIDATE_PER_TOPIC:
                continue
            try:
                m = json.loads(msg[13:])
                for p in null_paths(m)[: max(0, 10 - len(nulls))]:
                    nulls.append(f"{topic}: {p}")
                if isinstance(m, dict) and isinstance(m.get("no_value"), dict):
                    whys = no_value.setdefault(topic, {})
                    for why in set(m["no_value"].values()):
                        whys[why] = whys.get(why, 0) + 1
                ch["validator"].validate(m)
                validated[topic] = validated.get(topic, 0) + 1
            except (jsonschema.ValidationError, ValueError) as e:
                if len(invalid) < 10:
                    invalid.append(f"{topic}: {str(e)[:300]}")
    except ConnectionClosed:
        closed_by_server = True
    finally:
        ws.close()
    print(
        json.dumps(
            {
                "subprotocol": ws.subprotocol,
                "server": server and server.get("name"),
                "advertised": sorted(ch["topic"] for ch in channels.values()),
                "schemas": {ch["topic"]: ch["schemaName"] for ch in channels.values()},
                "counts": counts,
                "validated": validated,
                "invalid": invalid,
                "nulls": nulls,
                "no_value": no_value,
                "errors": errors,
                "resubscribed": resubscribed,
                "closed_by_server": closed_by_server,
            }
        )
    )


if __name__ == "__main__":
    main()
