// Video to the browser (issue 21): the codecs this browser's WebCodecs VideoDecoder decodes (the
// viewer's `stream_offer`), and VideoStream, which decodes the TVID frames of the stream the
// coordinator chose and paints each decoded VideoFrame on the frame canvas.
// A lost frame (a decoder error, a delta frame dropped because the decoder is behind) stops
// decoding until the next keyframe, which is asked for once per loss (the `keyframe` message).

import { VIDEO_HEADER_SIZE, VideoCodec, codecLabel, codecString } from "./video_protocol.js";

/** Codecs a viewer offers, best first (by label: the `stream_offer` names). */
export const CODEC_PREFERENCE = Object.freeze([VideoCodec.H264, VideoCodec.VP9]);
/** Frames waiting in the decoder above which an arriving delta frame is dropped (a loss). */
export const MAX_DECODE_QUEUE = 4;
/** The transport of a viewer that gets TFRM frames of tiles. */
export const TILES = "tiles";
/** The colours of every stream's pictures (tessera/video/yuv_frame.py): full-range BT.601 (JPEG's
 * YCbCr) of sRGB pixels. The streams say so in band, but Chromium's decoder takes their colour
 * description as BT.709 limited range (darker, stretched), so the decoder is told. */
export const STREAM_COLOR_SPACE = Object.freeze({
  primaries: "bt709", transfer: "iec61966-2-1", matrix: "smpte170m", fullRange: true,
});

/**
 * The labels of the codecs `decoder` (a VideoDecoder class) decodes at `width`×`height` px with
 * `optimizeForLatency`, best first (CODEC_PREFERENCE); [] without WebCodecs.
 */
export async function decodableCodecs(width, height, decoder = globalThis.VideoDecoder) {
  if (typeof decoder?.isConfigSupported !== "function") return [];
  const supported = await Promise.all(CODEC_PREFERENCE.map(async (codec) => {
    const config = { codec: codecString(codec, width, height), codedWidth: width, codedHeight: height,
      optimizeForLatency: true };
    try {
      return (await decoder.isConfigSupported(config)).supported === true;
    } catch {
      return false;
    }
  }));
  return CODEC_PREFERENCE.filter((_, i) => supported[i]).map(codecLabel);
}

export class VideoStream {
  /**
   * @param {HTMLCanvasElement} canvas  resized to each painted frame's width × height
   * @param {{paintable: (frameId: number) => boolean, onPainted: (frame: object) => void,
   *   requestKeyframe: () => void, onError: (error: Error) => void}} hooks
   *   paintable: whether a decoded frame may be painted (no newer frame is on the canvas);
   *   onPainted: after a frame ({frameId, width, height, inputSeq}) is on the canvas;
   *   requestKeyframe: send `{"type": "keyframe"}`; onError: a decoder error (a loss)
   * @param {{VideoDecoder: Function, EncodedVideoChunk: Function}} webcodecs  the WebCodecs classes
   */
  constructor(canvas, hooks, webcodecs = globalThis) {
    this.canvas = canvas;
    this.context = canvas.getContext("2d", { alpha: false });
    this.hooks = hooks;
    this.webcodecs = webcodecs;
    /** "tiles" or the codec label of the stream (the coordinator's `stream` message). */
    this.transport = TILES;
    /** The `stream` message's WebCodecs codec string (null for tiles). */
    this.codec = null;
    this.decoder = null;
    /** The decoder's configuration as "codec widthxheight" (null: none). */
    this.configured = null;
    /** No delta frame is decoded until a keyframe comes (a new stream, or after a loss). */
    this.awaitingKeyframe = true;
    /** A keyframe was asked for since the last keyframe decoded. */
    this.requested = false;
    /** Chunk timestamp → {frameId, width, height, inputSeq} of frames in the decoder. */
    this.inDecoder = new Map();
    this.nextTimestamp = 0;
    /** The newest video frame id received (null: none yet). */
    this.received = null;
    this.decoded = 0;
    this.painted = 0;
    this.dropped = 0;
    this.keyframeRequests = 0;
    this.window = { start: null, bytes: 0, decoded: 0 };
  }

  /** Whether frames come as video (the coordinator chose a codec). */
  get active() {
    return this.transport !== TILES;
  }

  /** The coordinator's `stream` message: its transport and codec; a video stream starts at its next keyframe. */
  choose({ transport, codec }) {
    this.transport = transport;
    this.codec = transport === TILES ? null : codec ?? null;
    this.awaitingKeyframe = true;
    this.requested = false;
    if (!this.active) this.close();
  }

  /** Back to tiles with no decoder (a new connection). */
  reset() {
    this.choose({ transport: TILES, codec: null });
    this.received = null;
  }

  close() {
    if (this.decoder && this.decoder.state !== "closed") this.decoder.close();
    this.decoder = null;
    this.configured = null;
    this.inDecoder.clear();
  }

  /** Decode a parsed TVID frame (video_protocol.parseVideo); a delta frame may be dropped. */
  submit(frame) {
    this.window.bytes += VIDEO_HEADER_SIZE + frame.data.byteLength;
    this.received = frame.frameId;
    if (!frame.keyframe) {
      if (this.awaitingKeyframe) {
        this.dropped++;
        this.lose();
        return;
      }
      if (this.decoder.decodeQueueSize > MAX_DECODE_QUEUE) {
        this.dropped++;
        this.lose();
        return;
      }
    }
    const timestamp = this.nextTimestamp++;
    try {
      if (frame.keyframe) this.configureFor(frame);
      this.inDecoder.set(timestamp, { frameId: frame.frameId, width: frame.width, height: frame.height,
        inputSeq: frame.inputSeq });
      this.decoder.decode(new this.webcodecs.EncodedVideoChunk({
        type: frame.keyframe ? "key" : "delta", timestamp, data: frame.data,
      }));
      if (frame.keyframe) this.requested = false;
      this.awaitingKeyframe = false;
    } catch (error) {
      this.inDecoder.delete(timestamp);
      this.dropped++;
      this.fail(error);
    }
  }

  /** A decoder for the keyframe's codec and size: the one there is, reconfigured when either differs. */
  configureFor(frame) {
    const label = codecLabel(frame.codec);
    const codec = label === this.transport && this.codec ? this.codec : codecString(frame.codec, frame.width, frame.height);
    const configuration = `${codec} ${frame.width}x${frame.height}`;
    if (this.decoder && this.decoder.state !== "closed" && this.configured === configuration) return;
    if (!this.decoder || this.decoder.state === "closed") {
      this.decoder = new this.webcodecs.VideoDecoder({
        output: (videoFrame) => this.output(videoFrame),
        error: (error) => this.fail(error),
      });
    }
    this.decoder.configure({ codec, codedWidth: frame.width, codedHeight: frame.height, optimizeForLatency: true,
      colorSpace: { ...STREAM_COLOR_SPACE } });
    this.configured = configuration;
  }

  /** A decoded frame: painted unless a newer frame is on the canvas, then closed. */
  output(videoFrame) {
    try {
      const frame = this.inDecoder.get(videoFrame.timestamp);
      for (const timestamp of this.inDecoder.keys()) {
        if (timestamp > videoFrame.timestamp) break;
        this.inDecoder.delete(timestamp);
      }
      this.decoded++;
      this.window.decoded++;
      if (!frame || !this.hooks.paintable(frame.frameId)) return;
      if (this.canvas.width !== frame.width || this.canvas.height !== frame.height) {
        this.canvas.width = frame.width;
        this.canvas.height = frame.height;
      }
      // the picture is coded with even sides (a frame of odd width or height has one more column or row)
      this.context.drawImage(videoFrame, 0, 0, frame.width, frame.height, 0, 0, frame.width, frame.height);
      this.painted++;
      this.hooks.onPainted(frame);
    } finally {
      videoFrame.close();
    }
  }

  /** The decoder failed (it is closed now): a loss; the next keyframe gets a new decoder. */
  fail(error) {
    if (this.decoder && this.decoder.state === "closed") this.close();
    this.lose();
    this.hooks.onError(error);
  }

  /** A frame is lost: decode nothing until the next keyframe, and ask for it (once per loss). */
  lose() {
    this.awaitingKeyframe = true;
    if (this.requested) return;
    this.requested = true;
    this.keyframeRequests++;
    this.hooks.requestKeyframe();
  }

  /**
   * The `stream_report` figures since the last call (at `now`, ms): bytes received and frames
   * decoded per second, frames in the decoder now, frames dropped in all, the newest frame id
   * received (null: none yet; the coordinator counts what it wrote after it as on its way).
   */
  report(now) {
    const seconds = this.window.start === null ? 0 : (now - this.window.start) / 1000;
    const figures = {
      bytes_per_s: seconds > 0 ? this.window.bytes / seconds : 0,
      decoded_fps: seconds > 0 ? this.window.decoded / seconds : 0,
      decode_queue: this.decoder && this.decoder.state !== "closed" ? this.decoder.decodeQueueSize : 0,
      frames_dropped: this.dropped,
      frame: this.received,
    };
    this.window = { start: now, bytes: 0, decoded: 0 };
    return figures;
  }
}
