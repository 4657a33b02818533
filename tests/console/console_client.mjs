// Drives arbiterd's web console in Debian's Chromium (playwright-core) and measures the robot.
// Usage: node console_client.mjs URL drive|token|reconnect|hold|fault|controls|mapping|navigate|arm
//        [--shots DIR] [--token T] [--seconds S] [--map-name NAME]
// Prints one JSON object per step on stdout; tests/console/test_console_browser.py asserts.
import { readFile } from "node:fs/promises";
import { chromium } from "playwright-core";

const [url, scenario] = process.argv.slice(2);
const option = (name) => {
  const i = process.argv.indexOf(name);
  return i > 0 ? process.argv[i + 1] : undefined;
};
const shots = option("--shots");
const secret = option("--token");
const CHROMIUM = process.env.ARBITERD_CHROMIUM || "/usr/bin/chromium";
const ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
  "--disable-component-update", "--no-first-run"];
const LAPTOP = { width: 1280, height: 800 };
const PHONE = { viewport: { width: 390, height: 844 }, deviceScaleFactor: 2, isMobile: true,
  hasTouch: true };
// a desktop browser's window at phone size: no touch, a mouse, maybe a keyboard
const NARROW = { viewport: { width: 390, height: 844 } };

const report = (step, data = {}) => console.log(JSON.stringify({ step, ...data }));
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
setTimeout(() => { report("fail", { error: "overall timeout" }); process.exit(1); }, 150000).unref();

async function getJson(path) {
  const response = await fetch(new URL(path, url));
  return response.json();
}

const status = () => getJson("/api/status");

const truth = async () => (await status()).ground_truth;

// The server's e-stop once it is `engaged`: the page shows a latch at once, while its request
// may still be on the way (a loaded machine). Polls /api/status for up to 5 s.
async function serverEstop(engaged) {
  const t0 = Date.now();
  let s = await status();
  while (s.estop.engaged !== engaged && Date.now() - t0 < 5000) {
    await sleep(25);
    s = await status();
  }
  return s.estop;
}

// Samples /api/status every 25 ms until `done(sample)` or `ms` pass; returns the samples.
async function watch(ms, done = () => false) {
  const samples = [];
  const t0 = Date.now();
  while (Date.now() - t0 < ms) {
    const s = await status();
    samples.push({ t: Date.now() - t0, target: s.target.linear_x, targetW: s.target.angular_z,
      v: s.twist.linear_x, w: s.twist.angular_z, reason: s.reason, truth: s.ground_truth });
    if (done(s)) break;
    await sleep(25);
  }
  return samples;
}

const still = (s) => s.twist.linear_x === 0 && s.twist.angular_z === 0;

// The first command of a press reached the robot (a loaded machine can delay the page's first
// input by a few hundred ms): the timed hold starts from here.
const commanded = () => watch(5000, (s) => s.reason === "command");

// Holds a key for `ms` (and, with `minMoved`, on until the robot has moved that far, for up to
// 5 s more: a loaded machine's stall stops and stale scans hold it now and then), then
// releases it and follows the robot until it is still.
async function holdKey(page, key, ms, minMoved = 0) {
  const before = await truth();
  await page.keyboard.down(key);
  await commanded();
  const held = await watch(ms);
  const far = (s) => Math.hypot(s.ground_truth.x - before.x, s.ground_truth.y - before.y) >= minMoved;
  if (minMoved > 0 && !far({ ground_truth: held[held.length - 1].truth })) {
    held.push(...await watch(5000, far));
  }
  await page.keyboard.up(key);
  const stopping = await watch(3000, still);
  return { before, atRelease: held[held.length - 1].truth, held: summary(held),
    stop: summary(stopping) };
}

function summary(samples) {
  const last = samples[samples.length - 1];
  return {
    ms: last.t, reasons: [...new Set(samples.map((s) => s.reason))],
    still: last.v === 0 && last.w === 0,
    zeroCommanded: samples.some((s) => s.reason === "command" && s.target === 0 &&
      s.targetW === 0),
    end: last.truth,
  };
}

async function waitReady(page) {
  await page.waitForSelector("#conn[data-state=connected]", { timeout: 15000 });
  await page.waitForFunction(() => /scan [1-9]\d* points/.test(
    document.getElementById("view-info").textContent), null, { timeout: 15000 });
  await page.waitForSelector("#components tr", { timeout: 15000 });
}

async function newPage(browser, options) {
  const context = await browser.newContext(options);
  const page = await context.newPage();
  const errors = [];
  // the browser's own line for a 503 is not the page's error: /api/health answers 503 while
  // a component is in error (a stall stop on a busy machine, a driver fault)
  page.on("console", (m) => {
    if (m.type() === "error" && !m.text().includes("status of 503")) errors.push(m.text());
  });
  page.on("pageerror", (e) => errors.push(`pageerror: ${e.message}`));
  await page.goto(url);
  return { page, context, errors };
}

// Headless Chromium keeps every tab visible, so the page is told it was hidden the way a
// browser says it: document.visibilityState "hidden" and a visibilitychange event.
async function hideTab(page) {
  await page.evaluate(() => {
    Object.defineProperty(document, "visibilityState", { configurable: true, get: () => "hidden" });
    Object.defineProperty(document, "hidden", { configurable: true, get: () => true });
    document.dispatchEvent(new Event("visibilitychange"));
  });
}

const text = (page, selector) => page.$eval(selector, (e) => e.textContent);

async function driveScenario(browser) {
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  // health may read degraded for a poll while the simulated lidar catches up on a busy
  // machine: wait for the state the test asserts (the report says what it was if it never came)
  await page.waitForFunction(() => document.querySelector("#health-status")?.textContent === "ok",
    null, { timeout: 15000 }).catch(() => {});
  report("loaded", {
    conn: await text(page, "#conn"), access: await page.$eval("#access", (e) => e.dataset.state),
    components: await page.$$eval("#components tr", (rows) => rows.map((r) => r.dataset.component)),
    scan: await text(page, "#view-info"), health: await text(page, "#health-status"),
    mode: await text(page, "#mode"), errors: [...errors],
  });
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  report("view", { hint: await page.isVisible("#drive-panel .hint"), ...await inView(page) });

  report("forward", await holdKey(page, "w", 1000, 0.3));
  report("left", await holdKey(page, "a", 600));
  report("right", await holdKey(page, "d", 600));

  const box = await page.locator("#joystick").boundingBox();
  const cx = box.x + box.width / 2;
  const cy = box.y + box.height / 2;
  const before = await truth();
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  await page.mouse.move(cx, cy - box.width * 0.4, { steps: 5 });
  await commanded();
  const held = await watch(1000);
  await hideTab(page);
  const hidden = await watch(3000, still);
  await page.mouse.up();
  report("joystick", { before, atHide: held[held.length - 1].truth, held: summary(held),
    hidden: summary(hidden), command: await text(page, "#command") });
  await page.evaluate(() => {
    delete document.visibilityState;
    delete document.hidden;
    document.dispatchEvent(new Event("visibilitychange"));
  });

  if (shots) await page.screenshot({ path: `${shots}/console-laptop.png` });
  await page.keyboard.press("Space");
  await page.waitForSelector("#estop-box[data-engaged=true]", { timeout: 5000 });
  const latched = { estop: await serverEstop(true) };
  const blocked = await holdKey(page, "w", 800);
  report("estop", { engaged: latched.estop.engaged, reason: latched.estop.reason,
    shown: await text(page, "#estop-state"), blocked });

  const release = page.locator("#estop-release");
  await release.click(); // a click is not a deliberate release
  await sleep(300);
  const afterClick = (await status()).estop.engaged;
  await holdRelease(page);
  await page.waitForSelector("#estop-box[data-engaged=false]", { timeout: 5000 });
  report("release", { afterClick, afterHold: (await status()).estop.engaged });
  report("errors", { errors });
  await context.close();
  await phone(browser);
}

// Presses and holds "Hold to release" past its one second (the page measures the hold).
async function holdRelease(page) {
  const rb = await page.locator("#estop-release").boundingBox();
  await page.mouse.move(rb.x + rb.width / 2, rb.y + rb.height / 2);
  await page.mouse.down();
  await sleep(1300);
  await page.mouse.up();
}

async function phone(browser) {
  const { page, context, errors } = await newPage(browser, PHONE);
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  const box = await page.locator("#joystick").boundingBox();
  const x = box.x + box.width / 2;
  const y = box.y + box.height / 2;
  const cdp = await context.newCDPSession(page);
  const touch = (type, points) => cdp.send("Input.dispatchTouchEvent", { type, touchPoints: points });
  const before = await truth();
  await touch("touchStart", [{ x, y }]);
  for (let i = 1; i <= 5; i++) await touch("touchMove", [{ x, y: y - (box.height * 0.08) * i }]);
  await commanded();
  const held = await watch(1000);
  await touch("touchEnd", []);
  const stop = await watch(3000, still);
  if (shots) await page.screenshot({ path: `${shots}/console-phone.png` });
  report("touch", { before, atRelease: held[held.length - 1].truth, held: summary(held),
    stop: summary(stop), errors, hint: await page.isVisible("#drive-panel .hint") });
  await context.close();
  const narrow = await newPage(browser, NARROW);
  await narrow.page.waitForSelector("#components tr", { timeout: 15000 });
  report("narrow", { hint: await narrow.page.isVisible("#drive-panel .hint") });
  await narrow.context.close();
}

// The latest scan around the robot (laser frame turned by the odometry heading) against what
// the view shows: every point must be inside.
async function inView(page) {
  await page.waitForFunction(() => document.getElementById("view").dataset.halfHeightM, null,
    { timeout: 10000 });
  const [scan, s] = [await getJson("/api/scan"), await status()];
  let ex = 0;
  let ey = 0;
  scan.ranges.forEach((r, i) => {
    if (r === null || !(r >= scan.range_min && r <= scan.range_max)) return;
    const a = scan.angle_min + i * scan.angle_increment + s.pose.theta;
    ex = Math.max(ex, Math.abs(r * Math.cos(a)));
    ey = Math.max(ey, Math.abs(r * Math.sin(a)));
  });
  const shown = await page.$eval("#view", (e) => ({ halfWidth: Number(e.dataset.halfWidthM),
    halfHeight: Number(e.dataset.halfHeightM) }));
  return { scanHalfWidth: ex, scanHalfHeight: ey, ...shown, info: await text(page, "#view-info") };
}

async function tokenScenario(browser) {
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#token-dialog[open]", { timeout: 10000 });
  const asked = await text(page, "#token-why");
  await page.click("#token-cancel");
  await page.waitForSelector("#access[data-state=read-only]", { timeout: 5000 });
  const none = await holdKey(page, "w", 1000);
  report("without", { asked, access: await text(page, "#access"),
    banner: await text(page, "#banner"), command: await text(page, "#command"), moved: none });

  // anyone may stop the robot; releasing needs the token
  await page.keyboard.press("Space");
  await page.waitForSelector("#estop-box[data-engaged=true]", { timeout: 5000 });
  const latched = (await serverEstop(true)).engaged;
  await holdRelease(page);
  await page.waitForFunction(() => /needs the token/.test(
    document.getElementById("estop-state").textContent), null, { timeout: 5000 });
  report("estopWithout", { latched, afterHold: (await status()).estop.engaged,
    shown: await text(page, "#estop-state"), banner: await text(page, "#banner"),
    pageErrors: errors.filter((e) => e.startsWith("pageerror")) });
  const released = await fetch(new URL("/api/estop", url), { method: "POST",
    headers: { "Content-Type": "application/json", Authorization: `Bearer ${secret}` },
    body: JSON.stringify({ engaged: false }) });
  if (released.status !== 200) throw new Error(`release with the token: ${released.status}`);
  await page.waitForSelector("#estop-box[data-engaged=false]", { timeout: 5000 });

  await page.click("#token-button");
  await page.fill("#token-input", `${secret}-wrong`);
  await page.click("#token-ok");
  await page.waitForSelector("#access[data-state=refused]", { timeout: 10000 });
  const wrong = await holdKey(page, "w", 1000);
  report("wrong", { access: await text(page, "#access"), banner: await text(page, "#banner"),
    moved: wrong });

  await page.click("#token-button");
  await page.fill("#token-input", secret);
  await page.click("#token-ok");
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  const right = await holdKey(page, "w", 1000, 0.3);
  const stored = await page.evaluate(() => sessionStorage.getItem("arbiterd.token"));
  await page.keyboard.press("Space");
  await page.waitForSelector("#estop-box[data-engaged=true]", { timeout: 5000 });
  report("with", { access: await text(page, "#access"), banner: await text(page, "#banner"),
    moved: right, stored: stored === secret, estop: (await serverEstop(true)).engaged });
  report("errors", { errors });
  await context.close();
}

// The daemon is stopped after "ready" and started again after "lost" (by the pytest side).
async function reconnectScenario(browser) {
  const { page, context } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  report("ready");
  await page.waitForFunction(() => document.getElementById("conn").textContent === "disconnected",
    null, { timeout: 20000 });
  report("lost", { conn: await text(page, "#conn"), banner: await text(page, "#banner") });
  await page.waitForSelector("#conn[data-state=connected]", { timeout: 40000 });
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  const drove = await holdKey(page, "w", 1000, 0.3);
  report("back", { conn: await text(page, "#conn"), banner: await text(page, "#banner"),
    bannerHidden: await page.$eval("#banner", (e) => e.hidden), drove });
  await context.close();
}

// For `arbiterd bench --only console`: the page drives in a circle (W+A held) for --seconds.
async function holdScenario(browser) {
  const seconds = Number(option("--seconds") || 3);
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  await page.keyboard.down("w");
  await page.keyboard.down("a");
  report("driving");
  await sleep(seconds * 1000);
  await page.keyboard.up("a");
  await page.keyboard.up("w");
  report("held", { seconds, errors });
  await context.close();
}

// A robot whose driver is faulted (health 503, commands 409): the page must not look drivable.
async function faultScenario(browser) {
  const shown = async (page) => ({
    conn: await text(page, "#conn"), access: await text(page, "#access"),
    accessState: await page.$eval("#access", (e) => e.dataset.state),
    banner: await text(page, "#banner"),
    bannerKind: await page.$eval("#banner", (e) => (e.hidden ? "hidden" : e.dataset.kind)),
    health: await text(page, "#health-status"),
  });
  const faulted = async (page) => {
    await page.waitForSelector("#conn[data-state=connected]", { timeout: 15000 });
    await page.waitForSelector("#access[data-state=fault]", { timeout: 15000 });
    await page.waitForSelector("#banner[data-kind=fault]:not([hidden])", { timeout: 10000 });
    await page.waitForSelector("#components tr[data-component=control]", { timeout: 10000 });
  };
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await faulted(page);
  await page.keyboard.down("w");
  await page.waitForFunction(() => /not sent/.test(document.getElementById("command").textContent),
    null, { timeout: 5000 });
  const laptop = { ...await shown(page), command: await text(page, "#command"),
    control: await text(page, "#components tr[data-component=control]") };
  if (shots) await page.screenshot({ path: `${shots}/console-fault-laptop.png` });
  await page.keyboard.up("w");
  // a 503 from /api/health is a console message of the browser's own; page errors are ours
  report("fault", { ...laptop, pageErrors: errors.filter((e) => e.startsWith("pageerror")) });
  await context.close();

  const phone = await newPage(browser, PHONE);
  await faulted(phone.page);
  const box = await phone.page.locator("#banner").boundingBox();
  if (shots) await phone.page.screenshot({ path: `${shots}/console-fault-phone.png` });
  report("faultPhone", { ...await shown(phone.page), bannerTop: box.y,
    pageErrors: phone.errors.filter((e) => e.startsWith("pageerror")) });
  await phone.context.close();
}

// Everything beyond driving: wander, explore, the recorder and its recordings, odometry and simulation
// reset, the log tail and the health details.
async function controlsScenario(browser) {
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  const until = (what, predicate, ms = 10000) => page.waitForFunction(predicate, null,
    { timeout: ms }).catch((e) => { throw new Error(`${what}: ${e.message}`); });
  const autonomyMode = async () => (await getJson("/api/autonomy")).mode;
  const polled = async (what, fn, ms = 10000) => {
    const t0 = Date.now();
    for (;;) {
      const value = await fn();
      if (value) return value;
      if (Date.now() - t0 > ms) throw new Error(`timed out: ${what}`);
      await sleep(25);
    }
  };

  // wander on: the robot's answer is shown (a stall stop on a busy machine may end it soon)
  await until("the wander state arrived", () =>
    document.getElementById("wander-state").textContent.startsWith("off"));
  await page.click("#wander");
  await until("wander switched on", () =>
    /^wander on/.test(document.getElementById("robot-message").textContent));
  const wanderOn = await text(page, "#wander-state");

  await page.click("#record");
  await until("recording shown with its size", () =>
    /\.mcap · \d/.test(document.getElementById("record-state").textContent));
  await until("the recorder's file in Health", () => /recording arbiterd-.*\.mcap · \d/.test(
    document.querySelector("#components tr[data-component=recorder]")?.textContent || ""));
  await until("the recorder's log line in the tail", () =>
    /flight recorder: writing/.test(document.getElementById("log").textContent));
  await until("the nearest obstacle in Health", () => /nearest obstacle \d+\.\d\d m/.test(
    document.querySelector("#components tr[data-component=collision_monitor]")?.textContent || ""));
  const health = await page.$$eval("#components tr", (rows) =>
    Object.fromEntries(rows.map((r) => [r.dataset.component, r.cells[2].textContent])));
  const recordState = await text(page, "#record-state");
  if (shots) await page.screenshot({ path: `${shots}/console-controls-laptop.png`, fullPage: true });

  // off, unless the robot already switched it off itself (a stall stop does on a busy machine)
  if (await page.$eval("#wander", (e) => e.getAttribute("aria-pressed")) === "true") {
    await page.click("#wander");
  }
  await polled("wander off", async () => (await autonomyMode()) === "off");

  // explore on: the exploration's state is shown; then off again
  await page.click("#explore");
  await until("exploring switched on", () =>
    /^exploring:/.test(document.getElementById("robot-message").textContent));
  const exploreOn = await text(page, "#wander-state");
  const exploreMode = await autonomyMode();
  if (await page.$eval("#explore", (e) => e.getAttribute("aria-pressed")) === "true") {
    await page.click("#explore");
  }
  await polled("exploring off", async () => (await autonomyMode()) === "off");
  await page.click("#record");
  await until("the recording listed, finished", () => {
    const link = document.querySelector("#recordings a");
    return link && link.dataset.recording === "false";
  });
  const [download] = await Promise.all([page.waitForEvent("download"),
    page.click("#recordings a")]);
  const magic = (await readFile(await download.path())).subarray(0, 8).toString("latin1");

  await holdKey(page, "w", 600);
  const moved = (await status()).pose;
  await page.click("#odom-reset");
  const afterOdom = await polled("odometry at the origin", async () => {
    const p = (await status()).pose;
    return Math.hypot(p.x, p.y) < 0.05 ? p : null;
  });
  await holdKey(page, "w", 600);
  await page.click("#sim-reset");
  const afterSim = await polled("odometry on the ground truth", async () => {
    const s = await status();
    const t = s.ground_truth;
    return Math.hypot(s.pose.x - t.x, s.pose.y - t.y) < 0.05 && Math.hypot(t.x, t.y) < 0.05
      ? s : null;
  });
  report("controls", {
    wanderOn, exploreOn, exploreMode, recordState, health, magic, moved, afterOdom, afterSim: afterSim.pose,
    truth: afterSim.ground_truth, logLines: await page.$$eval("#log li", (l) => l.length),
    message: await text(page, "#robot-message"), errors: [...errors],
  });
  await context.close();

  const phone = await newPage(browser, PHONE);
  await waitReady(phone.page);
  await phone.page.waitForSelector("#recordings a", { timeout: 10000 });
  await phone.page.tap("#odom-reset"); // a log line: the tail shows what the robot says now
  await phone.page.waitForSelector("#log li", { timeout: 10000 });
  await phone.page.$eval("#robot-panel", (e) => e.scrollIntoView({ block: "start" }));
  await phone.page.waitForFunction(() => window.scrollY > 0, null, { timeout: 5000 });
  if (shots) await phone.page.screenshot({ path: `${shots}/console-controls-phone.png` });
  report("controlsPhone", { hint: await phone.page.isVisible("#drive-panel .hint"),
    errors: phone.errors });
  await phone.context.close();
}

// The mapping component: the map drawn under the scan, Save map (a refused name, then a good
// one), and, after the test switches the robot to localisation, a drag that sets the pose.
async function mappingScenario(browser) {
  const name = option("--map-name");
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  const until = (what, predicate, arg, ms = 20000) => page.waitForFunction(predicate, arg,
    { timeout: ms }).catch((e) => { throw new Error(`${what}: ${e.message}`); });
  const mapping = async () => (await getJson("/api/health")).components.mapping;

  await holdKey(page, "w", 800); // the robot maps as it drives
  await until("a map with occupied cells drawn in the map frame", () => {
    const view = document.getElementById("view");
    return Number(view.dataset.mapOccupied) > 0 &&
      / · map frame/.test(document.getElementById("view-info").textContent);
  });
  // the next frame has the map in it: count the canvas's pixels of the occupied colour
  const drawn = await page.evaluate(() => new Promise((resolve) => {
    requestAnimationFrame(() => requestAnimationFrame(() => {
      const view = document.getElementById("view");
      const { data } = view.getContext("2d").getImageData(0, 0, view.width, view.height);
      let occupied = 0;
      let free = 0;
      for (let i = 0; i < data.length; i += 4) {
        if (data[i] === 45 && data[i + 1] === 55 && data[i + 2] === 72) occupied++;
        if (data[i] === 255 && data[i + 1] === 255 && data[i + 2] === 255) free++;
      }
      resolve({ occupied, free, version: Number(view.dataset.mapVersion),
        cells: Number(view.dataset.mapOccupied), pixels: view.width * view.height });
    }));
  }));
  if (shots) await page.screenshot({ path: `${shots}/console-map.png` });
  report("map", { ...drawn, saveShown: await page.isVisible("#map-save"),
    hintShown: await page.isVisible("#map-hint"), health: await mapping() });

  const saveAs = async (answer) => {
    page.once("dialog", (dialog) => dialog.accept(answer));
    await page.evaluate(() => { document.getElementById("map-message").textContent = ""; });
    await page.click("#map-save");
    await until("the save's answer", () =>
      document.getElementById("map-message").textContent !== "" &&
      !/…$/.test(document.getElementById("map-message").textContent));
    return { text: await text(page, "#map-message"),
      kind: await page.$eval("#map-message", (e) => e.dataset.kind) };
  };
  report("save", { refused: await saveAs("no spaces/here"), saved: await saveAs(name) });
  report("saved", {}); // the test switches the robot to localisation in the saved map now

  await until("the pose tool (localisation mode)", () =>
    document.getElementById("view").dataset.poseTool === "true", null, 30000);
  let before = await mapping(); // a revolution matched in the loaded map: its pose
  for (const t0 = Date.now(); !(before.mode === "localize" && before.pose); before = await mapping()) {
    if (Date.now() - t0 > 10000) throw new Error("timed out: a pose in the loaded map");
    await sleep(50);
  }
  const [x, y, deg] = before.pose;
  const target = { x: x + 0.2, y: y - 0.1, theta: ((deg + 15) * Math.PI) / 180 };
  const [a, b, c, d, e, f] = (await page.$eval("#view", (v) => v.dataset.transform))
    .split(",").map(Number);
  const box = await page.locator("#view").boundingBox();
  const dpr = await page.evaluate(() => window.devicePixelRatio || 1);
  const screen = (p) => ({ x: box.x + (a * p.x + c * p.y + e) / dpr,
    y: box.y + (b * p.x + d * p.y + f) / dpr });
  const from = screen(target);
  const to = screen({ x: target.x + Math.cos(target.theta), y: target.y + Math.sin(target.theta) });
  const request = page.waitForRequest((r) => r.url().endsWith("/api/pose") &&
    r.method() === "POST", { timeout: 10000 });
  await page.mouse.move(from.x, from.y);
  await page.mouse.down();
  await page.mouse.move(to.x, to.y, { steps: 8 });
  await page.mouse.up();
  const sent = (await request).postDataJSON();
  await until("the pose's answer", () =>
    /^pose set to/.test(document.getElementById("map-message").textContent));
  report("pose", { target, sent, before, message: await text(page, "#map-message"),
    hintShown: await page.isVisible("#map-hint"), errors: [...errors] });
  await context.close();
}

// The navigation component: the figure-eight started and cancelled from its buttons; then the
// "go to" tool, a tap on the view at the goal the test names (odometry frame), the plan drawn,
// the state line until the robot is there.
async function navigateScenario(browser) {
  const [gx, gy] = option("--goal").split(",").map(Number);
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await waitReady(page);
  await page.waitForSelector("#access[data-state=drive]", { timeout: 10000 });
  await page.waitForSelector("#goal-tool", { state: "visible", timeout: 10000 });
  const until = (what, predicate, arg, ms = 20000) => page.waitForFunction(predicate, arg,
    { timeout: ms }).catch(async (e) => {
      throw new Error(`${what}: ${e.message}; the state line: ${await text(page, "#nav-state")}`);
    });
  const navState = (name) => until(name, (n) =>
    document.getElementById("nav-state").dataset.state === n, name);

  await page.click("#figure-eight");
  await navState("following");
  await until("the figure-eight's plan drawn", () =>
    Number(document.getElementById("view").dataset.planPoints) > 100); // /plan comes by rosbridge
  const figurePlan = await page.$eval("#view", (v) => Number(v.dataset.planPoints));
  await page.click("#nav-cancel");
  await navState("canceled");
  report("figure", { planPoints: figurePlan, state: await text(page, "#nav-state"),
    cancelShown: await page.isVisible("#nav-cancel") });

  await page.click("#zoom-out"); // the goal and the robot in view
  await page.click("#goal-tool");
  const pressed = await page.$eval("#goal-tool", (b) => b.getAttribute("aria-pressed"));
  await until("the goal tool on", () => document.getElementById("view").dataset.goalTool === "true");
  const [a, b, c, d, e, f] = (await page.$eval("#view", (v) => v.dataset.transform))
    .split(",").map(Number);
  const box = await page.locator("#view").boundingBox();
  const dpr = await page.evaluate(() => window.devicePixelRatio || 1);
  const at = { x: box.x + (a * gx + c * gy + e) / dpr, y: box.y + (b * gx + d * gy + f) / dpr };
  const request = page.waitForRequest((r) => r.url().endsWith("/api/goal") &&
    r.method() === "POST", { timeout: 10000 });
  await page.mouse.click(at.x, at.y);
  const sent = (await request).postDataJSON();
  await until("the plan drawn", () => Number(document.getElementById("view").dataset.planPoints) > 1);
  const planPoints = await page.$eval("#view", (v) => Number(v.dataset.planPoints));
  const following = await text(page, "#nav-state");
  const cancelShown = await page.isVisible("#nav-cancel");
  if (shots) await page.screenshot({ path: `${shots}/console-navigate.png` });
  await until("the goal reached", () =>
    document.getElementById("nav-state").dataset.state === "succeeded", null, 60000);
  report("goal", { pressed, sent, planPoints, following, cancelShown, truth: await truth(),
    reached: await text(page, "#nav-state"), toolAfter: await page.$eval("#view",
      (v) => v.dataset.goalTool), planAfter: await page.$eval("#view", (v) => v.dataset.planPoints),
    errors: [...errors] });
  if (option("--fetch")) await fetchSteps(page, until, option("--fetch").split(",").map(Number));
  await context.close();
}

// Where the view draws the point (x, y) of its frame, in page coordinates.
async function pageXY(page, x, y) {
  const [a, b, c, d, e, f] = (await page.$eval("#view", (v) => v.dataset.transform))
    .split(",").map(Number);
  const box = await page.locator("#view").boundingBox();
  const dpr = await page.evaluate(() => window.devicePixelRatio || 1);
  return { x: box.x + (a * x + c * y + e) / dpr, y: box.y + (b * x + d * y + f) / dpr };
}

// The fetch tool: two taps (the object, the drop point) send POST /api/fetch; the state line
// follows; cancel fetch ends it.
async function fetchSteps(page, until, [ox, oy, dx, dy]) {
  await page.waitForSelector("#fetch-tool", { state: "visible", timeout: 10000 });
  await page.click("#fetch-tool");
  const pressed = await page.$eval("#fetch-tool", (b) => b.getAttribute("aria-pressed"));
  const object = await pageXY(page, ox, oy);
  await page.mouse.click(object.x, object.y);
  const prompt = await text(page, "#fetch-state");
  const request = page.waitForRequest((r) => r.url().endsWith("/api/fetch") &&
    r.method() === "POST", { timeout: 10000 });
  const drop = await pageXY(page, dx, dy);
  await page.mouse.click(drop.x, drop.y);
  const sent = (await request).postDataJSON();
  await until("the fetch under way", () => document.getElementById("fetch-state").dataset.state
    === "NAV_TO_OBJECT");
  const running = await text(page, "#fetch-state");
  const cancelShown = await page.isVisible("#fetch-cancel");
  await page.click("#fetch-cancel");
  await until("the fetch canceled", () =>
    /^fetch canceled/.test(document.getElementById("fetch-state").textContent));
  report("fetch", { pressed, prompt, sent, running, cancelShown,
    ended: await text(page, "#fetch-state"), api: await getJson("/api/fetch"),
    toolAfter: await page.$eval("#fetch-tool", (b) => b.getAttribute("aria-pressed")) });
}

// The arm panel: a pose button moves the arm there (the side view follows), the gripper opens,
// and on a phone the panel fits the screen.
async function armScenario(browser) {
  const { page, context, errors } = await newPage(browser, { viewport: LAPTOP });
  await page.waitForSelector("#arm-panel:not([hidden]) #arm-poses button", { timeout: 15000 });
  const poses = await page.$$eval("#arm-poses button", (b) => b.map((e) => e.textContent));
  const before = await page.$eval("#arm-view .links", (e) => e.getAttribute("points"));
  await page.click('#arm-poses button[data-pose="pregrasp"]');
  await page.waitForSelector('#arm-poses button[data-pose="pregrasp"][aria-pressed="true"]',
    { timeout: 15000 });
  const at = { points: await page.$eval("#arm-view .links", (e) => e.getAttribute("points")),
    state: await text(page, "#arm-state"), api: await getJson("/api/arm") };
  await page.click("#gripper-close");
  await page.waitForFunction(() => / gripper 0 mm/.test(
    document.getElementById("arm-state").textContent), null, { timeout: 15000 });
  const closed = (await getJson("/api/arm")).gripper_m;
  if (shots) await page.screenshot({ path: `${shots}/console-arm-laptop.png` });
  report("arm", { poses, before, at, closed, message: await text(page, "#arm-message"),
    errors: [...errors] });
  await context.close();
  const phone = await newPage(browser, PHONE);
  await phone.page.waitForSelector("#arm-panel:not([hidden]) #arm-poses button", { timeout: 15000 });
  const box = await phone.page.locator("#arm-panel").boundingBox();
  if (shots) {
    await phone.page.locator("#arm-panel").scrollIntoViewIfNeeded();
    await phone.page.screenshot({ path: `${shots}/console-arm-phone.png` });
  }
  report("armPhone", { width: box.width, errors: phone.errors });
  await phone.context.close();
}

const browser = await chromium.launch({ executablePath: CHROMIUM, args: ARGS });
try {
  if (scenario === "drive") await driveScenario(browser);
  else if (scenario === "token") await tokenScenario(browser);
  else if (scenario === "hold") await holdScenario(browser);
  else if (scenario === "reconnect") await reconnectScenario(browser);
  else if (scenario === "fault") await faultScenario(browser);
  else if (scenario === "controls") await controlsScenario(browser);
  else if (scenario === "mapping") await mappingScenario(browser);
  else if (scenario === "navigate") await navigateScenario(browser);
  else if (scenario === "arm") await armScenario(browser);
  else throw new Error(`unknown scenario ${scenario}`);
  report("done", { ok: true });
} catch (error) {
  report("fail", { error: String(error?.stack ?? error) });
  process.exitCode = 1;
} finally {
  await browser.close();
}
