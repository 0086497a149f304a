// A third-party viewer of baromapd's live view: @foxglove/ws-protocol's FoxgloveClient.
//
//   node view.js URL OUT.json [--subprotocol NAME] [--max-s S]
//
// Subscribes to every channel the server advertises, decodes each message with the schema
// the server sent (protobuf through its FileDescriptorSet, JSON), and writes what it saw to
// OUT.json when the server goes away, on SIGTERM, or after --max-s seconds. The client offers
// the subprotocol given (default foxglove.websocket.v1, FoxgloveClient.SUPPORTED_SUBPROTOCOL,
// as older Foxglove releases and Lichtblick offer it).
"use strict";

const fs = require("node:fs");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const [url, out, ...rest] = process.argv.slice(2);
const option = (name, fallback) => {
  const i = rest.indexOf(name);
  return i >= 0 ? rest[i + 1] : fallback;
};
const subprotocol = option("--subprotocol", FoxgloveClient.SUPPORTED_SUBPROTOCOL);
const maxS = Number(option("--max-s", "900"));

const seen = {
  url,
  subprotocol,
  negotiated: null,
  serverInfo: null,
  channels: {}, // topic -> {schemaName, encoding, messages, decoded, errors}
  scan: null, // the last LaserScan: frame, beam count
  transforms: [], // "parent->child" pairs seen on /tf and /tf_static
  floorStates: [], // [t_s, floor_id, phase] at each change
  grids: [], // [t_s, columns, rows, known cells, occupied cells, frame, z]
  mapInfos: [], // [t_s, floor_id, keyframes, resumed]
  closed: null,
  errors: [],
};

const decoders = new Map(); // channel id -> (bytes) => object
const bySubscription = new Map(); // subscription id -> channel

function decoderFor(channel) {
  if (channel.encoding === "protobuf") {
    const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
    return (bytes) =>
      type.toObject(type.decode(bytes), { longs: Number, enums: String });
  }
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  throw new Error(`no decoder for ${channel.encoding}`);
}

const seconds = (stamp) => (stamp ? (stamp.seconds || 0) + (stamp.nanos || 0) / 1e9 : 0);

function take(topic, message) {
  if (topic === "/scan") {
    seen.scan = { frame: message.frameId, beams: (message.ranges || []).length };
  } else if (topic === "/tf" || topic === "/tf_static") {
    const pair = `${message.parentFrameId}->${message.childFrameId}`;
    if (!seen.transforms.includes(pair)) seen.transforms.push(pair);
  } else if (topic === "/floor/state") {
    const last = seen.floorStates[seen.floorStates.length - 1];
    const state = [message.t_ns / 1e9, message.floor_id, message.phase];
    if (!last || last[1] !== state[1] || last[2] !== state[2]) seen.floorStates.push(state);
  } else if (topic === "/live/map") {
    const data = Buffer.from(message.data || []);
    let known = 0;
    let occupied = 0;
    for (let i = 0; i < data.length; i++) {
      const cell = data.readInt8(i);
      if (cell >= 0) known++;
      if (cell >= 65) occupied++;
    }
    const rows = message.columnCount ? data.length / message.columnCount : 0;
    const z = message.pose && message.pose.position ? message.pose.position.z || 0 : 0;
    seen.grids.push([seconds(message.timestamp), message.columnCount, rows, known, occupied, message.frameId, z]);
  } else if (topic === "/live/map/info") {
    seen.mapInfos.push([message.t_ns / 1e9, message.floor_id, message.keyframes, message.resumed]);
  }
}

function finish(why) {
  if (seen.closed === null) seen.closed = why;
  fs.writeFileSync(out, JSON.stringify(seen, null, 1));
  process.exit(0);
}

const ws = new WebSocket(url, [subprotocol]);
const client = new FoxgloveClient({ ws });
client.on("open", () => {
  seen.negotiated = ws.protocol;
});
client.on("serverInfo", (info) => {
  seen.serverInfo = { name: info.name, capabilities: info.capabilities };
});
client.on("error", (error) => seen.errors.push(String(error)));
client.on("advertise", (channels) => {
  for (const channel of channels) {
    seen.channels[channel.topic] = {
      schemaName: channel.schemaName,
      encoding: channel.encoding,
      messages: 0,
      decoded: 0,
      errors: 0,
    };
    try {
      decoders.set(channel.id, decoderFor(channel));
    } catch (error) {
      seen.errors.push(`${channel.topic}: ${error}`);
    }
    bySubscription.set(client.subscribe(channel.id), channel);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channel = bySubscription.get(subscriptionId);
  if (!channel) return;
  const counts = seen.channels[channel.topic];
  counts.messages++;
  const decode = decoders.get(channel.id);
  if (!decode) return;
  try {
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    take(channel.topic, decode(bytes));
    counts.decoded++;
  } catch (error) {
    counts.errors++;
    if (counts.errors === 1) seen.errors.push(`${channel.topic}: ${error}`);
  }
});
client.on("close", () => finish("server closed"));
process.on("SIGTERM", () => finish("SIGTERM"));
setTimeout(() => finish("time limit"), maxS * 1000);
