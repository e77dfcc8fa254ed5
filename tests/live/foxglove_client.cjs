// A live-view client built on the official Foxglove library (@foxglove/ws-protocol, subprotocol
// foxglove.websocket.v1): connect (retrying while the run starts), subscribe to the given topics and print, as one
// JSON object, the negotiated subprotocol, the advertised topics and the messages received until their stamps span
// `seconds` of the run's time (or the run ends): the run's clock, not how fast a loaded machine delivers them.
// Usage: node foxglove_client.cjs ws://127.0.0.1:PORT SECONDS TOPIC...
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, seconds, ...topics] = process.argv.slice(2);
const deadline = Date.now() + 60000;
const span = BigInt(Math.round(Number(seconds) * 1e9));
const out = { subprotocol: null, channels: [], messages: {}, errors: [] };
for (const t of topics) out.messages[t] = [];

function connect() {
  const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ ws });
  const subs = new Map();
  let opened = false;
  let first = null;
  client.on("open", () => { opened = true; out.subprotocol = ws.protocol; });
  client.on("error", (err) => {
    if (!opened && Date.now() < deadline) return; // the run is still starting: the close below retries
    out.errors.push(String(err && err.message ? err.message : err));
  });
  client.on("close", () => {
    if (!opened && Date.now() < deadline) { setTimeout(connect, 200); return; }
    finish();
  });
  client.on("advertise", (channels) => {
    for (const ch of channels) {
      out.channels.push(ch.topic);
      if (topics.includes(ch.topic)) subs.set(client.subscribe(ch.id), ch.topic);
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const topic = subs.get(subscriptionId);
    const body = JSON.parse(new TextDecoder().decode(data));
    out.messages[topic].push([String(timestamp), String(Date.now()), body]);
    if (first === null) first = BigInt(timestamp);
    if (BigInt(timestamp) - first >= span) { client.close(); finish(); }
  });
}

let done = false;
function finish() {
  if (done) return;
  done = true;
  process.stdout.write(JSON.stringify(out) + "\n", () => process.exit(0)); // a pipe takes 64 KiB at once
}

setTimeout(() => { out.errors.push("no data within 60 s"); finish(); }, 90000);
connect();
