// On-screen joystick: pointer events (mouse, pen, a thumb on a phone); springs back on release.

export class Joystick {
  // onMove(x, y): x right and y forward, each -1..1; (0, 0) on release.
  constructor(pad, stick, onMove) {
    Object.assign(this, { pad, stick, onMove, pointer: null });
    pad.addEventListener("pointerdown", (event) => {
      event.preventDefault();
      pad.setPointerCapture(event.pointerId);
      this.pointer = event.pointerId;
      pad.dataset.active = "true";
      this.move(event);
    });
    pad.addEventListener("pointermove", (event) => {
      if (event.pointerId === this.pointer) this.move(event);
    });
    for (const name of ["pointerup", "pointercancel", "lostpointercapture"]) {
      pad.addEventListener(name, (event) => {
        if (event.pointerId === this.pointer) this.release();
      });
    }
  }

  move(event) {
    const box = this.pad.getBoundingClientRect();
    const radius = box.width * 0.33;
    let dx = (event.clientX - (box.left + box.width / 2)) / radius;
    let dy = (event.clientY - (box.top + box.height / 2)) / radius;
    const length = Math.hypot(dx, dy);
    if (length > 1) { dx /= length; dy /= length; }
    this.stick.style.transform = `translate(${dx * radius}px, ${dy * radius}px)`;
    const round = (v) => (Math.abs(v) < 0.08 ? 0 : Math.round(v * 100) / 100);
    this.onMove(round(dx), round(-dy));
  }

  release() {
    this.pointer = null;
    this.pad.dataset.active = "false";
    this.stick.style.transform = "";
    this.onMove(0, 0);
  }
}
