// Drives arbiterd's rosbridge server with the real roslib (2.x, or 1.x with --v1) on Node.
// Usage: node roslib_client.mjs ws://127.0.0.1:9090/ [--v1] [--expect-scan]
// Prints one JSON object per step on stdout; exits 0 only when every step passed.
const url = process.argv[2];
const v1 = process.argv.includes("--v1");
const expectScan = process.argv.includes("--expect-scan");
const lib = v1 ? (await import("roslib1")).default : await import("roslib");
const { Ros, Topic, Service } = lib;

const report = (step, data) => console.log(JSON.stringify({ step, ...data }));
const fail = (why) => {
  report("fail", { error: String(why) });
  process.exit(1);
};
setTimeout(() => fail("overall timeout"), 30000).unref();

function within(ms, what, executor) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`timed out: ${what}`)), ms);
    executor(
      (value) => { clearTimeout(timer); resolve(value); },
      (error) => { clearTimeout(timer); reject(error); },
    );
  });
}

const ros = new Ros({ url });
const statuses = [];
const emit = ros.emit.bind(ros);
ros.emit = (event, ...args) => {
  if (typeof event === "string" && event.startsWith("status")) statuses.push(args[0]);
  return emit(event, ...args);
};
ros.on("error", (e) => fail(`ros error: ${e?.message ?? e}`));
await within(5000, "connection", (ok) => ros.on("connection", ok));
report("connected", { version: v1 ? 1 : 2 });

try {
  // discovery through rosapi (2.x calls "rosapi/topics", 1.x "/rosapi/topics")
  const topics = await within(5000, "getTopics", (ok, no) => ros.getTopics(ok, no));
  const table = Object.fromEntries(topics.topics.map((t, i) => [t, topics.types[i]]));
  for (const [name, type] of [["/odom", "nav_msgs/msg/Odometry"],
    ["/cmd_vel", "geometry_msgs/msg/Twist"], ["/scan", "sensor_msgs/msg/LaserScan"]]) {
    if (table[name] !== type) fail(`getTopics: ${name} is ${table[name]}, expected ${type}`);
  }
  report("getTopics", { count: topics.topics.length });

  // a service call, and one that fails
  const topicType = new Service({ ros, name: "/rosapi/topic_type",
    serviceType: "rosapi_msgs/srv/TopicType" });
  const typed = await within(5000, "topic_type", (ok, no) =>
    topicType.callService({ topic: "/odom" }, ok, no));
  if (typed.type !== "nav_msgs/msg/Odometry") fail(`topic_type: ${JSON.stringify(typed)}`);
  const missing = new Service({ ros, name: "/no_such_service", serviceType: "std_srvs/srv/Empty" });
  const refusal = await within(5000, "missing service", (ok) =>
    missing.callService({}, () => fail("a missing service answered"), ok));
  if (!String(refusal).includes("does not exist")) fail(`missing service: ${refusal}`);
  report("services", { type: typed.type, refusal: String(refusal) });

  // subscribe /odom, drive on /cmd_vel, and see the robot move
  const odom = new Topic({ ros, name: "/odom", messageType: "nav_msgs/msg/Odometry",
    throttle_rate: 50 });
  let latest = null;
  const first = await within(5000, "first /odom", (ok) => odom.subscribe((m) => {
    latest = m;
    ok(m);
  }));
  const x0 = first.pose.pose.position.x;
  const cmd = new Topic({ ros, name: "/cmd_vel", messageType: "geometry_msgs/msg/Twist" });
  cmd.advertise();
  const drive = setInterval(() => cmd.publish({ linear: { x: 0.3, y: 0, z: 0 },
    angular: { x: 0, y: 0, z: 0 } }), 50);
  await within(8000, "/odom to show motion", (ok) => {
    const check = setInterval(() => {
      if (latest && latest.pose.pose.position.x - x0 > 0.05) {
        clearInterval(check);
        ok();
      }
    }, 20);
  });
  clearInterval(drive);
  cmd.publish({ linear: { x: 0, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } });
  report("drove", { from: x0, to: latest.pose.pose.position.x,
    stamp: latest.header.stamp });

  // /scan: a LaserScan whose missing returns are null
  const scanTopic = new Topic({ ros, name: "/scan", messageType: "sensor_msgs/msg/LaserScan" });
  let scan = null;
  scanTopic.subscribe((m) => { scan = m; });
  if (expectScan) {
    await within(8000, "a /scan", (ok) => {
      const check = setInterval(() => { if (scan) { clearInterval(check); ok(); } }, 20);
    });
    if (!Array.isArray(scan.ranges) || scan.ranges.length === 0) fail("scan without ranges");
    report("scan", { rays: scan.ranges.length, frame: scan.header.frame_id });
  } else {
    const subs = new Service({ ros, name: "/rosapi/subscribers",
      serviceType: "rosapi_msgs/srv/Subscribers" });
    const who = await within(5000, "subscribers", (ok, no) =>
      subs.callService({ topic: "/scan" }, ok, no));
    if (!who.subscribers.includes("/rosbridge_websocket")) fail("/scan subscription missing");
    report("scan", { subscribed: true, rays: null });
  }

  // a malformed publish gets a status error (the server keeps the socket open)
  const before = statuses.length;
  cmd.publish({ linear: { x: "fast", y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } });
  await within(5000, "a status error", (ok) => {
    const check = setInterval(() => {
      if (statuses.length > before) { clearInterval(check); ok(); }
    }, 10);
  });
  const status = statuses[before];
  if (status.level !== "error" || !status.msg.includes("linear.x")) {
    fail(`unexpected status ${JSON.stringify(status)}`);
  }
  report("status", { level: status.level, msg: status.msg, id: status.id ?? null });
  const after = await within(5000, "getTopics after the error", (ok, no) =>
    ros.getTopics(ok, no));
  report("alive", { topics: after.topics.length });

  odom.unsubscribe();
  scanTopic.unsubscribe();
  cmd.unadvertise();
  ros.close();
  report("done", { ok: true });
  process.exit(0);
} catch (error) {
  fail(error?.message ?? error);
}
