"""Tessera's shared core: the vocabulary, wire format, codecs and balancers both sides import.

Nothing here opens a socket, reads a clock or touches GL.
"""
