// HTTP API client of the console: same origin, JSON, the tab's token as a Bearer header.

export class Api {
  constructor(getToken) {
    this.getToken = getToken;
  }

  // One request: {status, body}; throws only when the robot does not answer at all.
  async request(method, path, body, timeoutMs = 3000) {
    const headers = {};
    const token = this.getToken();
    if (token) headers.Authorization = `Bearer ${token}`;
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
}
