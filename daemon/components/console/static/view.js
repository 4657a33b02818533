// Top-down view in the odometry frame, centred on the robot: /scan on a metres grid, the
// footprint, the odometry trail and, on the simulated robot, the ground truth beside it (in the
// odometry frame too: the gap is the drift). Until
// the user zooms, the view fits the latest scan (the walls of a room or of the simulated arena).
// When the robot maps (map.js), the view is in the map frame: the occupancy grid under the scan,
// and the odometry-frame scan, trail and robot moved by map -> odom to the robot's map pose.

const TRAIL_MAX = 2000;
const SPANS = [2, 4, 8, 12, 16, 24, 32, 48]; // zoom steps: metres across the shorter side
const DEFAULT_SPAN = 8;
const FIT_MARGIN = 1.08; // the farthest point this far inside the edge
const FIT_STEP = 2; // a fitted span is a whole number of FIT_STEP metres

export function poseOf(msg) {
  const p = msg.pose.pose.position;
  const q = msg.pose.pose.orientation;
  const theta = Math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z));
  return { x: p.x, y: p.y, theta };
}

// a ∘ b: the pose b (in a's child frame) in a's parent frame
export function compose(a, b) {
  const c = Math.cos(a.theta);
  const s = Math.sin(a.theta);
  return { x: a.x + c * b.x - s * b.y, y: a.y + s * b.x + c * b.y, theta: a.theta + b.theta };
}

function cssColor(name) {
  return getComputedStyle(document.documentElement).getPropertyValue(name).trim() || "#888";
}

export class View {
  constructor(canvas, info) {
    this.canvas = canvas;
    this.info = info;
    this.ctx = canvas.getContext("2d");
    this.span = DEFAULT_SPAN;
    this.fit = true; // follow the scan's extent until the user zooms
    this.onFitChange = () => {};
    this.headingUp = false;
    this.pose = { x: 0, y: 0, theta: 0 };
    this.truth = null;
    this.trail = [];
    this.truthTrail = [];
    this.scan = null; // {xy: Float32Array in the laser frame, pose: the odometry pose then}
    this.footprint = 0.2;
    this.pending = false;
    this.map = null; // the occupancy grid (map.js mapImage), drawn in the map frame
    this.mapToOdom = null; // where the odometry frame is in the map; null: no map frame
    this.poseTool = false; // dragging sets the pose in the map (localisation mode)
    this.goalTool = false; // a tap (and drag for a heading) sends a navigation goal
    this.drag = null; // {start, end, tool} in the view's frame while dragging
    this.onPoseDrag = () => {};
    this.onGoalDrag = () => {};
    this.plan = null; // the navigation plan ([[x, y], ...]) and goal, in the view's frame
    this.goal = null;
    this.worldOf = null; // device pixel -> view-frame metres, from the last draw
    new ResizeObserver(() => this.request()).observe(canvas);
    canvas.addEventListener("wheel", (event) => {
      event.preventDefault();
      this.zoom(event.deltaY > 0 ? 1 : -1);
    }, { passive: false });
    this.listenForPoseDrag();
  }

  // -- the map frame ----------------------------------------------------------------------------

  setMap(map) {
    this.map = map;
    this.canvas.dataset.mapVersion = String(map.version); // what is drawn, for tests
    this.canvas.dataset.mapOccupied = String(map.occupied);
    this.request();
  }

  setMapToOdom(transform) {
    this.mapToOdom = transform;
    this.request();
  }

  legendMap(on) {
    const key = document.querySelector(".key.map");
    if (key) key.hidden = !on;
  }

  // The robot's pose in the view's frame: the map's when there is one.
  shown(pose) { return this.mapToOdom ? compose(this.mapToOdom, pose) : pose; }

  setPoseTool(on) {
    if (on === this.poseTool) return;
    this.poseTool = on;
    this.canvas.dataset.poseTool = String(on);
    this.toolChanged();
  }

  setGoalTool(on) {
    if (on === this.goalTool) return;
    this.goalTool = on;
    this.canvas.dataset.goalTool = String(on);
    this.toolChanged();
  }

  // The tool a press on the view uses: the goal tool while it is on, else the pose tool.
  tool() { return this.goalTool ? "goal" : this.poseTool ? "pose" : null; }

  toolChanged() {
    const on = this.tool() !== null;
    this.drag = null;
    this.canvas.style.touchAction = on ? "none" : "";
    this.canvas.style.cursor = on ? "crosshair" : "";
    this.request();
  }

  // The navigation plan and goal to draw (null: none), in the view's frame.
  setPlan(points, goal) {
    this.plan = points && points.length ? points : null;
    this.goal = goal || null;
    this.canvas.dataset.planPoints = String(this.plan ? this.plan.length : 0); // for tests
    this.request();
  }

  // Press where the robot is (or should go), drag towards where it faces, release:
  // onPoseDrag({x, y, theta}) or onGoalDrag({x, y, theta}) (theta null: a tap, any heading).
  listenForPoseDrag() {
    const { canvas } = this;
    const at = (event) => {
      const dpr = window.devicePixelRatio || 1;
      const rect = canvas.getBoundingClientRect();
      const p = this.worldOf.transformPoint(new DOMPoint((event.clientX - rect.left) * dpr,
        (event.clientY - rect.top) * dpr));
      return { x: p.x, y: p.y };
    };
    canvas.addEventListener("pointerdown", (event) => {
      const tool = this.tool();
      if (!tool || !this.worldOf || event.button !== 0) return;
      event.preventDefault();
      canvas.setPointerCapture(event.pointerId);
      const start = at(event);
      this.drag = { start, end: start, scale: this.worldOf.a, tool };
      this.request();
    });
    canvas.addEventListener("pointermove", (event) => {
      if (!this.drag) return;
      this.drag.end = at(event);
      this.request();
    });
    const finish = (event, send) => {
      const { drag } = this;
      if (!drag) return;
      this.drag = null;
      this.request();
      if (!send) return;
      const end = at(event);
      const dx = end.x - drag.start.x;
      const dy = end.y - drag.start.y;
      const still = Math.hypot(dx, dy) < 8 * Math.abs(drag.scale);
      if (drag.tool === "goal") { // a tap: any heading at the goal
        this.onGoalDrag({ x: drag.start.x, y: drag.start.y, theta: still ? null : Math.atan2(dy, dx) });
        return;
      }
      // a click without a drag keeps the heading the robot has now
      const theta = still ? this.shown(this.pose).theta : Math.atan2(dy, dx);
      this.onPoseDrag({ x: drag.start.x, y: drag.start.y,
        theta: Math.atan2(Math.sin(theta), Math.cos(theta)) });
    };
    canvas.addEventListener("pointerup", (event) => finish(event, true));
    canvas.addEventListener("pointercancel", (event) => finish(event, false));
  }

  zoom(step) {
    const next = step > 0 ? SPANS.find((s) => s > this.span) ?? SPANS[SPANS.length - 1]
      : [...SPANS].reverse().find((s) => s < this.span) ?? SPANS[0];
    this.span = next;
    this.setFit(false);
    this.request();
  }

  setFit(on) {
    this.fit = on;
    this.onFitChange(on);
    if (on) this.fitScan();
    this.request();
  }

  // The span that shows every point of the latest scan around the robot; it grows at once
  // and shrinks only by a whole step (no flicker as the robot drives).
  fitScan() {
    if (!this.scan || !this.fit) return;
    const { canvas } = this;
    const w = canvas.clientWidth;
    const h = canvas.clientHeight;
    if (!w || !h) return;
    const { xy } = this.scan;
    const pose = this.shown(this.scan.pose);
    const here = this.shown(this.pose);
    const c = Math.cos(pose.theta);
    const s = Math.sin(pose.theta);
    let ex = 0;
    let ey = 0;
    for (let i = 0; i < xy.length; i += 2) {
      const dx = c * xy[i] - s * xy[i + 1] + pose.x - here.x;
      const dy = s * xy[i] + c * xy[i + 1] + pose.y - here.y;
      if (this.headingUp) {
        ex = ey = Math.max(ex, Math.hypot(dx, dy));
      } else {
        ex = Math.max(ex, Math.abs(dx));
        ey = Math.max(ey, Math.abs(dy));
      }
    }
    if (!ex && !ey) return;
    const scale = Math.min(w / (2 * ex * FIT_MARGIN), h / (2 * ey * FIT_MARGIN)); // px per m
    const needed = Math.max(SPANS[0], Math.ceil(Math.min(w, h) / scale / FIT_STEP) * FIT_STEP);
    if (needed > this.span || needed <= this.span - FIT_STEP) this.span = needed;
  }

  clearTrail() { this.trail = []; this.truthTrail = []; this.request(); }

  setOdom(pose) {
    this.pose = pose;
    addToTrail(this.trail, pose);
    this.request();
  }

  setTruth(pose) {
    this.truth = pose;
    addToTrail(this.truthTrail, pose);
    this.request();
  }

  setScan(msg) {
    const xy = new Float32Array(msg.ranges.length * 2);
    let n = 0;
    msg.ranges.forEach((r, i) => {
      if (r === null || !(r >= msg.range_min && r <= msg.range_max)) return;
      const a = msg.angle_min + i * msg.angle_increment;
      xy[n++] = r * Math.cos(a);
      xy[n++] = r * Math.sin(a);
    });
    this.scan = { xy: xy.subarray(0, n), pose: this.pose, received: performance.now() };
    this.fitScan();
    this.request();
  }

  request() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => { this.pending = false; this.draw(); });
  }

  draw() {
    const { canvas, ctx } = this;
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * dpr);
    const h = Math.round(canvas.clientHeight * dpr);
    if (!w || !h) return;
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    const { span } = this;
    const scale = Math.min(w, h) / span; // px per metre
    canvas.dataset.halfWidthM = (w / scale / 2).toFixed(3); // what is in view, for tests
    canvas.dataset.halfHeightM = (h / scale / 2).toFixed(3);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, w, h);
    const here = this.shown(this.pose);
    ctx.translate(w / 2, h / 2);
    ctx.scale(scale, -scale);
    if (this.headingUp) ctx.rotate(Math.PI / 2 - here.theta);
    ctx.translate(-here.x, -here.y);
    const m = ctx.getTransform(); // view-frame metres -> device pixels, for tests too
    canvas.dataset.transform = [m.a, m.b, m.c, m.d, m.e, m.f].map((v) => v.toFixed(4)).join(",");
    this.worldOf = m.inverse();
    const px = 1 / scale;
    const reach = Math.hypot(w, h) / 2 / scale + 1;
    this.drawMap();
    this.drawGrid(here, reach, px, dpr);
    ctx.save();
    if (this.mapToOdom) { // the trails (both in the odometry frame), where the map puts it
      ctx.translate(this.mapToOdom.x, this.mapToOdom.y);
      ctx.rotate(this.mapToOdom.theta);
    }
    this.drawTrail(this.truthTrail, cssColor("--truth"), 1.5 * dpr * px);
    this.drawTrail(this.trail, cssColor("--odom"), 2 * dpr * px);
    ctx.restore();
    this.drawPlan(cssColor("--accent"), dpr * px);
    this.drawScan(cssColor("--scan"), 3 * dpr * px);
    if (this.truth) this.drawRobot(this.shown(this.truth), cssColor("--truth"), false, dpr * px);
    this.drawRobot(here, cssColor("--odom"), true, dpr * px);
    if (this.drag) this.drawDrag(dpr * px);
    const frame = this.mapToOdom ? " · map frame" : "";
    this.info.textContent = `grid 1 m · ${span} m across${this.fit ? " (fit)" : ""}${frame}` +
      (this.scan ? ` · scan ${this.scan.xy.length / 2} points` : " · no scan yet");
  }

  // The occupancy grid, one cell a resolution-sized square, y up from the origin.
  drawMap() {
    if (!this.map) return;
    const { ctx, map } = this;
    ctx.save();
    ctx.imageSmoothingEnabled = false;
    ctx.translate(map.origin.x, map.origin.y);
    ctx.scale(map.resolution, map.resolution);
    ctx.drawImage(map.canvas, 0, 0);
    ctx.restore();
  }

  // The navigation plan, dashed, and a ring at its goal.
  drawPlan(color, px) {
    const { ctx, plan, goal } = this;
    if (!plan && !goal) return;
    ctx.save();
    ctx.strokeStyle = color;
    ctx.lineWidth = 2 * px;
    if (plan) {
      ctx.setLineDash([6 * px, 4 * px]);
      ctx.beginPath();
      plan.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
      ctx.stroke();
      ctx.setLineDash([]);
    }
    if (goal) {
      ctx.beginPath();
      ctx.arc(goal.x, goal.y, 8 * px, 0, 2 * Math.PI);
      ctx.stroke();
    }
    ctx.restore();
  }

  // The pose being dragged: a dot where it was pressed, an arrow towards the heading.
  drawDrag(px) {
    const { ctx } = this;
    const { start, end } = this.drag;
    const color = cssColor("--accent");
    ctx.strokeStyle = color;
    ctx.fillStyle = color;
    ctx.lineWidth = 3 * px;
    ctx.beginPath();
    ctx.arc(start.x, start.y, 6 * px, 0, 2 * Math.PI);
    ctx.fill();
    ctx.beginPath();
    ctx.moveTo(start.x, start.y);
    ctx.lineTo(end.x, end.y);
    ctx.stroke();
  }

  drawGrid(here, reach, px, dpr) {
    const { ctx } = this;
    const { x: cx, y: cy } = here;
    ctx.lineWidth = px * dpr;
    ctx.strokeStyle = cssColor("--line");
    ctx.beginPath();
    for (let x = Math.floor(cx - reach); x <= cx + reach; x++) {
      ctx.moveTo(x, cy - reach); ctx.lineTo(x, cy + reach);
    }
    for (let y = Math.floor(cy - reach); y <= cy + reach; y++) {
      ctx.moveTo(cx - reach, y); ctx.lineTo(cx + reach, y);
    }
    ctx.stroke();
    ctx.strokeStyle = cssColor("--muted");
    ctx.beginPath(); // the frame's origin and axes (odometry's, or the map's)
    ctx.moveTo(0, 0); ctx.lineTo(1, 0); ctx.moveTo(0, 0); ctx.lineTo(0, 1);
    ctx.stroke();
    this.drawLabels(here, reach, dpr);
  }

  // Grid values (m) along the bottom and left edges; none when the view turns with the robot.
  drawLabels(here, reach, dpr) {
    if (this.headingUp) return;
    const { ctx, canvas } = this;
    const step = Math.max(1, Math.round(this.span / 4));
    const m = ctx.getTransform();
    const { x: cx, y: cy } = here;
    ctx.save();
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = cssColor("--muted");
    ctx.font = `${11 * dpr}px system-ui, sans-serif`;
    for (let x = Math.ceil((cx - reach) / step) * step; x <= cx + reach; x += step) {
      ctx.fillText(`${x} m`, m.transformPoint(new DOMPoint(x, 0)).x + 3 * dpr, canvas.height - 4 * dpr);
    }
    for (let y = Math.ceil((cy - reach) / step) * step; y <= cy + reach; y += step) {
      const sy = m.transformPoint(new DOMPoint(0, y)).y;
      if (sy < canvas.height - 18 * dpr) ctx.fillText(`${y} m`, 3 * dpr, sy - 3 * dpr);
    }
    ctx.restore();
  }

  drawTrail(trail, color, width) {
    if (trail.length < 2) return;
    const { ctx } = this;
    ctx.strokeStyle = color;
    ctx.lineWidth = width;
    ctx.beginPath();
    ctx.moveTo(trail[0].x, trail[0].y);
    for (const p of trail) ctx.lineTo(p.x, p.y);
    ctx.stroke();
  }

  drawScan(color, size) {
    if (!this.scan) return;
    const { ctx } = this;
    const { xy } = this.scan;
    const pose = this.shown(this.scan.pose);
    const c = Math.cos(pose.theta);
    const s = Math.sin(pose.theta);
    ctx.fillStyle = color;
    for (let i = 0; i < xy.length; i += 2) {
      const x = pose.x + c * xy[i] - s * xy[i + 1];
      const y = pose.y + s * xy[i] + c * xy[i + 1];
      ctx.fillRect(x - size / 2, y - size / 2, size, size);
    }
  }

  drawRobot(pose, color, filled, px) {
    const { ctx } = this;
    const r = this.footprint;
    ctx.save();
    ctx.translate(pose.x, pose.y);
    ctx.rotate(pose.theta);
    ctx.lineWidth = 2 * px;
    ctx.strokeStyle = color;
    ctx.fillStyle = color;
    ctx.globalAlpha = filled ? 0.35 : 1;
    ctx.beginPath();
    ctx.arc(0, 0, r, 0, 2 * Math.PI);
    if (filled) ctx.fill(); else ctx.stroke();
    ctx.globalAlpha = 1;
    ctx.beginPath(); // heading
    ctx.moveTo(0, 0);
    ctx.lineTo(r * 1.4, 0);
    ctx.stroke();
    ctx.restore();
  }
}

function addToTrail(trail, pose) {
  const last = trail[trail.length - 1];
  if (last && Math.hypot(pose.x - last.x, pose.y - last.y) < 0.02) return;
  trail.push({ x: pose.x, y: pose.y });
  if (trail.length > TRAIL_MAX) trail.splice(0, trail.length - TRAIL_MAX);
}
