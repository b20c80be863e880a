// Viewer frame format TFRM, mirroring tessera/wire/protocol.py (same constant names and layouts).
// Header `<4sBBHIIII`: magic, version, flags (bit 0 = FRAME_STILL, bits 1-7 = the samples of a
// progressive still's frame, 0 for a frame not accumulated), tile_count, frame_id, width,
// height, input_seq (the newest input sequence number of this viewer the frame accounts for, 0 = none).
// Tile entry `<IIIIBBHI`: x, y, w, h, codec, reserved, node (the rendering node's slot, NO_NODE_SLOT
// for none), length.
// Then the tiles' encoded bytes in table order. All integers little-endian.

export const PROTOCOL_VERSION = 2;
export const FRAME_MAGIC = "TFRM";
export const FRAME_HEADER_SIZE = 24;
export const FRAME_TILE_SIZE = 24;
/** Frame header flag: the lossless still frame shown once motion stopped. */
export const FRAME_STILL = 0x01;
/** Frame header flags bits 1-7: the samples a progressive still's frame holds (0: not accumulated). */
export const FRAME_SAMPLES_SHIFT = 1;
/** A tile entry's `node` when no one node rendered the tile (a sort-last frame merged by the
 * coordinator, or a node that has left since). */
export const NO_NODE_SLOT = 0xffff;

/** Tile codecs, as tessera.wire.codec.Codec. */
export const Codec = Object.freeze({ RAW: 0, JPEG: 1, PNG: 2 });
const CODECS = new Set(Object.values(Codec));

/** A frame message that does not follow the protocol; the message says what. */
export class ProtocolError extends Error {
  constructor(message) {
    super(message);
    this.name = "ProtocolError";
  }
}

/**
 * Parse one binary frame message.
 * @param {ArrayBuffer} buffer
 * @returns {{frameId: number, width: number, height: number, still: boolean, samples: number, inputSeq: number,
 *   tiles: {x: number, y: number, w: number, h: number, codec: number, node: number,
 *   bytes: Uint8Array}[]}} tile bytes are views into `buffer`, rects in pixels from the top-left
 */
export function parseFrame(buffer) {
  if (buffer.byteLength < FRAME_HEADER_SIZE) {
    throw new ProtocolError("frame message shorter than its header");
  }
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  const version = view.getUint8(4);
  if (magic !== FRAME_MAGIC || version !== PROTOCOL_VERSION) {
    throw new ProtocolError(`bad frame magic/version ${JSON.stringify(magic)}/${version}`);
  }
  const still = (view.getUint8(5) & FRAME_STILL) !== 0;
  const samples = view.getUint8(5) >> FRAME_SAMPLES_SHIFT;
  const count = view.getUint16(6, true);
  const frameId = view.getUint32(8, true);
  const width = view.getUint32(12, true);
  const height = view.getUint32(16, true);
  const inputSeq = view.getUint32(20, true);
  const tableEnd = FRAME_HEADER_SIZE + count * FRAME_TILE_SIZE;
  if (buffer.byteLength < tableEnd) {
    throw new ProtocolError("frame message shorter than its tile table");
  }
  const tiles = [];
  let offset = tableEnd;
  for (let i = 0; i < count; i++) {
    const at = FRAME_HEADER_SIZE + i * FRAME_TILE_SIZE;
    const length = view.getUint32(at + 20, true);
    if (offset + length > buffer.byteLength) {
      throw new ProtocolError("frame message length does not match its tile table");
    }
    const codec = view.getUint8(at + 16);
    if (!CODECS.has(codec)) {
      throw new ProtocolError(`unknown tile codec ${codec}`);
    }
    tiles.push({
      x: view.getUint32(at, true),
      y: view.getUint32(at + 4, true),
      w: view.getUint32(at + 8, true),
      h: view.getUint32(at + 12, true),
      codec,
      node: view.getUint16(at + 18, true),
      bytes: new Uint8Array(buffer, offset, length),
    });
    offset += length;
  }
  if (offset !== buffer.byteLength) {
    throw new ProtocolError("frame message length does not match its tile table");
  }
  return { frameId, width, height, still, samples, inputSeq, tiles };
}
