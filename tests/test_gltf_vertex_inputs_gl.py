"""What trimesh drops of a glTF file's textured primitives, read and drawn (issue 20): TANGENTs
under a normal map (their handedness flips it), a texture's ``texCoord`` and its
``KHR_texture_transform``; on generated files, a quad facing the camera."""

from __future__ import annotations

import base64
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from node.gl.renderer import TileRenderer
from node.gl.shading import ShaderVariant, ShadingOptions
from node.scene.loading import load_scene
from node.scene.material import UvTransform, texture_uv_transform
from tessera.geometry import Camera

CAMERA = Camera(eye=(0.0, 0.0, 2.2), target=(0.0, 0.0, 0.0), fovy_deg=50.0, near=0.1, far=10.0)
SIZE = (96, 96)
#: The quad's corners (x, y) and their glTF uvs (origin at the image's top left).
CORNERS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32)
UVS = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
#: A 64x64 image of four quadrants: top left red, top right green, bottom left blue, bottom right white.
QUADRANTS = {"red": (0, 0), "green": (0, 1), "blue": (1, 0), "white": (1, 1)}
COLOURS = {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255), "white": (255, 255, 255)}


def png_uri(pixels: np.ndarray) -> str:
    data = io.BytesIO()
    Image.fromarray(pixels).save(data, format="PNG")
    return "data:image/png;base64," + base64.b64encode(data.getvalue()).decode()


def quadrant_image() -> np.ndarray:
    image = np.zeros((64, 64, 3), np.uint8)
    for name, (row, column) in QUADRANTS.items():
        image[row * 32:(row + 1) * 32, column * 32:(column + 1) * 32] = COLOURS[name]
    return image


def write_quad(path: Path, material: dict[str, Any], image: np.ndarray, tangents: np.ndarray | None = None,
               uvs1: np.ndarray | None = None) -> Path:
    """A glTF file of one quad in the z = 0 plane facing +z, uvs 0…1, with ``material`` (its
    textures all ``image``) and optional TANGENT (4, 4) and TEXCOORD_1 (4, 2) attributes."""
    arrays = {"POSITION": np.concatenate([CORNERS, np.zeros((4, 1), np.float32)], axis=1),
              "NORMAL": np.tile(np.array([0, 0, 1], np.float32), (4, 1)), "TEXCOORD_0": UVS}
    if tangents is not None:
        arrays["TANGENT"] = tangents.astype(np.float32)
    if uvs1 is not None:
        arrays["TEXCOORD_1"] = uvs1.astype(np.float32)
    blob, views, accessors, attributes = b"", [], [], {}
    kinds = {2: "VEC2", 3: "VEC3", 4: "VEC4"}
    for name, values in arrays.items():
        attributes[name] = len(accessors)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": values.nbytes})
        accessor = {"bufferView": len(views) - 1, "componentType": 5126, "count": 4, "type": kinds[values.shape[1]]}
        if name == "POSITION":
            accessor |= {"min": [-1, -1, 0], "max": [1, 1, 0]}
        accessors.append(accessor)
        blob += values.tobytes()
    indices = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": indices.nbytes})
    accessors.append({"bufferView": len(views) - 1, "componentType": 5123, "count": 6, "type": "SCALAR"})
    blob += indices.tobytes()
    document = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": "quad"}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": len(accessors) - 1, "material": 0}]}],
        "materials": [{"name": "quad", **material}], "textures": [{"source": 0}], "images": [{"uri": png_uri(image)}],
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(blob).decode()}],
        "bufferViews": views, "accessors": accessors}
    path.write_text(json.dumps(document))
    return path


def render(ctx, path: Path, key_light: float = 1.5) -> np.ndarray:
    renderer = TileRenderer(ctx, load_scene(str(path)), (0.0, 0.0, 0.0),
                            shading=ShadingOptions(msaa=1, key_light=key_light))
    try:
        return renderer.render_frame(CAMERA, SIZE).pixels
    finally:
        renderer.release()


def tilted_normal_map() -> np.ndarray:
    """A flat normal map tilted towards the tangent frame's +y (the bitangent) by about 45°."""
    return np.tile(np.array([128, 218, 218], np.uint8), (16, 16, 1))


def with_tangents(xyz: tuple[float, float, float], w: float) -> np.ndarray:
    return np.tile(np.array([*xyz, w], np.float32), (4, 1))


@pytest.mark.gl
def test_the_files_tangents_frame_the_normal_map_and_their_handedness_flips_it(ctx, tmp_path):
    """A normal map tilted towards +bitangent: with the file's tangents along +x (w = 1) it shades as
    the frame derived from the uvs (also +x, +y); w = −1 turns the tilt towards −y, and tangents
    along +y (bitangent −x) towards −x: both clearly differ."""
    material = {"pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.6, 0.6, 1.0], "metallicFactor": 0.0,
                                         "roughnessFactor": 0.5}, "normalTexture": {"index": 0}}
    image = tilted_normal_map()
    derived = write_quad(tmp_path / "derived.gltf", material, image)
    right = write_quad(tmp_path / "right.gltf", material, image, with_tangents((1, 0, 0), 1.0))
    flipped = write_quad(tmp_path / "flipped.gltf", material, image, with_tangents((1, 0, 0), -1.0))
    turned = write_quad(tmp_path / "turned.gltf", material, image, with_tangents((0, 1, 0), 1.0))
    (batch,) = load_scene(str(flipped)).batches
    assert batch.tangents is not None and np.allclose(batch.tangents, [[1, 0, 0, -1]] * 4)
    assert ShaderVariant.of(batch) == ShaderVariant(normal_map=True, tangents=True)
    assert load_scene(str(derived)).batches[0].tangents is None
    pictures = {name: render(ctx, path).astype(int) for name, path in
                (("derived", derived), ("right", right), ("flipped", flipped), ("turned", turned))}
    inside = pictures["derived"][24:72, 24:72]
    assert inside.min() > 0, "the quad fills the middle of the frame"
    assert np.abs(pictures["right"] - pictures["derived"]).max() <= 2
    for name in ("flipped", "turned"):
        assert np.abs(pictures[name][24:72, 24:72] - inside).mean() > 8, name


def quadrant_colours(pixels: np.ndarray) -> list[str]:
    """The colour names seen in the rendered quad's top left, top right, bottom left and bottom
    right corners (rows 0 at the top)."""
    names = []
    for rows, columns in ((slice(26, 34), slice(26, 34)), (slice(26, 34), slice(62, 70)),
                          (slice(62, 70), slice(26, 34)), (slice(62, 70), slice(62, 70))):
        mean = pixels[rows, columns].reshape(-1, 3).astype(float).mean(axis=0)
        names.append("white" if mean.min() > 0.6 * mean.max() else ("red", "green", "blue")[int(np.argmax(mean))])
    return names


@pytest.mark.gl
def test_texture_transforms_and_a_second_uv_set_move_the_base_colour_texture(ctx, tmp_path):
    """The four-quadrant image: as it is; rotated by π/2 (the image turns clockwise on the quad); the
    extension's example selecting its lower-left quadrant (blue everywhere); and read through a
    TEXCOORD_1 that mirrors u (texCoord overridden by the extension)."""
    def material(extension: dict[str, Any] | None = None, tex_coord: int | None = None) -> dict[str, Any]:
        info: dict[str, Any] = {"index": 0}
        if extension is not None:
            info["extensions"] = {"KHR_texture_transform": extension}
        if tex_coord is not None:
            info["texCoord"] = tex_coord
        return {"pbrMetallicRoughness": {"baseColorTexture": info, "metallicFactor": 0.0, "roughnessFactor": 1.0}}

    image = quadrant_image()
    mirrored = UVS * np.array([-1, 1], np.float32) + np.array([1, 0], np.float32)
    cases = {
        "plain": (material(), ["red", "green", "blue", "white"]),
        "rotated": (material({"rotation": math.pi / 2}), ["blue", "red", "white", "green"]),
        "quadrant": (material({"offset": [0, 1], "rotation": math.pi / 2, "scale": [0.5, 0.5]}), ["blue"] * 4),
        "second set": (material({"texCoord": 1}, tex_coord=0), ["green", "red", "white", "blue"]),
    }
    for name, (case, expected) in cases.items():
        path = write_quad(tmp_path / f"{name}.gltf", case, image, uvs1=mirrored)
        (batch,) = load_scene(str(path)).batches
        assert (batch.uvs1 is not None) == (name == "second set"), name
        assert quadrant_colours(render(ctx, path, key_light=0.0)) == expected, name


def test_a_textures_uv_transform_follows_its_texcoord_and_extension():
    assert texture_uv_transform({"index": 0}) == UvTransform() and UvTransform().identity
    assert texture_uv_transform({"index": 0, "texCoord": 1}).uv_set == 1
    assert texture_uv_transform({"index": 0, "texCoord": 3}).uv_set == 0, "only two sets are read"
    assert texture_uv_transform({"texCoord": 1, "extensions": {"KHR_texture_transform": {"texCoord": 0}}}).uv_set == 0
    odd = {"extensions": {"KHR_texture_transform": {"offset": "far", "rotation": None, "scale": [1, "x"]}}}
    assert texture_uv_transform(odd) == UvTransform()
    # Offset (0.25, 0) and scale (2, 1) in glTF's space: the renderer's u' = 2u + 0.25, v' = v.
    shifted = texture_uv_transform({"extensions": {"KHR_texture_transform": {"offset": [0.25, 0], "scale": [2, 1]}}})
    assert np.allclose(shifted.matrix, (2.0, 0.0, 0.25, 0.0, 1.0, 0.0))
