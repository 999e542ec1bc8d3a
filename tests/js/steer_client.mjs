// Steers a live rgtbus run with the official Foxglove WebSocket client (@foxglove/ws-protocol).
//
//   node steer_client.mjs ws://HOST:PORT STEPS.json
//
// STEPS.json: a list of steps, taken in order once the run's first message has arrived:
//   {"set": {"channel.noise": 0.05}}                      setParameters (answered: parameterValues)
//   {"call": "/control/influence", "request": {...}}      a service call (answered: response or failure)
//   {"auth": "HEX"}                                       /control/auth {"proof": HEX}
//   {"auth_key": "KEY"}                                   the same, HEX the proof of holding KEY:
//                                                         HMAC-SHA256(KEY, "rgtbus-control:" + session id)
//   {"get": ["channel.noise"]}                            getParameters
//   {"sleep": MS}                                         wait MS ms, then print the server's time
// Prints one JSON object a line: {"op": "serverInfo"|"answer"|"failure"|"parameters"|"control"|"end", ...}
// ("control": each /control/* message received, decoded; "end": message counts) and exits
// when /run arrives or the server closes.
import pkg from "@foxglove/ws-protocol";
import WebSocket from "ws";
import { readFileSync } from "node:fs";
import { createHmac } from "node:crypto";

const { FoxgloveClient } = pkg;
const [url, stepsFile] = process.argv.slice(2);
const steps = JSON.parse(readFileSync(stepsFile, "utf8"));
const out = (o) => process.stdout.write(JSON.stringify(o) + "\n");

const ws = new WebSocket(url, ["foxglove.sdk.v1"]); // the SDK refuses foxglove.websocket.v1
const client = new FoxgloveClient({ ws });
const topics = new Map(); // subscription id -> topic
const services = new Map(); // name -> id
const counts = {};
let started = false;
let callId = 0;
const pending = new Map(); // call id -> resolve

let session = "";
client.on("serverInfo", (info) => {
  session = info.sessionId ?? "";
  out({ op: "serverInfo", info });
});
client.on("advertise", (channels) => {
  for (const ch of channels) topics.set(client.subscribe(ch.id), ch.topic);
});
client.on("advertiseServices", (list) => {
  for (const s of list) services.set(s.name, s.id);
});
client.on("parameterValues", (event) => {
  out({ op: "parameters", id: event.id ?? null, parameters: event.parameters });
  const done = pending.get(event.id);
  if (done) done();
});
client.on("serviceCallResponse", (r) => {
  const text = new TextDecoder().decode(r.data);
  out({ op: "answer", callId: r.callId, response: JSON.parse(text) });
  pending.get(r.callId)?.();
});
client.on("serviceCallFailure", (r) => {
  out({ op: "failure", callId: r.callId, message: r.message });
  pending.get(r.callId)?.();
});
client.on("error", (e) => out({ op: "error", message: String(e?.message ?? e) }));
client.on("close", () => finish());

const answered = (id) => new Promise((resolve) => pending.set(id, resolve));

let serverTime = null; // the latest time broadcast, ns (a string: a bigint)
client.on("time", (t) => {
  serverTime = String(t.timestamp);
});

async function take(step) {
  if (step.sleep !== undefined) {
    await new Promise((resolve) => setTimeout(resolve, step.sleep));
    out({ op: "time", time: serverTime });
    return;
  }
  if (step.set) {
    const id = `set-${++callId}`;
    const wait = answered(id);
    client.setParameters(
      Object.entries(step.set).map(([name, value]) => ({ name, value })),
      id,
    );
    return wait;
  }
  if (step.get) {
    const id = `get-${++callId}`;
    const wait = answered(id);
    client.getParameters(step.get, id);
    return wait;
  }
  if (step.auth_key !== undefined) {
    step = { auth: createHmac("sha256", step.auth_key).update("rgtbus-control:" + session).digest("hex") };
  }
  const name = step.auth !== undefined ? "/control/auth" : step.call;
  const request = step.auth !== undefined ? { proof: step.auth } : (step.request ?? {});
  const id = ++callId;
  const wait = answered(id);
  client.sendServiceCallRequest({
    serviceId: services.get(name),
    callId: id,
    encoding: "json",
    data: new DataView(new TextEncoder().encode(JSON.stringify(request)).buffer),
  });
  return wait;
}

client.on("message", async (m) => {
  const topic = topics.get(m.subscriptionId);
  counts[topic] = (counts[topic] ?? 0) + 1;
  if (topic.startsWith("/control/")) {
    const text = new TextDecoder().decode(m.data);
    out({ op: "control", topic, message: JSON.parse(text) });
  }
  if (!started) {
    started = true;
    for (const step of steps) await take(step);
    out({ op: "steps done" });
  }
  if (topic === "/run") finish();
});

let finished = false;
function finish() {
  if (finished) return;
  finished = true;
  out({ op: "end", counts });
  client.close();
  process.exit(0);
}
setTimeout(() => {
  out({ op: "timeout" });
  finish();
}, 120000);
