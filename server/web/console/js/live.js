// The live link: one WebSocket to /ws/client. The token goes in the first frame (never
// in the URL); then the topics are subscribed, each answered by its current state
// (snapshot: true) and then its changes. A lost link is taken up again with backoff,
// and every topic is subscribed again (so the snapshots bring the view up to date).

const FIRST_RETRY_MS = 500;
const LAST_RETRY_MS = 10000;
const PING_EVERY_MS = 15000; // a silent link (a phone that lost its network) is found by this
const PING_ANSWER_MS = 10000;
const TOPICS_PER_OP = 64; // the wire models' bound

export class LiveLink {
  /**
   * onEvent(topic, data, snapshot): each event pushed.
   * onState(state, info): "connecting" | "live" | "lost" (info.retryInMs) | "refused".
   * pingTopic: a topic the user may name (an unsubscribe of it, answered by an ack,
   * proves the link still carries frames both ways).
   */
  constructor({ token, onEvent, onState, pingTopic }) {
    this.token = token;
    this.onEvent = onEvent;
    this.onState = onState;
    this.pingTopic = pingTopic;
    this.topics = new Set();
    this.ws = null;
    this.retryMs = FIRST_RETRY_MS;
    this.ids = 1;
    this.stopped = false;
    this.authed = false;
    this.timers = new Set();
  }

  start() {
    this.stopped = false;
    this.connect();
  }

  stop() {
    this.stopped = true;
    for (const t of this.timers) clearTimeout(t);
    this.timers.clear();
    if (this.ws) this.ws.close(1000, "bye");
  }

  /** Subscribe (now if the link is up, and again after every reconnect). */
  subscribe(topics) {
    const fresh = topics.filter((t) => !this.topics.has(t));
    fresh.forEach((t) => this.topics.add(t));
    if (this.authed && fresh.length) this.sendSubscribe(fresh);
  }

  /** Drop the link and take it up again at once (tests use it; so can a user). */
  reconnectNow() {
    this.retryMs = FIRST_RETRY_MS;
    if (this.ws) this.ws.close(4000, "reconnect");
  }

  later(fn, ms) {
    const t = setTimeout(() => {
      this.timers.delete(t);
      fn();
    }, ms);
    this.timers.add(t);
    return t;
  }

  connect() {
    if (this.stopped) return;
    this.authed = false;
    this.onState("connecting", {});
    const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/client`;
    const ws = new WebSocket(url);
    this.ws = ws;
    ws.onopen = () => ws.send(JSON.stringify({ op: "auth", id: "0", token: this.token }));
    ws.onmessage = (m) => this.received(ws, m);
    ws.onclose = (ev) => this.closed(ws, ev);
  }

  received(ws, message) {
    if (ws !== this.ws || typeof message.data !== "string") return;
    this.lastFrameAt = Date.now();
    let frame;
    try {
      frame = JSON.parse(message.data);
    } catch {
      return;
    }
    if (frame.op === "ack" && frame.id === "0") {
      if (!frame.ok) return; // the server closes the socket next (4401 / 4403)
      this.authed = true;
      this.retryMs = FIRST_RETRY_MS;
      this.onState("live", {});
      if (this.topics.size) this.sendSubscribe([...this.topics]);
      this.schedulePing(ws);
    } else if (frame.op === "ack" && frame.id === this.pingId) {
      this.pingId = null;
    } else if (frame.op === "event") {
      this.onEvent(frame.topic, frame.data, Boolean(frame.snapshot));
    } else if (frame.op === "ack" && !frame.ok) {
      console.warn("refused:", frame.error);
    }
  }

  sendSubscribe(topics) {
    for (let i = 0; i < topics.length; i += TOPICS_PER_OP) {
      const chunk = topics.slice(i, i + TOPICS_PER_OP);
      this.ws.send(JSON.stringify({ op: "subscribe", id: `s${this.ids++}`, topics: chunk }));
    }
  }

  schedulePing(ws) {
    this.later(() => {
      if (ws !== this.ws || ws.readyState !== WebSocket.OPEN) return;
      this.pingId = `p${this.ids++}`;
      const asked = this.pingId;
      ws.send(JSON.stringify({ op: "unsubscribe", id: asked, topics: [this.pingTopic] }));
      this.later(() => {
        if (ws !== this.ws || this.pingId !== asked) return;
        ws.close(4000, "no answer");
        // Lost now: a browser without a network never confirms the close (onclose).
        this.closed(ws, { code: 4000, reason: "no answer" });
      }, PING_ANSWER_MS);
      this.schedulePing(ws);
    }, PING_EVERY_MS);
  }

  closed(ws, ev) {
    if (ws !== this.ws) return;
    this.ws = null;
    this.authed = false;
    if (this.stopped) return;
    if (ev.code === 4401 || ev.code === 4403) {
      this.onState("refused", { code: ev.code, reason: ev.reason });
      return; // fatal: a new token is needed, retrying will not help
    }
    const wait = Math.round(this.retryMs * (0.8 + Math.random() * 0.4));
    this.retryMs = Math.min(this.retryMs * 2, LAST_RETRY_MS);
    this.onState("lost", { retryInMs: wait, code: ev.code });
    this.later(() => this.connect(), wait);
  }
}
