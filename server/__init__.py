"""Tessera coordinator: partitions the screen, dispatches tiles to render nodes, gathers and
publishes complete frames, serves the viewer and the REST API."""
