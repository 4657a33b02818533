// The real Foxglove Studio web app (the prebuilt bundle of @foxglove/studio-base 1.48.0, React 17)
// in Debian's Chromium (WebGL through SwiftShader) against arbiterd's rosbridge, with a layout
// holding one 3D panel that shows /map and /scan in frame `map`.
//   node foxglove_app.mjs WS_URL HTTP_PORT SCREENSHOT.png [GOAL_JSON]
// Serves a host page (App + the Rosbridge and Foxglove WebSocket data sources + an in-memory
// layout storage) on 127.0.0.1:HTTP_PORT, opens it with ?ds=SOURCE&ds.url=WS_URL&layoutId=…
// (SOURCE: rosbridge-websocket, or foxglove-websocket when FOXGLOVE_APP_SOURCE=foxglove), waits
// until the app's own topic table (its Data source sidebar) counts /map and /scan messages
// received, then until the panel's pixels show the map, and writes the screenshot.
// With GOAL_JSON ({"api", "frame", "target": [x, y], "distance": m, "clicks": [[x, y], [x, y]]})
// the panel shows /scan and /plan in `frame`, looking straight down (2D camera) at `target` with `distance`
// metres from its top edge to its bottom edge, its publish tool set to *Publish pose* on
// /goal_pose; the mouse presses the panel's publish button, clicks the scene at clicks[0] (the
// position) then at clicks[1] (the heading), and the script follows `api`/api/goal until the
// navigation ends. The app's WebSocket frames are watched: what it advertised and published, and
// every `status` op it received.
// Prints one JSON object per step on stdout; exits 0 only when every step passed.
import { createServer } from "node:http";
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";
import { chromium } from "playwright-core";

const require = createRequire(import.meta.url);
const [wsUrl, httpPort, shotPath, goalJson] = process.argv.slice(2);
const GOAL = goalJson ? JSON.parse(goalJson) : null;
const CHROMIUM = process.env.ARBITERD_CHROMIUM || "/usr/bin/chromium";
// the app's connection: "Rosbridge" (default) or "Foxglove WebSocket"
const SOURCE = process.env.FOXGLOVE_APP_SOURCE === "foxglove" ? "foxglove-websocket"
  : "rosbridge-websocket";
// WebGL without a GPU: SwiftShader through ANGLE
const ARGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
  "--ignore-gpu-blocklist", "--disable-background-networking", "--disable-component-update",
  "--no-first-run"];
const LAYOUT_ID = "arbiterd-3d";
const BACKGROUND = "#203050"; // the scene's background: no map colour is near it
const report = (step, data = {}) => console.log(JSON.stringify({ step, ...data }));
setTimeout(() => { report("fail", { error: "overall timeout" }); process.exit(1); }, 280000).unref();

const STUDIO = path.dirname(require.resolve("@foxglove/studio-base/package.json"));
const FILES = {
  "/react.js": require.resolve("react/umd/react.production.min.js"),
  "/react-dom.js": require.resolve("react-dom/umd/react-dom.production.min.js"),
};

// One 3D panel, following frame `map`, looking down on it, /map and /scan visible.
const LAYOUT = {
  configById: {
    "3D!arbiterd": {
      followTf: "map",
      followMode: "follow-none",
      cameraState: { perspective: false, distance: 30, phi: 0, thetaOffset: 0,
        target: [0, 0, 0], targetOffset: [0, 0, 0], targetOrientation: [0, 0, 0, 1],
        fovy: 45, near: 0.5, far: 5000 },
      scene: { backgroundColor: BACKGROUND },
      transforms: {},
      topics: { "/map": { visible: true }, "/scan": { visible: true, pointSize: 4 } },
      layers: {},
      publish: { type: "point", poseTopic: "/move_base_simple/goal",
        pointTopic: "/clicked_point", poseEstimateTopic: "/initialpose" },
    },
  },
  globalVariables: {},
  userNodes: {},
  playbackConfig: { speed: 1 },
  layout: "3D!arbiterd",
};
if (GOAL) { // the goal test: /scan in GOAL.frame, top-down, the pose tool on /goal_pose
  const panel = LAYOUT.configById["3D!arbiterd"];
  panel.followTf = GOAL.frame;
  panel.cameraState = { ...panel.cameraState, distance: GOAL.distance,
    targetOffset: [GOAL.target[0], GOAL.target[1], 0] };
  panel.topics = { "/scan": { visible: true, pointSize: 4 }, "/plan": { visible: true } };
  panel.publish = { ...panel.publish, type: "pose", poseTopic: "/goal_pose" };
}

const HOST_JS = `
const layout = ${JSON.stringify({ id: LAYOUT_ID, name: "arbiterd map", permission: "CREATOR_WRITE",
    baseline: { data: LAYOUT, savedAt: "2024-01-01T00:00:00.000Z" }, working: undefined,
    syncInfo: undefined })};
const layouts = new Map([[layout.id, layout]]);
const layoutStorage = {
  async list() { return [...layouts.values()]; },
  async get(_ns, id) { return layouts.get(id); },
  async put(_ns, l) { layouts.set(l.id, l); return l; },
  async delete(_ns, id) { layouts.delete(id); },
  async importLayouts() {},
};
const values = new Map();
const appConfiguration = {
  get: (key) => values.get(key),
  set: async (key, value) => { values.set(key, value); },
  addChangeListener() {},
  removeChangeListener() {},
};
(async () => {
  await window.initI18n();
  ReactDOM.render(React.createElement(window.App, {
    deepLinks: [location.href], appConfiguration, layoutStorage, extensionLoaders: [],
    dataSources: [new window.RosbridgeDataSourceFactory(),
      new window.FoxgloveWebSocketDataSourceFactory()], enableGlobalCss: true,
  }), document.getElementById("root"));
})().catch((e) => console.error("host: " + (e && e.stack || e)));
`;

const HOST_HTML = `<!doctype html><html><head><meta charset="utf-8"><title>Foxglove Studio</title>
<style>html, body, #root { height: 100%; margin: 0; }</style></head><body><div id="root"></div>
<script src="/react.js"></script><script src="/react-dom.js"></script>
<script>window.react = window.React; window["react-dom"] = window.ReactDOM;</script>
<script src="/assets/index.js"></script><script src="/host.js"></script></body></html>`;

const TYPES = { ".js": "text/javascript", ".wasm": "application/wasm", ".png": "image/png",
  ".svg": "image/svg+xml", ".woff2": "font/woff2", ".woff": "font/woff", ".ttf": "font/ttf",
  ".json": "application/json", ".css": "text/css" };

const server = createServer(async (req, res) => {
  const url = new URL(req.url, "http://x");
  try {
    if (url.pathname === "/") {
      res.writeHead(200, { "Content-Type": "text/html" }).end(HOST_HTML);
    } else if (url.pathname === "/host.js") {
      res.writeHead(200, { "Content-Type": "text/javascript" }).end(HOST_JS);
    } else if (FILES[url.pathname] || url.pathname.startsWith("/assets/")) {
      const file = FILES[url.pathname] ??
        path.join(STUDIO, "assets", path.basename(url.pathname));
      const body = await readFile(file);
      res.writeHead(200, { "Content-Type": TYPES[path.extname(file)] ?? "application/octet-stream" })
        .end(body);
    } else {
      res.writeHead(404).end();
    }
  } catch {
    res.writeHead(404).end();
  }
});
await new Promise((resolve) => server.listen(Number(httpPort), "127.0.0.1", resolve));

// The app's own topic table (the Data source sidebar): name, datatype, messages received, rate.
function topicTable() {
  const lines = document.body.innerText.split("\n").map((l) => l.trim());
  const topics = {};
  for (let i = 0; i + 2 < lines.length; i++) {
    if (/^\/[\w/]+$/.test(lines[i]) && /^\w+\/(msg\/)?\w+$/.test(lines[i + 1])) {
      const count = Number(lines[i + 2].replace(/,/g, ""));
      topics[lines[i]] = { type: lines[i + 1], received: Number.isFinite(count) ? count : 0 };
    }
  }
  return topics;
}

// Counts the screenshot's pixels by colour, in a canvas of the page itself.
async function countColours(page, png, clip) {
  return page.evaluate(async ({ b64, clip: c }) => {
    const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
    const bitmap = await createImageBitmap(blob);
    const canvas = document.createElement("canvas");
    canvas.width = bitmap.width;
    canvas.height = bitmap.height;
    const ctx = canvas.getContext("2d");
    ctx.drawImage(bitmap, 0, 0);
    const { data } = ctx.getImageData(Math.round(c.x), Math.round(c.y), Math.round(c.width),
      Math.round(c.height));
    // Foxglove's defaults, as SwiftShader shades them: unknown cells grey (127), free cells light
    // grey to white, occupied black (mostly under the scan's points), /scan red
    const out = { pixels: data.length / 4, unknown: 0, free: 0, occupied: 0, scan: 0,
      background: 0 };
    for (let i = 0; i < data.length; i += 4) {
      const [r, g, b] = [data[i], data[i + 1], data[i + 2]];
      const grey = Math.abs(r - g) < 6 && Math.abs(g - b) < 6;
      if (grey && r >= 185) out.free++;
      else if (grey && r >= 120 && r <= 135) out.unknown++;
      else if (grey && r < 30) out.occupied++;
      else if (r > 120 && g < 40 && b < 40) out.scan++;
      else if (Math.abs(r - 0x20) < 6 && Math.abs(g - 0x30) < 6 && Math.abs(b - 0x50) < 6) {
        out.background++;
      }
    }
    const histogram = new Map();
    for (let i = 0; i < data.length; i += 4) {
      const key = `${data[i] >> 3 << 3},${data[i + 1] >> 3 << 3},${data[i + 2] >> 3 << 3}`;
      histogram.set(key, (histogram.get(key) || 0) + 1);
    }
    out.top = [...histogram].sort((x, y) => y[1] - x[1]).slice(0, 10);
    return out;
  }, { b64: png.toString("base64"), clip });
}

async function drawMap(page) {
  const canvas = page.locator("canvas").first();
  await canvas.waitFor({ timeout: 30000 });
  const clip = await canvas.boundingBox();
  // the map is drawn once the map -> odom -> base_link -> laser chain and /map have arrived
  let counts = null;
  const t0 = Date.now();
  for (;;) {
    // SwiftShader on two shared cores: a frame can take seconds
    const png = await page.screenshot({ timeout: 90000 });
    counts = await countColours(page, png, clip);
    if (counts.free > 0.02 * counts.pixels && counts.unknown > 0.1 * counts.pixels &&
        counts.scan > 100) break;
    if (Date.now() - t0 > 45000) break; // reported as it is: the test asserts
    // the next frames (the scene renders on requestAnimationFrame)
    await page.evaluate(() => new Promise((resolve) => {
      let n = 0;
      const next = () => (++n >= 10 ? resolve() : requestAnimationFrame(next));
      requestAnimationFrame(next);
    }));
  }
  await page.screenshot({ path: shotPath, timeout: 90000 });
  const text = await page.evaluate(() => document.body.innerText);
  const unknownType = text.split("\n").filter((l) => /unknown message type|no message definition|unsupported/i.test(l));
  report("rendered", { counts, clip, unknownType, errors: errors.slice(0, 20),
    topicErrors: text.split("\n").filter((l) => /error/i.test(l)).slice(0, 20) });
}

// The scene's point (x, y) in the display frame, in page pixels: the 2D camera looks down -z
// at GOAL.target, x to the right, y up, GOAL.distance metres over the canvas' height.
function pixelOf(box, [x, y]) {
  const scale = box.height / GOAL.distance;
  return { x: box.x + box.width / 2 + (x - GOAL.target[0]) * scale,
    y: box.y + box.height / 2 - (y - GOAL.target[1]) * scale };
}

async function until(what, test, timeoutMs) {
  const t0 = Date.now();
  for (;;) {
    const value = await test();
    if (value) return value;
    if (Date.now() - t0 > timeoutMs) throw new Error(`timed out waiting for ${what}`);
    await new Promise((resolve) => setTimeout(resolve, 200));
  }
}

async function sendGoal(page) {
  // the publish control shows once the renderer has a fixed frame (the first /tf)
  const button = page.getByTestId("publish-button");
  await button.waitFor({ timeout: 60000 });
  const before = await button.getAttribute("title");
  await button.click();
  await until("the publish tool armed", async () =>
    (await button.getAttribute("title")) === "Click to cancel", 30000);
  const box = await page.locator("canvas").first().boundingBox();
  const [at, toward] = GOAL.clicks.map((p) => pixelOf(box, p));
  await page.mouse.click(at.x, at.y); // the position
  await page.mouse.move(toward.x, toward.y, { steps: 5 });
  await page.mouse.click(toward.x, toward.y); // the heading
  const published = await until("the app's publish on /goal_pose", () =>
    frames.sent.find((f) => f.op === "publish" && f.topic === "/goal_pose"), 30000);
  report("published", { title: before, box, pixels: [at, toward], msg: published.msg,
    cdr: published.cdr, advertised: advertised() });
  // the robot drives; the app stays connected, receiving everything, until navigation ends
  const goal = await until("the navigation's end", async () => {
    const body = await (await fetch(`${GOAL.api}/api/goal`)).json();
    return ["succeeded", "failed", "canceled"].includes(body.state) ? body : null;
  }, 150000);
  report("navigation", { goal });
  await page.screenshot({ path: shotPath, timeout: 90000 });
  const text = await page.evaluate(() => document.body.innerText);
  // the player's problems (the Data source sidebar's Problems tab): "No problems found" or a list
  const tab = page.getByRole("tab", { name: /^Problems/ });
  await tab.click();
  const problems = await until("the Problems tab", async () => {
    const shown = await page.evaluate(() => document.body.innerText);
    const lines = shown.split("\n").map((l) => l.trim()).filter(Boolean);
    const after = lines.slice(lines.lastIndexOf("Problems") + 1);
    return shown.includes("No problems found") || (await tab.innerText()) !== "Problems"
      ? { tab: await tab.innerText(), lines: after.slice(0, 20) } : null;
  }, 30000);
  report("app", { statuses: frames.statuses, received: frames.received, problems,
    errors: errors.slice(0, 20),
    unknownType: text.split("\n").filter((l) => /unknown message type|no message definition|unsupported/i.test(l)),
    topics: await page.evaluate(topicTable) });
}

const browser = await chromium.launch({ executablePath: CHROMIUM, args: ARGS });
let page = null;
const errors = [];
// the app's rosbridge traffic as JSON text frames (the binary ones are cbor-raw messages)
const frames = { sent: [], statuses: [], received: {} }; // received: text ops by name
// what the app advertised: rosbridge's one topic per op, or the Foxglove protocol's channels
const advertised = () => frames.sent.filter((f) => f.op === "advertise").flatMap((f) =>
  f.channels ? f.channels.map((c) => ({ topic: c.topic, type: c.schemaName, id: c.id }))
    : [{ topic: f.topic, type: f.type }]);
// a Foxglove client's binary MESSAGE_DATA (opcode 1, channel id, the CDR message) as a publish
const foxgloveMessage = (payload) => {
  const bytes = Buffer.from(payload);
  if (bytes.length < 5 || bytes[0] !== 1) return null;
  const channelId = bytes.readUInt32LE(1);
  const channel = advertised().find((c) => c.id === channelId);
  return { op: "publish", topic: channel?.topic, cdr: bytes.subarray(5).toString("base64") };
};
const parse = (payload) => {
  if (typeof payload !== "string") return null;
  try { return JSON.parse(payload); } catch { return null; }
};
try {
  const context = await browser.newContext({ viewport: { width: 800, height: 500 } });
  page = await context.newPage();
  page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
  page.on("pageerror", (e) => errors.push(`pageerror: ${e.message}`));
  page.on("response", (r) => { if (r.status() >= 400) errors.push(`${r.status()} ${r.url()}`); });
  page.on("websocket", (ws) => {
    ws.on("framesent", ({ payload }) => {
      const op = typeof payload === "string" ? parse(payload) : foxgloveMessage(payload);
      if (op && op.op !== "call_service") frames.sent.push(op);
    });
    ws.on("framereceived", ({ payload }) => {
      const op = parse(payload);
      if (op?.op) frames.received[op.op] = (frames.received[op.op] ?? 0) + 1;
      if (op?.op === "status") frames.statuses.push(op);
    });
  });
  const query = new URLSearchParams({ ds: SOURCE, "ds.url": wsUrl,
    layoutId: LAYOUT_ID });
  await page.goto(`http://127.0.0.1:${httpPort}/?${query}`);
  const webgl = await page.evaluate(() => {
    const gl = document.createElement("canvas").getContext("webgl2");
    if (!gl) return null;
    const info = gl.getExtension("WEBGL_debug_renderer_info");
    return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : "webgl2";
  });
  report("webgl", { renderer: webgl });

  const maps = GOAL ? 0 : 1; // the goal test runs without [mapping]
  await page.waitForFunction(`((t) => (t["/map"]?.received ?? 0) >= ${maps} &&
    (t["/scan"]?.received ?? 0) >= 3)((${topicTable})())`, null, { timeout: 60000, polling: 250 })
    .catch((e) => { throw new Error(`the app received /map and /scan: ${e.message}`); });
  const topics = await page.evaluate(topicTable);
  report("topics", { topics });

  await (GOAL ? sendGoal(page) : drawMap(page));
  report("done", { ok: true });
} catch (error) {
  report("fail", { error: String(error?.stack ?? error) });
  process.exitCode = 1;
  if (page) { // what the app showed and did, to say why
    await page.screenshot({ path: shotPath }).catch(() => {});
    report("state", { errors: errors.slice(0, 20),
      topics: await page.evaluate(topicTable).catch(() => null),
      text: (await page.evaluate(() => document.body.innerText).catch(() => "")).slice(0, 3000) });
  }
} finally {
  await browser.close();
  server.close();
}
