"""The widened phantom panel: per-seed draws of what varies between real recordings.

``synth.panel = "widened"`` draws, from the seed alone, the conditions a lab's recordings differ
in (issue 15): the camera's in-plane angle and zoom, the optics blur, whether the fixture is in
view, the M5-family geometry of the mould, the material of this batch, the distribution of the
aerodynamic load, the vibrometer's artefacts, whether its UFF export has a units record, and the
lamp (its angle off the camera axis, its direction about it, the share of diffuse light).
The ranges are the constants below (see docs/synth.md for their sources; [est] marks our own
estimates, [pub] published values from the reference note "The physical set-up: numbers to build with").

The draw is a pure function of the seed (its own generator, ``default_rng([seed, STREAM])``),
so it does not disturb the default phantom's random stream, and every drawn value is written to
truth.h5 (:meth:`WidenedDraw.truth_attrs`). The files a lab would have receive only what a lab
knows: the mould's geometry, the nominal material, fps, px_per_mm (from a calibration target)
and the camera rotation in the seeds where ``rotation_stated`` is drawn true (half of them:
some labs measure the mounting angle, others do not).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from vfcli.config import MeshConfig

#: seed-sequence tag of the widened draw's own generator
STREAM = 0x5715

#: field of view (the frame's smaller side), log-uniform from FOV_REL[0] x the glottis length (it
#: runs off the image) to FOV_REL[1] x the folds' larger extent max(L, 2 D + gap) (all in view) [est]
FOV_REL = (0.65, 1.3)

#: (low, high) of each drawn quantity (uniform; psf_sigma_px log-uniform)
RANGES: dict[str, tuple[float, float]] = {
    "rotation_deg": (-180.0, 180.0),         # camera in-plane angle, any [issue 15]
    "centre_offset_rel": (-0.15, 0.15),      # glottis centre from the image centre, x image size [est]
    "psf_sigma_px": (0.3, 3.0),              # Gaussian optics blur, log [issue 15]
    "thickness_mm": (2.5, 3.5),              # T, Scherer 3.0 [est range]
    "exit_radius_mm": (0.8, 1.2),            # R_O, Scherer 0.987 [est range]
    "entrance_radius_rel": (0.9, 1.1),       # R_L / (T / 2), Scherer 1 [est range]
    "entrance_sweep_deg": (40.0, 60.0),      # Scherer 50 [est range]; at most 90 - inferior angle
    "inferior_angle_deg": (30.0, 50.0),      # Scherer 40 [est range]
    "depth_mm": (5.0, 10.0),                 # D: CAD 5-6, default 8 [pub + est]
    "length_mm": (15.0, 17.0),               # L [pub: 15 common, 15-17]
    "gap_mm": (0.0, 0.3),                    # pre-phonatory gap [est]
    "youngs_rel": (0.85, 1.15),              # E of this batch / nominal [est: batch tolerance]
    "density_rel": (0.97, 1.03),             # density of this batch / nominal [est]
    "load_lag_cycles": (0.0, 0.1),           # intraglottal drive delay behind p_sub [est]
    "load_harmonic_rel": (0.0, 0.3),         # its own 2nd-harmonic modulation [est]
    "load_gap_gain": (0.0, 0.5),             # its drop relative to p_sub at the widest opening [est]
    "ldv_dropout_fraction": (0.02, 0.1),     # points with spike bursts or frozen segments [est]
    "ldv_spike_window_s": (0.001, 0.005),    # a spike burst's length, s [est]
    "ldv_gap_noise_rel": (0.3, 2.0),         # signal-loss noise through the gap / signal RMS [est]
    "light_tilt_deg": (0.0, 20.0),           # the lamp's angle off the camera axis [est]
    "light_azimuth_deg": (-180.0, 180.0),    # its direction about the axis, from the glottis' axis, any [est]
    "ambient": (0.1, 0.35),                  # share of the light that does not depend on the surface normal [est]
}


@dataclass(frozen=True)
class LoadDistribution:
    """The intraglottal driving pressure, not a fixed multiple of the subglottal pressure.

    ``p_med(phase) = p_sub(phase - lag) (1 + h cos(4 pi phase + psi)) (1 - g a(phase))`` with
    ``a`` the glottal opening over the cycle relative to its widest (0 closed .. 1 widest).
    The Bernoulli profile of :mod:`vfcli.synth.aero` is applied to ``p_med`` instead of ``p_sub``.

    lag_cycles : delay of the drive, cycles.  harmonic_rel : h (1).  harmonic_phase_rad : psi.
    gap_gain : g (1).
    """

    lag_cycles: float
    harmonic_rel: float
    harmonic_phase_rad: float
    gap_gain: float

    def __call__(self, p_sub: np.ndarray, opening_mm: np.ndarray) -> np.ndarray:
        """(P,) driving pressure (Pa) from one sampled cycle of p_sub (P,) Pa and the opening (P,) mm."""
        n = len(p_sub)
        spec = np.fft.rfft(p_sub) * np.exp(-2j * np.pi * np.arange(n // 2 + 1) * self.lag_cycles)
        lagged = np.fft.irfft(spec, n=n)
        phase = np.arange(n) / n
        widest = float(np.max(opening_mm))
        rel = np.clip(opening_mm / widest, 0.0, 1.0) if widest > 0 else np.zeros(n)
        return lagged * (1.0 + self.harmonic_rel * np.cos(4 * np.pi * phase + self.harmonic_phase_rad)) * (
            1.0 - self.gap_gain * rel)


@dataclass(frozen=True)
class WidenedDraw:
    """All values drawn for one widened phantom (lengths mm, angles degrees)."""

    rotation_deg: float
    rotation_stated: bool
    fov_mm: float
    px_per_mm: float
    centre_offset_px: tuple[float, float]
    psf_sigma_px: float
    fixture_in_view: bool
    thickness_mm: float
    exit_radius_mm: float
    entrance_radius_mm: float
    entrance_sweep_deg: float
    inferior_angle_deg: float
    depth_mm: float
    length_mm: float
    gap_mm: float
    youngs_modulus_pa: float
    density_kg_m3: float
    load: LoadDistribution
    ldv_dropout_fraction: float
    ldv_spike_window_s: float
    ldv_gap_noise_rel: float
    uff_units_record: bool
    light_tilt_deg: float
    light_azimuth_deg: float
    ambient: float

    @property
    def light_dir(self) -> tuple[float, float, float]:
        """(3,) direction towards the lamp in model axes (x along the glottis, z up the camera axis), z = 1."""
        t, a = np.radians(self.light_tilt_deg), np.radians(self.light_azimuth_deg)
        return (float(np.tan(t) * np.cos(a)), float(np.tan(t) * np.sin(a)), 1.0)

    def true_mesh(self, nominal: MeshConfig) -> MeshConfig:
        """The phantom's true [mesh]: drawn geometry and this batch's material."""
        return nominal.model_copy(update=dict(self._geometry(), youngs_modulus_pa=self.youngs_modulus_pa,
                                              density_kg_m3=self.density_kg_m3))

    def lab_mesh(self, nominal: MeshConfig) -> MeshConfig:
        """What the lab knows of the mould: the drawn geometry, the nominal material."""
        return nominal.model_copy(update=self._geometry())

    def _geometry(self) -> dict[str, float]:
        keys = ("thickness_mm", "exit_radius_mm", "entrance_radius_mm", "entrance_sweep_deg",
                "inferior_angle_deg", "depth_mm", "length_mm", "gap_mm")
        return {k: getattr(self, k) for k in keys}

    def truth_attrs(self) -> dict[str, Any]:
        """Every drawn value as truth.h5 root attributes (``widened_<name>``)."""
        out: dict[str, Any] = {}
        for k, v in asdict(self).items():
            if isinstance(v, dict):
                out.update({f"widened_load_{kk}": float(vv) for kk, vv in v.items()})
            elif isinstance(v, tuple):
                out[f"widened_{k}"] = np.asarray(v, dtype=float)
            else:
                out[f"widened_{k}"] = v
        return out


def _u(rng: np.random.Generator, key: str) -> float:
    lo, hi = RANGES[key]
    return float(rng.uniform(lo, hi))


def _log_u(rng: np.random.Generator, key: str) -> float:
    lo, hi = RANGES[key]
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_widened(seed: int, width_px: int, height_px: int, nominal: MeshConfig) -> WidenedDraw:
    """Draw one widened phantom's conditions from ``seed`` (same seed, same draw).

    width_px, height_px : the frame size (the zoom sets px_per_mm so the field of view, the
        frame's smaller side in mm, lies between 0.65 x the glottis length and 1.3 x the folds'
        larger extent, max(L, 2 D + gap), log-uniform).
    nominal : the [mesh] config whose E and density are the batch's nominal values.
    """
    rng = np.random.default_rng([int(seed), STREAM])
    rotation = _u(rng, "rotation_deg")
    rotation_stated = bool(rng.uniform() < 0.5)
    thickness = _u(rng, "thickness_mm")
    exit_r = _u(rng, "exit_radius_mm")
    entrance_r = _u(rng, "entrance_radius_rel") * thickness / 2
    sweep = _u(rng, "entrance_sweep_deg")
    inf_angle = _u(rng, "inferior_angle_deg")
    # the entrance arc may not turn past the inferior surface's direction: that would be a concave
    # corner (Scherer's M5 is tangent there, sweep + angle = 90), which the mesher refuses
    sweep = min(sweep, 90.0 - inf_angle)
    depth = _u(rng, "depth_mm")
    length = _u(rng, "length_mm")
    gap = _u(rng, "gap_mm")
    fov_lo = FOV_REL[0] * length
    fov_hi = FOV_REL[1] * max(length, 2 * depth + gap)
    fov = float(np.exp(rng.uniform(np.log(fov_lo), np.log(fov_hi))))
    size = min(width_px, height_px)
    centre = (_u(rng, "centre_offset_rel") * width_px, _u(rng, "centre_offset_rel") * height_px)
    psf = _log_u(rng, "psf_sigma_px")
    fixture = bool(rng.uniform() < 0.5)
    youngs = _u(rng, "youngs_rel") * nominal.youngs_modulus_pa
    density = _u(rng, "density_rel") * nominal.density_kg_m3
    load = LoadDistribution(_u(rng, "load_lag_cycles"), _u(rng, "load_harmonic_rel"),
                            float(rng.uniform(-np.pi, np.pi)), _u(rng, "load_gap_gain"))
    dropout = _u(rng, "ldv_dropout_fraction")
    spike_window = _u(rng, "ldv_spike_window_s")
    gap_noise = _u(rng, "ldv_gap_noise_rel")
    units = bool(rng.uniform() < 0.5)
    # drawn last, so that every draw above is what it was before the lamp was drawn (session 56)
    tilt, azimuth, ambient = _u(rng, "light_tilt_deg"), _u(rng, "light_azimuth_deg"), _u(rng, "ambient")
    return WidenedDraw(rotation, rotation_stated, fov, size / fov, centre, psf, fixture, thickness, exit_r,
                       entrance_r, sweep, inf_angle, depth, length, gap, youngs, density, load, dropout,
                       spike_window, gap_noise, units, tilt, azimuth, ambient)
