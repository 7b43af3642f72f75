"""The optimize window's default: one glottal cycle of the video, counted with the recording's own f0.

A fixed 84 frames is one cycle only at 120 Hz and 10 kHz: at 100 Hz it covers 0.84 of the cycle, at 200 Hz
1.7 cycles.  Real stores (HDF5 files written by the store's writer), the f0 from /sync or, without it,
measured on the video's pressure."""
from __future__ import annotations

import numpy as np
import pytest

from vfcli.config import RecordingConfig
from vfcli.errors import ConfigError
from vfcli.store import Store
from vfcli.store.fit import window_frames


def _store(tmp_path, f0_video_hz=None, pressure_f0_hz=None):
    store = Store(tmp_path / "r.h5")
    with store.write("test") as w:
        with w.stage("hsc", config_json="{}") as s:
            s.put("frame_time", np.arange(10) * 1e-4)
            if pressure_f0_hz is not None:
                fs = 50_000.0
                t = np.arange(int(0.05 * fs)) / fs
                p = 800 + 300 * np.sin(2 * np.pi * pressure_f0_hz * t) + 60 * np.sin(4 * np.pi * pressure_f0_hz * t + 1)
                s.put("pressure", p)
                s.set_attrs(pressure_fs_hz=fs)
        if f0_video_hz is not None:
            with w.stage("sync", config_json="{}", upstream=[("hsc", None)]) as s:
                s.put("ok", np.ones(3, bool))
                s.set_attrs(f0_video_hz=f0_video_hz)
    return store


@pytest.mark.parametrize("f0, dt, frames", [(120.07, 1e-4, 84), (120.0, 1e-4, 84), (125.0, 1e-4, 80),
                                            (200.0, 5e-5, 100), (90.0, 1 / 6000, 67), (100.0, 1e-4, 100)])
def test_the_default_window_is_one_cycle_at_sync_s_f0(tmp_path, f0, dt, frames):
    with _store(tmp_path, f0_video_hz=f0).read() as r:
        n = window_frames(r, RecordingConfig(), dt)
    assert n == frames
    assert n * dt * f0 >= 1.0 - 1e-9 and (n - 1) * dt * f0 < 1.0      # the fewest frames that hold a cycle


def test_without_sync_the_cycle_is_counted_with_the_video_s_pressure(tmp_path):
    with _store(tmp_path, pressure_f0_hz=150.0).read() as r:
        assert window_frames(r, RecordingConfig(), 1e-4) == 67          # 10000 / 150 = 66.7


def test_a_set_window_is_kept_and_no_f0_without_one_is_a_config_error(tmp_path):
    cfg = RecordingConfig.model_validate({"optimize": {"n_frames": 40}})
    with _store(tmp_path).read() as r:
        assert window_frames(r, cfg, 1e-4) == 40
        with pytest.raises(ConfigError, match="optimize.n_frames"):
            window_frames(r, RecordingConfig(), 1e-4)
