"""The wire: tile codecs, the binary frame format, the JSON message catalogue, the depth tile
format, and the per-socket message-rate limit."""
