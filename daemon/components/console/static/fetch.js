// The fetch mission in the console: the "fetch" tool (tap where the object stands, then where
// to drop it: POST /api/fetch), its state from /fetch/state and cancel (DELETE /api/fetch).

import { report } from "./api.js";

const STRING = "std_msgs/msg/String";
const ENDED = new Set(["IDLE"]);

// One line of the fetch state: the state and step, or how the last one ended and why.
export function describeFetch(fetch) {
  if (ENDED.has(fetch.state)) {
    if (!fetch.result) return "fetch: tap the object, then the drop point";
    return [`fetch ${fetch.result}`, fetch.reason].filter(Boolean).join(" · ");
  }
  const parts = [`fetch: ${fetch.state}`];
  if (fetch.step) parts.push(fetch.step);
  if (fetch.elapsed_s != null) parts.push(`${Math.round(fetch.elapsed_s)} s`);
  return parts.join(" · ");
}

export class FetchPanel {
  // el: {tool, cancel, state}; onRefused(what) when the token is missing or wrong
  constructor(el, api, bridge, view, { onRefused }) {
    Object.assign(this, { el, api, bridge, view, onRefused });
    this.present = false;
    this.picking = false;
    this.object = null; // the first tap, until the second one
    el.tool.addEventListener("click", () => this.toggleTool());
    el.cancel.addEventListener("click", () => this.cancel());
    const goTo = view.onGoalDrag; // the view's taps go to the navigation tool otherwise
    view.onGoalDrag = (point) => (this.picking ? this.pick(point) : goTo(point));
  }

  // Every health answer: the tool appears with an available fetch component, once.
  health(fetch) {
    const present = Boolean(fetch) && !fetch.note;
    if (present === this.present) return;
    this.present = present;
    this.el.tool.hidden = !present;
    this.el.state.hidden = !present;
    if (!present) return;
    this.bridge.subscribe("/fetch/state", STRING, (m) => this.stateArrived(JSON.parse(m.data)));
    this.stateArrived(fetch);
  }

  toggleTool() {
    this.setPicking(!this.picking);
    if (this.picking) this.show("tap where the object stands");
  }

  setPicking(on) {
    this.picking = on;
    this.object = null;
    this.view.setGoalTool(on);
    this.el.tool.setAttribute("aria-pressed", String(on));
  }

  // A tap while picking: the object first, then the drop point, which sends the mission.
  async pick({ x, y }) {
    if (!this.object) {
      this.object = [x, y];
      this.view.setPlan(null, { x, y });
      this.view.setGoalTool(true); // stays on for the second tap
      this.show("now tap where to drop it");
      return;
    }
    const body = { object: this.object, drop: [x, y] };
    this.setPicking(false);
    await this.answer(() => this.api.post("/api/fetch", body), "to start a fetch");
  }

  stateArrived(fetch) {
    this.el.cancel.hidden = ENDED.has(fetch.state);
    this.el.state.dataset.state = fetch.state;
    if (!this.picking) this.show(describeFetch(fetch));
  }

  show(text) { this.el.state.textContent = text; }

  async cancel() {
    await this.answer(() => this.api.request("DELETE", "/api/fetch"), "to cancel the fetch");
  }

  answer(request, what) {
    return report(request, what, { ok: (body) => this.stateArrived(body),
      show: (text) => this.show(text), refused: this.onRefused });
  }
}
