// The fleet page: the robots of GET /api/robots every second, their e-stops, and STOP ALL.
"use strict";

const rows = document.getElementById("robots");
const message = document.getElementById("message");
const canvas = document.getElementById("map");

function cell(text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  return td;
}

function age(robot) {
  if (robot.age_s === null) return "never";
  return robot.age_s < 1 ? "now" : `${robot.age_s.toFixed(0)} s ago`;
}

async function post(path, body) {
  const response = await fetch(path, {
    method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body || {}),
  });
  const answer = await response.json().catch(() => ({}));
  if (!response.ok) throw new Error(answer.error || `HTTP ${response.status}`);
  return answer;
}

async function stop(path, body) {
  try {
    const answer = await post(path, body);
    const silent = answer.silent.length ? `; no answer from ${answer.silent.join(", ")}` : "";
    const refused = Object.keys(answer.errors).length
      ? `; refused by ${Object.keys(answer.errors).join(", ")}` : "";
    message.textContent = `e-stop latched on ${answer.stopped.join(", ") || "no robot"}` +
      silent + refused;
  } catch (err) {
    message.textContent = `stop failed: ${err.message}`;
  }
  refresh();
}

function row(robot) {
  const tr = document.createElement("tr");
  tr.dataset.robot = robot.robot_id;
  const name = document.createElement("td");
  if (robot.console) {
    const link = document.createElement("a");
    link.href = robot.console;
    link.textContent = robot.robot_id;
    link.target = "_blank";
    name.append(link);
  } else {
    name.textContent = robot.robot_id;
  }
  tr.append(name);
  const state = robot.online ? (robot.stale ? "stale" : robot.health) : "offline";
  tr.append(cell(state, robot.online && !robot.stale ? robot.health : "stale"));
  tr.append(cell(robot.estop_engaged ? "LATCHED" : robot.estop_engaged === false ? "off" : "?",
                 robot.estop_engaged ? "estop" : ""));
  tr.append(cell(robot.battery === null ? "—" : `${Math.round(robot.battery * 100)} %`));
  const p = robot.pose;
  tr.append(cell(p ? `${p.x.toFixed(2)}, ${p.y.toFixed(2)}, ${(p.theta * 180 / Math.PI).toFixed(0)}°`
                   : "—"));
  tr.append(cell(age(robot)));
  const td = document.createElement("td");
  const button = document.createElement("button");
  button.className = "stop";
  button.type = "button";
  button.textContent = "stop";
  button.addEventListener("click",
    () => stop(`/api/robots/${encodeURIComponent(robot.robot_id)}/estop`, { engaged: true }));
  td.append(button);
  tr.append(td);
  return tr;
}

function draw(robots) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const posed = robots.filter((r) => r.pose);
  const span = Math.max(2, ...posed.map((r) => Math.max(Math.abs(r.pose.x), Math.abs(r.pose.y)) * 2.4));
  const scale = canvas.width / span;
  const cx = canvas.width / 2, cy = canvas.height / 2;
  for (const robot of posed) {
    const x = cx + robot.pose.x * scale, y = cy - robot.pose.y * scale;
    ctx.fillStyle = robot.estop_engaged ? "#ef5350" : robot.online && !robot.stale ? "#66bb6a" : "#777";
    ctx.beginPath();
    ctx.arc(x, y, 7, 0, 2 * Math.PI);
    ctx.fill();
    ctx.strokeStyle = ctx.fillStyle;
    ctx.beginPath();
    ctx.moveTo(x, y);
    ctx.lineTo(x + 14 * Math.cos(robot.pose.theta), y - 14 * Math.sin(robot.pose.theta));
    ctx.stroke();
    ctx.fillStyle = "#e8eaed";
    ctx.fillText(robot.robot_id, x + 10, y - 10);
  }
}

async function refresh() {
  try {
    const response = await fetch("/api/robots");
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    const robots = await response.json();
    rows.replaceChildren(...robots.map(row));
    document.getElementById("count").textContent =
      `· ${robots.filter((r) => r.online).length} of ${robots.length} online`;
    draw(robots);
  } catch (err) {
    message.textContent = `fleet unreachable: ${err.message}`;
  }
}

document.getElementById("stop-all").addEventListener("click", () => stop("/api/stop_all"));
refresh();
setInterval(refresh, 1000);
