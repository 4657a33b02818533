// Latency HUD: command -> execution from /latency_reports (p50/p99, sparkline), the round trip
// of this page's own commands, the link round trip, and the daemon's /api/latency figures.

const WINDOW = 200;

export function percentile(values, pct) {
  if (!values.length) return NaN;
  const sorted = [...values].sort((a, b) => a - b);
  return sorted[Math.min(sorted.length - 1, Math.round((pct / 100) * (sorted.length - 1)))];
}

const ms = (v) => (Number.isFinite(v) ? `${v < 10 ? v.toFixed(2) : v.toFixed(1)} ms` : "–");

export class Hud {
  constructor(el) {
    this.el = el; // {p50, p99, rtt, link, api, spark}
    this.exec = [];
    this.roundTrips = [];
    this.sent = new Map(); // id -> performance.now() at send
  }

  commandSent(id) {
    this.sent.set(id, performance.now());
    if (this.sent.size > WINDOW) this.sent.delete(this.sent.keys().next().value);
  }

  report(data) {
    const r = JSON.parse(data);
    if (Number.isFinite(r.exec_ms)) push(this.exec, r.exec_ms);
    const t0 = this.sent.get(r.id);
    if (t0 !== undefined) {
      this.sent.delete(r.id);
      push(this.roundTrips, performance.now() - t0);
    }
    this.render();
  }

  link(roundTripMs) { this.el.link.textContent = ms(roundTripMs); }

  api(stats) {
    const exec = stats.receipt_to_exec_ms || {};
    const tick = (stats.tick || {}).lateness_ms || {};
    this.el.api.textContent = `daemon: ${stats.commands ?? 0} commands, receipt → exec ` +
      `p50 ${ms(exec.p50)} p99 ${ms(exec.p99)} · tick lateness p99 ${ms(tick.p99)}`;
  }

  render() {
    this.el.p50.textContent = ms(percentile(this.exec, 50));
    this.el.p99.textContent = ms(percentile(this.exec, 99));
    this.el.rtt.textContent = ms(percentile(this.roundTrips, 50));
    sparkline(this.el.spark, this.exec.slice(-100));
  }
}

function push(list, value) {
  list.push(value);
  if (list.length > WINDOW) list.shift();
}

function sparkline(canvas, values) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.round(canvas.clientWidth * dpr);
  const h = Math.round(canvas.clientHeight * dpr);
  if (!w || !h) return;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, w, h);
  if (values.length < 2) return;
  const top = Math.max(...values) || 1;
  ctx.strokeStyle = getComputedStyle(document.documentElement).getPropertyValue("--accent");
  ctx.lineWidth = 1.5 * dpr;
  ctx.beginPath();
  values.forEach((v, i) => {
    const x = (i / (values.length - 1)) * (w - 2) + 1;
    const y = h - 2 - (v / top) * (h - 4);
    if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y);
  });
  ctx.stroke();
  ctx.fillStyle = getComputedStyle(document.documentElement).getPropertyValue("--muted");
  ctx.font = `${10 * dpr}px system-ui, sans-serif`;
  ctx.fillText(`max ${ms(top)}`, 4 * dpr, 11 * dpr);
}
