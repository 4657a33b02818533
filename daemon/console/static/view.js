// Top-down view in the odometry frame, centred on the robot: /scan on a metres grid, the
// footprint, the odometry trail and, on the simulated robot, the ground truth beside it. Until
// the user zooms, the view fits the latest scan (the walls of a room or of the simulated arena).

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
    new ResizeObserver(() => this.request()).observe(canvas);
    canvas.addEventListener("wheel", (event) => {
      event.preventDefault();
      this.zoom(event.deltaY > 0 ? 1 : -1);
    }, { passive: false });
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
    const { xy, pose } = this.scan;
    const c = Math.cos(pose.theta);
    const s = Math.sin(pose.theta);
    let ex = 0;
    let ey = 0;
    for (let i = 0; i < xy.length; i += 2) {
      const dx = c * xy[i] - s * xy[i + 1] + pose.x - this.pose.x;
      const dy = s * xy[i] + c * xy[i + 1] + pose.y - this.pose.y;
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
    ctx.translate(w / 2, h / 2);
    ctx.scale(scale, -scale);
    if (this.headingUp) ctx.rotate(Math.PI / 2 - this.pose.theta);
    ctx.translate(-this.pose.x, -this.pose.y);
    const px = 1 / scale;
    const reach = Math.hypot(w, h) / 2 / scale + 1;
    this.drawGrid(reach, px, dpr);
    this.drawTrail(this.truthTrail, cssColor("--truth"), 1.5 * dpr * px);
    this.drawTrail(this.trail, cssColor("--odom"), 2 * dpr * px);
    this.drawScan(cssColor("--scan"), 3 * dpr * px);
    if (this.truth) this.drawRobot(this.truth, cssColor("--truth"), false, dpr * px);
    this.drawRobot(this.pose, cssColor("--odom"), true, dpr * px);
    this.info.textContent = `grid 1 m · ${span} m across${this.fit ? " (fit)" : ""}` +
      (this.scan ? ` · scan ${this.scan.xy.length / 2} points` : " · no scan yet");
  }

  drawGrid(reach, px, dpr) {
    const { ctx } = this;
    const { x: cx, y: cy } = this.pose;
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
    ctx.beginPath(); // the odometry origin's axes
    ctx.moveTo(0, 0); ctx.lineTo(1, 0); ctx.moveTo(0, 0); ctx.lineTo(0, 1);
    ctx.stroke();
    this.drawLabels(reach, dpr);
  }

  // Grid values (m) along the bottom and left edges; none when the view turns with the robot.
  drawLabels(reach, dpr) {
    if (this.headingUp) return;
    const { ctx, canvas } = this;
    const step = Math.max(1, Math.round(this.span / 4));
    const m = ctx.getTransform();
    const { x: cx, y: cy } = this.pose;
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
    const { xy, pose } = this.scan;
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
