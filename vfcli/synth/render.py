"""Phantom image formation: the high-speed camera's 12-bit frames of the deformed folds.

A frame is formed in three steps, each a pure function:

1. :func:`render_radiance`: noiseless irradiance in [0, 1] of full scale.  The
   superior-view surface is rasterised on a supersampled grid (anti-aliasing,
   so sub-pixel motion changes the image continuously); each visible point
   gets the albedo of a procedural silicone texture attached to its MATERIAL
   coordinates (so it moves with the surface and optical flow can track it),
   Lambert shading at the vertex normals (Gouraud-interpolated) with a slightly oblique
   light along the camera axis; the glottal gap shows the dark, faint texture
   of the subglottal channel far below, other uncovered pixels the fixture.
   The fine image is box-averaged to camera pixels and blurred by a Gaussian PSF.
2. :func:`expose`: photon (Poisson) and read noise at a stated SNR, black level,
   quantisation to the bit depth (12-bit in uint16).
3. :func:`render_truth`: what the phantom's truth file records per pixel: the
   true velocity of the visible material point (mm/s), the visible indicator,
   the gap mask at pixel centres and the gap's area fraction per pixel.

:func:`render_frame` chains them.  :class:`SceneTextures` holds the random
textures, built once per phantom from a seeded generator.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from vfcli.camera.camera import Camera
from vfcli.camera.raster import Raster, fold_x_range, gap_mask, interpolate, rasterize


@dataclass(frozen=True)
class RenderSettings:
    """Look of the phantom video (all levels are fractions of the full scale above black).

    supersample : anti-aliasing factor per axis (2 -> 2 x 2 samples per pixel).
    bit_depth : camera bit depth (12 for the SA-X2); stored in uint16.
    black_level_dn : dark offset, counts.
    surface_level : radiance of a horizontal fold surface of mean albedo.
    gap_level : mean radiance of the subglottal channel seen through the gap.
    fixture_level : radiance of uncovered pixels that are not gap (the fixture).
    texture_contrast : relative RMS of the smooth albedo variation of the silicone.
    texture_feature_mm : correlation length of the silicone texture, mm.
    mark_density : area fraction covered by dark (graphite) marks.
    mark_darkness : relative albedo drop inside a mark (0..1).
    mark_feature_mm : correlation length of the field that shapes the marks, mm.
    light_dir : (3,) direction towards the light (normalised internally).
    ambient : share of the radiance that does not depend on the surface normal.
    psf_sigma_px : Gaussian optics blur, camera pixels (0: none).
    snr : signal-to-noise ratio (mean / std) at ``surface_level``.
    read_noise_dn : read noise, counts RMS.
    fixture_in_view : True, uncovered pixels outside the gap show the fixture (``fixture_level``);
        False, they show the flat top of the silicone block the folds are cast in (static, at
        ``surface_level`` with the texture contrast), so nothing but silicone and gap is in view.
    two_sided_lambert : False, Lambert's law at the outward normals, ``max(n . l, 0)``; True, the default
        panel's look from before session 57, ``|n . l|``, which lights a wall facing away from the lamp
        like one facing it (kept so that the default phantom, the demo's, stays the recording it was).
    """

    supersample: int = 2
    bit_depth: int = 12
    black_level_dn: float = 32.0
    surface_level: float = 0.6
    gap_level: float = 0.04
    fixture_level: float = 0.2
    texture_contrast: float = 0.12
    texture_feature_mm: float = 0.12
    mark_density: float = 0.12
    mark_darkness: float = 0.55
    mark_feature_mm: float = 0.15
    light_dir: tuple[float, float, float] = (0.2, 0.1, 1.0)
    ambient: float = 0.2
    psf_sigma_px: float = 0.7
    snr: float = 40.0
    read_noise_dn: float = 2.0
    fixture_in_view: bool = True
    two_sided_lambert: bool = False

    def __post_init__(self) -> None:
        if int(self.supersample) < 1:
            raise ValueError(f"render supersample must be >= 1, got {self.supersample}")
        if not 8 <= int(self.bit_depth) <= 16:
            raise ValueError(f"render bit_depth must be 8..16, got {self.bit_depth}")
        if not 0 <= self.black_level_dn < self.full_scale_dn / 2:
            raise ValueError(f"render black_level_dn must be in [0, half the range), got {self.black_level_dn}")
        if self.snr <= 0 or self.read_noise_dn < 0:
            raise ValueError("render snr must be > 0 and read_noise_dn >= 0")
        if self.read_noise_dn * self.snr >= self.surface_level * self.full_scale_dn:
            raise ValueError(f"render snr {self.snr} is unreachable with read noise {self.read_noise_dn} DN")

    @property
    def max_dn(self) -> int:
        """Largest count, ``2**bit_depth - 1``."""
        return (1 << int(self.bit_depth)) - 1

    @property
    def full_scale_dn(self) -> float:
        """Counts above black at radiance 1."""
        return self.max_dn - self.black_level_dn

    @property
    def dn_per_electron(self) -> float:
        """Conversion gain that gives ``snr`` at ``surface_level`` (shot + read noise)."""
        ref = self.surface_level * self.full_scale_dn
        return ((ref / self.snr) ** 2 - self.read_noise_dn ** 2) / ref

    def noise_std_dn(self, radiance: np.ndarray | float) -> np.ndarray:
        """Expected noise std (counts) at a radiance (fraction of full scale), before quantisation."""
        signal = np.asarray(radiance, dtype=float) * self.full_scale_dn
        return np.sqrt(signal * self.dn_per_electron + self.read_noise_dn ** 2)


class PeriodicTexture:
    """A band-limited random field on a periodic square grid, sampled bilinearly.

    values : (n, n) float, samples at ``(i * spacing, j * spacing)`` (first axis u).
    spacing_mm : grid spacing, mm; the period is ``n * spacing_mm``.
    """

    def __init__(self, values: np.ndarray, spacing_mm: float) -> None:
        self.values = np.asarray(values, dtype=np.float32)
        self.spacing_mm = float(spacing_mm)

    @property
    def period_mm(self) -> float:
        return self.values.shape[0] * self.spacing_mm

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Field values (float32) at (..., 2) coordinates in mm (periodic, bilinear)."""
        n = self.values.shape[0]
        flat = self.values.ravel()
        q = np.asarray(uv, dtype=float).reshape(-1, 2) / self.spacing_mm
        i0 = np.floor(q)
        f = (q - i0).astype(np.float32)
        i0 = np.mod(i0.astype(np.int64), n)
        i1 = i0 + 1
        i1[i1 == n] = 0
        a, b = i0[:, 0] * n, i1[:, 0] * n
        fu, fv = f[:, 0], f[:, 1]
        top = flat[a + i0[:, 1]]
        top += (flat[a + i1[:, 1]] - top) * fv
        bot = flat[b + i0[:, 1]]
        bot += (flat[b + i1[:, 1]] - bot) * fv
        return (top + (bot - top) * fu).reshape(np.shape(uv)[:-1])


def smooth_noise(shape: tuple[int, int], correlation_px: float, rng: np.random.Generator) -> np.ndarray:
    """Periodic Gaussian-correlated noise, zero mean, unit std: (shape) float64.

    White noise filtered in Fourier space by ``exp(-(k * correlation_px)^2 / 2)``
    (k in rad/px): band-limited, smooth at the grid scale when correlation_px >~ 3.
    """
    white = rng.standard_normal(shape)
    ku = 2 * np.pi * np.fft.fftfreq(shape[0])[:, None]
    kv = 2 * np.pi * np.fft.rfftfreq(shape[1])[None, :]
    filt = np.exp(-0.5 * (ku ** 2 + kv ** 2) * correlation_px ** 2)
    field = np.fft.irfft2(np.fft.rfft2(white) * filt, s=shape)
    field -= field.mean()
    return field / field.std()


def silicone_texture(settings: RenderSettings, rng: np.random.Generator,
                     n: int = 1024, spacing_mm: float = 0.025) -> PeriodicTexture:
    """Albedo texture of the silicone (mean 1): smooth variation plus dark graphite marks."""
    base = 1.0 + settings.texture_contrast * smooth_noise((n, n), settings.texture_feature_mm / spacing_mm, rng)
    marks_field = smooth_noise((n, n), settings.mark_feature_mm / spacing_mm, rng)
    if settings.mark_density > 0:
        thr = np.quantile(marks_field, 1.0 - settings.mark_density)
        marks = np.clip((marks_field - thr) / 0.5 + 0.5, 0.0, 1.0)      # soft-edged blobs
        marks = marks * marks * (3 - 2 * marks)
    else:
        marks = np.zeros_like(base)
    albedo = np.clip(base * (1.0 - settings.mark_darkness * marks), 0.02, None)
    return PeriodicTexture(albedo / albedo.mean(), spacing_mm)


@dataclass(frozen=True, eq=False)
class SceneTextures:
    """Random textures of one phantom (build with :func:`make_scene_textures`).

    surface : silicone albedo on material coordinates (mm).
    channel : (H*f, W*f) radiance of the subglottal channel seen through the gap.
    fixture : (H*f, W*f) radiance of the fixture (uncovered pixels outside the gap).
    """

    surface: PeriodicTexture
    channel: np.ndarray
    fixture: np.ndarray


def make_scene_textures(camera: Camera, settings: RenderSettings, rng: np.random.Generator) -> SceneTextures:
    """Draw the phantom's textures (silicone albedo, channel and fixture backgrounds)."""
    f = int(settings.supersample)
    shape = (camera.height * f, camera.width * f)
    surface = silicone_texture(settings, rng)
    # the channel is far below: blurred, faint, fixed in the image
    channel = settings.gap_level * (1.0 + 0.3 * smooth_noise(shape, 6.0 * f, rng))
    noise = smooth_noise(shape, 2.0 * f, rng)
    if settings.fixture_in_view:
        fixture = settings.fixture_level * (1.0 + 0.1 * noise)
    else:
        fixture = settings.surface_level * (1.0 + settings.texture_contrast * noise)
    return SceneTextures(surface, np.clip(channel, 0, None), np.clip(fixture, 0, None))


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N, 3) unit area-weighted vertex normals (orientation follows the triangles' winding)."""
    v = np.asarray(vertices, dtype=float)
    t = np.asarray(triangles, dtype=np.int64)
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])      # 2 * area * unit normal
    out = np.zeros_like(v)
    for k in range(3):
        out[:, k] = (np.bincount(t[:, 0], fn[:, k], len(v)) + np.bincount(t[:, 1], fn[:, k], len(v))
                     + np.bincount(t[:, 2], fn[:, k], len(v)))
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


def _fold_offsets(textures: SceneTextures) -> np.ndarray:
    """Texture-space offsets (mm) per fold, so the two folds' textures are unrelated."""
    p = textures.surface.period_mm
    return np.array([[0.0, 0.0], [0.37 * p, 0.61 * p]])


def render_radiance(camera: Camera, vertices: np.ndarray, triangles: np.ndarray, material_uv: np.ndarray,
                    triangle_fold: np.ndarray, textures: SceneTextures,
                    settings: RenderSettings = RenderSettings()) -> np.ndarray:
    """Noiseless camera image of the folds: (H, W) float64 radiance, fraction of full scale.

    Parameters
    ----------
    camera : the camera.
    vertices : (N, 3) deformed surface vertices at this instant, mm.
    triangles : (K, 3) int surface triangles (the superior-view surface of both folds;
        winding outward: the shading uses the outward normals, ``max(n . l, 0)``).
    material_uv : (N, 2) material (texture) coordinates of the vertices, mm-scaled
        (e.g. rest (x, y) of a flat superior surface, or (u L, v arc length)); fixed in time.
    triangle_fold : (K,) int fold (0 left, 1 right) of each triangle.
    textures : from :func:`make_scene_textures` with the same camera and settings.
    settings : the look.
    """
    f = int(settings.supersample)
    fine = camera.supersampled(f)
    if textures.channel.shape != fine.shape:
        raise ValueError(f"textures were made for {textures.channel.shape}, camera needs {fine.shape}")
    ras = rasterize(fine, vertices, triangles)
    fold = np.asarray(triangle_fold, dtype=np.int64).ravel()
    gap = gap_mask(fine, ras, fold, fold_x_range(vertices, triangles, fold))
    return _radiance_from_raster(camera, ras, gap, vertices, triangles, material_uv, triangle_fold,
                                 textures, settings)


def _radiance_from_raster(camera: Camera, ras: Raster, gap_fine: np.ndarray, vertices, triangles, material_uv,
                          triangle_fold, textures: SceneTextures, settings: RenderSettings) -> np.ndarray:
    f = int(settings.supersample)
    fold = np.asarray(triangle_fold, dtype=np.int64).ravel()
    vis = ras.visible_index
    tri = ras.visible_triangle
    # per-vertex Lambert shading (Gouraud), blended with the texture coordinates in one pass
    light = np.asarray(settings.light_dir, dtype=float)
    light = light / np.linalg.norm(light)
    # Lambert's cosine law at the outward normals (the view surface's winding is outward, and every point the
    # camera sees faces it): a surface turned away from the lamp gets the diffuse share only. |n . l| (the default
    # panel's historical look) lights the steep medial wall that faces away from a tilted lamp like the one facing it.
    cosine = vertex_normals(vertices, triangles) @ light
    lambert = (np.abs(cosine) if settings.two_sided_lambert else np.clip(cosine, 0.0, None)) / abs(light[2])
    attrs = np.column_stack([np.asarray(material_uv, dtype=float),
                             settings.ambient + (1.0 - settings.ambient) * lambert])
    blended = ras.interpolate_visible(attrs)
    albedo = textures.surface.sample(blended[:, :2] + _fold_offsets(textures)[fold[tri]])
    shade = blended[:, 2]

    img = textures.fixture.ravel().copy()
    gap = gap_fine.ravel()
    img[gap] = textures.channel.ravel()[gap]
    img[vis] = settings.surface_level * albedo * shade
    img = img.reshape(camera.height, f, camera.width, f).mean(axis=(1, 3))
    if settings.psf_sigma_px > 0:
        img = ndimage.gaussian_filter(img, settings.psf_sigma_px, mode="nearest")
    return img


def expose(radiance: np.ndarray, settings: RenderSettings, rng: np.random.Generator) -> np.ndarray:
    """Sensor: Poisson photon noise, Gaussian read noise, black level, quantisation.

    radiance : (H, W) fraction of full scale (values > 1 saturate).
    Returns (H, W) uint16 counts in ``[0, 2**bit_depth - 1]``; the noise std at
    ``surface_level`` is ``surface_level * full_scale / snr``.
    """
    k = settings.dn_per_electron
    signal_dn = np.clip(np.asarray(radiance, dtype=float), 0.0, None) * settings.full_scale_dn
    electrons = rng.poisson(signal_dn / k)
    counts = settings.black_level_dn + k * electrons + settings.read_noise_dn * rng.standard_normal(signal_dn.shape)
    return np.clip(np.rint(counts), 0, settings.max_dn).astype(np.uint16)


@dataclass(frozen=True, eq=False)
class FrameTruth:
    """Per-pixel truth of one frame (camera pixel centres).

    velocity : (H, W, 3) true velocity (u, v, w) of the visible material point, mm/s; NaN where none.
    visible : (H, W) bool, a fold surface is visible at the pixel centre.
    gap : (H, W) bool, the pixel centre lies in the glottal gap.
    gap_fraction : (H, W) float, fraction of the pixel's sub-samples in the gap
        (glottal area = ``gap_fraction.sum() / px_per_mm**2`` mm^2).
    """

    velocity: np.ndarray
    visible: np.ndarray
    gap: np.ndarray
    gap_fraction: np.ndarray


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    """One phantom frame: ``image`` (H, W) uint16 counts, ``radiance`` (H, W) noiseless, and its truth."""

    image: np.ndarray
    radiance: np.ndarray
    truth: FrameTruth


def render_truth(camera: Camera, vertices: np.ndarray, triangles: np.ndarray, velocities: np.ndarray,
                 triangle_fold: np.ndarray, supersample: int = 2) -> FrameTruth:
    """Truth at the pixel centres: visible material point velocity and gap.

    velocities : (N, 3) true vertex velocities, mm/s (the same instant as ``vertices``).
    Other parameters as :func:`render_radiance`.
    """
    f = int(supersample)
    fine = camera.supersampled(f)
    ras_f = rasterize(fine, vertices, triangles)
    fold = np.asarray(triangle_fold, dtype=np.int64).ravel()
    gap_f = gap_mask(fine, ras_f, fold, fold_x_range(vertices, triangles, fold))
    return _truth_from_raster(camera, ras_f, gap_f, vertices, triangles, velocities, triangle_fold, f)


def _truth_from_raster(camera, ras_f, gap_f, vertices, triangles, velocities, triangle_fold, f) -> FrameTruth:
    fold = np.asarray(triangle_fold, dtype=np.int64).ravel()
    frac = gap_f.reshape(camera.height, f, camera.width, f).mean(axis=(1, 3))
    if f % 2 == 1:                       # the centre sub-sample is the pixel centre
        c = (f - 1) // 2
        ras = ras_f
        sl = (slice(c, None, f), slice(c, None, f))
        vel = interpolate(ras, velocities)[sl]
        visible, gap = ras.mask[sl], gap_f[sl]
    else:
        ras = rasterize(camera, vertices, triangles)
        vel = interpolate(ras, velocities)
        visible, gap = ras.mask, gap_mask(camera, ras, fold, fold_x_range(vertices, triangles, fold))
    return FrameTruth(vel, visible, gap, frac)


def render_frame(camera: Camera, vertices: np.ndarray, triangles: np.ndarray, material_uv: np.ndarray,
                 triangle_fold: np.ndarray, velocities: np.ndarray, textures: SceneTextures,
                 settings: RenderSettings, rng: np.random.Generator) -> RenderedFrame:
    """One phantom frame with its truth (see :func:`render_radiance`, :func:`expose`, :func:`render_truth`).

    vertices : (N, 3) surface at the frame's instant, mm; or (E, N, 3) at E sub-instants
        spread over the exposure (motion blur: the radiance is their mean, the truth is
        taken at sub-instant ``E // 2``, so pass ``velocities`` for that instant).
    velocities : (N, 3) true vertex velocities, mm/s.
    Other parameters as :func:`render_radiance`; ``rng`` draws the sensor noise.
    One supersampled rasterisation per sub-instant serves the image and the truth.
    """
    f = int(settings.supersample)
    fine = camera.supersampled(f)
    if textures.channel.shape != fine.shape:
        raise ValueError(f"textures were made for {textures.channel.shape}, camera needs {fine.shape}")
    stack = np.asarray(vertices, dtype=float)
    stack = stack[None] if stack.ndim == 2 else stack
    fold = np.asarray(triangle_fold, dtype=np.int64).ravel()
    radiance = np.zeros(camera.shape)
    truth = None
    for e, verts in enumerate(stack):
        ras = rasterize(fine, verts, triangles)
        gap_f = gap_mask(fine, ras, fold, fold_x_range(verts, triangles, fold))
        radiance += _radiance_from_raster(camera, ras, gap_f, verts, triangles, material_uv, fold,
                                          textures, settings)
        if e == len(stack) // 2:
            truth = _truth_from_raster(camera, ras, gap_f, verts, triangles, velocities, fold, f)
    radiance /= len(stack)
    return RenderedFrame(expose(radiance, settings, rng), radiance, truth)
