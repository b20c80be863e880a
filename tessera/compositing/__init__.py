"""Depth compositing: the layers nodes read back with depth and their merge into one frame."""
