// The arm panel ([arm] on): pose buttons, the gripper, and a side view drawn from GET /api/arm.
const SVG = "http://www.w3.org/2000/svg";
// the seed's geometry (daemon/arm/kinematics.py): joint1 on base_link at x, z; link lengths
const MOUNT = [0.10, 0.18];
const LINKS = [0.200, 0.410, 0.200];
const OPEN_M = 0.035;

// The mount and each link's end (x forward, z up, m) for three joint angles (rad).
export function linkPoints(angles) {
  const points = [MOUNT];
  let [x, z] = MOUNT;
  let pitch = 0;
  LINKS.forEach((length, i) => {
    pitch += angles[i];
    x += length * Math.sin(pitch);
    z += length * Math.cos(pitch);
    points.push([x, z]);
  });
  return points;
}

const svgPoints = (points) => points.map(([x, z]) => `${x.toFixed(4)},${(-z).toFixed(4)}`).join(" ");

function node(tag, attrs, parent) {
  const element = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) element.setAttribute(k, String(v));
  parent.appendChild(element);
  return element;
}

export class ArmPanel {
  // el: {panel, poses, open, close, state, view, message}; api: the HTTP client;
  // onRefused(what): the daemon asked for a token.
  constructor(el, api, { onRefused = () => {} } = {}) {
    Object.assign(this, { el, api, onRefused });
    this.present = false;
    this.poseNames = "";
    el.open.addEventListener("click", () => this.send({ gripper_m: OPEN_M }, "open the gripper"));
    el.close.addEventListener("click", () => this.send({ gripper_m: 0 }, "close the gripper"));
    const view = el.view;
    node("line", { x1: -0.3, y1: 0, x2: 1.05, y2: 0, class: "ground" }, view);
    node("rect", { x: -0.2, y: -0.18, width: 0.4, height: 0.18, rx: 0.02, class: "base" }, view);
    this.target = node("polyline", { class: "target", points: "" }, view);
    this.arm = node("polyline", { class: "links", points: "" }, view);
    this.tip = node("circle", { r: 0.025, class: "tip", cx: 0, cy: 0 }, view);
  }

  // The arm component's health (undefined: no arm): shows or hides the panel.
  health(component) {
    this.present = Boolean(component);
    this.el.panel.hidden = !this.present;
  }

  say(text, kind = "info") {
    this.el.message.textContent = text;
    this.el.message.dataset.kind = kind;
  }

  async send(body, what) {
    let answer;
    try {
      answer = await this.api.post("/api/arm", body);
    } catch {
      this.say(`${what}: the robot does not answer`, "error");
      return;
    }
    if (answer.status === 200) {
      this.say(`${what}: ${answer.body.duration_s.toFixed(2)} s`);
      this.render(answer.body);
      return;
    }
    if (answer.status === 401) this.onRefused(`to ${what}`);
    this.say(`${what}: ${answer.body?.error || `HTTP ${answer.status}`}`, "error");
  }

  renderPoses(names) {
    if (names.join() === this.poseNames) return;
    this.poseNames = names.join();
    this.el.poses.replaceChildren(...names.map((name) => {
      const button = document.createElement("button");
      button.type = "button";
      button.textContent = name;
      button.dataset.pose = name;
      button.addEventListener("click", () => this.send({ pose: name }, `pose ${name}`));
      return button;
    }));
  }

  // One GET /api/arm answer.
  render(state) {
    this.renderPoses(state.poses || []);
    for (const button of this.el.poses.children) {
      button.setAttribute("aria-pressed", String(button.dataset.pose === state.pose));
    }
    const joints = Object.values(state.joints);
    const here = linkPoints(joints.slice(0, 3).map((j) => j.position));
    this.arm.setAttribute("points", svgPoints(here));
    this.target.setAttribute("points", svgPoints(linkPoints(joints.slice(0, 3).map((j) => j.target))));
    const [x, z] = here[here.length - 1];
    this.tip.setAttribute("cx", x.toFixed(4));
    this.tip.setAttribute("cy", (-z).toFixed(4));
    this.tip.setAttribute("r", (0.015 + state.gripper_m / 2).toFixed(4));
    const where = state.pose ? `at ${state.pose}` : state.moving ? `moving to ${state.target_pose || "target"}` : "stopped";
    const frozen = state.frozen_by_estop ? " · frozen (e-stop)" : "";
    const fault = state.fault ? ` · fault: ${state.fault}` : "";
    this.el.state.textContent = `${where} · gripper ${(state.gripper_m * 1000).toFixed(0)} mm` +
      ` · tip x ${state.end_effector.x.toFixed(2)} z ${state.end_effector.z.toFixed(2)} m${frozen}${fault}`;
    this.el.view.dataset.pose = state.pose || "";
  }
}
