"""A node keeps the prefiltered environment in its scene cache folder (start-up: read, not
convolved again); what it reads equals what it computes, and a file it cannot read is computed again."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from node.gl import image_lighting
from node.gl.image_lighting import PrefilteredEnvironment, keep_environments_in, prefiltered_environment


@pytest.fixture
def kept(tmp_path: Path) -> Iterator[Path]:
    keep_environments_in(tmp_path)
    yield tmp_path
    keep_environments_in(None)


def same(a: PrefilteredEnvironment, b: PrefilteredEnvironment) -> bool:
    return (len(a.levels) == len(b.levels)
            and all(np.array_equal(x, y) for x, y in zip(a.levels, b.levels, strict=True))
            and np.array_equal(a.sh, b.sh) and np.array_equal(a.lut, b.lut))


def test_the_studio_is_kept_read_back_equal_and_computed_again_when_unreadable(kept: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    computed = prefiltered_environment(None)
    files = list(kept.glob("environment-*.npz"))
    assert len(files) == 1
    image_lighting.prefiltered_environment.cache_clear()
    monkeypatch.setattr(image_lighting, "_prefilter", lambda *_: pytest.fail("computed, not read"))
    assert same(prefiltered_environment(None), computed)
    monkeypatch.undo()
    files[0].write_bytes(b"not an archive")
    image_lighting.prefiltered_environment.cache_clear()
    assert same(prefiltered_environment(None), computed)
    assert same(image_lighting._read_kept(files[0]), computed), "and kept again"


def test_an_environment_file_that_changes_is_prefiltered_again(kept: Path, tmp_path: Path) -> None:
    hdr = tmp_path / "sky.hdr"
    hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n" + bytes([128, 128, 128, 129]) * 8)
    first = image_lighting._kept_name(hdr)
    hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n" + bytes([64, 64, 64, 130]) * 8 + b"\n")
    assert image_lighting._kept_name(hdr) != first
