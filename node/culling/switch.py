"""The CPU↔GPU frustum-culling switch of seed 001 §6.1.1–6.2 (Fig. 6.4), as a pure state machine.

It reads no clock: after every frame it is told how long the CPU cull took (seconds), or that the
GPU culled that frame, and it answers which device culls the next frame. A *bottleneck* frame is
one whose CPU cull took longer than ``threshold_s`` (the seed's best heuristic of four; 3×10⁻⁴ s).

Transitions (n = ``frames_to_switch``, m = current GPU stint, ``check_frames`` = 2):

- CPU → CPU: no bottleneck.  CPU → CPU_TO_GPU: a bottleneck frame (it counts as the first of n).
- CPU_TO_GPU → CPU: a frame without bottleneck (the count is reset).
  CPU_TO_GPU → GPU: the n-th consecutive bottleneck frame; the GPU culls from the next frame on.
- GPU → GPU: fewer than m frames culled on the GPU.  GPU → GPU_TO_CPU: the m-th GPU frame; the
  CPU culls the next frame again.
- GPU_TO_CPU → GPU: a bottleneck within the first ``check_frames`` CPU frames; m is multiplied
  by ``gpu_frames_growth`` (doubled) and the GPU resumes at once.
  GPU_TO_CPU → CPU: ``check_frames`` frames without bottleneck.

Interpretations: the seed's Fig. 6.4 says m is "incremented", its §6.2 says "doubled": doubled here
(factor configurable). The seed does not say what m is after the CPU has kept control; here it
returns to its initial value when GPU_TO_CPU hands back to CPU, so the next bottleneck episode
starts again with m = ``gpu_frames``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace


class CullMode(enum.Enum):
    """A node's ``--culling``: none, always on the CPU, always on the GPU, this switch, or ``auto``:
    the switch on a hardware GPU, the CPU on a software rasterizer (:func:`resolve_culling`)."""

    OFF = "off"
    CPU = "cpu"
    GPU = "gpu"
    HYBRID = "hybrid"
    AUTO = "auto"


#: GL_RENDERER names of rasterizers that run on the CPU (Mesa's llvmpipe, softpipe, swrast)
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast")


def resolve_culling(mode: CullMode, gl_renderer: str) -> CullMode:
    """The mode that runs for ``mode`` on the GL renderer named ``gl_renderer``: ``auto`` is
    ``cpu`` on a software rasterizer — its "GPU" culling is compute shaders on the same CPU cores,
    so handing culling over cannot relieve the CPU, which is the seed's premise, and it measured
    slower (docs/explanation/culling.md) — and ``hybrid`` otherwise; other modes are themselves."""
    if mode is not CullMode.AUTO:
        return mode
    software = any(name in gl_renderer.lower() for name in SOFTWARE_RENDERERS)
    return CullMode.CPU if software else CullMode.HYBRID


class CullDevice(enum.Enum):
    """Which processor culls a frame."""

    CPU = "cpu"
    GPU = "gpu"


class CullState(enum.Enum):
    """The four states of seed 001 Fig. 6.4."""

    CPU = "cpu"
    CPU_TO_GPU = "cpu_to_gpu"
    GPU = "gpu"
    GPU_TO_CPU = "gpu_to_cpu"

    @property
    def device(self) -> CullDevice:
        return CullDevice.GPU if self is CullState.GPU else CullDevice.CPU


@dataclass(frozen=True, slots=True)
class SwitchParams:
    """Seed 001 §6.2's values: bottleneck above 0.3 ms of CPU culling, 5 frames to switch,
    500 frames on the GPU, 2 frames to check, stint doubled."""

    threshold_s: float = 3e-4
    frames_to_switch: int = 5
    gpu_frames: int = 500
    check_frames: int = 2
    gpu_frames_growth: int = 2

    def __post_init__(self) -> None:
        if self.threshold_s <= 0.0:
            raise ValueError(f"threshold_s must be > 0, got {self.threshold_s}")
        if min(self.frames_to_switch, self.gpu_frames, self.check_frames, self.gpu_frames_growth) < 1:
            raise ValueError(f"frame counts and growth must be ≥ 1: {self}")


@dataclass(frozen=True, slots=True)
class HybridCullingSwitch:
    """Immutable switch state: ``state``, ``counter`` (frames counted in it), ``gpu_stint`` (m).

    Start with ``HybridCullingSwitch.start()``; after each frame call :meth:`step`.
    """

    params: SwitchParams
    state: CullState
    counter: int
    gpu_stint: int

    @classmethod
    def start(cls, params: SwitchParams = SwitchParams()) -> HybridCullingSwitch:
        return cls(params, CullState.CPU, 0, params.gpu_frames)

    @property
    def device(self) -> CullDevice:
        """The device that culls the next frame."""
        return self.state.device

    def step(self, cpu_cull_s: float | None) -> HybridCullingSwitch:
        """The switch after one frame: ``cpu_cull_s`` is the CPU culling time of that frame in
        seconds, or ``None`` when the GPU culled it (it must match :attr:`device`)."""
        if (cpu_cull_s is None) != (self.device is CullDevice.GPU):
            raise ValueError(f"the {self.device.value.upper()} culled this frame (state {self.state.name}), "
                             f"got cpu_cull_s={cpu_cull_s!r}")
        p = self.params
        if self.state is CullState.GPU:
            if self.counter + 1 >= self.gpu_stint:
                return replace(self, state=CullState.GPU_TO_CPU, counter=0)
            return replace(self, counter=self.counter + 1)
        assert cpu_cull_s is not None
        bottleneck = cpu_cull_s > p.threshold_s
        if self.state is CullState.GPU_TO_CPU:
            if bottleneck:
                return replace(self, state=CullState.GPU, counter=0,
                               gpu_stint=self.gpu_stint * p.gpu_frames_growth)
            if self.counter + 1 >= p.check_frames:
                return replace(self, state=CullState.CPU, counter=0, gpu_stint=p.gpu_frames)
            return replace(self, counter=self.counter + 1)
        if not bottleneck:
            return replace(self, state=CullState.CPU, counter=0)
        if self.counter + 1 >= p.frames_to_switch:
            return replace(self, state=CullState.GPU, counter=0)
        return replace(self, state=CullState.CPU_TO_GPU, counter=self.counter + 1)
