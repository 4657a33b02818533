// Moves arbiterd's arm with the real roslib 2.x on Node: /arm/pose, the joint command topics,
// and /joint_states read back until they converge.
// Usage: node roslib_arm.mjs ws://127.0.0.1:9090/ TOLERANCE_RAD TOLERANCE_M
// Prints one JSON object per step on stdout; exits 0 only when every step passed.
import { Ros, Topic } from "roslib";

const [url, tolRad, tolM] = process.argv.slice(2);
const tolerance = [...Array(3).fill(Number(tolRad)), Number(tolM), Number(tolM)];
const report = (step, data) => console.log(JSON.stringify({ step, ...data }));
const fail = (why) => {
  report("fail", { error: String(why) });
  process.exit(1);
};
setTimeout(() => fail("overall timeout"), 30000).unref();

const ros = new Ros({ url });
const statuses = [];
const emit = ros.emit.bind(ros);
ros.emit = (event, ...args) => {
  if (typeof event === "string" && event.startsWith("status")) statuses.push(args[0]);
  return emit(event, ...args);
};
ros.on("error", (e) => fail(`ros error: ${e?.message ?? e}`));
await new Promise((ok) => ros.on("connection", ok));

let latest = null;
const states = new Topic({ ros, name: "/joint_states", messageType: "sensor_msgs/msg/JointState" });
states.subscribe((m) => { latest = m; });

// Resolves with the first /joint_states whose positions are within tolerance of `want`.
function converged(want, what, ms = 10000) {
  return new Promise((ok, no) => {
    const t0 = Date.now();
    const check = setInterval(() => {
      if (latest && latest.position.every((p, i) => Math.abs(p - want[i]) <= tolerance[i])) {
        clearInterval(check);
        ok(latest);
      } else if (Date.now() - t0 > ms) {
        clearInterval(check);
        no(new Error(`timed out: ${what}; last ${JSON.stringify(latest?.position)}`));
      }
    }, 10);
  });
}

const float = (name) => {
  const topic = new Topic({ ros, name, messageType: "std_msgs/msg/Float64" });
  topic.advertise();
  return topic;
};

try {
  const pose = new Topic({ ros, name: "/arm/pose", messageType: "std_msgs/msg/String" });
  pose.advertise();
  pose.publish({ data: "pregrasp" });
  const atPose = await converged([1.043, 0.934, 0.495, 0.035, 0.035], "pregrasp");
  report("pregrasp", { name: atPose.name, position: atPose.position });

  const want = [0.3, -0.4, 0.6, 0.01, 0.01];
  ["/arm_joint1_cmd", "/arm_joint2_cmd", "/arm_joint3_cmd", "/left_finger_cmd"]
    .forEach((name, i) => float(name).publish({ data: want[i] }));
  const atJoints = await converged(want, "the joint commands");
  report("joints", { position: atJoints.position, velocity: atJoints.velocity });

  const before = statuses.length;
  pose.publish({ data: "wave" });
  await new Promise((ok) => {
    const check = setInterval(() => {
      if (statuses.length > before) { clearInterval(check); ok(); }
    }, 10);
  });
  report("refused", { level: statuses[before].level, msg: statuses[before].msg });
  states.unsubscribe();
  ros.close();
  report("done", { ok: true });
  process.exit(0);
} catch (error) {
  fail(error?.message ?? error);
}
