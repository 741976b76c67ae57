// A Foxglove WebSocket client built on the official npm client library
// (@foxglove/ws-protocol 0.8 over the `ws` package), independent of the
// server's code: connects to the live view offering SUBPROTOCOL, checks the
// advertised channels, subscribes to detections, transforms and the mirror,
// and counts what arrives.
//
// Usage: node live_view_client.js PORT SUBPROTOCOL
// Exit 0 when every wanted channel delivered, 3 when the server refused the
// connection (prints the HTTP status), 1 otherwise.
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [port, subprotocol] = process.argv.slice(2);
const WANTED = {
  "/camera/left/detections": 5,
  "/tf": 5,
  "/mirror/tf": 1,
  "/camera/left/calibration": 1,
};

const ws = new WebSocket(`ws://127.0.0.1:${port}`, [subprotocol]);
ws.on("unexpected-response", (_request, response) => {
  console.log(JSON.stringify({ refused: response.statusCode, subprotocol }));
  process.exit(3);
});
const client = new FoxgloveClient({ ws });
const topics = new Map();
const counts = Object.fromEntries(Object.keys(WANTED).map((t) => [t, 0]));
let serverName = null;

const timer = setTimeout(() => {
  console.log(JSON.stringify({ timeout: true, counts }));
  process.exit(1);
}, 20000);

client.on("serverInfo", (info) => {
  serverName = info.name;
});
client.on("error", (error) => {
  console.log(JSON.stringify({ error: String(error) }));
  process.exit(1);
});
client.on("advertise", (channels) => {
  for (const c of channels) {
    if (c.topic in WANTED && !topics.has(c.id)) {
      if (c.encoding !== "protobuf" || !c.schemaName.startsWith("foxglove.")) {
        console.log(JSON.stringify({ badChannel: c.topic, encoding: c.encoding, schema: c.schemaName }));
        process.exit(1);
      }
      topics.set(client.subscribe(c.id), c.topic);
    }
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const topic = topics.get(subscriptionId);
  if (topic === undefined || data.byteLength === 0) {
    return;
  }
  counts[topic] += 1;
  if (Object.entries(WANTED).every(([t, n]) => counts[t] >= n)) {
    clearTimeout(timer);
    console.log(JSON.stringify({ server: serverName, subprotocol: ws.protocol, counts }));
    client.close();
    process.exit(0);
  }
});
