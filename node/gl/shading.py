"""The one shading path of every draw (tiles, depth layers, blended layers, render-once): the
glTF 2.0 metallic-roughness BRDF of the specification's Appendix B, lit by the environment
(:mod:`node.gl.image_lighting`) and a camera-attached key light, tone mapped with Khronos PBR
Neutral and sRGB-encoded. Laid out by term after the Khronos glTF Sample Viewer (``brdf.glsl``,
``ibl.glsl``, ``punctual.glsl``, ``tonemapping.glsl``): material inputs gathered once, image-based
and punctual light added separately, emission added, tone mapping last.

Material inputs: base colour factor × vertex colour × base colour texture (sRGB), metallic and
roughness factors × the metallic-roughness texture's B and G channels, a tangent-space normal map
(``normalTexture.scale``; in the frame of the file's TANGENTs, bitangent = normal × tangent · w,
else one generated per pixel from the screen-space derivatives of position and texture
coordinates, Schüler 2006), occlusion (R, with its strength, applied to image-based light only, as
the spec advises), emissive factor × strength (``KHR_materials_emissive_strength``) × emissive
texture (sRGB). Each texture reads its coordinate set (0 or 1) through its
``KHR_texture_transform``. Surfaces are lit two-sided: a normal facing away from the eye is
flipped, its tangent frame with it.

Image-based light uses the split-sum approximation with Fdez-Agüera's multiple-scattering term
(as the Sample Viewer), so a rough white surface in a uniform environment reflects exactly that
environment (the white-furnace test). Tone mapping: Khronos PBR Neutral, chosen over ACES because
it keeps base colours' hue and saturation (a product viewer's need: what the file says is what is
shown) and is linear below 0.76.

Cost on llvmpipe (docs/benchmarks/picture.md: ``python -m bench.shading``), where every texture lookup
and every varying costs: variants by ``#define`` (:class:`ShaderVariant`), so what a batch lacks
costs nothing — no texture lookup at all without textures (scans, most CAD parts: a 1×1 stand-in
texture costs as much as a real one), tangents, a second uv set and uv transforms only where used —
each with and without the discards of alpha masks and depth peeling (opaque and blended batches
have none: the depth test then runs before the shader, and with chunks drawn nearest first,
:mod:`node.culling.order`, hidden fragments are not shaded). Diffuse image light is evaluated per
vertex (a quadratic in the normal, so interpolating it changes a dense mesh's picture by well under
a level), except under a normal map; sRGB encoding by three square roots instead of a pow; the
specular map in half floats.

Derivatives are taken in 2×2 pixel quads of the frame-sized framebuffer every tile is drawn into,
so a tile is still bit-identical to that region of the whole frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from node.culling.switch import SOFTWARE_RENDERERS
from node.gl.view_tools import CLIP_FRAGMENT, CLIP_VERTEX
from node.scene.mesh import MeshBatch
from tessera.antialiasing import GRID_FILTERS

#: Radiance of the key light (white), a directional light attached to the camera.
KEY_LIGHT = 1.5
#: ``--msaa auto``: :data:`HARDWARE_MSAA` samples on a GPU; on a software rasterizer, where 4
#: multisamples cost 2.6-3.5x the frame time, an ordered grid of samples drawn as a frame that many
#: times as large and resolved (:mod:`tessera.antialiasing`), chosen by frame size
#: (:class:`AntialiasingChoice`).
AUTO_MSAA = 0
#: ``--msaa filter``: one sample per pixel resolved by the 3x3 filter (1.1-1.2x on llvmpipe).
FILTER_MSAA = -1
HARDWARE_MSAA = 4
#: Sample counts ``--msaa`` accepts besides auto and filter (1: off).
MSAA_CHOICES = (1, 2, 4, 8)
#: ``--msaa auto`` on a software rasterizer: the grids a frame may get, most samples first; the
#: first whose samples a frame stay within :data:`SAMPLE_BUDGET`, else the pair (2 × 1, two samples
#: a pixel, the default of every size before issue 37). The pair misses 40 dB against the 4×4
#: supersampled frame on small frames, where geometry thinner than a pixel is most of the error:
#: the diorama from random cameras at 640x360 35.7-41.1 dB (3x3: 42.5-47.7), at 960x540
#: 37.4-42.5 (2x2: 40.3-45.4), at 1280x720 38.6-43.5, at 1920x1080 40.3-45.2 (``/tmp`` study, seven
#: scenes, three random cameras each: the worst of each size was the diorama's).
SOFTWARE_GRIDS = ((4, 4), (3, 3), (2, 2))
#: Samples a frame draws at most with ``--msaa auto`` on a software rasterizer (unless it is the
#: pair's): as many as a 1920x1080 frame has pixels — 3x3 at 640x360, 2x2 at 960x540, the pair
#: from 1280x720 on (as many as before at 720p and up, at most 1.13x the 720p pair's below).
SAMPLE_BUDGET = 1920 * 1080


@dataclass(frozen=True, slots=True)
class Antialiasing:
    """How plain tiles and whole frames are drawn and resolved: ``samples`` multisamples per pixel
    (a blit resolves them), or at one sample a ``grid`` (kx, ky) of samples per pixel (the frame
    drawn kx × ky times as large: (2, 1) is the pair, ¼ pixel left and right of the centre),
    ``filtered`` by :mod:`tessera.antialiasing`'s filter or averaged."""

    samples: int = 1
    grid: tuple[int, int] = (1, 1)
    filtered: bool = False

    @property
    def paired(self) -> bool:
        """Two samples a pixel, drawn twice as wide."""
        return self.grid == (2, 1)

    @property
    def resolved(self) -> bool:
        """Its frames go through :func:`tessera.antialiasing.resolve_grid`."""
        return self.filtered or self.grid != (1, 1)

    @property
    def label(self) -> str:
        """What is drawn, as logs and benchmarks say it: '4x MSAA', '2 samples (twice as wide) + 3x3
        filter', '3x3 samples (3x3 as large)', '1 sample + 3x3 filter'."""
        if self.paired:
            drawn = "2 samples (twice as wide)"
        elif self.grid != (1, 1):
            drawn = f"{self.grid[0]}x{self.grid[1]} samples ({self.grid[0]}x{self.grid[1]} as large)"
        else:
            drawn = f"{self.samples}x MSAA" if self.samples > 1 else "1 sample"
        return drawn + (" + 3x3 filter" if self.filtered else "")


@dataclass(frozen=True, slots=True)
class AntialiasingChoice:
    """What a node draws at each frame size: ``fixed`` at every size, or (None, ``--msaa auto`` on a
    software rasterizer) the grid :data:`SOFTWARE_GRIDS` and :data:`SAMPLE_BUDGET` give the size."""

    fixed: Antialiasing | None = None

    def for_size(self, size: tuple[int, int]) -> Antialiasing:
        """How a frame of ``size`` = (w, h) px is drawn."""
        if self.fixed is not None:
            return self.fixed
        pixels = size[0] * size[1]
        grid = next((g for g in SOFTWARE_GRIDS if g[0] * g[1] * pixels <= SAMPLE_BUDGET), (2, 1))
        return Antialiasing(grid=grid, filtered=grid in GRID_FILTERS)

    @property
    def label(self) -> str:
        return self.fixed.label if self.fixed is not None else "by frame size (4x4, 3x3, 2x2 samples or the pair)"


@dataclass(frozen=True, slots=True)
class ShadingOptions:
    """How a node shades: ``msaa`` samples per pixel of plain tiles and whole frames (:data:`AUTO_MSAA`,
    :data:`FILTER_MSAA`: as :func:`resolve_antialiasing` resolves them; depth layers
    are always drawn at 1x: sort-last merging needs one exact depth per pixel), ``environment`` a
    Radiance .hdr lighting the scene (None: the generated studio), ``key_light`` the key light's
    radiance (0: image-based light alone)."""

    msaa: int = AUTO_MSAA
    environment: Path | None = None
    key_light: float = KEY_LIGHT


def resolve_antialiasing(msaa: int, gl_renderer: str, max_samples: int) -> AntialiasingChoice:
    """What ``--msaa`` = ``msaa`` draws on the GL renderer named ``gl_renderer`` offering at most
    ``max_samples``: :data:`AUTO_MSAA` is :data:`HARDWARE_MSAA` samples on a GPU and a grid by
    frame size on a software rasterizer (:class:`AntialiasingChoice`); 2 on a software rasterizer
    is the pair, filtered (its GL would draw 4 multisamples, at 2.6-3.5x the cost);
    :data:`FILTER_MSAA` one filtered sample; a multisample count is capped at ``max_samples``."""
    software = any(name in gl_renderer.lower() for name in SOFTWARE_RENDERERS)
    if msaa == FILTER_MSAA:
        return AntialiasingChoice(Antialiasing(filtered=True))
    if msaa == AUTO_MSAA:
        if software:
            return AntialiasingChoice()
        msaa = HARDWARE_MSAA
    if msaa == 2 and software:
        return AntialiasingChoice(Antialiasing(grid=(2, 1), filtered=True))
    return AntialiasingChoice(Antialiasing(samples=max(1, min(msaa, max_samples))))


#: The irradiance polynomial E(n)/π = Σ k_i·m_i(n) of :func:`node.gl.image_lighting.irradiance_polynomial`,
#: split into its even part (bands 0 and 2: E(−n) keeps it) and its odd part (band 1: E(−n) negates it).
IRRADIANCE = """
uniform vec3 u_sh[9];
vec3 irradiance_even(vec3 n) {
    return u_sh[0] + u_sh[4] * (n.x * n.y) + u_sh[5] * (n.y * n.z) + u_sh[6] * (n.z * n.z)
        + u_sh[7] * (n.x * n.z) + u_sh[8] * (n.x * n.x - n.y * n.y);
}
vec3 irradiance_odd(vec3 n) {
    return u_sh[1] * n.y + u_sh[2] * n.z + u_sh[3] * n.x;
}
"""

VERTEX_SHADER = """
uniform mat4 u_view_projection;
uniform mat3 u_normal_matrix;
uniform vec3 u_eye;
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_color;
out vec3 v_position;
out vec3 v_normal;
out vec2 v_uv;
#if VERTEX_COLORS
out vec4 v_color;
#endif
#if !NORMAL_MAP
out vec3 v_irradiance_even;
out vec3 v_irradiance_odd;
#endif
#if TANGENTS
in vec4 in_tangent;
out vec4 v_tangent;
#endif
#if UV1
in vec2 in_uv1;
out vec2 v_uv1;
#endif
""" + IRRADIANCE + CLIP_VERTEX + """
void main() {
    v_position = world_position(in_position).xyz;
    v_normal = u_normal_matrix * in_normal;
#if !NORMAL_MAP
    float normal_length = length(v_normal);
    vec3 n = normal_length > 0.0 ? v_normal / normal_length : normalize(u_eye - v_position);
    v_irradiance_even = irradiance_even(n);
    v_irradiance_odd = irradiance_odd(n);
#endif
#if TANGENTS
    // A mirroring model matrix turns the bitangent round (the normal matrix has its determinant's sign).
    v_tangent = vec4(mat3(u_model) * in_tangent.xyz, in_tangent.w * sign(determinant(u_normal_matrix)));
#endif
#if UV1
    v_uv1 = in_uv1;
#endif
    v_uv = in_uv;
#if VERTEX_COLORS
    v_color = in_color;
#endif
    gl_Position = u_view_projection * vec4(in_position, 1.0);
}
"""

FRAGMENT_SHADER = """
const float PI = 3.14159265358979;
uniform vec4 u_base_color;
uniform float u_metallic;
uniform float u_roughness;
uniform vec3 u_emissive;
uniform float u_normal_scale;
uniform float u_occlusion_strength;
uniform float u_alpha_cutoff;
uniform float u_lod_bias;   // a progressive still's sample reads textures finer (issue 20)
uniform sampler2D u_texture;
uniform sampler2D u_metallic_roughness;
uniform sampler2D u_normal_texture;
uniform sampler2D u_occlusion;
uniform sampler2D u_emissive_texture;
uniform sampler2D u_specular_map;
uniform sampler2D u_brdf_lut;
uniform float u_specular_levels;
uniform vec3 u_eye;
uniform vec3 u_light_direction;
uniform float u_key_light;
uniform bool u_peel;
uniform sampler2D u_floor;
uniform sampler2D u_ceil;
uniform ivec2 u_origin;
uniform bool u_cap;          // the frame cuts the scene: the inside of cut surfaces is capped
uniform vec3 u_cap_color;
uniform vec4 u_tint;         // the selected object's tint (sRGB, amount)
in vec3 v_position;
in vec3 v_normal;
in vec2 v_uv;
#if VERTEX_COLORS
in vec4 v_color;
#else
const vec4 v_color = vec4(1.0);
#endif
#if !NORMAL_MAP
in vec3 v_irradiance_even;
in vec3 v_irradiance_odd;
#endif
#if TANGENTS
in vec4 v_tangent;
#endif
#if UV1
in vec2 v_uv1;
#endif
out vec4 f_color;
#if DISCARDS
""" + CLIP_FRAGMENT + """
#endif
""" + IRRADIANCE + """
#if UV_TRANSFORM
// Per texture slot (base colour, metallic-roughness, normal, occlusion, emissive): its coordinate
// set and KHR_texture_transform (node.scene.material.UvTransform).
uniform mat3x2 u_uv_matrix[5];
uniform int u_uv_set[5];
#endif

vec2 slot_uv(int slot) {
#if UV_TRANSFORM && UV1
    return u_uv_matrix[slot] * vec3(u_uv_set[slot] == 1 ? v_uv1 : v_uv, 1.0);
#elif UV_TRANSFORM
    return u_uv_matrix[slot] * vec3(v_uv, 1.0);
#else
    return v_uv;
#endif
}
// sRGB encoding: 1.055·c^(1/2.4) − 0.055 fitted by c, √c, c^(1/4), c^(1/8) (least squares on
// [0.0031308, 1], within 0.015 of an 8-bit level: three square roots cost less than a pow on llvmpipe).
vec3 linear_to_srgb(vec3 c) {
    vec3 s1 = sqrt(c);
    vec3 s2 = sqrt(s1);
    vec3 s3 = sqrt(s2);
    vec3 encoded = 0.64456019 * s1 + 0.70994624 * s2 - 0.33605189 * s3 - 0.01848584 * c;
    return mix(c * 12.92, encoded, step(0.0031308, c));
}

// Khronos PBR Neutral tone mapping (https://github.com/KhronosGroup/ToneMapping).
vec3 pbr_neutral(vec3 color) {
    const float start = 0.8 - 0.04;
    const float desaturation = 0.15;
    float x = min(color.r, min(color.g, color.b));
    float offset = x < 0.08 ? x - 6.25 * x * x : 0.04;
    color -= offset;
    float peak = max(color.r, max(color.g, color.b));
    if (peak < start) return color;
    const float d = 1.0 - start;
    float new_peak = 1.0 - d * d / (peak + d - start);
    color *= new_peak / peak;
    float g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0);
    return mix(color, vec3(new_peak), g);
}

vec2 equirect(vec3 d) {
    return vec2(atan(d.x, -d.z) * (0.5 / PI) + 0.5, acos(clamp(d.y, -1.0, 1.0)) / PI);
}

float pow5(float x) {
    float x2 = x * x;
    return x2 * x2 * x;
}

vec3 fresnel_schlick(vec3 f0, float v_dot_h) {
    return f0 + (1.0 - f0) * pow5(clamp(1.0 - v_dot_h, 0.0, 1.0));
}

float visibility_ggx(float n_dot_l, float n_dot_v, float a2) {
    float ggxv = n_dot_l * sqrt(n_dot_v * n_dot_v * (1.0 - a2) + a2);
    float ggxl = n_dot_v * sqrt(n_dot_l * n_dot_l * (1.0 - a2) + a2);
    float ggx = ggxv + ggxl;
    return ggx > 0.0 ? 0.5 / ggx : 0.0;
}

float distribution_ggx(float n_dot_h, float a2) {
    float f = n_dot_h * n_dot_h * (a2 - 1.0) + 1.0;
    return a2 / (PI * f * f);
}

// The tangent frame from the screen-space derivatives of position and the normal map's coordinates
// ``uv`` (Schüler 2006), for meshes without tangents.
vec3 perturbed_normal(vec3 n, vec3 tangent_normal, vec2 uv) {
    vec3 dp1 = dFdx(v_position);
    vec3 dp2 = dFdy(v_position);
    vec2 duv1 = dFdx(uv);
    vec2 duv2 = dFdy(uv);
    vec3 dp2perp = cross(dp2, n);
    vec3 dp1perp = cross(n, dp1);
    vec3 t = dp2perp * duv1.x + dp1perp * duv2.x;
    vec3 b = dp2perp * duv1.y + dp1perp * duv2.y;
    float scale = max(dot(t, t), dot(b, b));
    if (scale <= 0.0) return n;
    float inverse = inversesqrt(scale);
    return normalize(mat3(t * inverse, b * inverse, n) * tangent_normal);
}

void main() {
#if DISCARDS
    if (cut_away(v_position)) discard;
    if (u_peel) {
        ivec2 texel = ivec2(gl_FragCoord.xy) - u_origin;
        if (gl_FragCoord.z <= texelFetch(u_floor, texel, 0).r || gl_FragCoord.z >= texelFetch(u_ceil, texel, 0).r)
            discard;
    }
#endif
#if BASE_MAP
    vec4 base = u_base_color * v_color * texture(u_texture, slot_uv(0), u_lod_bias);
#else
    vec4 base = u_base_color * v_color;
#endif
#if METAL_ROUGH_MAP
    vec4 metal_rough = texture(u_metallic_roughness, slot_uv(1), u_lod_bias);
    float metallic = clamp(u_metallic * metal_rough.b, 0.0, 1.0);
    float roughness = clamp(u_roughness * metal_rough.g, 0.0, 1.0);
#else
    float metallic = clamp(u_metallic, 0.0, 1.0);
    float roughness = clamp(u_roughness, 0.0, 1.0);
#endif
#if DISCARDS
    if (base.a < u_alpha_cutoff) discard;
#endif
    float alpha = max(roughness * roughness, 1e-3);
    float a2 = alpha * alpha;

    vec3 v = normalize(u_eye - v_position);
    float normal_length = length(v_normal);
    vec3 geometric = normal_length > 0.0 ? v_normal / normal_length : v;
    // Two-sided: a normal facing away is flipped (its tangent frame with it), and E(−n) is the
    // even part less the odd one.
    float side = dot(geometric, v) < 0.0 ? -1.0 : 1.0;
    if (u_cap) {   // the inside of a cut surface (its normals turn from the eye): a solid cap
        vec3 facing = cross(dFdx(v_position), dFdy(v_position));
        if (dot(geometric, facing) * dot(v, facing) < 0.0) {
            f_color = vec4(mix(u_cap_color, u_tint.rgb, u_tint.a), 1.0);
            return;
        }
    }
    vec3 n = geometric * side;
#if NORMAL_MAP
    vec2 normal_uv = slot_uv(2);
    vec3 mapped = texture(u_normal_texture, normal_uv, u_lod_bias).rgb * 2.0 - 1.0;
    mapped = normalize(mapped * vec3(u_normal_scale, u_normal_scale, 1.0));
#if TANGENTS
    // The file's tangent, made orthogonal to the normal; bitangent = cross(normal, tangent) · w.
    vec3 t = v_tangent.xyz - geometric * dot(geometric, v_tangent.xyz);
    float t_length2 = dot(t, t);
    if (t_length2 > 0.0) {
        t *= inversesqrt(t_length2);
        vec3 b = cross(geometric, t) * (v_tangent.w < 0.0 ? -1.0 : 1.0);
        n = side * normalize(mat3(t, b, geometric) * mapped);
    } else {
        n = perturbed_normal(n, mapped, normal_uv);
    }
#else
    n = perturbed_normal(n, mapped, normal_uv);
#endif
    vec3 diffuse_light = max(irradiance_even(n) + irradiance_odd(n), vec3(0.0));
#else
    vec3 diffuse_light = max(v_irradiance_even + side * v_irradiance_odd, vec3(0.0));
#endif
    float n_dot_v = clamp(dot(n, v), 1e-4, 1.0);
    vec3 c_diff = base.rgb * (1.0 - metallic);
    vec3 f0 = mix(vec3(0.04), base.rgb, metallic);

    // Image-based light (split sum, multiple scattering after Fdez-Agüera).
    vec2 ab = texture(u_brdf_lut, vec2(n_dot_v, roughness)).rg;
    vec3 fr = max(vec3(1.0 - roughness), f0) - f0;
    vec3 k_s = f0 + fr * pow5(1.0 - n_dot_v);
    vec3 fss_ess = k_s * ab.x + ab.y;
    float ems = 1.0 - (ab.x + ab.y);
    vec3 f_avg = f0 + (1.0 - f0) / 21.0;
    vec3 fms_ems = ems * fss_ess * f_avg / (1.0 - f_avg * ems);
    vec3 reflected = reflect(-v, n);
    vec3 specular_light = textureLod(u_specular_map, equirect(reflected), roughness * u_specular_levels).rgb;
    vec3 k_d = c_diff * (1.0 - fss_ess - fms_ems);
    vec3 color = fss_ess * specular_light + (fms_ems + k_d) * diffuse_light;
#if OCCLUSION_MAP
    float occlusion = texture(u_occlusion, slot_uv(3), u_lod_bias).r;
    color *= 1.0 + u_occlusion_strength * (occlusion - 1.0);
#endif

    // Key light (punctual, directional).
    vec3 l = u_light_direction;
    float n_dot_l = dot(n, l);
    if (n_dot_l > 0.0 && u_key_light > 0.0) {
        vec3 h = normalize(l + v);
        vec3 f = fresnel_schlick(f0, clamp(dot(v, h), 0.0, 1.0));
        vec3 f_diffuse = (1.0 - f) * c_diff / PI;
        vec3 f_specular = f * (distribution_ggx(clamp(dot(n, h), 0.0, 1.0), a2) * visibility_ggx(n_dot_l, n_dot_v, a2));
        color += (f_diffuse + f_specular) * (u_key_light * n_dot_l);
    }

#if EMISSIVE_MAP
    color += u_emissive * texture(u_emissive_texture, slot_uv(4), u_lod_bias).rgb;
#else
    color += u_emissive;
#endif
    f_color = vec4(mix(linear_to_srgb(clamp(pbr_neutral(color), 0.0, 1.0)), u_tint.rgb, u_tint.a), base.a);
}
"""


@dataclass(frozen=True, order=True, slots=True)
class ShaderVariant:
    """What a batch's shaders do beyond the plain path (each a ``#define``, so what a batch lacks
    costs nothing: on llvmpipe a 1×1 stand-in texture costs as much as a real one, a varying of ones
    as much as vertex colours): ``vertex_colors``, the batch's colours; the texture lookups
    of its maps (``base_map``, ``metal_rough_map``, ``normal_map``: diffuse image light then per
    pixel, ``occlusion_map``, ``emissive_map``; only with texture coordinates); ``tangents``, the
    file's tangents under the normal map (else the frame derived per pixel); ``uv_transform``, a
    texture reads a transformed or second coordinate set (``KHR_texture_transform``, ``texCoord``);
    ``uv1``, the second set."""

    vertex_colors: bool = False
    base_map: bool = False
    metal_rough_map: bool = False
    normal_map: bool = False
    occlusion_map: bool = False
    emissive_map: bool = False
    tangents: bool = False
    uv_transform: bool = False
    uv1: bool = False

    @classmethod
    def of(cls, batch: MeshBatch) -> ShaderVariant:
        material = batch.material
        colored = batch.colors is not None
        if batch.uvs is None or (batch.texture is None and not material.textured):
            return cls(colored)
        normal_map = material.normal_texture is not None
        return cls(colored, batch.texture is not None, material.metallic_roughness_texture is not None, normal_map,
                   material.occlusion_texture is not None, material.emissive_texture is not None,
                   normal_map and batch.tangents is not None, material.uv_transformed,
                   material.uv_transformed and batch.uvs1 is not None)

    @property
    def textured(self) -> bool:
        """Whether it looks up any texture of the batch."""
        return self.base_map or self.metal_rough_map or self.normal_map or self.occlusion_map or self.emissive_map

    def source(self, body: str, discards: bool = False) -> str:
        """``body`` (:data:`VERTEX_SHADER` or :data:`FRAGMENT_SHADER`) with this variant's defines and
        ``DISCARDS`` (the fragment discards of alpha masks and depth peeling)."""
        flags = {"VERTEX_COLORS": self.vertex_colors, "BASE_MAP": self.base_map,
                 "METAL_ROUGH_MAP": self.metal_rough_map, "NORMAL_MAP": self.normal_map,
                 "OCCLUSION_MAP": self.occlusion_map, "EMISSIVE_MAP": self.emissive_map, "TANGENTS": self.tangents,
                 "UV_TRANSFORM": self.uv_transform, "UV1": self.uv1, "DISCARDS": discards}
        return "#version 330\n" + "".join(f"#define {name} {int(on)}\n" for name, on in flags.items()) + body


def vertex_shader(variant: ShaderVariant) -> str:
    """The vertex shader of ``variant``."""
    return variant.source(VERTEX_SHADER)


def fragment_shader(variant: ShaderVariant, discards: bool) -> str:
    """The fragment shader of ``variant``, with the fragment discards of alpha masks and depth
    peeling (``discards``) or without."""
    return variant.source(FRAGMENT_SHADER, discards)
