"""Image-based lighting for the glTF metallic-roughness BRDF (split-sum, Karis 2013), computed with
numpy at start-up and cached per process, then uploaded per renderer:

- prefiltered specular: an equirectangular mip chain, level k convolved with the GGX lobe of
  perceptual roughness k / (LEVELS − 1) (n = v = r, weights D(h)·(n·l)·dω summed exactly over the
  texels of the environment at 64x32; level 0 is the environment itself at 256x128, a mirror);
- diffuse irradiance: the environment's 9 spherical-harmonic coefficients convolved with the
  cosine lobe (Ramamoorthi & Hanrahan 2001), divided by π, handed to the shaders as the quadratic
  polynomial in n they make (:func:`irradiance_polynomial`), evaluated per vertex;
- the split-sum BRDF table: (n·v, roughness) → (A, B), the scale and bias of F0, by GGX
  importance sampling with the height-correlated Smith visibility of the glTF spec (Appendix B).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import moderngl
import numpy as np

from node.gl import environment as environment_module
from node.gl.environment import directions, read_hdr, solid_angles, studio_environment

#: Mip levels of the prefiltered specular map (256x128 … 8x4); level k is roughness k / (LEVELS − 1).
LEVELS = 6
#: Height of the prefiltered map's level 0, texels.
BASE_HEIGHT = 128
#: The BRDF table's side (n·v and roughness samples) and its importance samples per entry.
LUT_SIZE, LUT_SAMPLES = 32, 256
#: Cosine-lobe convolution of the SH bands 0, 1, 2, divided by π.
SH_BAND_SCALE = (1.0, 2.0 / 3.0, 1.0 / 4.0)
#: Output rows convolved at once (bounds the weight matrix's memory).
ROWS_PER_PASS = 1024
#: The real SH basis' constants: Y_00, Y_1m, Y_2-2/Y_2-1/Y_21, Y_20 (× (3z² − 1)), Y_22 (× (x² − y²)).
SH_Y00, SH_Y1, SH_Y2, SH_Y20, SH_Y22 = 0.282095, 0.488603, 1.092548, 0.315392, 0.546274


@dataclass(frozen=True, eq=False)
class PrefilteredEnvironment:
    """``levels``: LEVELS arrays (h_k, 2h_k, 3) float32, h_k = BASE_HEIGHT >> k; ``sh`` (9, 3)
    float32 irradiance coefficients (already × band scale, for :func:`sh_basis`); ``lut``
    (LUT_SIZE, LUT_SIZE, 2) float32, row j roughness (j + ½)/LUT_SIZE, column i n·v likewise;
    ``prefilter_ms`` the time it took."""

    levels: tuple[np.ndarray, ...]
    sh: np.ndarray
    lut: np.ndarray
    prefilter_ms: float


def resample(image: np.ndarray, height: int) -> np.ndarray:
    """(h, 2h, 3) equirectangular ``image`` to (height, 2·height, 3): box-averaged when h is a
    multiple of ``height``, nearest texel otherwise."""
    source = image.shape[0]
    if source % height == 0:
        factor = source // height
        return image.reshape(height, factor, 2 * height, factor, 3).mean(axis=(1, 3), dtype=np.float64).astype(
            np.float32)
    rows = np.minimum(((np.arange(height) + 0.5) * source / height).astype(int), source - 1)
    columns = np.minimum(((np.arange(2 * height) + 0.5) * 2 * source / (2 * height)).astype(int), 2 * source - 1)
    return np.ascontiguousarray(image[rows][:, columns])


def ggx_convolve(source: np.ndarray, height: int, roughness: float) -> np.ndarray:
    """(height, 2·height, 3) float32: ``source`` (h, 2h, 3) convolved with the GGX lobe of perceptual
    ``roughness`` around each output direction (D(n·h)·(n·l)·dω weights, normalised)."""
    alpha2 = roughness ** 4
    to = directions(height).reshape(-1, 3).astype(np.float32)
    src = directions(source.shape[0]).reshape(-1, 3).astype(np.float32)
    weights_base = solid_angles(source.shape[0]).reshape(-1).astype(np.float32)
    radiance = source.reshape(-1, 3).astype(np.float32)
    alpha2 = np.float32(alpha2)
    out = np.empty((len(to), 3), np.float32)
    for start in range(0, len(to), ROWS_PER_PASS):
        cosine = to[start:start + ROWS_PER_PASS] @ src.T
        denominator = (cosine + 1.0) * ((alpha2 - 1.0) * 0.5) + 1.0
        np.multiply(denominator, denominator, out=denominator)
        weights = np.maximum(cosine, 0.0, out=cosine)
        weights *= weights_base
        weights /= denominator
        out[start:start + ROWS_PER_PASS] = (weights @ radiance) / weights.sum(axis=1, keepdims=True)
    return out.reshape(height, 2 * height, 3)


def sh_basis(d: np.ndarray) -> np.ndarray:
    """(..., 9) real SH basis Y_00, Y_1-1, Y_10, Y_11, Y_2-2, Y_2-1, Y_20, Y_21, Y_22 of unit
    directions ``d`` (..., 3) (the shader evaluates the same polynomial)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.full_like(x, SH_Y00), SH_Y1 * y, SH_Y1 * z, SH_Y1 * x, SH_Y2 * x * y, SH_Y2 * y * z,
                     SH_Y20 * (3.0 * z * z - 1.0), SH_Y2 * x * z, SH_Y22 * (x * x - y * y)], axis=-1)


def irradiance_polynomial(sh: np.ndarray) -> np.ndarray:
    """(9, 3) float32 k with Σ c_i·Y_i(n) = k_0 + k_1·y + k_2·z + k_3·x + k_4·xy + k_5·yz + k_6·z² +
    k_7·xz + k_8·(x² − y²) for unit n = (x, y, z) and the (9, 3) coefficients ``sh`` (the basis'
    constants folded in: what :data:`node.gl.shading.IRRADIANCE` evaluates)."""
    c = sh.astype(np.float64)
    k = c * np.array([SH_Y00, SH_Y1, SH_Y1, SH_Y1, SH_Y2, SH_Y2, 3.0 * SH_Y20, SH_Y2, SH_Y22])[:, None]
    k[0] -= SH_Y20 * c[6]
    return k.astype(np.float32)


def irradiance_sh(image: np.ndarray) -> np.ndarray:
    """(9, 3) float32 coefficients c with Σ c_i·Y_i(n) = E(n)/π for the (h, 2h, 3) ``image``."""
    basis = sh_basis(directions(image.shape[0])) * solid_angles(image.shape[0])[..., None]
    coefficients = np.einsum("hwk,hwc->kc", basis, image.astype(np.float64))
    bands = np.array([SH_BAND_SCALE[0]] + [SH_BAND_SCALE[1]] * 3 + [SH_BAND_SCALE[2]] * 5)
    return (coefficients * bands[:, None]).astype(np.float32)


def brdf_lut(size: int = LUT_SIZE, samples: int = LUT_SAMPLES) -> np.ndarray:
    """(size, size, 2) float32 split-sum table: row = roughness, column = n·v, (A, B) with the
    specular integral = F0·A + B (GGX, height-correlated Smith visibility, Schlick Fresnel)."""
    grid = (np.arange(size) + 0.5) / size
    n_dot_v = grid[None, :, None]
    alpha = (grid ** 2)[:, None, None]
    index = np.arange(samples)
    bits = index.astype(np.uint32)
    bits = ((bits << 16) | (bits >> 16)) & 0xFFFFFFFF
    bits = ((bits & 0x55555555) << 1) | ((bits & 0xAAAAAAAA) >> 1)
    bits = ((bits & 0x33333333) << 2) | ((bits & 0xCCCCCCCC) >> 2)
    bits = ((bits & 0x0F0F0F0F) << 4) | ((bits & 0xF0F0F0F0) >> 4)
    bits = ((bits & 0x00FF00FF) << 8) | ((bits & 0xFF00FF00) >> 8)
    u1, u2 = (index + 0.5) / samples, bits.astype(np.float64) / 2.0 ** 32
    phi = 2.0 * np.pi * u1
    cos_h = np.sqrt((1.0 - u2) / (1.0 + (alpha * alpha - 1.0) * u2))
    sin_h = np.sqrt(1.0 - cos_h * cos_h)
    h = np.stack(np.broadcast_arrays(sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h), axis=-1)
    v = np.stack(np.broadcast_arrays(np.sqrt(1.0 - n_dot_v * n_dot_v), 0.0 * n_dot_v, n_dot_v), axis=-1)
    v_dot_h = np.sum(v * h, axis=-1)
    n_dot_l = 2.0 * v_dot_h * h[..., 2] - n_dot_v
    a2 = alpha * alpha
    lit = n_dot_l > 0.0
    nl = np.maximum(n_dot_l, 1e-8)
    visibility = 0.5 / (nl * np.sqrt(n_dot_v ** 2 * (1.0 - a2) + a2) + n_dot_v * np.sqrt(nl ** 2 * (1.0 - a2) + a2))
    g_vis = np.where(lit, visibility * 4.0 * nl * np.maximum(v_dot_h, 0.0) / cos_h, 0.0)
    fresnel = (1.0 - np.maximum(v_dot_h, 0.0)) ** 5
    return np.stack([((1.0 - fresnel) * g_vis).mean(axis=-1), (fresnel * g_vis).mean(axis=-1)], axis=-1).astype(
        np.float32)


#: Where prefiltered environments are kept across runs (:func:`keep_environments_in`); empty: nowhere.
_KEPT_IN: list[Path] = []


def keep_environments_in(folder: Path | None) -> None:
    """Keep the environments this process prefilters in ``folder`` (the node's scene cache folder;
    None: nowhere), and read them from there: a node's start-up then skips the 0.7 s of the
    studio's convolution. A file is named by the digest of this code, of the environment file (its
    path, size and time) and of numpy's version, so a change of any of them computes it again; one
    that cannot be read is computed again."""
    _KEPT_IN[:] = [] if folder is None else [folder]
    prefiltered_environment.cache_clear()


def _kept_name(path: Path | None) -> str:
    digest = hashlib.sha256(np.__version__.encode())
    for module in (__file__, environment_module.__file__):
        digest.update(Path(module).read_bytes())
    if path is not None:
        status = path.stat()
        digest.update(f"{path.resolve()}|{status.st_size}|{status.st_mtime_ns}".encode())
    return f"environment-{digest.hexdigest()[:32]}.npz"


def _read_kept(file: Path) -> PrefilteredEnvironment | None:
    try:
        with np.load(file) as arrays:
            levels = tuple(np.array(arrays[f"level{k}"], np.float32) for k in range(LEVELS))
            sh, lut = np.array(arrays["sh"], np.float32), np.array(arrays["lut"], np.float32)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    shapes_good = all(level.shape == (BASE_HEIGHT >> k, 2 * (BASE_HEIGHT >> k), 3) for k, level in enumerate(levels))
    return PrefilteredEnvironment(levels, sh, lut, 0.0) if shapes_good and sh.shape == (9, 3) else None


def _keep(file: Path, lighting: PrefilteredEnvironment) -> None:
    with contextlib.suppress(OSError):
        file.parent.mkdir(parents=True, exist_ok=True)
        partial = file.with_name(f"{file.name}.{os.getpid()}.part")
        with partial.open("wb") as out:
            np.savez(out, sh=lighting.sh, lut=lighting.lut, **{f"level{k}": a for k, a in enumerate(lighting.levels)})
        os.replace(partial, file)


@functools.lru_cache(maxsize=4)
def prefiltered_environment(path: Path | None) -> PrefilteredEnvironment:
    """The lighting of the environment in ``path`` (a Radiance .hdr; None: the studio), computed
    once per process, or read where :func:`keep_environments_in` keeps it. Raises
    :class:`node.gl.environment.EnvironmentError`."""
    started = time.perf_counter()
    kept = None
    with contextlib.suppress(OSError):
        kept = _KEPT_IN[0] / _kept_name(path) if _KEPT_IN else None
    found = None if kept is None else _read_kept(kept)
    if found is not None:
        return dataclasses.replace(found, prefilter_ms=(time.perf_counter() - started) * 1e3)
    lighting = _prefilter(path, started)
    if kept is not None:
        _keep(kept, lighting)
    return lighting


def _prefilter(path: Path | None, started: float) -> PrefilteredEnvironment:
    image = studio_environment() if path is None else read_hdr(path)
    base = resample(image, BASE_HEIGHT)
    coarse = resample(base, BASE_HEIGHT // 4)
    levels = [base]
    for level in range(1, LEVELS):
        levels.append(ggx_convolve(coarse, BASE_HEIGHT >> level, level / (LEVELS - 1)))
    sh = irradiance_sh(coarse)
    lut = brdf_lut()
    return PrefilteredEnvironment(tuple(levels), sh, lut, (time.perf_counter() - started) * 1e3)


def half_rgba(image: np.ndarray) -> bytes:
    """(h, w, 3) float radiance as RGBA half floats (alpha 1), the specular map's texel format."""
    rgba = np.concatenate([image, np.ones((*image.shape[:2], 1), image.dtype)], axis=2)
    return np.ascontiguousarray(rgba, np.float16).tobytes()


class ImageLighting:
    """The GL textures of a :class:`PrefilteredEnvironment` on ``ctx``: the specular mip chain (RGBA
    half floats: llvmpipe samples them faster than RGB float32, to 3 significant digits) and the
    BRDF table; :meth:`use` binds them and sets the irradiance polynomial."""

    def __init__(self, ctx: moderngl.Context, lighting: PrefilteredEnvironment) -> None:
        self.lighting = lighting
        self.polynomial = irradiance_polynomial(lighting.sh)
        base = lighting.levels[0]
        self.specular = ctx.texture((base.shape[1], base.shape[0]), 4, half_rgba(base), dtype="f2")
        self.specular.build_mipmaps(0, LEVELS - 1)
        for level, image in enumerate(lighting.levels[1:], start=1):
            self.specular.write(half_rgba(image), level=level)
        self.specular.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.specular.repeat_y = False
        self.lut = ctx.texture((LUT_SIZE, LUT_SIZE), 2, lighting.lut.tobytes(), dtype="f4")
        self.lut.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.lut.repeat_x = self.lut.repeat_y = False

    def use(self, program: moderngl.Program, specular_unit: int, lut_unit: int) -> None:
        """Bind the textures to the units and set ``u_sh`` (the irradiance polynomial) and
        ``u_specular_levels`` of ``program``."""
        self.specular.use(specular_unit)
        self.lut.use(lut_unit)
        program["u_sh"].write(self.polynomial.tobytes())
        program["u_specular_levels"].value = float(LEVELS - 1)

    def release(self) -> None:
        self.specular.release()
        self.lut.release()
