// Video frame message TVID (issue 21), mirroring tessera/wire/video.py (same constant names).
// Header `<4sBBBBIIII`: magic, version (PROTOCOL_VERSION), flags (bit 0 = VIDEO_KEYFRAME: the
// decoder may start here), codec (VideoCodec), reserved, frame_id, width, height, input_seq (at
// offset 20, as in a TFRM frame). Then one access unit: H.264 in Annex B with SPS/PPS before every
// keyframe, VP9 as the encoder's packet. All integers little-endian.

import { PROTOCOL_VERSION, ProtocolError } from "./protocol.js";

export const VIDEO_MAGIC = "TVID";
export const VIDEO_KEYFRAME = 0x01;
export const VIDEO_HEADER_SIZE = 24;

/** A stream's codec, as tessera.wire.video.VideoCodec; its label (lower case) is what `stream_offer` names. */
export const VideoCodec = Object.freeze({ H264: 0, VP9: 1 });
const LABELS = new Map(Object.entries(VideoCodec).map(([name, value]) => [value, name.toLowerCase()]));

/** The codec's name in `stream_offer` and `stream` ("h264", "vp9"). */
export function codecLabel(codec) {
  const label = LABELS.get(codec);
  if (label === undefined) throw new ProtocolError(`unknown video codec ${codec}`);
  return label;
}

/** H.264 levels [level_idc, largest frame in 16×16 macroblocks, macroblocks per second], Table A-1. */
export const H264_LEVELS = [
  [30, 1620, 40500], [31, 3600, 108000], [32, 5120, 216000], [40, 8192, 245760], [42, 8704, 522240],
  [50, 22080, 589824], [51, 36864, 983040], [52, 36864, 2073600], [60, 139264, 4177920],
];
/** VP9 levels [level × 10, largest frame in pixels, pixels per second], the VP9 levels table. */
export const VP9_LEVELS = [
  [10, 36864, 829440], [11, 73728, 2764800], [20, 122880, 4608000], [21, 245760, 9216000],
  [30, 552960, 20736000], [31, 983040, 36864000], [40, 2228224, 83558400], [41, 2228224, 160432128],
  [50, 8912896, 311951360], [51, 8912896, 588251136], [52, 8912896, 1176502272], [60, 35651584, 1176502272],
  [61, 35651584, 2353004544],
];
/** The level named when no level of the table holds the size and rate. */
const BEYOND_LEVELS = 62;

/**
 * The WebCodecs codec string of `codec` (VideoCodec) for frames of `width`×`height` px at up to
 * `fps`: H.264 Main (`avc1.4d40LL`: CABAC), VP9 profile 0 8-bit (`vp09.00.LL.08`); the
 * level is the smallest that holds the size and rate (as tessera.wire.video.codec_string).
 */
export function codecString(codec, width, height, fps = 60) {
  if (codec === VideoCodec.H264) {
    const blocks = Math.ceil(width / 16) * Math.ceil(height / 16);
    const level = H264_LEVELS.find(([, frame, rate]) => blocks <= frame && blocks * fps <= rate)?.[0] ?? BEYOND_LEVELS;
    return `avc1.4d40${level.toString(16).padStart(2, "0")}`;
  }
  if (codec === VideoCodec.VP9) {
    const pixels = width * height;
    const level = VP9_LEVELS.find(([, frame, rate]) => pixels <= frame && pixels * fps <= rate)?.[0] ?? BEYOND_LEVELS;
    return `vp09.00.${String(level).padStart(2, "0")}.08`;
  }
  throw new ProtocolError(`unknown video codec ${codec}`);
}

/** The binary viewer message is a TVID video frame (not a TFRM frame of tiles). */
export function isVideo(buffer) {
  if (buffer.byteLength < 4) return false;
  return String.fromCharCode(...new Uint8Array(buffer, 0, 4)) === VIDEO_MAGIC;
}

/**
 * Parse one TVID message; ProtocolError on anything malformed.
 * @param {ArrayBuffer} buffer
 * @returns {{frameId: number, width: number, height: number, codec: number, keyframe: boolean,
 *   inputSeq: number, data: Uint8Array}} data: the access unit, a view into `buffer`
 */
export function parseVideo(buffer) {
  if (buffer.byteLength < VIDEO_HEADER_SIZE) throw new ProtocolError("video message shorter than its header");
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  const version = view.getUint8(4);
  if (magic !== VIDEO_MAGIC || version !== PROTOCOL_VERSION) {
    throw new ProtocolError(`bad video magic/version ${JSON.stringify(magic)}/${version}`);
  }
  const codec = view.getUint8(6);
  if (!LABELS.has(codec)) throw new ProtocolError(`unknown video codec ${codec}`);
  if (buffer.byteLength === VIDEO_HEADER_SIZE) throw new ProtocolError("video message without an access unit");
  return {
    frameId: view.getUint32(8, true),
    width: view.getUint32(12, true),
    height: view.getUint32(16, true),
    codec,
    keyframe: (view.getUint8(5) & VIDEO_KEYFRAME) !== 0,
    inputSeq: view.getUint32(20, true),
    data: new Uint8Array(buffer, VIDEO_HEADER_SIZE),
  };
}
