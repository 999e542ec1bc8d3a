// A Foxglove WebSocket client for tests/test_serve.py: the official @foxglove/ws-protocol
// client (what Foxglove itself speaks), subscribed to every channel the server advertises,
// driving `rgtbus replay LOG --serve` through playback control requests.
//
//   node serve_client.mjs URL PLAN_JSON
//
// PLAN_JSON: a list of steps, run in turn once every advertised channel is subscribed:
//   {"play": true|false, "speed": X, "seek": NS|null, "until": UNTIL}
// sends one PlaybackControlRequest (id "step<i>") and waits for UNTIL:
//   "state"              the server's PlaybackState answering this request
//   {"ended": N, "since": I}  a PlaybackState "Ended", and N messages since step I (default:
//                        this step) began (the server
//                        sends states and times ahead of the messages queued before them:
//                        they go on its control plane, messages on its data plane)
//   {"messages": N}      N more messages
//   {"wait_ms": MS}      MS milliseconds
// Prints one JSON line per event: {"ev": "message", "step", "topic", "t", "data" (base64)},
// {"ev": "state", "step", "status", "time", "speed", "didSeek", "requestId"},
// {"ev": "time", "t"}, {"ev": "advertise", "topics"}, {"ev": "done"}; exits 0 once the plan
// is done, 1 on a timeout or a closed connection (stderr says which).
//
// The client library (0.8.0) has no PlaybackControlRequest of its own, nor parses the
// server's PlaybackState (opcode 5): both are framed here as foxglove-sdk 0.30 does
// (rust/foxglove/src/protocol/common/{client,server}/playback_*.rs).
import { createRequire } from "node:module";

const require = createRequire(import.meta.url); // resolved from tests/js/node_modules
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, planText] = process.argv.slice(2);
const plan = JSON.parse(planText);
const TIMEOUT_MS = 60000; // a step's limit: generous, a 2-core machine under load

const out = (obj) =>
  process.stdout.write(JSON.stringify(obj, (_, v) => (typeof v === "bigint" ? v.toString() : v)) + "\n");

function fail(why) {
  process.stderr.write(`serve_client: ${why}\n`);
  process.exit(1);
}

const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
ws.binaryType = "arraybuffer";
const client = new FoxgloveClient({ ws });
const topics = new Map(); // subscription id -> topic

let step = -1; // the step under way (-1: before the plan)
let waiter = null; // (event) => true once the step's wait is over
const notify = (ev) => {
  if (waiter && waiter(ev)) {
    waiter = null;
    setImmediate(next);
  }
};

client.on("error", () => {}); // the PlaybackState frame is not the library's: ignored there
client.on("close", () => fail(`connection closed during step ${step}`));
const silent = setTimeout(() => fail("no advertisement from the server"), TIMEOUT_MS);
client.on("advertise", (channels) => {
  clearTimeout(silent);
  for (const ch of channels) {
    topics.set(client.subscribe(ch.id), ch.topic);
  }
  out({ ev: "advertise", topics: channels.map((ch) => ch.topic) });
  if (step === -1) {
    setTimeout(next, 200); // the subscriptions go first, on the same socket
  }
});
client.on("message", (m) => {
  const bytes = Buffer.from(m.data.buffer, m.data.byteOffset, m.data.byteLength);
  received += 1;
  out({ ev: "message", step, topic: topics.get(m.subscriptionId), t: m.timestamp, data: bytes.toString("base64") });
  notify({ ev: "message" });
});
client.on("time", (t) => {
  out({ ev: "time", t: t.timestamp });
  notify({ ev: "time", t: BigInt(t.timestamp) });
});
ws.addEventListener("message", (event) => {
  if (typeof event.data === "string") return;
  const v = new DataView(event.data);
  if (v.byteLength < 19 || v.getUint8(0) !== 5) return; // not a PlaybackState
  const idLength = v.getUint32(15, true);
  const state = {
    ev: "state",
    step,
    status: ["playing", "paused", "buffering", "ended"][v.getUint8(1)],
    time: v.getBigUint64(2, true),
    speed: v.getFloat32(10, true),
    didSeek: v.getUint8(14) !== 0,
    requestId: Buffer.from(event.data, 19, idLength).toString("utf8"),
  };
  out(state);
  notify(state);
});

function request(play, speed, seek, id) {
  const idBytes = Buffer.from(id, "utf8");
  const b = Buffer.alloc(1 + 1 + 4 + 1 + 8 + 4 + idBytes.length);
  let o = b.writeUInt8(3, 0); // opcode: PlaybackControlRequest
  o = b.writeUInt8(play ? 0 : 1, o); // 0 Play, 1 Pause
  o = b.writeFloatLE(speed, o);
  o = b.writeUInt8(seek == null ? 0 : 1, o);
  o = b.writeBigUInt64LE(BigInt(seek ?? 0), o);
  o = b.writeUInt32LE(idBytes.length, o);
  idBytes.copy(b, o);
  ws.send(b);
}

let timer = null;
let received = 0; // messages so far
const counts = []; // messages received before each step began
function next() {
  clearTimeout(timer);
  step += 1;
  counts.push(received);
  if (step >= plan.length) {
    out({ ev: "done" });
    client.close();
    process.exit(0);
  }
  const s = plan[step];
  const id = `step${step}`;
  const until = s.until;
  if (until === "state") {
    waiter = (ev) => ev.ev === "state" && ev.requestId === id;
  } else if (until.ended !== undefined) {
    let ended = false;
    let left = until.ended - (until.since === undefined ? 0 : received - counts[until.since]);
    waiter = (ev) => {
      if (ev.ev === "state" && ev.status === "ended") ended = true;
      if (ev.ev === "message") left -= 1;
      return ended && left <= 0;
    };
  } else if (until.messages !== undefined) {
    let left = until.messages;
    waiter = (ev) => ev.ev === "message" && --left <= 0;
  } else if (until.wait_ms !== undefined) {
    waiter = null;
    setTimeout(next, until.wait_ms);
  }
  if (waiter) {
    timer = setTimeout(() => fail(`step ${step}: ${JSON.stringify(until)} not reached in ${TIMEOUT_MS} ms`), TIMEOUT_MS);
  }
  request(s.play, s.speed, s.seek ?? null, id);
}
