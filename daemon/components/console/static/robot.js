// The robot panel: wander and explore on/off, the flight recorder and its recordings (download), odometry
// and simulation reset. Each button is one HTTP call; what the robot says back is shown.

export function fileSize(bytes) {
  if (!Number.isFinite(bytes)) return "";
  if (bytes < 1e3) return `${bytes} B`;
  if (bytes < 1e6) return `${(bytes / 1e3).toFixed(1)} kB`;
  return `${(bytes / 1e6).toFixed(1)} MB`;
}

export const baseName = (path) => String(path || "").split("/").pop();

export class RobotPanel {
  // el: {wander, explore, wanderState, record, recordState, odomReset, simReset, message, recordings,
  //      refresh}; api: the HTTP client; onRefused(what): the daemon asked for a token.
  constructor(el, api, { onRefused = () => {}, onOdometryReset = () => {} } = {}) {
    Object.assign(this, { el, api, onRefused, onOdometryReset });
    this.autonomy = null; // the last /autonomy/state
    this.recording = null; // the recorder's health
    el.wander.addEventListener("click", () => this.toggleWander());
    el.explore.addEventListener("click", () => this.toggleExplore());
    el.record.addEventListener("click", () => this.toggleRecord());
    el.odomReset.addEventListener("click", () => this.resetOdometry());
    el.simReset.addEventListener("click", () => this.resetSimulation());
    el.refresh.addEventListener("click", () => this.refreshRecordings());
  }

  say(text, kind = "info") {
    this.el.message.textContent = text;
    this.el.message.dataset.kind = kind;
  }

  // One POST; the body when it was taken, else null (and the reason shown).
  async post(path, body, what) {
    let answer;
    try {
      answer = await this.api.post(path, body);
    } catch {
      this.say(`${what}: the robot does not answer`, "error");
      return null;
    }
    if (answer.status === 200) return answer.body;
    if (answer.status === 401) this.onRefused(`to ${what}`);
    const why = answer.body?.error || `HTTP ${answer.status}`;
    this.say(`${what}: ${why}${answer.status === 401 ? " (use Token…)" : ""}`, "error");
    return null;
  }

  // -- wander and explore (POST /api/autonomy; the state arrives on /autonomy/state) ----------

  setAutonomy(state) {
    this.autonomy = state;
    const on = state.mode === "wander";
    this.el.wander.setAttribute("aria-pressed", String(on));
    this.el.wander.textContent = on ? "stop wander" : "wander";
    const exploring = state.mode === "explore";
    this.el.explore.setAttribute("aria-pressed", String(exploring));
    this.el.explore.textContent = exploring ? "stop exploring" : "explore";
    const x = state.exploration;
    this.el.wanderState.textContent = x && (exploring || state.mode === "off")
      ? `explore · ${x.state} · ${x.explored_m2.toFixed(1)} m² known` +
        (x.reason ? ` · ${x.reason}` : "")
      : `${state.mode} · ${state.state}` + (state.reason ? ` · ${state.reason}` : "");
  }

  async toggleExplore() {
    const mode = this.autonomy?.mode === "explore" ? "off" : "explore";
    const body = await this.post("/api/autonomy", { mode }, `switch exploring ${mode === "off" ? "off" : "on"}`);
    if (body) {
      this.setAutonomy(body);
      this.say(mode === "explore" ? "exploring: the robot drives to the unexplored places, then back; any drive command takes over" : "exploring off");
    }
  }

  async toggleWander() {
    const mode = this.autonomy?.mode === "wander" ? "off" : "wander";
    const body = await this.post("/api/autonomy", { mode }, `switch wander ${mode === "off" ? "off" : "on"}`);
    if (body) {
      this.setAutonomy(body);
      this.say(mode === "wander" ? "wander on: the robot drives by itself; any drive command takes over" : "wander off");
    }
  }

  // -- the flight recorder (POST /api/record; its state is in /api/health) ------------------

  setRecorder(recorder) {
    if (!recorder) return;
    const was = this.recording?.recording;
    this.recording = recorder;
    const on = Boolean(recorder.recording);
    this.el.record.setAttribute("aria-pressed", String(on));
    this.el.record.textContent = on ? "stop recording" : "record";
    this.el.recordState.textContent = recorder.error ? `error: ${recorder.error}`
      : on ? `${baseName(recorder.file)} · ${fileSize(recorder.file_bytes ?? 0)}` : "not recording";
    if (was !== undefined && was !== on) this.refreshRecordings();
  }

  async toggleRecord() {
    const enabled = !this.recording?.recording;
    const body = await this.post("/api/record", { enabled }, enabled ? "start recording" : "stop recording");
    if (body) {
      this.setRecorder(body);
      this.say(enabled ? `recording to ${baseName(body.file)}` : "recording stopped");
    }
  }

  async refreshRecordings() {
    let answer;
    try {
      answer = await this.api.get("/api/recordings");
    } catch {
      return;
    }
    if (answer.status !== 200 || !answer.body?.recordings) return;
    const items = [...answer.body.recordings].reverse().map((r) => this.recordingItem(r));
    if (!items.length) {
      const none = document.createElement("li");
      none.className = "muted";
      none.textContent = "none yet";
      items.push(none);
    }
    this.el.recordings.replaceChildren(...items);
  }

  recordingItem(r) {
    const li = document.createElement("li");
    const link = document.createElement("a");
    link.href = `/api/recordings/${encodeURIComponent(r.name)}`;
    link.download = r.name;
    link.textContent = r.name;
    link.dataset.recording = String(Boolean(r.recording));
    link.addEventListener("click", (event) => this.download(event, r.name));
    const about = document.createElement("span");
    about.textContent = [fileSize(r.size), Number.isFinite(r.duration_s) ? `${r.duration_s.toFixed(0)} s` : "",
      r.recording ? "recording" : (r.complete ? "" : "incomplete")].filter(Boolean).join(" · ");
    li.append(link, about);
    return li;
  }

  // A plain link when no token is needed; with a token the file is fetched with the Bearer
  // header (a link cannot carry it, and the token stays out of the URL and the history).
  async download(event, name) {
    if (!this.api.getToken()) return;
    event.preventDefault();
    try {
      const blob = await this.api.download(`/api/recordings/${encodeURIComponent(name)}`);
      const url = URL.createObjectURL(blob);
      const a = document.createElement("a");
      a.href = url;
      a.download = name;
      a.click();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
    } catch (error) {
      this.say(`download ${name}: ${error.message}`, "error");
    }
  }

  // -- resets ------------------------------------------------------------------------------------

  async resetOdometry() {
    const body = await this.post("/api/odom/reset", {}, "reset odometry");
    if (body) {
      this.onOdometryReset();
      this.say("odometry reset: the robot is at the origin");
    }
  }

  async resetSimulation() {
    const body = await this.post("/api/sim/reset", {}, "reset the simulation");
    if (body) {
      this.onOdometryReset();
      const t = body.ground_truth;
      this.say(`simulation reset: the robot is back at (${t.x.toFixed(2)}, ${t.y.toFixed(2)}); odometry with it`);
    }
  }
}
