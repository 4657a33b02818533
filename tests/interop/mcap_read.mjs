// Reads an arbiterd recording as Foxglove does: @mcap/core with @mcap/support's decompressors,
// messages decoded with @foxglove/rosmsg + @foxglove/rosmsg2-serialization from the ros2msg schemas.
// Usage: node mcap_read.mjs FILE [--stream]   (--stream: McapStreamReader, for a file cut short)
// Prints one JSON object: header, per-topic counts and encodings, time order, the last /odom.
import { open } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const file = process.argv[2];
const streaming = process.argv.includes("--stream");
const decompressHandlers = await loadDecompressHandlers();
const topics = {};
const readers = new Map();
const schemas = new Map();
const channels = new Map();
let lastTime = -1n;
let monotonic = true;
let lastOdom = null;
let header = null;

function readerFor(channel) {
  let reader = readers.get(channel.id);
  if (!reader) {
    const schema = schemas.get(channel.schemaId);
    const text = new TextDecoder().decode(schema.data);
    reader = new MessageReader(parse(text, { ros2: true }));
    readers.set(channel.id, reader);
  }
  return reader;
}

function take(message) {
  const channel = channels.get(message.channelId);
  const schema = schemas.get(channel.schemaId);
  const entry = (topics[channel.topic] ??= {
    schema: schema.name, schemaEncoding: schema.encoding,
    messageEncoding: channel.messageEncoding, count: 0, decoded: 0,
  });
  entry.count += 1;
  if (message.logTime < lastTime) monotonic = false;
  lastTime = message.logTime;
  const decoded = readerFor(channel).readMessage(message.data);
  entry.decoded += 1;
  if (channel.topic === "/odom") lastOdom = decoded;
}

async function readIndexed() {
  const handle = await open(file, "r");
  const readable = {
    size: async () => BigInt((await handle.stat()).size),
    read: async (offset, size) => {
      const buffer = new Uint8Array(Number(size));
      await handle.read(buffer, 0, Number(size), Number(offset));
      return buffer;
    },
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  header = reader.header;
  for (const [id, schema] of reader.schemasById) schemas.set(id, schema);
  for (const [id, channel] of reader.channelsById) channels.set(id, channel);
  for await (const message of reader.readMessages()) take(message);
  await handle.close();
}

async function readStream() {
  const reader = new McapStreamReader({ decompressHandlers });
  const handle = await open(file, "r");
  reader.append(new Uint8Array(await handle.readFile()));
  await handle.close();
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Header") header = record;
    else if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") take(record);
  }
}

try {
  await (streaming ? readStream() : readIndexed());
} catch (error) {
  console.log(JSON.stringify({ error: String(error?.stack ?? error) }));
  process.exit(1);
}
const odom = lastOdom && {
  sec: lastOdom.header.stamp.sec, nanosec: lastOdom.header.stamp.nanosec,
  x: lastOdom.pose.pose.position.x, y: lastOdom.pose.pose.position.y,
  qz: lastOdom.pose.pose.orientation.z, qw: lastOdom.pose.pose.orientation.w,
};
console.log(JSON.stringify({
  profile: header?.profile, library: header?.library, topics, monotonic,
  lastTimeNs: lastTime.toString(), lastOdom: odom,
}));
