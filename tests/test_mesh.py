"""M5 tetrahedral mesh: volume, tags, orientation, (u, v) maps, mirror symmetry."""
import json
from pathlib import Path

import numpy as np
import pytest

from vfcli.model.m5 import M5Params
from vfcli.model.mesh import (SIDE_INFERIOR, SIDE_NONE, SIDE_SUPERIOR, TAG_FIXTURE, TAG_INFERIOR, TAG_MEDIAL,
                        TAG_SUPERIOR, FoldMesh, boundary_faces, build_mesh, dihedral_angles_deg)

PARAMS = M5Params()


@pytest.fixture(scope="module")
def mesh():
    return build_mesh(PARAMS, target_edge_mm=1.5)


def _face_normals(m):
    p = m.nodes[m.faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n, p.mean(axis=1)


@pytest.mark.parametrize("edge", [2.0, 1.5])
def test_volume_of_each_fold_matches_analytic_area_times_length(edge):
    m = build_mesh(PARAMS, target_edge_mm=edge)
    for fold in (0, 1):
        assert m.fold_volume(fold) == pytest.approx(PARAMS.volume_mm3(), rel=0.01)
    assert np.all(m.tet_volumes() > 0)


def test_boundary_is_closed_and_outward(mesh):
    n, c = _face_normals(mesh)
    for fold in (0, 1):
        sel = mesh.face_fold == fold
        # divergence theorem: (1/3) sum c . n dA = volume only for a closed, outward surface
        vol = np.sum(np.einsum("ij,ij->i", c[sel], n[sel])) / 6.0
        assert vol == pytest.approx(mesh.fold_volume(fold), rel=1e-10)
        assert np.abs(n[sel].sum(axis=0)).max() < 1e-9
    np.testing.assert_array_equal(np.sort(np.sort(mesh.faces, axis=1), axis=0),
                                  np.sort(np.sort(boundary_faces(mesh.tets), axis=1), axis=0))


def test_every_boundary_face_has_exactly_one_geometric_tag(mesh):
    assert set(np.unique(mesh.face_tag)) == {TAG_INFERIOR, TAG_SUPERIOR, TAG_MEDIAL, TAG_FIXTURE}
    n, c = _face_normals(mesh)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    half_gap = PARAMS.gap_mm / 2
    lateral = np.abs(np.abs(c[:, 1]) - (half_gap + PARAMS.depth_mm)) < 1e-9
    ends = (np.abs(c[:, 0]) < 1e-9) | (np.abs(c[:, 0] - PARAMS.length_mm) < 1e-9)
    np.testing.assert_array_equal(mesh.face_tag == TAG_FIXTURE, lateral | ends)
    free = ~(lateral | ends)
    medial = free & (np.abs(n[:, 2]) < 1e-9) & (np.abs(np.abs(c[:, 1]) - half_gap) < 1e-9)
    np.testing.assert_array_equal(mesh.face_tag == TAG_MEDIAL, medial)
    np.testing.assert_array_equal(mesh.face_tag == TAG_SUPERIOR, free & ~medial & (n[:, 2] > 0))
    np.testing.assert_array_equal(mesh.face_tag == TAG_INFERIOR, free & ~medial & (n[:, 2] < 0))
    # medial faces point to the midplane
    med = mesh.face_tag == TAG_MEDIAL
    assert np.all(n[med, 1] * np.sign(c[med, 1]) < -0.999)


def test_folds_are_node_for_node_mirror_images(mesh):
    half = mesh.n_nodes // 2
    np.testing.assert_allclose(mesh.nodes[:half], mesh.nodes[half:] * [1, -1, 1], atol=1e-12)
    np.testing.assert_array_equal(mesh.fold_nodes(0), np.arange(half))
    np.testing.assert_array_equal(mesh.uv[:half], mesh.uv[half:])
    assert np.all(mesh.nodes[mesh.fold_nodes(0), 1] < 0) and np.all(mesh.nodes[mesh.fold_nodes(1), 1] > 0)
    assert mesh.nodes[:, 2].max() == pytest.approx(0.0, abs=1e-12)
    assert mesh.fold_volume(0) == pytest.approx(mesh.fold_volume(1), rel=1e-12)


def test_offsets_and_rotation_move_only_their_fold():
    base = build_mesh(PARAMS, target_edge_mm=2.0)
    moved = build_mesh(M5Params(offset_y_mm=(0.0, 0.3), rotation_deg=(5.0, 0.0)), target_edge_mm=2.0)
    half = base.n_nodes // 2
    np.testing.assert_allclose(moved.nodes[half:], base.nodes[half:] + [0, 0.3, 0])
    assert not np.allclose(moved.nodes[:half], base.nodes[:half])
    assert moved.fold_volume(0) == pytest.approx(base.fold_volume(0), rel=1e-12)
    assert np.all(moved.tet_volumes() > 0)


def test_uv_maps_are_one_to_one_and_consistently_oriented(mesh):
    side = mesh.face_side
    free_faces = mesh.face_tag != TAG_FIXTURE
    on_free = np.zeros(mesh.n_nodes, bool)
    on_free[mesh.faces[free_faces]] = True
    np.testing.assert_array_equal(on_free, mesh.node_side != SIDE_NONE)
    assert np.all(np.isfinite(mesh.uv[on_free])) and np.all(np.isnan(mesh.uv[~on_free]))
    assert mesh.uv[on_free].min() >= 0.0 and mesh.uv[on_free].max() <= 1.0
    for fold in (0, 1):
        nodes = mesh.fold_nodes(fold)
        for s in (SIDE_INFERIOR, SIDE_SUPERIOR):
            sel = free_faces & (side == s) & (mesh.face_fold == fold)
            ids = np.unique(mesh.faces[sel])
            ids = ids[np.isin(ids, nodes)]
            uv = np.round(mesh.uv[ids], 12)
            assert len(np.unique(uv, axis=0)) == len(ids), "two nodes share a (u, v)"
            t = mesh.uv[mesh.faces[sel]]
            area = 0.5 * ((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                          - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1]))
            assert np.all(area > 1e-8) or np.all(area < -1e-8), "uv triangles fold over"
            assert np.abs(area).sum() == pytest.approx(1.0, rel=1e-9)  # covers [0, 1]^2 once


def test_sides_split_in_the_middle_of_the_medial_surface(mesh):
    n1 = mesh.fold_nodes(1)
    p, uv, side = mesh.nodes[n1], mesh.uv[n1], mesh.node_side[n1]
    split = np.abs(p[:, 2] - PARAMS.split_z_mm) < 1e-9
    split &= np.abs(p[:, 1] - PARAMS.gap_mm / 2) < 1e-9
    assert split.sum() >= 2
    np.testing.assert_allclose(uv[split, 1], 1.0)
    assert np.all(side[split] == SIDE_SUPERIOR)
    np.testing.assert_allclose(uv[side > 0, 0], p[side > 0, 0] / PARAMS.length_mm)
    assert np.all(p[side == SIDE_SUPERIOR, 2] >= PARAMS.split_z_mm - 1e-9)
    assert np.all(p[side == SIDE_INFERIOR, 2] < PARAMS.split_z_mm)
    lateral = np.abs(p[:, 1] - (PARAMS.gap_mm / 2 + PARAMS.depth_mm)) < 1e-9
    np.testing.assert_allclose(uv[lateral & (side > 0), 1], 0.0)


def test_round_trip_through_plain_arrays(mesh):
    arrays = mesh.to_arrays()
    assert set(arrays) == {"nodes", "tets", "tet_fold", "faces", "face_tag", "face_fold", "uv", "node_side"}
    again = FoldMesh(**{k: np.array(v) for k, v in arrays.items()})
    for k, v in arrays.items():
        np.testing.assert_array_equal(getattr(again, k), v)


def test_quality_reported_and_bad_sizes_rejected(mesh):
    assert mesh.min_dihedral_deg() > 1.0
    with pytest.raises(ValueError):
        build_mesh(PARAMS, target_edge_mm=0.0)
    with pytest.raises(ValueError):
        build_mesh(PARAMS, min_ratio=0.9)
    with pytest.raises(ValueError):
        FoldMesh(**{**mesh.to_arrays(), "tets": mesh.tets[:, :3]})


def test_preview_png_shows_every_tag_colour(mesh, tmp_path):
    import matplotlib.image as mpimg
    from matplotlib.colors import to_rgb

    from vfcli.model.preview import TAG_STYLE, render_mesh_png

    out = tmp_path / "mesh.png"
    assert render_mesh_png(mesh, out, backend="matplotlib") == "matplotlib"
    img = mpimg.imread(out)[..., :3]
    for colour, label in TAG_STYLE.values():
        close = np.all(np.abs(img - np.array(to_rgb(colour))) < 0.02, axis=-1)
        assert close.sum() > 50, f"no {label} pixels in the preview"


def test_the_pyvista_picture_is_drawn_while_the_caller_goes_on(mesh, tmp_path):
    """`vfcli report` begins the mesh picture before its other figures: pyvista's process is running when the
    constructor returns (the caller's work overlaps it; a tiny store's report 6.2 -> 3.6 s, session 45), and
    :meth:`result` gives the picture (matplotlib's where VTK cannot draw off-screen)."""
    pytest.importorskip("pyvista")
    from vfcli.model.preview import MeshPicture

    out = tmp_path / "m.png"
    picture = MeshPicture(mesh, out)
    assert picture.job.proc.poll() is None and not out.exists()
    assert picture.result() in ("pyvista", "matplotlib") and out.stat().st_size > 10_000


def test_a_caller_that_fails_before_the_picture_leaves_no_pyvista_process_behind(mesh, tmp_path):
    """`vfcli report` failing between starting the mesh picture and waiting for it (a bug, exit 1): leaving the
    picture's context ends its pyvista process and removes its temporary folder (before, the process went on
    drawing into the report's deleted folder)."""
    pytest.importorskip("pyvista")
    from vfcli.model.preview import MeshPicture

    with pytest.raises(ZeroDivisionError):
        with MeshPicture(mesh, tmp_path / "m.png") as picture:
            job = picture.job
            assert job.proc.poll() is None
            1 / 0
    assert job.proc.returncode is not None and not Path(job.tmp.name).exists()
    assert picture.job is None


@pytest.mark.parametrize("overrides, field, allowed", [
    (["mesh.min_dihedral_deg=18.5"], "mesh.min_dihedral_deg = 18.5", "less than or equal to 18"),
    (["mesh.target_edge_mm=0.1"], "mesh.target_edge_mm = 0.1", "greater than or equal to 0.7"),   # tetgen ran 12 min
    (["mesh.inferior_angle_deg=60"], "mesh.inferior_angle_deg 60", "at most 40 deg"),
    (["mesh.entrance_sweep_deg=70"], "mesh.entrance_sweep_deg 70", "at most 20 deg"),
    (["mesh.entrance_sweep_deg=1", "mesh.inferior_angle_deg=89"], "mesh.inferior_angle_deg 89", "mm tall"),
])
def test_a_mesh_tetgen_or_the_m5_profile_cannot_take_exits_2_and_leaves_the_store(tmp_path, overrides, field, allowed):
    """min_dihedral_deg above the bound tetgen's refinement ends at; a concave or 461 mm tall M5 profile:
    one line naming the setting and what is allowed, before anything is built."""
    from conftest import run_vfcli

    store = tmp_path / "rec.h5"
    assert run_vfcli("mesh", store, "--set", "mesh.target_edge_mm=3").returncode == 0
    before = (store.read_bytes(), store.stat().st_mtime_ns)
    res = run_vfcli("mesh", store, "--force", "--set", "mesh.target_edge_mm=3", *[a for o in overrides for a in ("--set", o)],
                    timeout=120)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr
    assert field in res.stderr and allowed in res.stderr
    assert (store.read_bytes(), store.stat().st_mtime_ns) == before


def test_a_quality_refinement_that_does_not_end_stops_with_a_config_error(monkeypatch):
    """Above MAX_MIN_DIHEDRAL_DEG tetgen's refinement runs without end (25 degrees: > 60 s and a growing
    memory at 1.5 mm); its bound on added points (-S) stops it with one clear line."""
    import vfcli.model.mesh as mesh_module
    from vfcli.errors import ConfigError

    monkeypatch.setattr(mesh_module, "MAX_MIN_DIHEDRAL_DEG", 34.0)  # let build_mesh pass 25 to tetgen
    with pytest.raises(ConfigError, match="did not end within .* mesh.min_dihedral_deg 25"):
        build_mesh(PARAMS, target_edge_mm=1.5, min_dihedral_deg=25.0)


def test_sigterm_while_tetgen_meshes_ends_the_process_at_once_and_leaves_the_store(tmp_path):
    """tetgen's C code never returns to Python's SIGTERM handler until it is done: a SIGTERM sent while it meshed
    at mesh.target_edge_mm = 0.1 went unanswered for 12 min.  Now the signal's default action ends the process at
    once (returncode -SIGTERM, where the handler would have exited 143 after tetgen), the store left as by kill -9."""
    import signal
    import subprocess
    import sys

    from conftest import ROOT, run_vfcli

    store = tmp_path / "rec.h5"
    assert run_vfcli("mesh", store, "--set", "mesh.target_edge_mm=3").returncode == 0
    before = (store.read_bytes(), store.stat().st_mtime_ns)
    proc = subprocess.Popen([sys.executable, "-m", "vfcli.cli.main", "mesh", str(store), "--force", "-v", "--set",
                             "mesh.target_edge_mm=0.7"], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:                      # tetgen takes 1.2 s at 0.7 mm: the signal lands inside it
        if "tetgen meshes the folds" in line:
            proc.send_signal(signal.SIGTERM)
            break
    assert proc.wait(timeout=60) == -signal.SIGTERM
    assert (store.read_bytes(), store.stat().st_mtime_ns) == before
    assert run_vfcli("info", "--verify", store).returncode == 0
    res = run_vfcli("mesh", store, "--force", "--set", "mesh.target_edge_mm=3", "--json")
    assert res.returncode == 0 and not list(tmp_path.glob(".rec.h5.vfcli-*.tmp")), res.stderr
    # the dihedral target is tetgen's goal, not a bound: the summary says how many tets miss it
    from vfcli.store import Store
    from vfcli.store.mesh import read_mesh

    out = json.loads(res.stdout)
    with Store(store).read() as r:
        stored = read_mesh(r)
    below = int((dihedral_angles_deg(stored.nodes, stored.tets).min(axis=1) < 15.0).sum())
    assert out["min_dihedral_target_deg"] == 15.0 and out["tets_below_target"] == below > 0
