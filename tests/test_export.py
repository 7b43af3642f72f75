"""`vfcli export` on an optimised phantom: the ParaView files read back (by VTK and pyvista) equal to
the store step by step, the overlay video is H.264 yuv420p and shows the model where the camera sees
it, the tables repeat the store, and an export never modifies the store and does nothing twice."""
from __future__ import annotations

import csv
import hashlib
import re
import subprocess

import numpy as np
import pytest

from _export_store import optimised_store
from conftest import run_vfcli
from vfcli.store.runs import read_mesh, read_run, run_names
from vfcli.store.transaction import Store
from vfcli.store.parts import copy_store


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    store = optimised_store(tmp_path_factory)
    out = tmp_path_factory.mktemp("export") / "out"
    res = run_vfcli("export", store, "--to", out)
    assert res.returncode == 0, res.stderr
    return store, out, res


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_vtkhdf_reads_back_equal_to_the_store_at_every_step(exported):
    import vtk
    import pyvista as pv

    store, out, _ = exported
    with Store(store).read() as r:
        mesh = read_mesh(r)
        runs = [read_run(r, n) for n in run_names(r)]
    assert {p.stem for p in (out / "paraview").glob("*.vtkhdf")} == {run.name for run in runs}
    for run in runs:
        reader = vtk.vtkHDFReader()
        reader.SetFileName(str(out / "paraview" / f"{run.name}.vtkhdf"))
        reader.UpdateInformation()
        assert reader.GetNumberOfSteps() == len(run.sim_time)
        vel = np.gradient(run.displacements.astype(float), run.sim_time, axis=0)
        for k in range(len(run.sim_time)):
            reader.SetStep(k)
            reader.Update()
            grid = pv.wrap(reader.GetOutput())
            assert grid.field_data["Time"][0] == pytest.approx(run.sim_time[k], abs=1e-12)
            assert np.array_equal(grid.cells_dict[pv.CellType.TETRA], mesh.tets)
            np.testing.assert_allclose(grid.points, mesh.nodes + run.displacements[k], atol=1e-9)
            np.testing.assert_array_equal(grid.point_data["displacement_mm"], run.displacements[k])
            np.testing.assert_array_equal(grid.point_data["displacement_std_mm"], run.displacement_std[k])
            np.testing.assert_allclose(grid.point_data["velocity_mm_per_s"], vel[k], rtol=1e-6,
                                       atol=1e-6 * np.abs(vel).max())
            assert grid.point_data["surface_load_Pa"].shape == (mesh.n_nodes, 3)
            # the .vtu files' fold array, which the .vtkhdf lacked
            np.testing.assert_array_equal(grid.point_data["fold"], np.isin(np.arange(mesh.n_nodes), mesh.fold_nodes(1)))


def test_the_pressure_run_pushes_the_inferior_surface_up_by_about_the_recorded_pressure(exported):
    import vtk
    import pyvista as pv

    store, out, _ = exported
    with Store(store).read() as r:
        mesh = read_mesh(r)
        run = read_run(r, "pressure")
        pt, p = r.read("hsc", "pressure_time"), r.read("hsc", "pressure")
    p_rms = float(np.sqrt(np.mean(p[(pt >= run.sim_time[0]) & (pt <= run.sim_time[-1])] ** 2)))
    reader = vtk.vtkHDFReader()
    reader.SetFileName(str(out / "paraview" / "pressure.vtkhdf"))
    reader.SetStep(len(run.sim_time) // 2)
    reader.Update()
    load = pv.wrap(reader.GetOutput()).point_data["surface_load_Pa"]
    inferior = np.unique(mesh.faces[mesh.face_tag == 1])
    inner = np.setdiff1d(inferior, np.unique(mesh.faces[mesh.face_tag != 1]))   # not on a tag boundary
    assert inner.size > 10
    up = load[inner, 2]
    assert np.median(up) > 0                                # pressure pushes into the body: +z from below
    assert 0.2 * p_rms < np.median(np.linalg.norm(load[inner], axis=1)) < 5 * p_rms
    fixture_only = np.setdiff1d(np.unique(mesh.faces[mesh.face_tag == 4]), np.unique(mesh.faces[mesh.face_tag != 4]))
    assert np.all(load[fixture_only] == 0)                  # nothing applied on the clamped walls


def test_pvd_collection_reads_back_with_pyvista(exported):
    import pyvista as pv

    store, out, _ = exported
    with Store(store).read() as r:
        mesh = read_mesh(r)
        run = read_run(r, "free")
    reader = pv.get_reader(str(out / "paraview" / "free.pvd"))
    np.testing.assert_allclose(reader.time_values, run.sim_time, rtol=1e-8)
    for k, t in enumerate(reader.time_values):
        reader.set_active_time_value(t)
        grid = reader.read()[0]
        np.testing.assert_allclose(grid.points, mesh.nodes + run.displacements[k], atol=1e-9)
        np.testing.assert_array_equal(grid.point_data["displacement_mm"], run.displacements[k])


def test_a_second_export_does_nothing_and_the_store_is_never_modified(exported, tmp_path):
    store, _, _ = exported
    copy = tmp_path / "rec.h5"
    copy_store(store, copy)
    before = (_sha(copy), copy.stat().st_mtime_ns)
    out = tmp_path / "out"
    first = run_vfcli("export", copy, "--to", out, "--what", "figures,tables")
    assert first.returncode == 0, first.stderr
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    second = run_vfcli("export", copy, "--to", out, "--what", "figures,tables")
    assert second.returncode == 0, second.stderr
    assert "up to date" in second.stdout
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == stamps
    assert (_sha(copy), copy.stat().st_mtime_ns) == before
    # another selection is another export: it writes
    third = run_vfcli("export", copy, "--to", out, "--what", "tables", "--run", "pressure")
    assert third.returncode == 0 and "written" in third.stdout
    assert (_sha(copy), copy.stat().st_mtime_ns) == before


def test_overlay_video_is_h264_yuv420p_and_shows_the_model_where_the_camera_sees_it(exported):
    import imageio_ffmpeg

    store, out, _ = exported
    mp4 = out / "video" / "overlay.mp4"
    info = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(mp4)], capture_output=True, text=True)
    assert re.search(r"Video: h264.*yuv420p", info.stderr), info.stderr
    with Store(store).read() as r:
        runs = [read_run(r, n) for n in run_names(r)]
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    w, h = meta["size"]
    frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
    assert len(frames) == len(runs[0].sim_time)
    # the frames are the grey video, coloured where the run's superior surface projects with the
    # fitted camera pose and grey elsewhere (mask drawn here from the store, not from the export)
    import cv2

    from vfcli.stages.export_job import run_camera

    with Store(store).read() as r:
        mesh = read_mesh(r)
        shape = r.frames("hsc", "frames")[0].shape
    sup = mesh.faces[mesh.face_tag == 2]
    k = int(np.argmax(np.abs(runs[0].displacements).max(axis=(1, 2))))
    frame = frames[k].astype(int)
    sat = frame.max(axis=2) - frame.min(axis=2)
    scale = 2
    panel_w = shape[1] * scale
    for j, run in enumerate(runs):
        cam = run_camera(run, shape)
        px = (cam.project(mesh.nodes + run.displacements[k]) + 0.5) * scale - 0.5
        mask = np.zeros((h, panel_w), np.uint8)
        cv2.fillPoly(mask, [np.round(px[f]).astype(np.int32) for f in sup], 1)
        far = cv2.dilate(mask, np.ones((9, 9), np.uint8)) == 0
        far[:60] = False                  # the caption
        far[:, -40:] = False              # the colour bar
        x0 = j * (panel_w + 4)
        s_in = sat[:shape[0] * scale, x0:x0 + panel_w][mask.astype(bool)].mean()
        s_out = sat[:shape[0] * scale, x0:x0 + panel_w][far].mean() if far.any() else 0.0
        assert mask.mean() > 0.2 and s_in > s_out + 10, (run.name, s_in, s_out)
    assert len(list((out / "video").glob("overlay_t*ms.png"))) == min(4, len(runs[0].sim_time))


def test_figures_are_written_as_png_and_svg(exported):
    _, out, _ = exported
    names = {p.name for p in (out / "figures").iterdir()}
    for stem in ("fig7_convergence", "fig8_velocities", "glottal_area", "kymogram", "sync_quality",
                 "uncertainty_pressure", "uncertainty_free"):
        assert {f"{stem}.png", f"{stem}.svg"} <= names, stem
    svg = (out / "figures" / "uncertainty_pressure.svg").read_text()
    assert "left fold" in svg and "right fold" in svg and "(mm)" in svg


def test_a_figure_asked_for_its_png_only_writes_no_svg(tmp_path):
    """What the HTML report asks for (it embeds the PNG): one file, the same picture the default writes beside
    its SVG; an unknown format is refused before anything is written."""
    from vfcli.export import figures

    hist = {"fit": {"iteration": np.arange(4), "total": np.array([1.0, 0.3, 0.1, 0.05])}}
    (tmp_path / "both").mkdir()
    both = figures.convergence(hist, tmp_path / "both" / "fig7")
    png = figures.convergence(hist, tmp_path / "fig7", formats=("png",))
    assert [p.name for p in both] == ["fig7.png", "fig7.svg"] and all(p.stat().st_size > 1000 for p in both)
    assert png == [tmp_path / "fig7.png"] and sorted(p.name for p in tmp_path.iterdir()) == ["both", "fig7.png"]
    assert png[0].read_bytes() == both[0].read_bytes()
    with pytest.raises(ValueError, match="figure format 'pdf'"):
        figures.convergence(hist, tmp_path / "x", formats=("pdf",))
    assert not (tmp_path / "x.pdf").exists()


def test_tables_repeat_the_store_and_the_fit_follows_the_vibrometer(exported):
    store, out, _ = exported
    with Store(store).read() as r:
        runs = {n: read_run(r, n) for n in run_names(r)}
        aligned = r.read("sync", "aligned_w")
        ft = r.read("sync", "frame_time")
        ok = r.read("sync", "ok")
        dropout, used = r.read("ldv", "dropout").astype(bool), r.read("fields", "ldv_used").astype(bool)
    rows = list(csv.DictReader(open(out / "tables" / "runs.csv")))
    assert {row["run"] for row in rows} == set(runs)
    for row in rows:
        assert float(row["E_final"]) == pytest.approx(float(runs[row["run"]].history["total"][-1]), rel=1e-5)
        # the stage's time (setup, fit, stated uncertainty) beside its fit loop's
        assert float(row["wall_time_s"]) == pytest.approx(runs[row["run"]].attrs["stage_time_s"], abs=1e-3)
        assert float(row["fit_time_s"]) < float(row["wall_time_s"])
    ldv = list(csv.DictReader(open(out / "tables" / "ldv_velocities.csv")))
    meas = np.array([float(x["measured_vz_mm_per_s"]) for x in ldv])
    sim = np.array([float(x["run_pressure_vz_mm_per_s"]) for x in ldv])
    idx = np.array([[int(x["point"]), int(np.argmin(np.abs(ft - float(x["time_s"]))))] for x in ldv])
    np.testing.assert_allclose(meas, aligned[idx[:, 0], idx[:, 1]], rtol=1e-5, atol=1e-3)
    # a dropout point (spikes, a frozen stretch) was "aligned" like any other, with nothing to tell it from them
    flags = {int(x["point"]): (x["dropout"] == "True", x["used_by_fields"] == "True") for x in ldv}
    assert [flags[p] for p in sorted(flags)] == [(bool(dropout[p]), bool(used[p])) for p in sorted(flags)]
    assert dropout[sorted(flags)].any() and not any(u for d, u in flags.values() if d)
    use = ok[idx[:, 0]] & np.isfinite(sim) & np.isfinite(meas)
    assert use.sum() > 100
    corr = np.corrcoef(meas[use], sim[use])[0, 1]
    assert corr > 0.8, corr   # the simulated surface moves with the measured one at the LDV points


def test_unknown_run_and_unknown_item_are_one_line_errors(exported, tmp_path):
    store, _, _ = exported
    res = run_vfcli("export", store, "--to", tmp_path / "o", "--run", "nope")
    assert res.returncode == 5 and "nope" in res.stderr and "Traceback" not in res.stderr
    res = run_vfcli("export", store, "--to", tmp_path / "o", "--what", "paraview,movies")
    assert res.returncode == 2 and "movies" in res.stderr and "Traceback" not in res.stderr
    res = run_vfcli("export", store, "--to", tmp_path / "o", "--point", "5000,3")
    assert res.returncode == 2 and "5000,3" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "o").exists()


def test_the_convergence_figure_ticks_whole_iterations_on_a_short_run(tmp_path, monkeypatch):
    """A run of two iterations was drawn on ticks 0, 0.25, ..., 2 (fractional iterations); the ticks are whole."""
    import matplotlib.pyplot as plt

    from vfcli.export import figures

    ticks = []
    monkeypatch.setattr(plt.Figure, "savefig", lambda fig, *a, **k: ticks.append(fig.axes[0].get_xticks()))
    figures.convergence({"default": {"iteration": np.arange(3), "total": np.array([35.7, 1.1, 0.88])}},
                        tmp_path / "fig7", formats=("png",))
    shown = [t for t in ticks[0] if -0.5 <= t <= 2.5]
    assert shown and all(float(t).is_integer() for t in shown), shown
