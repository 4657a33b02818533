// HTTP API client of the console: same origin, JSON, the tab's token as a Bearer header.

export class Api {
  constructor(getToken) {
    this.getToken = getToken;
  }

  headers() {
    const token = this.getToken();
    return token ? { Authorization: `Bearer ${token}` } : {};
  }

  // One request: {status, body}; throws only when the robot does not answer at all.
  async request(method, path, body, timeoutMs = 3000) {
    const headers = this.headers();
    if (body !== undefined) headers["Content-Type"] = "application/json";
    const response = await fetch(path, {
      method, headers, cache: "no-store",
      body: body === undefined ? undefined : JSON.stringify(body),
      signal: AbortSignal.timeout(timeoutMs),
    });
    let parsed = null;
    try { parsed = await response.json(); } catch { parsed = null; }
    return { status: response.status, body: parsed };
  }

  get(path) { return this.request("GET", path); }
  post(path, body) { return this.request("POST", path, body); }

  // A file (a recording) as a Blob, with the token; throws saying why it is not there.
  async download(path) {
    const response = await fetch(path, { headers: this.headers(), cache: "no-store" });
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    return response.blob();
  }
}

// Sends a request (a function returning Api.request's promise) and reports its answer to a
// panel: ok(body) on 200, else show(the daemon's error text), after refused(what) on 401.
export async function report(request, what, { ok, show, refused }) {
  let answer;
  try {
    answer = await request();
  } catch {
    show("the robot does not answer");
    return;
  }
  if (answer.status === 200) {
    ok(answer.body);
    return;
  }
  if (answer.status === 401) refused(what);
  show(answer.body?.error || `HTTP ${answer.status}`);
}
