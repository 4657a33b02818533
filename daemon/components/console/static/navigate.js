// The navigation component in the console: the "go to" tool (tap the view for a goal, drag for
// its heading: POST /api/goal), the plan from /plan drawn on the view, the state and progress
// from /navigation/state, cancel (DELETE /api/goal) and the built-in figure-eight.

import { report } from "./api.js";

const PATH = "nav_msgs/msg/Path";
const STRING = "std_msgs/msg/String";
const ACTIVE = new Set(["planning", "following", "recovering"]);
const FIGURE_EIGHT_M = 2.0; // the figure-eight's size from the console (m)

// One line of the navigation state: what it does, how far, how long, or why it ended.
export function describe(nav) {
  const parts = [nav.state];
  if (ACTIVE.has(nav.state) && nav.plan_length_m && nav.distance_remaining_m != null) {
    parts.push(`${nav.distance_remaining_m.toFixed(2)} m to go`);
    if (nav.eta_s != null) parts.push(`ETA ${Math.round(nav.eta_s)} s`);
  }
  if (nav.reason) parts.push(nav.reason);
  return parts.join(" · ");
}

export class NavPanel {
  // el: {tool, figure8, cancel, state}; onRefused(what) when the token is missing or wrong
  constructor(el, api, bridge, view, { onRefused }) {
    Object.assign(this, { el, api, bridge, view, onRefused });
    this.present = false;
    this.goals = null; // the navigation's goal count in its last state
    this.held = null; // a refusal or error on screen: {text, goals} until something new happens
    el.tool.addEventListener("click", () => this.toggleTool());
    el.figure8.addEventListener("click", () =>
      this.send({ path: "figure_eight", size: FIGURE_EIGHT_M }, "the figure-eight"));
    el.cancel.addEventListener("click", () => this.cancel());
    view.onGoalDrag = (goal) => this.goTo(goal);
  }

  // Every health answer: the tools appear with the component, once.
  health(nav) {
    const present = Boolean(nav);
    if (present === this.present) return;
    this.present = present;
    for (const button of [this.el.tool, this.el.figure8]) button.hidden = !present;
    this.el.state.hidden = !present;
    if (!present) return;
    this.bridge.subscribe("/plan", PATH, (m) => this.planArrived(m));
    this.bridge.subscribe("/navigation/state", STRING, (m) => this.stateArrived(JSON.parse(m.data)));
    this.stateArrived(nav);
  }

  toggleTool() {
    this.held = null; // the user acts: the refusal has been read
    const on = !this.view.goalTool;
    this.view.setGoalTool(on);
    this.el.tool.setAttribute("aria-pressed", String(on));
    if (on) this.show("tap the view where the robot should go; drag for its heading");
  }

  planArrived(msg) {
    const points = (msg.poses || []).map((p) => [p.pose.position.x, p.pose.position.y]);
    this.view.setPlan(points, this.view.goal);
  }

  stateArrived(nav) {
    const active = ACTIVE.has(nav.state);
    this.goals = nav.goals ?? this.goals;
    // the 1 Hz state of the previous goal must not wipe a refusal: it stays until a new goal
    // starts (the count moves, or navigation becomes active) or the user acts
    if (this.held && !active && (nav.goals ?? null) === this.held.goals) return;
    this.held = null;
    this.el.cancel.hidden = !active;
    this.el.state.dataset.state = nav.state;
    this.show(describe(nav));
    const goal = nav.goal && nav.goal.x !== undefined ? { x: nav.goal.x, y: nav.goal.y } : null;
    if (!active) this.view.setPlan(null, null);
    else this.view.setPlan(this.view.plan, goal);
  }

  show(text) { this.el.state.textContent = text; }

  hold(text) {
    this.held = { text, goals: this.goals };
    this.el.state.dataset.state = "refused";
    this.show(text);
  }

  // A goal from the view: in the frame the view draws (the map's once /tf placed it).
  async goTo({ x, y, theta }) {
    const goal = { x, y, frame: this.view.mapToOdom ? "map" : "odom" };
    if (theta !== null) goal.theta = theta;
    this.view.setGoalTool(false);
    this.el.tool.setAttribute("aria-pressed", "false");
    this.view.setPlan(null, { x, y });
    await this.send(goal, "a goal");
  }

  async send(body, what) {
    this.held = null;
    await this.answer(() => this.api.post("/api/goal", body), `to send ${what}`);
  }

  async cancel() {
    await this.answer(() => this.api.request("DELETE", "/api/goal"), "to cancel the goal");
  }

  answer(request, what) {
    return report(request, what, { ok: (body) => this.stateArrived(body),
      show: (text) => this.hold(text), refused: this.onRefused });
  }
}
