"""Tessera render node: loads a scene, renders assigned tiles on EGL, streams them to the coordinator."""
