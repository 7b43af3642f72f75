"""A phantom recording: the true motion, and what the camera, the vibrometer and the
pressure sensor record of it (numpy in, numpy out; the files are written by
:mod:`vfcli.stages.synth`).

Steps
-----
1. The two M5 folds (P2 FEM) and the aerodynamic load patterns (:mod:`vfcli.synth.aero`).
2. One cycle of subglottal pressure (``n_phase`` samples); the load coefficients consistent
   with the glottal shape they produce, and the medial adduction that closes the glottis for
   ``closed_fraction`` of the cycle (the folds are pressed together at rest, as in a rig).
3. The response with the hidden effect (:mod:`vfcli.synth.effects`), as a periodic motion.
4. The video's pressure (drifting f0, sensor noise); every frame rendered at its cycle
   phase through a camera with a small unknown rotation and offset.
5. The vibrometer: a jittered 17 x 22 grid, one epoch per point at its own phase and f0.

``synth.panel = "widened"`` first draws the conditions of :mod:`vfcli.synth.widened` (camera
angle and zoom, blur, fixture, geometry, material, load distribution, vibrometer artefacts)
and builds the same steps on them; the default panel is unchanged (same bytes).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterator

import numpy as np

from vfcli.camera.camera import Camera
from vfcli.config import MeshConfig, SynthConfig
from vfcli.model.fem import ElasticModel
from vfcli.synth.instruments import (
    LdvSettings, PeriodicTable, PressureRecord, PressureWaveform, ldv_scan_grid, simulate_ldv_scan,
    slow_f0_drift, video_pressure, vertical_velocity_table,
)
from vfcli.synth.instruments import LdvScan as SimulatedScan
from vfcli.model.m5 import m5_params_from
from vfcli.model.mesh import TAG_MEDIAL, TAG_SUPERIOR, FoldMesh, build_mesh
from vfcli.synth.render import FrameTruth, RenderSettings, make_scene_textures, render_frame
from vfcli.synth import aero, effects
from vfcli.synth.motion import PeriodicMotion
from vfcli.synth.widened import LoadDistribution, WidenedDraw, draw_widened

log = logging.getLogger(__name__)

def resolve_effect(cfg: SynthConfig, rng: np.random.Generator) -> tuple[str, float]:
    """(effect, strength): 'random' draws an effect (none included) with the seeded generator."""
    effect = cfg.effect
    if effect == "random":
        effect = str(rng.choice(effects.EFFECTS))
    strength = effects.DEFAULT_STRENGTH[effect] if cfg.strength is None else float(cfg.strength)
    return effect, strength


@dataclass
class TrueMotion:
    """The folds' true motion over one cycle.

    mesh : the phantom's mesh with the adduction applied (rest positions, mm).
    motion : vertex displacements as a periodic function of the cycle phase.
    adduction_mm : shift of each fold towards the midplane at rest.
    load_coefficients : (n_phase, J) Pa, the aerodynamic load over one cycle.
    """

    mesh: FoldMesh
    motion: PeriodicMotion
    adduction_mm: float
    load_coefficients: np.ndarray
    effect: str
    strength: float


def true_motion(cfg: SynthConfig, mesh_cfg: MeshConfig, waveform: PressureWaveform, effect: str, strength: float,
                load: LoadDistribution | None = None) -> TrueMotion:
    """Solve the phantom's physics over one cycle (see the module docstring).

    load : None, the medial Bernoulli profile scales p_sub; else the widened panel's own
        intraglottal drive.
    """
    params = m5_params_from(mesh_cfg)
    mesh = build_mesh(params, cfg.target_edge_mm, mesh_cfg.min_ratio, mesh_cfg.min_dihedral_deg)
    density = mesh_cfg.density_kg_m3 * (strength if effect == "inertia" else 1.0)
    model = ElasticModel(mesh, mesh_cfg.youngs_modulus_pa, mesh_cfg.poisson_ratio, density)
    grid = aero.medial_grid(params.length_mm, -params.thickness_mm, -params.exit_radius_mm)
    patterns = effects.load_patterns(model, grid)
    phase = np.arange(cfg.n_phase) / cfg.n_phase
    p_sub = waveform.at_phase(phase)
    half0, width_op = aero.width_operator(mesh.nodes, effects.right_medial_nodes(model), grid)
    c, adduction = effects.aerodynamic_coefficients(patterns, half0, width_op, p_sub, cfg.closed_fraction,
                                                    medial_drive=load)
    c = effects.band_limit(c, cfg.load_harmonics)
    if effect == "contact":
        adduction *= strength
    rest = mesh.nodes.copy()
    rest[model.folds[0].nodes, 1] += adduction
    rest[model.folds[1].nodes, 1] -= adduction
    if effect == "none":
        u = effects.quasi_static(patterns, c)
    elif effect == "inertia":
        u = effects.inertia(model, patterns, c, cfg.f0_hz)
    elif effect == "damping":
        u = effects.kelvin_voigt(patterns, c, strength)
    elif effect == "contact":
        u = effects.contact(model, patterns, c, rest)
    elif effect == "asymmetry":
        u = effects.asymmetric(patterns, c, model, strength)
    else:  # pragma: no cover - guarded by the config's Literal
        raise ValueError(effect)
    arrays = mesh.to_arrays()
    arrays["nodes"] = rest
    motion = PeriodicMotion.from_samples(u, cfg.n_phase // 2 - 1)
    return TrueMotion(FoldMesh(**arrays), motion, adduction, c, effect, strength)


def phantom_camera(cfg: SynthConfig, mesh_cfg: MeshConfig, rng: np.random.Generator) -> Camera:
    """The camera: the folds centred in the frame, with a small unknown rotation and offset."""
    rot = float(rng.uniform(-1, 1) * cfg.camera_rotation_max_deg)
    jitter = rng.uniform(-1, 1, size=2) * cfg.camera_offset_max_px
    return centred_camera(cfg.px_per_mm, rot, jitter, cfg.width_px, cfg.height_px, mesh_cfg.length_mm)


def centred_camera(px_per_mm: float, rot: float, jitter_px: np.ndarray, width: int, height: int,
                   length_mm: float) -> Camera:
    """A camera with the glottis centre (L/2, 0) at the image centre plus ``jitter_px`` (col, row)."""
    centre_px = np.array([(width - 1) / 2, (height - 1) / 2])
    c, s = np.cos(np.radians(rot)), np.sin(np.radians(rot))
    centre_mm = np.array([length_mm / 2, 0.0])
    offset = centre_px + jitter_px - px_per_mm * np.array([c * centre_mm[0] - s * centre_mm[1], s * centre_mm[0] + c * centre_mm[1]])
    return Camera(px_per_mm, rot, (float(offset[0]), float(offset[1])), width, height)


def view_surface(mesh: FoldMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangles, triangle fold, material coordinates (N, 2) mm) of the surface the camera sees."""
    sel = np.isin(mesh.face_tag, [TAG_SUPERIOR, TAG_MEDIAL])
    x, y, z = mesh.nodes.T
    material = np.column_stack([x, np.abs(y) - z])  # continuous over superior surface, arc and medial
    return mesh.faces[sel], mesh.face_fold[sel], material


@dataclass
class Recording:
    """What the instruments record of a phantom, plus the truth to score against."""

    truth: TrueMotion
    camera: Camera
    fps_hz: float
    pressure: PressureRecord
    frame_times: np.ndarray
    frame_phase: np.ndarray
    frame_f0: np.ndarray
    ldv_points_model_mm: np.ndarray
    ldv: SimulatedScan
    render_settings: RenderSettings
    waveform: PressureWaveform
    rng: np.random.Generator
    widened: WidenedDraw | None = None

    def ldv_points_camera_mm(self) -> np.ndarray:
        """LDV points in camera-frame mm (pixel coordinates / px_per_mm), as the lab registers them."""
        return self.camera.project(self.ldv_points_model_mm) / self.camera.px_per_mm

    def sync_offset_s(self) -> np.ndarray:
        """(P,) true epoch time (s from its first sample) whose phase equals the first frame's."""
        t = self.ldv.truth
        return np.mod(self.frame_phase[0] - t.start_phase, 1.0) / t.f0_hz

    def frames(self) -> Iterator[tuple[np.ndarray, FrameTruth, np.ndarray, np.ndarray]]:
        """Render the video frame by frame: (image uint16, truth, displacement, velocity)."""
        mesh = self.truth.mesh
        tris, tri_fold, material = view_surface(mesh)
        textures = make_scene_textures(self.camera, self.render_settings, self.rng)
        for phi, f0 in zip(self.frame_phase, self.frame_f0):
            disp = self.truth.motion.displacement(np.array([phi]))[0]
            vel = self.truth.motion.velocity(np.array([phi]), f0)[0]
            out = render_frame(self.camera, mesh.nodes + disp, tris, material, tri_fold, vel, textures,
                               self.render_settings, self.rng)
            yield out.image, out.truth, disp, vel


def render_settings(cfg: SynthConfig, wide: WidenedDraw | None = None) -> RenderSettings:
    """The look of a phantom's video: the default panel's (its historical two-sided shading, so the demo's recording
    stays as it was), or with a widened draw's optics blur, fixture and lamp, shaded by Lambert's law."""
    render = RenderSettings(supersample=cfg.supersample, snr=cfg.snr, two_sided_lambert=wide is None)
    if wide is None:
        return render
    return replace(render, psf_sigma_px=wide.psf_sigma_px, fixture_in_view=wide.fixture_in_view,
                   light_dir=wide.light_dir, ambient=wide.ambient)


def make_recording(cfg: SynthConfig, mesh_cfg: MeshConfig, progress: Callable[..., Any] | None = None) -> Recording:
    """Simulate a phantom recording (the video is rendered lazily by :meth:`Recording.frames`)."""
    rng = np.random.default_rng(cfg.seed)
    wide = draw_widened(cfg.seed, cfg.width_px, cfg.height_px, mesh_cfg) if cfg.panel == "widened" else None
    if wide is not None:
        mesh_cfg = wide.true_mesh(mesh_cfg)
    effect, strength = resolve_effect(cfg, rng)
    waveform = PressureWaveform(mean_pa=cfg.mean_pressure_pa, amplitude_rel=cfg.pressure_amplitude_rel,
                                phases_rad=tuple(np.round(rng.uniform(-np.pi, np.pi, 4), 3)))
    log.info("phantom: solving the true motion")
    truth = true_motion(cfg, mesh_cfg, waveform, effect, strength, None if wide is None else wide.load)
    if wide is None:
        camera = phantom_camera(cfg, mesh_cfg, rng)
    else:
        camera = centred_camera(wide.px_per_mm, wide.rotation_deg, np.asarray(wide.centre_offset_px),
                                cfg.width_px, cfg.height_px, mesh_cfg.length_mm)
    f0_fn = (lambda t: slow_f0_drift(t, cfg.f0_hz, 0.002, 0.3, rng)) if cfg.f0_drift_rel > 0 else cfg.f0_hz
    pressure = video_pressure(cfg.duration_s, cfg.ldv_fs_hz, f0_fn, waveform, float(rng.uniform()), cfg.pressure_noise_pa, rng)
    n_frames = int(round(cfg.duration_s * cfg.fps_hz))
    frame_times = np.arange(n_frames) / cfg.fps_hz
    frame_phase = pressure.phase_at(frame_times)
    dt = 0.5 / cfg.fps_hz
    frame_f0 = (pressure.phase_at(frame_times + dt) - pressure.phase_at(np.maximum(frame_times - dt, 0))) / (
        frame_times + dt - np.maximum(frame_times - dt, 0))
    # the vibrometer
    half_depth = mesh_cfg.depth_mm - 0.5
    points = ldv_scan_grid((0.5, mesh_cfg.length_mm - 0.5, -half_depth, half_depth), 22, 17, 0.03,
                           float(rng.uniform(-2, 2)), rng)
    phases = np.arange(cfg.n_phase) / cfg.n_phase
    tris, _, _ = view_surface(truth.mesh)
    verts = truth.mesh.nodes[None] + truth.motion.displacement(phases)
    vels = truth.motion.velocity(phases, cfg.f0_hz)
    table = vertical_velocity_table(points, verts, vels, tris)
    settings = LdvSettings(fs_hz=cfg.ldv_fs_hz, epoch_s=cfg.ldv_epoch_s, noise_rel=cfg.ldv_noise_rel,
                           dropout_fraction=cfg.ldv_dropout_fraction, f0_drift_rel=cfg.f0_drift_rel,
                           pressure_noise_pa=cfg.pressure_noise_pa)
    render = render_settings(cfg, wide)
    if wide is not None:
        settings = replace(settings, dropout_fraction=wide.ldv_dropout_fraction,
                           spike_window_s=wide.ldv_spike_window_s, gap_noise_rel=wide.ldv_gap_noise_rel)
    scan = simulate_ldv_scan(points, PeriodicTable(table), cfg.f0_hz, waveform, settings, rng)
    return Recording(truth, camera, cfg.fps_hz, pressure, frame_times, frame_phase, frame_f0, points, scan, render,
                     waveform, rng, wide)
