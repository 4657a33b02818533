// rosbridge v2 client of the console: one WebSocket, subscriptions and advertisements replayed
// on every reconnect, service calls as promises, `status` frames as events.

export class Bridge extends EventTarget {
  constructor(urlFn) {
    super();
    this.urlFn = urlFn; // () => the ws:// URL, or "" while it is not known yet
    this.ws = null;
    this.subscriptions = new Map(); // topic -> {type, options, handler}
    this.advertised = new Map(); // topic -> type
    this.calls = new Map(); // id -> {resolve, reject, timer}
    this.seq = 0;
    this.backoffMs = 500;
    this.timer = null;
  }

  get open() { return this.ws !== null && this.ws.readyState === WebSocket.OPEN; }

  connect() {
    clearTimeout(this.timer);
    this.timer = null;
    if (this.ws) return;
    const url = this.urlFn();
    if (!url) { this.retry(); return; }
    const ws = new WebSocket(url);
    this.ws = ws;
    ws.addEventListener("open", () => {
      this.backoffMs = 500;
      this.replay();
      this.emit("open");
    });
    ws.addEventListener("message", (event) => this.receive(event.data));
    ws.addEventListener("close", (event) => {
      if (this.ws !== ws) return;
      this.ws = null;
      this.failCalls("connection lost");
      this.emit("close", { code: event.code });
      this.retry();
    });
  }

  // Drop the connection and open a new one now (a new token, or a manual retry).
  reconnect() {
    const ws = this.ws;
    this.ws = null;
    this.failCalls("reconnecting");
    if (ws && ws.readyState === WebSocket.OPEN) ws.close(1000, "reconnect");
    else if (ws) ws.addEventListener("open", () => ws.close(1000, "reconnect"));
    this.connect();
  }

  retry() {
    if (this.timer) return;
    const delay = this.backoffMs;
    this.backoffMs = Math.min(this.backoffMs * 2, 5000);
    this.emit("retry", { delay });
    this.timer = setTimeout(() => this.connect(), delay);
  }

  subscribe(topic, type, handler, options = {}) {
    this.subscriptions.set(topic, { type, options, handler });
    if (this.open) this.sendSubscribe(topic);
  }

  advertise(topic, type) {
    this.advertised.set(topic, type);
    if (this.open) this.send({ op: "advertise", id: `advertise:${topic}`, topic, type });
  }

  // Publishes when connected; false when the message could not be sent.
  publish(topic, msg) {
    if (!this.open) return false;
    this.send({ op: "publish", topic, msg });
    return true;
  }

  callService(service, args = {}, timeoutMs = 3000) {
    if (!this.open) return Promise.reject(new Error("not connected"));
    const id = `call:${++this.seq}`;
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => {
        this.calls.delete(id);
        reject(new Error(`${service}: no answer in ${timeoutMs} ms`));
      }, timeoutMs);
      this.calls.set(id, { resolve, reject, timer });
      this.send({ op: "call_service", id, service, args });
    });
  }

  // -- inside ----------------------------------------------------------------------------

  replay() {
    for (const [topic, type] of this.advertised) {
      this.send({ op: "advertise", id: `advertise:${topic}`, topic, type });
    }
    for (const topic of this.subscriptions.keys()) this.sendSubscribe(topic);
  }

  sendSubscribe(topic) {
    const { type, options } = this.subscriptions.get(topic);
    this.send({ op: "subscribe", id: `subscribe:${topic}`, topic, type, ...options });
  }

  send(frame) { this.ws.send(JSON.stringify(frame)); }

  receive(text) {
    let frame;
    try { frame = JSON.parse(text); } catch { return; }
    if (frame.op === "publish") {
      this.subscriptions.get(frame.topic)?.handler(frame.msg);
    } else if (frame.op === "service_response") {
      const call = this.calls.get(frame.id);
      if (!call) return;
      this.calls.delete(frame.id);
      clearTimeout(call.timer);
      if (frame.result === false) call.reject(new Error(String(frame.values)));
      else call.resolve(frame.values);
    } else if (frame.op === "status") {
      this.emit("status", frame);
    }
  }

  failCalls(why) {
    for (const call of this.calls.values()) {
      clearTimeout(call.timer);
      call.reject(new Error(why));
    }
    this.calls.clear();
  }

  emit(name, detail = {}) { this.dispatchEvent(new CustomEvent(name, { detail })); }
}
