"""The hybrid culling switch (seed 001 Fig. 6.4, §6.2) driven by scripted CPU culling times."""

from __future__ import annotations

import pytest

from node.culling.switch import CullDevice, CullMode, CullState, HybridCullingSwitch, SwitchParams, resolve_culling

FAST = 1e-4   # below the seed's 3×10⁻⁴ s threshold
SLOW = 5e-4   # above it


def run(switch: HybridCullingSwitch, cpu_times: list[float]) -> tuple[HybridCullingSwitch, list[CullState]]:
    """Feed one frame per time; GPU frames are fed ``None`` whatever the script says."""
    states = []
    for cpu_time in cpu_times:
        switch = switch.step(None if switch.device is CullDevice.GPU else cpu_time)
        states.append(switch.state)
    return switch, states


def on_gpu(params: SwitchParams = SwitchParams()) -> HybridCullingSwitch:
    switch, states = run(HybridCullingSwitch.start(params), [SLOW] * params.frames_to_switch)
    assert states[-1] is CullState.GPU
    return switch


def test_seed_defaults():
    params = SwitchParams()
    assert (params.threshold_s, params.frames_to_switch, params.gpu_frames, params.check_frames,
            params.gpu_frames_growth) == (3e-4, 5, 500, 2, 2)
    switch = HybridCullingSwitch.start()
    assert switch.state is CullState.CPU and switch.device is CullDevice.CPU and switch.gpu_stint == 500


def test_stays_on_cpu_below_the_threshold():
    switch, states = run(HybridCullingSwitch.start(), [FAST, 3e-4, 0.0, FAST] * 50)
    assert set(states) == {CullState.CPU}
    assert switch.device is CullDevice.CPU


def test_switches_to_gpu_after_exactly_five_bottleneck_frames():
    _, states = run(HybridCullingSwitch.start(), [SLOW] * 5)
    assert states == [CullState.CPU_TO_GPU] * 4 + [CullState.GPU]
    switch, states = run(HybridCullingSwitch.start(), [SLOW] * 4)
    assert switch.device is CullDevice.CPU and states[-1] is CullState.CPU_TO_GPU


def test_an_interrupted_bottleneck_resets_the_count():
    switch, states = run(HybridCullingSwitch.start(), [SLOW] * 4 + [FAST] + [SLOW] * 4)
    assert states[4] is CullState.CPU
    assert switch.state is CullState.CPU_TO_GPU and switch.counter == 4
    switch, _ = run(switch, [SLOW])
    assert switch.state is CullState.GPU


def test_returns_to_cpu_check_after_500_gpu_frames():
    switch, states = run(on_gpu(), [SLOW] * 500)
    assert states[:499] == [CullState.GPU] * 499
    assert states[499] is CullState.GPU_TO_CPU and switch.device is CullDevice.CPU


def test_doubles_the_gpu_stint_when_the_bottleneck_reappears_within_two_frames():
    switch, _ = run(on_gpu(), [SLOW] * 500)
    switch, states = run(switch, [FAST, SLOW])
    assert states == [CullState.GPU_TO_CPU, CullState.GPU]
    assert switch.gpu_stint == 1000
    switch, states = run(switch, [SLOW] * 1000)
    assert states[:999] == [CullState.GPU] * 999 and states[999] is CullState.GPU_TO_CPU
    switch, states = run(switch, [SLOW])
    assert states == [CullState.GPU] and switch.gpu_stint == 2000


def test_stays_on_cpu_when_the_check_frames_are_clear():
    switch, _ = run(on_gpu(), [SLOW] * 500)
    switch, states = run(switch, [FAST, FAST, SLOW])
    assert states == [CullState.GPU_TO_CPU, CullState.CPU, CullState.CPU_TO_GPU]
    assert switch.gpu_stint == 500  # a new bottleneck episode starts from the seed's m again


def test_custom_parameters():
    params = SwitchParams(threshold_s=1e-3, frames_to_switch=2, gpu_frames=3, check_frames=1, gpu_frames_growth=3)
    switch, states = run(HybridCullingSwitch.start(params), [5e-4, 2e-3, 2e-3, 0, 0, 0, 2e-3])
    assert states == [CullState.CPU, CullState.CPU_TO_GPU, CullState.GPU, CullState.GPU, CullState.GPU,
                      CullState.GPU_TO_CPU, CullState.GPU]
    assert switch.gpu_stint == 9


def test_the_fed_frame_must_match_the_device():
    with pytest.raises(ValueError):
        HybridCullingSwitch.start().step(None)
    with pytest.raises(ValueError):
        on_gpu().step(SLOW)
    with pytest.raises(ValueError):
        SwitchParams(frames_to_switch=0)


@pytest.mark.parametrize("renderer,expected", [
    ("llvmpipe (LLVM 15.0.6, 256 bits)", CullMode.CPU),
    ("softpipe", CullMode.CPU),
    ("NVIDIA H100 80GB HBM3/PCIe/SSE2", CullMode.HYBRID),
    ("AMD Radeon RX 7900 XTX (radeonsi, navi31, LLVM 15.0.7, DRM 3.54)", CullMode.HYBRID),
])
def test_auto_culls_on_the_cpu_only_on_a_software_rasterizer(renderer, expected):
    assert resolve_culling(CullMode.AUTO, renderer) is expected
    for mode in (CullMode.OFF, CullMode.CPU, CullMode.GPU, CullMode.HYBRID):
        assert resolve_culling(mode, renderer) is mode
