"""glTF node animation (glTF 2.0 §3.11 Animations; Appendix C, Interpolation): the channels that
drive a node's translation, rotation or scale, sampled at a scene time (issue 11).

Pure: numpy only, no GL, no I/O. :func:`parse_animations` reads the animations of a
:class:`tessera.scene.gltf.GltfDocument` (keyframe times and values straight from the accessors);
:meth:`Animation.sample` gives, at time t seconds, each animated object's
:class:`tessera.scene.state.ObjectPatch`.

Interpolation, per sampler, with t_k ≤ t < t_k+1 and u = (t − t_k) / (t_k+1 − t_k):

* STEP: the value of keyframe k.
* LINEAR: (1 − u)·v_k + u·v_k+1; rotations by spherical linear interpolation along the shorter arc
  (Appendix C: a = arccos|d|, s = sign d, d = v_k·v_k+1; plain lerp, normalised, when a is tiny).
* CUBICSPLINE: each keyframe stores (in-tangent a_k, value v_k, out-tangent b_k); with
  Δ = t_k+1 − t_k, the cubic Hermite spline
  (2u³ − 3u² + 1)·v_k + Δ(u³ − 2u² + u)·b_k + (−2u³ + 3u²)·v_k+1 + Δ(u³ − u²)·a_k+1,
  rotations normalised afterwards.

Before the first keyframe and after the last, the value is clamped to that keyframe (§3.11: the
animation holds its ends). Several animations are all sampled at the same scene time; where two
channels drive the same property, the later one wins. Morph-target ``weights`` channels are not
node transforms and are skipped, as are channels whose node is not one of the scene's objects.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tessera.scene.gltf import GltfDocument, GltfError
from tessera.scene.state import ObjectPatch

INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")
#: Property → value components.
PATHS = {"translation": 3, "rotation": 4, "scale": 3}
#: Below this angle (rad) between two keyframe rotations, slerp falls back to a normalised lerp.
SLERP_EPSILON = 1e-6


class AnimationError(GltfError):
    """An animation that cannot be used: missing or mismatched accessors, bad times or values."""


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Unit quaternion (4,) [x, y, z, w] a fraction ``u`` of the shorter arc from ``q0`` to ``q1``
    (glTF Appendix C)."""
    d = float(np.dot(q0, q1))
    sign = -1.0 if d < 0.0 else 1.0
    angle = math.acos(min(abs(d), 1.0))
    if angle < SLERP_EPSILON:
        out = (1.0 - u) * q0 + u * sign * q1
        return out / np.linalg.norm(out)
    return (math.sin(angle * (1.0 - u)) * q0 + sign * math.sin(angle * u) * q1) / math.sin(angle)


@dataclass(frozen=True, eq=False)
class Sampler:
    """Keyframe ``times`` (K,) float64 seconds, non-decreasing, and ``values`` (K, C) float64 —
    (3K, C) for CUBICSPLINE, in (in-tangent, value, out-tangent) triples — interpolated by
    ``interpolation``; ``rotation`` values are unit quaternions [x, y, z, w]."""

    times: np.ndarray
    values: np.ndarray
    interpolation: str
    rotation: bool = False

    @property
    def cubic(self) -> bool:
        return self.interpolation == "CUBICSPLINE"

    def keyframe(self, k: int) -> np.ndarray:
        """Value (C,) of keyframe ``k``."""
        return self.values[3 * k + 1] if self.cubic else self.values[k]

    def sample(self, time: float) -> np.ndarray:
        """The value (C,) float64 at ``time`` seconds, clamped to the first and last keyframes."""
        times = self.times
        if not time > times[0]:
            return self.keyframe(0).copy()
        if time >= times[-1]:
            return self.keyframe(len(times) - 1).copy()
        k = int(np.searchsorted(times, time, side="right")) - 1
        span = float(times[k + 1] - times[k])
        u = (time - float(times[k])) / span
        if self.interpolation == "STEP":
            return self.keyframe(k).copy()
        v0, v1 = self.keyframe(k), self.keyframe(k + 1)
        if self.interpolation == "LINEAR":
            return slerp(v0, v1, u) if self.rotation else (1.0 - u) * v0 + u * v1
        out_tangent, in_tangent = self.values[3 * k + 2], self.values[3 * (k + 1)]
        u2, u3 = u * u, u * u * u
        value = ((2 * u3 - 3 * u2 + 1) * v0 + span * (u3 - 2 * u2 + u) * out_tangent
                 + (-2 * u3 + 3 * u2) * v1 + span * (u3 - u2) * in_tangent)
        return value / np.linalg.norm(value) if self.rotation else value


@dataclass(frozen=True, eq=False)
class Channel:
    """``sampler`` drives property ``path`` (translation, rotation or scale) of object ``target``."""

    target: str
    path: str
    sampler: Sampler


@dataclass(frozen=True, eq=False)
class Animation:
    """A named glTF animation: its channels, and its ``start``/``end`` keyframe times (s)."""

    name: str
    channels: tuple[Channel, ...]

    @property
    def start(self) -> float:
        return min(float(c.sampler.times[0]) for c in self.channels)

    @property
    def end(self) -> float:
        return max(float(c.sampler.times[-1]) for c in self.channels)

    def sample(self, time: float) -> dict[str, ObjectPatch]:
        """Each animated object's properties at ``time`` seconds."""
        return sample_animations([self], time)

    def to_json(self) -> dict[str, object]:
        """The summary: name, start and end (s), the objects it moves."""
        return {"name": self.name, "start": self.start, "end": self.end,
                "targets": sorted({c.target for c in self.channels})}

    def keyframes_json(self) -> dict[str, Any]:
        """Everything sampling needs, ``{"name", "channels": [{"target", "path", "interpolation",
        "times", "values"}]}``: what a node sends the coordinator (:meth:`from_keyframes_json`
        gives back the same numbers, bit for bit)."""
        return {"name": self.name, "channels": [
            {"target": c.target, "path": c.path, "interpolation": c.sampler.interpolation,
             "times": c.sampler.times.tolist(), "values": c.sampler.values.tolist()} for c in self.channels]}

    @classmethod
    def from_keyframes_json(cls, data: Mapping[str, Any]) -> Animation:
        """The animation :meth:`keyframes_json` describes, values kept as they are; raises
        AnimationError naming the channel and what is wrong."""
        name = str(data.get("name", ""))
        channels = []
        for index, channel in enumerate(data.get("channels") or []):
            where = f"animation {name!r} channel {index}"
            path, interpolation = channel.get("path"), channel.get("interpolation")
            if path not in PATHS:
                raise AnimationError(f"{where}: path {path!r}; expected one of {list(PATHS)}")
            if interpolation not in INTERPOLATIONS:
                raise AnimationError(f"{where}: interpolation {interpolation!r}; "
                                     f"expected one of {list(INTERPOLATIONS)}")
            try:
                times = np.asarray(channel.get("times"), dtype=np.float64)
                values = np.asarray(channel.get("values"), dtype=np.float64)
            except (TypeError, ValueError):
                raise AnimationError(f"{where}: times and values must be numbers") from None
            sampler = Sampler(times, values, str(interpolation), rotation=path == "rotation")
            _check_keyframes(sampler, str(path), where)
            channels.append(Channel(str(channel.get("target")), str(path), sampler))
        if not channels:
            raise AnimationError(f"animation {name!r} has no channel")
        return cls(name, tuple(channels))


def sample_animations(animations: Sequence[Animation], time: float) -> dict[str, ObjectPatch]:
    """Every animated object's properties at ``time`` seconds, over all ``animations``."""
    values: dict[str, dict[str, list[float]]] = {}
    for animation in animations:
        for channel in animation.channels:
            values.setdefault(channel.target, {})[channel.path] = channel.sampler.sample(time).tolist()
    return {name: ObjectPatch.from_json(fields, name) for name, fields in values.items()}


def parse_animations(document: GltfDocument, node_names: Mapping[int, str]) -> tuple[Animation, ...]:
    """The node TRS animations of ``document``, channels targeting ``node_names[node index]`` (the
    scene's object names; other nodes' channels are skipped). Animations left without a channel are
    dropped. Raises AnimationError naming the animation, channel or sampler."""
    out = []
    for number, spec in enumerate(document.json.get("animations", [])):
        name = str(spec.get("name") or f"animation{number}")
        samplers: dict[int, Sampler] = {}
        channels = []
        for index, channel in enumerate(spec.get("channels", [])):
            target = channel.get("target", {})
            path, node = target.get("path"), target.get("node")
            if path not in PATHS or node not in node_names:
                continue
            sampler_index = channel.get("sampler")
            where = f"animation {name!r} channel {index}"
            if not isinstance(sampler_index, int) or not 0 <= sampler_index < len(spec.get("samplers", [])):
                raise AnimationError(f"{where}: sampler {sampler_index!r} does not exist")
            sampler = samplers.get(sampler_index)
            if sampler is None:
                sampler = samplers[sampler_index] = _sampler(document, spec["samplers"][sampler_index], path,
                                                             f"animation {name!r} sampler {sampler_index}")
            channels.append(Channel(node_names[node], path, sampler))
        if channels:
            out.append(Animation(name, tuple(channels)))
    return tuple(out)


def _sampler(document: GltfDocument, spec: Mapping[str, object], path: str, where: str) -> Sampler:
    interpolation = spec.get("interpolation", "LINEAR")
    if interpolation not in INTERPOLATIONS:
        raise AnimationError(f"{where}: interpolation {interpolation!r}; expected one of {list(INTERPOLATIONS)}")
    try:
        times = document.accessor(spec.get("input"))
        values = document.accessor(spec.get("output"))
    except GltfError as exc:
        raise AnimationError(f"{where}: {exc}") from None
    if times.shape[1] != 1 or times.dtype != np.float64:
        raise AnimationError(f"{where}: input must be float SCALAR keyframe times")
    sampler = Sampler(times[:, 0], values.astype(np.float64), str(interpolation), rotation=path == "rotation")
    _check_keyframes(sampler, str(path), where)
    if path == "rotation" and interpolation != "CUBICSPLINE":   # slerp needs unit keyframes
        sampler = Sampler(sampler.times, sampler.values / np.linalg.norm(sampler.values, axis=1)[:, None],
                          sampler.interpolation, rotation=True)
    return sampler


def _check_keyframes(sampler: Sampler, path: str, where: str) -> None:
    """At least one keyframe; finite, non-decreasing times; as many finite values of ``path``'s
    components as the interpolation needs (3 per keyframe for CUBICSPLINE); no zero rotation keyframe."""
    times, values, components = sampler.times, sampler.values, PATHS[path]
    if times.ndim != 1 or len(times) == 0 or not np.isfinite(times).all() or (np.diff(times) < 0.0).any():
        raise AnimationError(f"{where}: keyframe times must be finite and increasing")
    expected = (3 if sampler.cubic else 1) * len(times)
    if values.ndim != 2 or values.shape != (expected, components):
        got = f"{values.shape[0]} of {values.shape[1]}" if values.ndim == 2 else f"shape {values.shape}"
        raise AnimationError(f"{where}: {path} output must be {expected} values of {components} components, got {got}")
    if not np.isfinite(values).all():
        raise AnimationError(f"{where}: output values must be finite")
    if sampler.rotation and (np.linalg.norm(values[1::3] if sampler.cubic else values, axis=1) == 0.0).any():
        raise AnimationError(f"{where}: a rotation keyframe is a zero quaternion")
