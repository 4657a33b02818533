// Does what the Foxglove / Lichtblick "Rosbridge" player does against arbiterd, and checks that
// what it decodes equals what the JSON path delivers for the same stamp; roslib 2.x's own `cbor`
// mode is checked the same way.
//   player: @foxglove/roslibjs, /rosapi/topics_and_raw_types, @foxglove/rosmsg parse(ros2) +
//           @foxglove/rosmsg2-serialization MessageReader, subscriptions with compression cbor-raw
// Usage: node foxglove_player.mjs ws://127.0.0.1:9090/ [--topics /odom,/scan,...]
// Prints one JSON object per step on stdout; exits 0 only when every check passed.
import { createRequire } from "node:module";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { Ros as Ros2, Topic as Topic2 } from "roslib";

const require = createRequire(import.meta.url);
const FoxRos = require("@foxglove/roslibjs/src/RosLib.js"); // the Node entry of the fork

const url = process.argv[2];
const topicArg = process.argv.indexOf("--topics");
const TOPICS = (topicArg > 0 ? process.argv[topicArg + 1]
  : "/odom,/scan,/tf,/robot_info,/rosout,/latency_reports").split(",");
const report = (step, data) => console.log(JSON.stringify({ step, ...data }));
const fail = (why) => {
  report("fail", { error: String(why) });
  process.exitCode = 1;
  setTimeout(() => process.exit(1), 200); // let stdout drain first
  throw why instanceof Error ? why : new Error(String(why));
};
setTimeout(() => fail("overall timeout"), 40000).unref();

function within(ms, what, executor) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`timed out: ${what}`)), ms);
    executor((v) => { clearTimeout(timer); resolve(v); }, (e) => { clearTimeout(timer); reject(e); });
  });
}

// -- keys: which JSON message is "the same message" -------------------------------------------
const stampKey = (s) => `${s.sec}.${s.nanosec ?? s.nsec}`;
const KEYS = {
  "/odom": (m) => stampKey(m.header.stamp),
  "/scan": (m) => stampKey(m.header.stamp),
  "/tf": (m) => stampKey(m.transforms[0].header.stamp),
  "/rosout": (m) => `${stampKey(m.stamp)} ${m.msg}`,
  "/robot_info": (m) => m.data,
  "/latency_reports": (m) => m.data,
};

// -- comparing a decoded message with the JSON one ----------------------------------------------
// float32 fields (from the advertised definitions) carry the JSON value rounded to float32 in CDR
const float32Fields = {};

function same(a, b, path, problems, float32 = new Set()) {
  if (problems.length > 5) return;
  if (typeof b === "number" || b === null) {
    const x = typeof a === "bigint" ? Number(a) : a;
    const field = path.split(".").pop();
    if (b === null) { // JSON writes non-finite floats as null
      if (Number.isFinite(x)) problems.push(`${path}: ${x} where JSON has null`);
    } else if (path.includes(".ranges[") || path.includes(".intensities[")) {
      // LaserScan: float32 on the binary paths, 4 decimals in JSON
      if (!(Math.abs(x - b) <= 1e-4 + Math.abs(b) * 1e-6)) problems.push(`${path}: ${x} != ${b}`);
    } else if (float32.has(field) ? x !== Math.fround(b) : x !== b) {
      problems.push(`${path}: ${x} != ${b}`);
    }
    return;
  }
  if (typeof b === "string" || typeof b === "boolean") {
    if (a !== b) problems.push(`${path}: ${JSON.stringify(a)} != ${JSON.stringify(b)}`);
    return;
  }
  if (Array.isArray(b)) {
    if (a == null || a.length !== b.length) {
      problems.push(`${path}: length ${a?.length} != ${b.length}`);
      return;
    }
    for (let i = 0; i < b.length; i++) same(a[i], b[i], `${path}[${i}]`, problems, float32);
    return;
  }
  for (const key of Object.keys(b)) same(a?.[key], b[key], `${path}.${key}`, problems, float32);
}

// -- the three clients ----------------------------------------------------------------------------
const seen = { json: {}, raw: {}, cbor: {} };
for (const table of Object.values(seen)) for (const t of TOPICS) table[t] = new Map();
const remember = (table, topic, msg) => {
  const key = KEYS[topic](msg);
  if (!table[topic].has(key)) table[topic].set(key, msg);
};

async function connect(Ros, name) {
  const ros = new Ros({ url });
  ros.on("error", (e) => fail(`${name}: ${e?.message ?? e}`));
  await within(5000, `${name} connection`, (ok) => ros.on("connection", ok));
  return ros;
}

const json = await connect(Ros2, "json client");
for (const topic of TOPICS) {
  new Topic2({ ros: json, name: topic }).subscribe((m) => remember(seen.json, topic, m));
}

// the player: discovery, ROS 2 detection, readers, cbor-raw subscriptions without a type
const player = await connect(FoxRos.Ros, "player");
const statuses = [];
player.on("status", (s) => statuses.push(s));
const discovered = await within(5000, "topics_and_raw_types",
  (ok, no) => player.getTopicsAndRawTypes(ok, no));
const types = {};
const readers = {};
discovered.topics.forEach((topic, i) => {
  types[topic] = discovered.types[i];
  const definitions = parse(discovered.typedefs_full_text[i], { ros2: true });
  readers[topic] = new MessageReader(definitions);
  float32Fields[topic] = new Set(definitions[0].definitions
    .filter((f) => f.type === "float32" && !f.isArray).map((f) => f.name));
});
const ros2 = discovered.types.includes("rcl_interfaces/msg/Log");
report("discovery", { topics: discovered.topics.length, ros2 });
if (!ros2) fail("the player would treat the server as ROS 1");
const receipts = {};
for (const topic of TOPICS) {
  if (!readers[topic]) fail(`${topic} is not advertised`);
  const sub = new FoxRos.Topic({ ros: player, name: topic, compression: "cbor-raw" });
  sub.subscribe((message) => {
    if (!(message.bytes instanceof Uint8Array)) fail(`${topic}: cbor-raw bytes missing`);
    receipts[topic] = { secs: message.secs, nsecs: message.nsecs };
    remember(seen.raw, topic, readers[topic].readMessage(message.bytes));
  });
}

// roslib 2.x in its own cbor mode
const cbor = await connect(Ros2, "cbor client");
for (const topic of TOPICS) {
  new Topic2({ ros: cbor, name: topic, compression: "cbor" }).subscribe(
    (m) => remember(seen.cbor, topic, m));
}

// traffic for the event topics: stamped commands (latency reports) and a log line
const stamped = new Topic2({ ros: json, name: "/stamped_cmd_vel", messageType: "std_msgs/msg/String" });
let sent = 0;
const traffic = setInterval(() => {
  sent += 1;
  stamped.publish({ data: JSON.stringify({ linear: { x: 0.05 }, angular: { z: 0.0 }, id: `fox-${sent}`,
    t_sent: Date.now() }) });
  if (sent % 10 === 1) connect(Ros2, "log line trigger").then((r) => r.close());
}, 100);

// -- matching -------------------------------------------------------------------------------------
function matches(mode) {
  const out = {};
  for (const topic of TOPICS) {
    const keys = [...seen[mode][topic].keys()].filter((k) => seen.json[topic].has(k));
    out[topic] = keys;
  }
  return out;
}
// /robot_info repeats the same text every second: one distinct message is all there is
const wanted = (topic) => (topic === "/robot_info" ? 1 : 2);
const complete = () => ["raw", "cbor"].every((mode) => {
  const m = matches(mode);
  return TOPICS.every((t) => m[t].length >= wanted(t));
});
try {
  await within(30000, "matched messages on every topic in both modes", (ok) => {
    const timer = setInterval(() => { if (complete()) { clearInterval(timer); ok(); } }, 50);
  });
} catch (e) {
  const counts = Object.fromEntries(Object.entries(seen).map(([mode, table]) =>
    [mode, Object.fromEntries(TOPICS.map((t) => [t, table[t].size]))]));
  const matched = Object.fromEntries(["raw", "cbor"].map((mode) => [mode,
    Object.fromEntries(Object.entries(matches(mode)).map(([t, keys]) => [t, keys.length]))]));
  report("counts", { counts, statuses, matched });
  fail(e);
}
clearInterval(traffic);

let ok = true;
for (const mode of ["raw", "cbor"]) {
  const m = matches(mode);
  for (const topic of TOPICS) {
    const problems = [];
    for (const key of m[topic]) {
      same(seen[mode][topic].get(key), seen.json[topic].get(key), topic, problems,
        mode === "raw" ? float32Fields[topic] : new Set());
    }
    ok &&= problems.length === 0;
    report("compared", { mode, topic, type: types[topic], matched: m[topic].length, problems });
  }
}
// Foxglove's app publishes times as its own {sec, nsec}: relayed to a JSON subscriber, the
// stamp comes back as ROS 2's {sec, nanosec} with the same nanoseconds
const FOX_STAMP = { sec: 1700000000, nsec: 123456789 };
const stampType = "geometry_msgs/msg/TwistStamped";
const publisher = new FoxRos.Topic({ ros: player, name: "/foxglove_stamped",
  messageType: stampType });
let again;
let relayed;
try {
  relayed = await within(5000, "a {sec, nsec} stamp published the way Foxglove does", (ok) => {
    new Topic2({ ros: json, name: "/foxglove_stamped", messageType: stampType })
      .subscribe((m) => ok(m.header.stamp));
    again = setInterval(() => publisher.publish({ header: { stamp: FOX_STAMP,
      frame_id: "base_link" } }), 100); // until the subscription is there
  });
} catch (e) {
  report("foxglove_stamp", { statuses });
  fail(e);
} finally {
  clearInterval(again);
}
report("foxglove_stamp", { sent: FOX_STAMP, relayed });

const now = Date.now() / 1000;
const clock = receipts["/odom"];
report("clock", { secs: clock.secs, nsecs: clock.nsecs, skew_s: now - (clock.secs + clock.nsecs / 1e9) });
report("done", { ok, statuses });
for (const ros of [json, player, cbor]) ros.close();
setTimeout(() => process.exit(ok ? 0 : 1), 100);
