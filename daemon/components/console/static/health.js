// Health panel: component states with their messages, mode, driver, uptime, motion, clamps, faults.
import { baseName, fileSize } from "./robot.js";

const DETAIL_KEYS = ["state", "model", "mode", "emulator", "scan_rate_hz", "clients", "port"];
const metres = (v) => (Number.isFinite(v) ? `${v.toFixed(2)} m` : "none in range");

// What matters about each known component when nothing is wrong with it.
const DETAILS = {
  control: (c) => [c.estop ? "e-stop engaged" : "e-stop released", `driver ${c.driver?.driver}`,
    `longest stall ${c.longest_stall_ms} ms`],
  collision_monitor: (c) => (c.enabled === false ? ["off"]
    : [`nearest obstacle ${metres(c.nearest_m)}`, `action ${c.action}`, `zone ${c.zone}`]),
  lidar: (c) => [c.state, c.model, Number.isFinite(c.scan_rate_hz) ? `${c.scan_rate_hz} Hz` : ""],
  autonomy: (c) => [`mode ${c.mode}`, `state ${c.state}`, c.reason],
  recorder: (c) => (c.recording ? [`recording ${baseName(c.file)}`, fileSize(c.file_bytes ?? 0),
    `${c.written} messages`] : ["not recording", c.dropped ? `${c.dropped} dropped` : ""]),
  rosbridge: (c) => [`${c.clients} clients`, `port ${c.port}`,
    c.dropped_messages ? `${c.dropped_messages} dropped` : ""],
  http: (c) => [`port ${c.port}`, `${c.connections} connections`],
  arm: (c) => [`servos ${c.backend}`, `${c.writes} writes`,
    c.frozen_by_estop ? "frozen by the e-stop" : ""],
  sim: (c) => [`${c.obstacles} obstacles`, `${c.collisions} collisions`, `emulator ${c.emulator}`],
};

export function uptime(seconds) {
  const s = Math.floor(seconds);
  const parts = [[Math.floor(s / 86400), "d"], [Math.floor(s / 3600) % 24, "h"],
    [Math.floor(s / 60) % 60, "min"], [s % 60, "s"]];
  const first = parts.findIndex(([v]) => v > 0);
  return parts.slice(first < 0 ? 3 : first, (first < 0 ? 3 : first) + 2)
    .map(([v, u]) => `${v} ${u}`).join(" ");
}

// The one line that says what a component is doing, or what is wrong with it.
export function componentMessage(c, name = "") {
  return c.problem || componentDetail(name, c);
}

export function componentDetail(name, c) {
  const known = DETAILS[name];
  if (known) return known(c).filter(Boolean).join(" · ");
  return DETAIL_KEYS.filter((k) => c[k] !== undefined && c[k] !== null && typeof c[k] !== "object")
    .slice(0, 3).map((k) => `${k.replace(/_/g, " ")} ${c[k]}`).join(" · ");
}

export function renderHealth(el, health) {
  el.status.textContent = health.status;
  el.status.dataset.state = health.status;
  el.summary.textContent = `${health.state} · ${health.mode} mode · driver ${health.driver} · ` +
    `v${health.version} · up ${uptime(health.uptime_s)}`;
  const rows = Object.entries(health.components).map(([name, c]) => {
    const tr = document.createElement("tr");
    tr.dataset.component = name;
    const cells = [name, c.status, componentMessage(c, name)];
    cells.forEach((text, i) => {
      const td = document.createElement("td");
      td.textContent = text;
      if (i === 1) td.className = `status-${c.status}`;
      if (i === 2) td.className = "msg";
      tr.append(td);
    });
    return tr;
  });
  el.table.replaceChildren(...rows);
}

export function renderMotion(el, status) {
  const clamps = Object.entries(status.clamps || {}).map(([k, n]) => `${k} ×${n}`).join(", ");
  const t = status.twist;
  el.textContent = `source ${status.active_source ?? "none"} (${status.reason}) · ` +
    `v ${t.linear_x.toFixed(2)} m/s ω ${t.angular_z.toFixed(2)} rad/s · ` +
    `clamps ${clamps || "none"} · fault ${status.fault ?? "none"}`;
}
