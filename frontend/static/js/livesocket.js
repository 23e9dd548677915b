// WS /ws/live as a resilient stream: snapshot first, then events; reconnects with back-off,
// resynchronises when the server says the browser missed something that matters, and probes
// a silent connection so a half-open socket never freezes the page.

const BACKOFF_MS = [500, 1000, 2000, 4000, 8000, 10000];
const SILENCE_MS = 15000; // no message for this long: ask for a snapshot (proves the socket works)
const PROBE_TIMEOUT_MS = 8000; // no answer to the probe: drop the socket and reconnect
const RESYNC_EVERY_MS = 3000;

export class LiveSocket {
  /**
   * @param {object} handlers onSnapshot(data), onEvent(msg), onMissed(msg), onState(state, info)
   *   state is "connecting", "live" or "reconnecting" (info.retryInMs, info.attempt).
   */
  constructor(handlers, url = null) {
    this.handlers = handlers;
    this.url = url || `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/live`;
    this.attempt = 0;
    this.ws = null;
    this.seq = 0;
    this.lastMessageAt = 0;
    this.probeSentAt = 0;
    this.stopped = false;
    this.retryTimer = null;
    this.watchdog = setInterval(() => this.check(), 2000);
  }

  start() {
    this.stopped = false;
    this.connect();
    return this;
  }

  stop() {
    this.stopped = true;
    clearInterval(this.watchdog);
    clearTimeout(this.retryTimer);
    this.ws?.close();
  }

  state(s, info = {}) {
    this.handlers.onState?.(s, info);
  }

  connect() {
    clearTimeout(this.retryTimer);
    this.state(this.attempt === 0 ? "connecting" : "reconnecting", { attempt: this.attempt });
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch {
      this.retry();
      return;
    }
    this.ws = ws;
    this.seq = 0;
    this.probeSentAt = 0;
    ws.onopen = () => {
      this.lastMessageAt = performance.now();
      // Events that come in a burst arrive as one message: far fewer sends for the ship.
      ws.send(JSON.stringify({ type: "batch" }));
    };
    ws.onmessage = (ev) => {
      if (ws !== this.ws) return;
      this.lastMessageAt = performance.now();
      this.probeSentAt = 0;
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch {
        return;
      }
      if (msg.type === "batch") {
        for (const m of msg.messages || []) this.receive(m);
      } else {
        this.receive(msg);
      }
    };
    ws.onclose = () => {
      if (ws !== this.ws) return;
      this.ws = null;
      this.retry();
    };
    ws.onerror = () => {
      /* onclose follows */
    };
  }

  receive(msg) {
    const expected = this.seq + 1;
    this.seq = msg.seq ?? expected;
    if (msg.type === "snapshot") {
      this.resyncAskedAt = 0;
      this.attempt = 0;
      this.probeSentAt = 0;
      this.state("live");
      this.handlers.onSnapshot?.(msg.data);
      return;
    }
    if (msg.seq !== undefined && msg.seq > expected) {
      // Messages in between never arrived: only a snapshot restores the state.
      this.resync();
    }
    if (msg.type === "error") {
      // The server answers but cannot give a snapshot (its database is down): it says what to do
      // and tries again by itself; the socket stays open.
      this.handlers.onServerError?.(msg);
      return;
    }
    if (msg.type === "missed") {
      this.handlers.onMissed?.(msg);
      if (msg.resync) this.resync();
      return;
    }
    if (msg.type === "event") this.handlers.onEvent?.(msg);
  }

  /** Ask for a fresh snapshot (at most one request in flight, and not more than every 3 s). */
  resync() {
    const now = performance.now();
    if (this.resyncAskedAt && now - this.resyncAskedAt < RESYNC_EVERY_MS) return;
    if (this.ws && this.ws.readyState === WebSocket.OPEN) {
      this.resyncAskedAt = now;
      this.ws.send(JSON.stringify({ type: "resync" }));
    }
  }

  retry() {
    if (this.stopped) return;
    const delay = BACKOFF_MS[Math.min(this.attempt, BACKOFF_MS.length - 1)];
    const jittered = Math.round(delay * (0.8 + Math.random() * 0.4));
    this.attempt += 1;
    this.state("reconnecting", { retryInMs: jittered, attempt: this.attempt, retryAt: performance.now() + jittered });
    this.retryTimer = setTimeout(() => this.connect(), jittered);
  }

  check() {
    const ws = this.ws;
    if (!ws || ws.readyState !== WebSocket.OPEN) return;
    const now = performance.now();
    if (this.probeSentAt && now - this.probeSentAt > PROBE_TIMEOUT_MS) {
      // Half-open: the socket looks open but nothing comes back.
      this.ws = null;
      ws.onclose = null;
      ws.close();
      this.retry();
    } else if (!this.probeSentAt && now - this.lastMessageAt > SILENCE_MS) {
      this.probeSentAt = now;
      this.resync();
    }
  }
}
