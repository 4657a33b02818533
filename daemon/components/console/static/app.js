// The console page: wires the HTTP API, the rosbridge connection, driving, the e-stop, the
// view, the latency HUD and the health panel together. docs/console.md describes it.
import { Api } from "./api.js";
import { ArmPanel } from "./arm.js";
import { BatteryGauge } from "./battery.js";
import { Bridge } from "./bridge.js";
import { Drive, isDriveKey } from "./drive.js";
import { renderHealth, renderMotion } from "./health.js";
import { Hud } from "./hud.js";
import { Joystick } from "./joystick.js";
import { LogTail } from "./log.js";
import { MapPanel } from "./map.js";
import { NavPanel } from "./navigate.js";
import { FetchPanel } from "./fetch.js";
import { RobotPanel } from "./robot.js";
import { TokenBox } from "./token.js";
import { View, poseOf } from "./view.js";

const $ = (id) => document.getElementById(id);
const STRING = "std_msgs/msg/String";
const RELEASE_HOLD_MS = 1000;
const REFUSAL_SHOWN_MS = 1500; // a command refusal from the robot stays on the command line

const state = {
  httpUp: null, // the last HTTP request was answered (null: not tried yet)
  wsPort: null, // rosbridge port from /api/health; 0 when rosbridge is disabled
  wsUp: false,
  retryS: 0,
  access: "unknown", // drive | read-only | refused | checking | unknown
  readNeedsToken: false,
  estop: null,
  estopNote: "", // why a release did not go through
  fault: null, // the driver fault from /api/status: the robot refuses every command
  refusal: { text: "", at: -Infinity }, // the robot's last refusal of this page's command
  mode: "",
  limits: { linear: 2, angular: 2 },
};

const token = new TokenBox({
  dialog: $("token-dialog"), form: $("token-form"), input: $("token-input"),
  why: $("token-why"), cancel: $("token-cancel"), onChange: tokenChanged,
});
const api = new Api(() => token.get());
const bridge = new Bridge(bridgeUrl);
const view = new View($("view"), $("view-info"));
const hud = new Hud({ p50: $("lat-p50"), p99: $("lat-p99"), rtt: $("lat-rtt"),
  link: $("link-rtt"), api: $("lat-api"), spark: $("sparkline") });
const clientTag = Math.random().toString(36).slice(2, 6);
let commandSeq = 0;
const drive = new Drive(sendCommand);
const battery = new BatteryGauge($("battery-pill"), (warning) => {
  state.batteryWarning = warning;
  renderBanner();
});
const logTail = new LogTail($("log"));
const robot = new RobotPanel({
  wander: $("wander"), explore: $("explore"), wanderState: $("wander-state"), record: $("record"),
  recordState: $("record-state"), odomReset: $("odom-reset"), simReset: $("sim-reset"),
  message: $("robot-message"), recordings: $("recordings"), refresh: $("recordings-refresh"),
}, api, { onRefused: (what) => tokenProblem(what), onOdometryReset: () => view.clearTrail() });
const armPanel = new ArmPanel({ panel: $("arm-panel"), poses: $("arm-poses"),
  open: $("gripper-open"), close: $("gripper-close"), state: $("arm-state"), view: $("arm-view"),
  message: $("arm-message") }, api, { onRefused: (what) => tokenProblem(what) });
const mapPanel = new MapPanel({ save: $("map-save"), message: $("map-message"),
  hint: $("map-hint") }, api, bridge, view, { onRefused: (what) => tokenProblem(what) });
const navPanel = new NavPanel({ tool: $("goal-tool"), figure8: $("figure-eight"),
  cancel: $("nav-cancel"), state: $("nav-state") }, api, bridge, view,
{ onRefused: (what) => tokenProblem(what) });
const fetchPanel = new FetchPanel({ tool: $("fetch-tool"), cancel: $("fetch-cancel"),
  state: $("fetch-state") }, api, bridge, view, { onRefused: (what) => tokenProblem(what) });

// -- connection, access and the banner ------------------------------------------------------

function bridgeUrl() {
  if (!state.wsPort) return "";
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const t = token.get();
  return `${scheme}://${location.hostname}:${state.wsPort}/` +
    (t ? `?token=${encodeURIComponent(t)}` : "");
}

function setAccess(access) {
  state.access = access;
  $("token-button").hidden = !(access === "read-only" || access === "refused" ||
    state.readNeedsToken || token.get());
  render();
}

// What this tab can do now: the token decides, and a faulted driver refuses everyone.
function renderAccess() {
  const pill = $("access");
  if (state.fault) {
    pill.textContent = "cannot drive: driver fault";
    pill.dataset.state = "fault";
    return;
  }
  pill.textContent = { drive: "can drive", "read-only": "read-only: token needed",
    refused: "token refused", checking: "", unknown: "" }[state.access];
  pill.dataset.state = state.access;
}

// The daemon says a token is missing or wrong: 401 on HTTP, a `status` error on rosbridge.
function tokenProblem(what) {
  const refused = Boolean(token.get());
  setAccess(refused ? "refused" : "read-only");
  if (refused) {
    token.ask(`The token was refused: it does not match the robot's (${what}).`,
      { refused: true, automatic: true });
  } else {
    token.ask(`This robot needs a token ${what}.`, { automatic: true });
  }
}

function tokenChanged() {
  state.readNeedsToken = false;
  state.estopNote = "";
  setAccess("unknown");
  bridge.reconnect();
  pollHealth();
}

function render() {
  const conn = $("conn");
  let text = "connecting…";
  let kind = "connecting";
  if (state.httpUp === false) [text, kind] = ["disconnected", "disconnected"];
  else if (state.httpUp && (state.wsUp || state.wsPort === 0)) [text, kind] = ["connected", "connected"];
  else if (state.httpUp && state.retryS) [text, kind] = ["rosbridge lost", "disconnected"];
  conn.textContent = text;
  conn.dataset.state = kind;
  renderAccess();
  renderBanner();
}

function renderBanner() {
  const banner = $("banner");
  const host = location.host;
  let message = "";
  let kind = "error";
  if (state.httpUp === false) {
    message = `Disconnected: the robot at ${host} does not answer. Retrying…`;
  } else if (state.readNeedsToken) {
    message = token.get() ? "The token was refused: this robot needs the right token even to read."
      : "This robot needs a token even to read its telemetry: use Token….";
  } else if (state.fault) {
    message = `Driver fault: ${state.fault}. The robot refuses every command until its ` +
      "driver is back; the daemon keeps reconnecting.";
    kind = "fault";
  } else if (state.wsPort === 0) {
    message = "rosbridge is disabled on this robot ([rosbridge] enabled = false): no live view or driving.";
  } else if (state.httpUp && !state.wsUp && state.retryS) {
    message = `No rosbridge connection to ${location.hostname}:${state.wsPort}; retrying in ` +
      `${state.retryS} s. The robot brakes when its driver's connection drops.`;
  } else if (state.access === "refused") {
    message = "The token was refused: it does not match the robot's. Enter it again with Token….";
  } else if (state.access === "read-only") {
    message = "Read-only: this robot needs a token to drive. Enter it with Token….";
    kind = "info";
  } else if (state.batteryWarning) {
    message = state.batteryWarning;
    kind = "fault";
  }
  banner.textContent = message;
  banner.dataset.kind = kind;
  banner.hidden = !message;
}

bridge.addEventListener("open", () => {
  state.wsUp = true;
  state.retryS = 0;
  setAccess("checking");
  ping(); // answered after any refusal of the advertisements: settles the access
});
bridge.addEventListener("close", () => {
  state.wsUp = false;
  drive.stopAll();
  render();
});
bridge.addEventListener("retry", (event) => {
  state.retryS = Math.round(event.detail.delay / 100) / 10;
  render();
});
bridge.addEventListener("status", (event) => {
  const { msg = "", level } = event.detail;
  if (level !== "error") return;
  if (msg.includes("token")) tokenProblem("to drive");
  else if (msg.startsWith("publish /stamped_cmd_vel: ")) {
    state.refusal = { text: msg.slice("publish /stamped_cmd_vel: ".length), at: performance.now() };
  }
});

async function ping() {
  const t0 = performance.now();
  try {
    await bridge.callService("/rosapi/get_time", {}, 3000);
  } catch {
    return;
  }
  hud.link(performance.now() - t0);
  if (state.access === "checking" || state.access === "unknown") setAccess("drive");
}

// -- telemetry ------------------------------------------------------------------------------

bridge.advertise("/stamped_cmd_vel", STRING);
bridge.subscribe("/odom", "nav_msgs/msg/Odometry", (m) => view.setOdom(poseOf(m)));
bridge.subscribe("/scan", "sensor_msgs/msg/LaserScan", (m) => view.setScan(m));
bridge.subscribe("/latency_reports", STRING, (m) => hud.report(m.data));
bridge.subscribe("/robot_info", STRING, (m) => robotInfo(JSON.parse(m.data)));
bridge.subscribe("/autonomy/state", STRING, (m) => robot.setAutonomy(JSON.parse(m.data)));
bridge.subscribe("/rosout", "rcl_interfaces/msg/Log", (m) => logTail.add(m));
bridge.subscribe("/battery_state", "sensor_msgs/msg/BatteryState", (m) => {
  if (!battery.asked) {
    battery.asked = true;
    api.get("/api/battery").then((r) => battery.setThresholds(r.body && r.body.thresholds))
      .catch(() => {});
  }
  battery.update(m);
});

function robotInfo(info) {
  $("robot-name").textContent = info.name || "arbiterd";
  document.title = `${info.name || "arbiterd"} · arbiterd console`;
  const limits = info.limits || {};
  const linear = limits["linear.x.max_velocity"];
  const angular = limits["angular.z.max_velocity"];
  if (linear > 0 && angular > 0 && (linear !== state.limits.linear || angular !== state.limits.angular)) {
    state.limits = { linear, angular };
    const slider = $("speed");
    slider.max = String(linear);
    slider.step = String(Math.max(0.01, Math.round(linear / 40 * 100) / 100));
    if (Number(slider.value) > linear) slider.value = String(linear);
    speedChanged();
  }
  const fp = info.footprint_radius ?? info.geometry?.footprint_radius;
  view.footprint = fp > 0 ? fp : (info.geometry?.wheel_separation || 0.3) / 2 + 0.05;
}

function speedChanged() {
  const v = Number($("speed").value);
  drive.limits = { linear: v, angular: (v / state.limits.linear) * state.limits.angular };
  $("speed-out").textContent = `${v.toFixed(2)} m/s`;
}

function healthArrived(health) {
  const port = health.components.rosbridge?.port;
  const firstTime = state.wsPort === null;
  state.wsPort = port || 0;
  if (health.mode !== state.mode) {
    state.mode = health.mode;
    $("mode").textContent = health.mode === "sim" ? "simulated robot" : "hardware";
    if (health.mode === "sim") {
      bridge.subscribe("/odom_ground_truth", "nav_msgs/msg/Odometry",
        (m) => view.setTruth(poseOf(m)), { throttle_rate: 100 });
      document.querySelector(".key.truth").hidden = false;
    }
    $("sim-reset").hidden = health.mode !== "sim";
  }
  robot.setRecorder(health.components.recorder);
  mapPanel.health(health.components.mapping);
  navPanel.health(health.components.navigation);
  fetchPanel.health(health.components.fetch);
  armPanel.health(health.components.arm);
  renderHealth({ status: $("health-status"), summary: $("health-summary"),
    table: $("components").tBodies[0] }, health);
  if (firstTime && state.wsPort) bridge.connect();
  if (firstTime) robot.refreshRecordings();
}

// Repeats `fn` every `periodMs`, never two at once.
function every(periodMs, fn) {
  const run = async () => {
    try { await fn(); } finally { setTimeout(run, periodMs); }
  };
  run();
}

async function guarded(path, onBody) {
  let answer;
  try {
    answer = await api.get(path);
  } catch {
    if (state.httpUp !== false) { state.httpUp = false; drive.stopAll(); render(); }
    return;
  }
  if (state.httpUp !== true) { state.httpUp = true; render(); }
  if (answer.status === 401) {
    if (!state.readNeedsToken) { state.readNeedsToken = true; tokenProblem("even to read"); }
    return;
  }
  if (state.readNeedsToken) { state.readNeedsToken = false; render(); }
  if (answer.body && !answer.body.error) onBody(answer.body);
  else if (answer.status === 503 && answer.body) onBody(answer.body);
}

const pollHealth = () => guarded("/api/health", healthArrived);
every(1000, pollHealth);
every(250, () => guarded("/api/status", statusArrived));
every(2000, () => guarded("/api/latency", (body) => hud.api(body)));
every(250, () => (armPanel.present ? guarded("/api/arm", (body) => armPanel.render(body)) : null));
every(2000, () => (state.wsUp ? ping() : null));

function statusArrived(status) {
  setEstop(status.estop.engaged, status.estop.reason);
  if ((status.fault || null) !== state.fault) {
    state.fault = status.fault || null;
    if (state.fault) drive.stopAll();
    render();
  }
  renderMotion($("motion"), status);
}

// -- driving ----------------------------------------------------------------------------------

function sendCommand(linear, angular) {
  if (!bridge.open || state.access === "read-only" || state.access === "refused" ||
      state.estop || state.fault) return false;
  const id = `console-${clientTag}-${++commandSeq}`;
  const body = { linear: { x: linear }, angular: { z: angular }, id, t_sent: Date.now() };
  hud.commandSent(id);
  return bridge.publish("/stamped_cmd_vel", { data: JSON.stringify(body) });
}

drive.onCommand = (linear, angular, sent) => {
  let why = "";
  if (!sent) {
    if (state.estop) why = " · not sent: e-stop engaged";
    else if (state.fault) why = " · not sent: driver fault (see above)";
    else if (state.access === "read-only") why = " · not sent: this robot needs a token to drive";
    else if (state.access === "refused") why = " · not sent: the token was refused";
    else why = " · not sent: not connected";
  } else if (performance.now() - state.refusal.at < REFUSAL_SHOWN_MS) {
    why = ` · refused by the robot: ${state.refusal.text}`;
  }
  $("command").textContent = `v ${linear.toFixed(2)} m/s · ω ${angular.toFixed(2)} rad/s${why}`;
};
drive.onGamepadStop = () => engageEstop();

const joystick = new Joystick($("joystick"), $("stick"), (x, y) => drive.setStick(x, y));

function typing(event) {
  const t = event.target;
  return $("token-dialog").open || (t instanceof HTMLInputElement && t.type !== "range");
}

window.addEventListener("keydown", (event) => {
  if (typing(event) || event.ctrlKey || event.metaKey || event.altKey) return;
  if (event.code === "Space") {
    event.preventDefault();
    if (!event.repeat) engageEstop();
  } else if (isDriveKey(event.code)) {
    event.preventDefault();
    drive.key(event.code, true);
  }
});
window.addEventListener("keyup", (event) => {
  if (event.code === "Space" && !typing(event)) event.preventDefault();
  if (isDriveKey(event.code)) drive.key(event.code, false);
});

function stopEverything() {
  joystick.release();
  drive.stopAll();
}
window.addEventListener("blur", stopEverything);
window.addEventListener("pagehide", stopEverything);
document.addEventListener("visibilitychange", () => {
  if (document.visibilityState !== "visible") stopEverything();
});

$("speed").addEventListener("input", speedChanged);
speedChanged();

// -- e-stop -----------------------------------------------------------------------------------

function setEstop(engaged, reason = "") {
  state.estop = engaged;
  if (!engaged) state.estopNote = "";
  $("estop-box").dataset.engaged = String(engaged);
  $("estop-state").textContent = engaged ? `E-STOP ENGAGED${reason ? ` (${reason})` : ""}` +
    (state.estopNote ? ` · ${state.estopNote}` : "") : "e-stop released";
  $("estop-release").hidden = !engaged;
  $("estop-pill").textContent = engaged ? "E-STOP ENGAGED" : "";
  $("estop-pill").dataset.engaged = String(engaged);
  if (engaged) drive.stopAll();
}

async function engageEstop() {
  drive.stopAll();
  setEstop(true, "console: sending");
  await estopRequest(true);
}

async function estopRequest(engaged) {
  let answer;
  try {
    answer = await api.post("/api/estop", { engaged, reason: "console" });
  } catch {
    setEstop(state.estop, "the robot does not answer");
    return;
  }
  if (answer.status === 401) { // only releasing needs the token; anyone may stop the robot
    state.estopNote = "releasing it needs the token";
    setEstop(true, "");
    tokenProblem("to release the e-stop");
  } else if (answer.status === 200) {
    setEstop(answer.body.engaged, answer.body.engaged ? "console" : "");
  } else if (answer.status === 429) { // latched already, and asked too often
    setEstop(true, "console");
  } else {
    setEstop(state.estop, answer.body?.error || `HTTP ${answer.status}`);
  }
}

$("estop").addEventListener("click", engageEstop);

// Releasing is deliberate: press and hold for RELEASE_HOLD_MS.
{
  const button = $("estop-release");
  const fill = $("release-fill");
  let started = 0;
  let frame = 0;
  const cancel = () => {
    cancelAnimationFrame(frame);
    started = 0;
    fill.style.width = "0";
  };
  const step = () => {
    const done = (performance.now() - started) / RELEASE_HOLD_MS;
    fill.style.width = `${Math.min(1, done) * 100}%`;
    if (done < 1) { frame = requestAnimationFrame(step); return; }
    cancel();
    estopRequest(false);
  };
  const start = () => {
    if (started) return;
    started = performance.now();
    frame = requestAnimationFrame(step);
  };
  button.addEventListener("pointerdown", (event) => {
    event.preventDefault();
    button.setPointerCapture(event.pointerId);
    start();
  });
  for (const name of ["pointerup", "pointercancel", "lostpointercapture"]) {
    button.addEventListener(name, cancel);
  }
  button.addEventListener("keydown", (event) => { if (event.key === "Enter") start(); });
  button.addEventListener("keyup", (event) => { if (event.key === "Enter") cancel(); });
}

// -- view controls ----------------------------------------------------------------------------

$("zoom-in").addEventListener("click", () => view.zoom(-1));
$("zoom-out").addEventListener("click", () => view.zoom(1));
$("clear-trail").addEventListener("click", () => view.clearTrail());
$("fit").addEventListener("click", () => view.setFit(!view.fit));
view.onFitChange = (on) => $("fit").setAttribute("aria-pressed", String(on));
$("heading-up").addEventListener("click", (event) => {
  view.headingUp = !view.headingUp;
  event.currentTarget.setAttribute("aria-pressed", String(view.headingUp));
  view.request();
});
$("token-button").addEventListener("click", () => token.ask(
  state.access === "refused" ? "The token was refused. Enter the robot's token:" :
    "Enter the robot's token:", { refused: state.access === "refused" }));
render();
