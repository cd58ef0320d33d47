// The stream stage: one WebSocket to /v1/sessions/{sid}/stream (wire protocol v1), frames up,
// one ack or error back per frame. The page offers the sightings extension: when the server
// selects it, every frame the page sends is a keyframe it picked itself (keyframes.mjs) and
// nothing goes between them (a page has no detections, so no sighting to send). A server
// without the extension picks keyframes among the frames it receives, so the page then sends
// every sampled frame whole, as any v1 client may.

import { decode } from "../vendor/msgpack-msgpack@3.1.3/dist.esm/index.mjs";
import { socketUrl } from "./api.mjs";

export const SIGHTINGS_SUBPROTOCOL = "semanticxr.sightings.v1";

/** What the page has sent and the server answered; shown on the page, checked by tests. */
export function emptyCounters() {
  return {
    frames: 0, // frames sent (each is mapped when the server picks them: keyframes)
    keyframes: 0, // of them, the page's keyframes
    messageBytes: 0, // whole messages on the socket
    payloadBytes: 0, // the rgb and depth data the server counts as bytes_in
    acked: 0,
    errors: 0,
    dropped: 0, // keyframes the server superseded before mapping them
    skipped: 0, // keyframes the page did not send because the link was still busy
    lastError: null,
    objects: null, // from the newest keyframe ack
    updateSeq: null,
  };
}

export class FrameStream {
  /** onState(state, detail): "connecting" | "open" | "closed" | "error". */
  constructor({ sid, onState = () => {}, onAck = () => {} }) {
    this.sid = sid;
    this.onState = onState;
    this.onAck = onAck;
    this.counters = emptyCounters();
    this.pending = new Map(); // seq -> sent time (ms), for the acks' round trip
    this.rttMs = null;
    this.socket = null;
    this.pickKeyframes = false;
  }

  open() {
    return new Promise((resolve, reject) => {
      this.onState("connecting");
      const socket = new WebSocket(socketUrl(`/v1/sessions/${encodeURIComponent(this.sid)}/stream`, { sid: this.sid }), [SIGHTINGS_SUBPROTOCOL]);
      socket.binaryType = "arraybuffer";
      socket.onopen = () => {
        this.socket = socket;
        this.pickKeyframes = socket.protocol === SIGHTINGS_SUBPROTOCOL;
        this.onState("open");
        resolve(this);
      };
      socket.onerror = () => this.onState("error", "the stream socket failed");
      socket.onclose = (event) => {
        const opened = this.socket === socket;
        this.socket = null;
        this.onState("closed", event.reason || `closed (${event.code})`);
        if (!opened) reject(new Error(`the stream socket did not open (${event.code} ${event.reason || ""})`.trim()));
      };
      socket.onmessage = (event) => this._reply(event.data);
    });
  }

  /** Whether a frame could go now without queueing behind another (a slow link). */
  get ready() {
    return this.socket !== null && this.socket.bufferedAmount === 0;
  }

  /** Send one packed frame message; `payload` = {rgb, depth} byte counts; `keyframe` = picked. */
  send(seq, message, payload, keyframe) {
    if (!this.socket) return false;
    this.socket.send(message);
    this.pending.set(seq, performance.now());
    const c = this.counters;
    c.frames += 1;
    if (keyframe) c.keyframes += 1;
    c.messageBytes += message.byteLength;
    c.payloadBytes += payload.rgb + payload.depth;
    return true;
  }

  _reply(data) {
    let reply;
    try {
      reply = decode(new Uint8Array(data));
    } catch {
      return;
    }
    const c = this.counters;
    const sent = this.pending.get(reply.seq);
    if (sent !== undefined) {
      this.pending.delete(reply.seq);
      this.rttMs = performance.now() - sent;
    }
    if (reply.type === "ack") {
      c.acked += 1;
      if (reply.dropped) c.dropped += 1;
      if (reply.objects !== undefined) c.objects = reply.objects;
      if (reply.update_seq !== undefined) c.updateSeq = reply.update_seq;
    } else if (reply.type === "error") {
      c.errors += 1;
      c.lastError = `${reply.code}: ${reply.message}`;
    }
    this.onAck(reply);
  }

  close() {
    if (this.socket) this.socket.close(1000, "the XR session ended");
    this.socket = null;
  }
}
