// Health panel: component states with their messages, mode, driver, uptime, motion, clamps, faults.

const DETAIL_KEYS = ["state", "model", "mode", "emulator", "scan_rate_hz", "clients", "port"];

export function uptime(seconds) {
  const s = Math.floor(seconds);
  const parts = [[Math.floor(s / 86400), "d"], [Math.floor(s / 3600) % 24, "h"],
    [Math.floor(s / 60) % 60, "min"], [s % 60, "s"]];
  const first = parts.findIndex(([v]) => v > 0);
  return parts.slice(first < 0 ? 3 : first, (first < 0 ? 3 : first) + 2)
    .map(([v, u]) => `${v} ${u}`).join(" ");
}

// The one line that says what a component is doing, or what is wrong with it.
export function componentMessage(c) {
  for (const key of ["error", "last_error", "fault"]) {
    if (c[key]) return `${key.replace("_", " ")}: ${c[key]}`;
  }
  if (c.driver && typeof c.driver === "object" && c.driver.fault) {
    return `driver fault: ${c.driver.fault}`;
  }
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
    const cells = [name, c.status, componentMessage(c)];
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
