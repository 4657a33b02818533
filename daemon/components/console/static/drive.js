// Driving: keyboard, joystick and gamepad mixed into one twist, sent at a steady rate while
// held (so the deadman never fires mid-drive) and as zero on release, blur or a hidden tab.

export const RATE_HZ = 20;
const DEADZONE = 0.12;
const KEYS = {
  KeyW: "forward", ArrowUp: "forward", KeyS: "back", ArrowDown: "back",
  KeyA: "left", ArrowLeft: "left", KeyD: "right", ArrowRight: "right",
};

export function isDriveKey(code) { return code in KEYS; }

const dead = (v) => (Math.abs(v) < DEADZONE ? 0 : v);

export class Drive {
  // send(linear, angular) publishes one stamped command and says whether it went out.
  constructor(send) {
    this.send = send;
    this.keys = new Set();
    this.stick = { x: 0, y: 0 }; // joystick, each -1..1, y forward
    this.pad = { x: 0, y: 0 }; // gamepad left stick, same convention
    this.limits = { linear: 0.5, angular: 1.0 };
    this.moving = false; // the last command sent was not zero
    this.onCommand = () => {};
    this.onGamepadStop = () => {};
    this.padStopWasDown = false;
    this.timer = setInterval(() => this.tick(), 1000 / RATE_HZ);
  }

  key(code, down) {
    const action = KEYS[code];
    if (!action) return;
    const had = this.keys.has(action);
    if (down) this.keys.add(action); else this.keys.delete(action);
    if (had !== down) this.tick();
  }

  setStick(x, y) { this.stick = { x, y }; this.tick(); }

  // Everything released and zero sent now (release, window blur, tab hidden).
  stopAll() {
    this.keys.clear();
    this.stick = { x: 0, y: 0 };
    this.pad = { x: 0, y: 0 };
    this.tick();
  }

  target() {
    const k = this.keys;
    if (k.size) {
      return this.scaled((k.has("left") ? 1 : 0) - (k.has("right") ? 1 : 0),
        (k.has("forward") ? 1 : 0) - (k.has("back") ? 1 : 0));
    }
    if (this.stick.x || this.stick.y) return this.scaled(-this.stick.x, this.stick.y);
    return this.scaled(-this.pad.x, this.pad.y);
  }

  scaled(turn, ahead) {
    return { linear: ahead * this.limits.linear, angular: turn * this.limits.angular };
  }

  tick() {
    this.readGamepad();
    const { linear, angular } = this.target();
    const zero = linear === 0 && angular === 0;
    if (!zero || this.moving) {
      const sent = this.send(linear, angular);
      this.moving = !zero && (sent || this.moving);
      this.onCommand(linear, angular, sent);
    }
  }

  readGamepad() {
    if (document.visibilityState !== "visible") { this.pad = { x: 0, y: 0 }; return; }
    const pads = navigator.getGamepads ? navigator.getGamepads() : [];
    const pad = Array.from(pads || []).find((p) => p && p.connected);
    if (!pad) return;
    this.pad = { x: dead(pad.axes[0] || 0), y: -dead(pad.axes[1] || 0) };
    const stopDown = Boolean(pad.buttons[1]?.pressed); // B / circle latches the e-stop
    if (stopDown && !this.padStopWasDown) this.onGamepadStop();
    this.padStopWasDown = stopDown;
  }
}
