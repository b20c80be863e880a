"""A session's levels-of-detail bound while its picture moves (issue 32): from ``floor_px`` (the
coordinator's ``--lod-error-px``) up to ``ceiling_px`` (``--lod-max-error-px``), raised when its
frames take longer than the target frame rate allows and lowered again when they are quick, so the
moving picture keeps to ``--target-fps`` where detail can be given up for it. Pure: frame times
come in, the bound goes out.

A frame's time is its slowest node's busy time (render, read back, encode, send of its tiles): the
frame's critical path, what the nodes need whatever the viewer's input rate (frames render on
demand, so the interval between frames says how fast the user moves, not how costly a frame is).
The bound moves by a factor of :data:`STEP` at most every :data:`HOLD` frames, and only outside a
band around the target (frames over :data:`SLOW` of the target interval raise it, under
:data:`QUICK` lower it): a picture that does not pump between two levels. Frames over :data:`FAR`
times the interval raise it by ``STEP²`` at every frame, without waiting :data:`HOLD` frames: a
model whose frames take seconds reaches the ceiling in two frames (it took six: 6 s of an 8 s
motion at 1 frame/s, drawn at finer bounds than the ceiling). Stills are always full
detail; the bound is kept for the next motion.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The bound a moving frame starts from, px (``--lod-error-px``); 0 turns levels of detail off.
#: Measured on the dragon, the Pan scan and the bunny, four cameras each, at 480x270 and 1280x720:
#: the moving frame's worst PSNR against full detail 39.6 dB at 0.5 px (7-27 % of the triangles
#: drawn), 37.0 dB at 0.75 px, 36.9 dB at 1 px. With normals counted in the levels' errors (levels
#: format 3), the Pan scan, four cameras at both sizes: worst 48.1 dB at 0.5 px, 42.7 dB at 1 px
#: (llvmpipe's pair); 39.5 and 36.9 dB with 4x MSAA, a GPU's (docs: benchmarks, Big models).
DEFAULT_LOD_ERROR_PX = 0.5
#: The most it is raised to, px (``--lod-max-error-px``): frame rate bought while the picture the user
#: gets changes little. The 24.8M-triangle model from ``bench.lod_cameras``' twelve cameras: 1.5 px is
#: 35.3 dB from the full-detail frame before the codec at the worst (near) camera, 0.75 px 38.6 dB;
#: after the interactive JPEG both are within 1.1 dB (32.0 / 33.1 dB), and 0.75 px costs a moving
#: frame 1.4-1.8 times the CPU (docs: benchmarks, Big models). ``--lod-max-error-px 0.75`` holds 38 dB.
DEFAULT_LOD_MAX_ERROR_PX = 1.5
#: The moving frame rate it aims at (``--target-fps``).
DEFAULT_TARGET_FPS = 15.0
#: Factor the bound moves by in one step.
STEP = 1.5
#: Frames between two steps.
HOLD = 3
#: Above this fraction of the target interval a frame is slow; below :data:`QUICK`, quick.
SLOW, QUICK = 1.1, 0.6
#: Above this many target intervals a frame is far too slow: the bound steps by ``STEP²``.
FAR = 3.0
#: Weight of a new frame in the smoothed frame time.
SMOOTHING = 0.35


@dataclass
class LodControl:
    """The bound of one session: ``floor_px`` … ``ceiling_px`` pixels (``floor_px`` 0: levels of
    detail off), aiming at ``target_fps`` frames a second."""

    floor_px: float
    ceiling_px: float
    target_fps: float
    bound_px: float = 0.0
    smoothed_s: float | None = None
    frames_since_step: int = 0

    def __post_init__(self) -> None:
        if not self.floor_px >= 0.0 or not self.ceiling_px >= 0.0 or not self.target_fps > 0.0:
            raise ValueError(f"need bounds >= 0 and a target > 0, got {self.floor_px}, {self.ceiling_px}, "
                             f"{self.target_fps}")
        self.ceiling_px = max(self.ceiling_px, self.floor_px)   # a floor above the ceiling lifts it
        self.bound_px = self.bound_px or self.floor_px

    @property
    def bound(self) -> float | None:
        """The bound a moving frame is drawn with now (None: full detail, levels off)."""
        return self.bound_px if self.floor_px > 0.0 else None

    def frame_done(self, busy_s: float) -> None:
        """An interactive frame took ``busy_s`` seconds of its slowest node."""
        if self.floor_px <= 0.0 or busy_s < 0.0:
            return
        self.smoothed_s = smoothed(self.smoothed_s, busy_s)
        self.frames_since_step += 1
        steps = pace_steps(self.smoothed_s, 1.0 / self.target_fps, self.frames_since_step,
                           self.bound_px < self.ceiling_px, self.bound_px > self.floor_px)
        if steps:
            self.bound_px = min(self.ceiling_px, max(self.floor_px, self.bound_px * STEP ** steps if steps > 0
                                                                   else self.bound_px / STEP))
            self.frames_since_step = 0


@dataclass
class FramePace:
    """The frame times of one loop aiming at ``target_fps``: the smoothed time (s) and the frames
    since its last step (:func:`pace_steps`)."""

    target_fps: float
    smoothed_s: float | None = None
    frames_since_step: int = 0

    def steps(self, busy_s: float, can_coarsen: bool, can_refine: bool) -> int:
        """A frame took ``busy_s`` seconds: the steps its loop takes now (:func:`pace_steps`)."""
        self.smoothed_s = smoothed(self.smoothed_s, busy_s)
        self.frames_since_step += 1
        steps = pace_steps(self.smoothed_s, 1.0 / self.target_fps, self.frames_since_step, can_coarsen, can_refine)
        if steps:
            self.frames_since_step = 0
        return steps


def smoothed(previous_s: float | None, busy_s: float) -> float:
    """The smoothed frame time (s) after a frame of ``busy_s`` (the first frame's own time)."""
    return busy_s if previous_s is None else (1.0 - SMOOTHING) * previous_s + SMOOTHING * busy_s


def pace_steps(smoothed_s: float, interval_s: float, frames_since_step: int, can_coarsen: bool,
               can_refine: bool) -> int:
    """How many factors of :data:`STEP` a moving picture's coarseness moves by after a frame (the
    module docstring's loop, shared by :class:`LodControl` and the point budget's
    :class:`tessera.scheduling.point_budget_control.PointBudgetControl`): 2 when the smoothed frame
    time ``smoothed_s`` is over :data:`FAR` target intervals ``interval_s`` (any frame), 1 over
    :data:`SLOW`, −1 under :data:`QUICK` (each :data:`HOLD` frames after the last step at the
    soonest), 0 inside the band or where the coarseness cannot move that way (``can_coarsen``,
    ``can_refine``)."""
    far = smoothed_s > FAR * interval_s and can_coarsen
    if frames_since_step < HOLD and not far:
        return 0
    if smoothed_s > SLOW * interval_s and can_coarsen:
        return 2 if far else 1
    if smoothed_s < QUICK * interval_s and can_refine:
        return -1
    return 0
