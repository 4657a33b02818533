// The mapping component in the console: the occupancy grid from GET /api/map drawn under the
// scan, the map -> odom transform from /tf that places the robot at its map pose, the Save map
// button and, in localisation mode, dragging on the view to set the pose (POST /api/pose).

const MIN_FETCH_MS = 2000; // GET /api/map at most this often, and only when map_version moved
const TF = "tf2_msgs/msg/TFMessage";
// unknown: a light grey veil, free: white, occupied: dark (the same in the dark theme: a map)
const UNKNOWN = [120, 130, 145, 50];
const FREE = [255, 255, 255, 255];
const OCCUPIED = [45, 55, 72, 255];
const OCCUPIED_AT = 50; // 0-100: a cell this sure or more is drawn occupied

// The grid of GET /api/map as an image, one pixel per cell, row 0 at the origin (y up).
export function mapImage(body) {
  const cells = Uint8Array.from(atob(body.data), (c) => c.charCodeAt(0));
  const { width, height } = body;
  const image = new ImageData(width, height);
  let occupied = 0;
  for (let i = 0; i < width * height; i++) {
    const v = cells[i] > 127 ? cells[i] - 256 : cells[i]; // int8
    if (v < 0) { image.data.set(UNKNOWN, 4 * i); continue; }
    const colour = v >= OCCUPIED_AT ? OCCUPIED : FREE;
    if (v >= OCCUPIED_AT) occupied += 1;
    image.data.set(colour, 4 * i);
  }
  const canvas = document.createElement("canvas");
  canvas.width = width;
  canvas.height = height;
  canvas.getContext("2d").putImageData(image, 0, 0);
  return { canvas, occupied, resolution: body.resolution, width, height,
    origin: { x: body.origin[0], y: body.origin[1] }, version: body.version,
    frame: body.frame_id || "map" };
}

export class MapPanel {
  // el: {save, message, hint}; onRefused(what) when the token is missing or wrong
  constructor(el, api, bridge, view, { onRefused }) {
    Object.assign(this, { el, api, bridge, view, onRefused });
    this.mapping = null; // health's components.mapping
    this.key = null; // the map (name, version, publications) drawn
    this.lastFetch = -Infinity;
    this.fetching = false;
    this.frame = "map";
    el.save.addEventListener("click", () => this.save());
    view.onPoseDrag = (pose) => this.setPose(pose);
  }

  // Every health answer: follows the map's version and the mode.
  health(mapping) {
    const first = !this.mapping && mapping;
    this.mapping = mapping || null;
    this.el.save.hidden = !mapping;
    const localize = mapping?.mode === "localize" && mapping.running;
    this.view.setPoseTool(Boolean(localize));
    this.el.hint.hidden = !localize;
    if (!mapping) return;
    if (first) {
      this.bridge.subscribe("/tf", TF, (m) => this.transforms(m));
      this.view.legendMap(true);
    }
    // a new version, or a map loaded (versions start again from 0 in a loaded map)
    const key = `${mapping.map}|${mapping.map_version}|${mapping.maps_published}`;
    const now = performance.now();
    if (key !== this.key && mapping.maps_published > 0 && !this.fetching &&
        now - this.lastFetch >= MIN_FETCH_MS) {
      this.lastFetch = now;
      this.fetch(key);
    }
  }

  async fetch(key) {
    this.fetching = true;
    try {
      const answer = await this.api.get("/api/map");
      if (answer.status === 200 && answer.body?.data !== undefined) {
        this.key = key;
        const map = mapImage(answer.body);
        this.frame = map.frame;
        this.view.setMap(map);
      }
    } catch {
      // the robot did not answer: the next health answer tries again
    } finally {
      this.fetching = false;
    }
  }

  // map -> odom from /tf: the odometry-frame scan, trail and robot drawn in the map frame
  transforms(msg) {
    for (const t of msg.transforms || []) {
      if (t.header.frame_id !== this.frame) continue;
      const q = t.transform.rotation;
      this.view.setMapToOdom({ x: t.transform.translation.x, y: t.transform.translation.y,
        theta: Math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z)) });
    }
  }

  show(text, kind = "info") {
    this.el.message.textContent = text;
    this.el.message.dataset.kind = kind;
  }

  async save() {
    const name = prompt("Save the map as (letters, digits, - and _):", "map");
    if (name === null) return;
    await this.post("/api/map/save", { name: name.trim() }, "to save the map", (body) =>
      `map saved: ${body.yaml} + ${body.image} (${body.width} × ${body.height} cells)`);
  }

  async setPose(pose) {
    const deg = (pose.theta * 180) / Math.PI;
    this.show(`setting the pose to ${pose.x.toFixed(2)} m, ${pose.y.toFixed(2)} m, ${deg.toFixed(0)}°…`);
    await this.post("/api/pose", pose, "to set the pose", () =>
      `pose set to ${pose.x.toFixed(2)} m, ${pose.y.toFixed(2)} m, ${deg.toFixed(0)}°`);
  }

  async post(path, body, what, done) {
    let answer;
    try {
      answer = await this.api.post(path, body);
    } catch {
      this.show("the robot does not answer", "error");
      return;
    }
    if (answer.status === 200) {
      this.show(done(answer.body));
    } else {
      if (answer.status === 401) this.onRefused(what);
      this.show(answer.body?.error || `HTTP ${answer.status}`, "error");
    }
  }
}
