"""Off-screen PNG preview of the two folds with their boundary tags in colour.

pyvista (VTK, the optional extra ``viz``) renders in a subprocess, so a missing
EGL/OSMesa library that makes VTK segfault cannot take the caller down; if pyvista
is not installed or that subprocess fails, a matplotlib 3-D rendering is drawn instead.
"""
from __future__ import annotations

import importlib.util
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from vfcli.model.mesh import TAG_FIXTURE, TAG_INFERIOR, TAG_MEDIAL, TAG_SUPERIOR, FoldMesh

log = logging.getLogger(__name__)

#: face-tag colours (RGB hex) and legend labels
TAG_STYLE = {
    TAG_SUPERIOR: ("#e8a33d", "superior"),
    TAG_MEDIAL: ("#d1495b", "medial"),
    TAG_INFERIOR: ("#3d7fc1", "inferior"),
    TAG_FIXTURE: ("#9a9a9a", "fixture (clamped)"),
}
_WINDOW = (1400, 700)

_PYVISTA_SCRIPT = r"""
import sys
import numpy as np
import pyvista as pv
data = np.load(sys.argv[1])
styles = [(int(t), c, l) for t, c, l in zip(data["tags"], data["colours"], data["labels"])]
pv.OFF_SCREEN = True
pl = pv.Plotter(off_screen=True, shape=(1, 2), window_size=[int(v) for v in data["window"]], border=False)
nodes, faces, tag = data["nodes"], data["faces"], data["face_tag"]
centre = nodes.mean(axis=0)
span = np.ptp(nodes, axis=0).max()
views = [("from anterior-superior", np.array([-1.3, -0.7, 1.2])),
         ("from anterior-inferior", np.array([-1.3, -0.7, -1.0]))]
for col, (name, direction) in enumerate(views):
    pl.subplot(0, col)
    pl.set_background("white")
    for t, colour, label in styles:
        f = faces[tag == t]
        if len(f) == 0:
            continue
        cells = np.hstack([np.full((len(f), 1), 3), f]).ravel()
        pl.add_mesh(pv.PolyData(nodes, cells), color=str(colour), show_edges=True, edge_color="#333333",
                    line_width=0.5, label=str(label), ambient=0.35, diffuse=0.7)
    if col == 0:
        pl.add_legend(bcolor="white", face="rectangle", size=(0.36, 0.16), loc="lower left")
    pl.add_text(name if col else name + "\n" + str(data["title"]), font_size=10, color="black",
                position="upper_left")
    if col == 1:
        pl.add_axes(xlabel="x", ylabel="y", zlabel="z")
    pl.camera.focal_point = centre
    pl.camera.position = centre + span * direction
    pl.camera.up = (0.0, 0.0, 1.0)
    pl.reset_camera()
    pl.camera.zoom(1.0)
pl.screenshot(sys.argv[2])
pl.close()
"""


def _title(mesh: FoldMesh) -> str:
    return f"M5 folds: {mesh.n_nodes} nodes, {len(mesh.tets)} tets"


class _PyvistaJob:
    """The pyvista subprocess drawing one mesh picture, started at once (:meth:`start`) and waited for by
    :meth:`done`, so that the caller can do other work meanwhile (the report draws its figures)."""

    def __init__(self, proc: subprocess.Popen, tmp: tempfile.TemporaryDirectory, path: Path):
        self.proc, self.tmp, self.path = proc, tmp, path

    @classmethod
    def start(cls, mesh: FoldMesh, path: Path) -> "_PyvistaJob | None":
        """The job, or None when pyvista is not installed or its process cannot start (a warning says which)."""
        if importlib.util.find_spec("pyvista") is None:  # an optional dependency (extra `viz`)
            log.warning("mesh preview: pyvista is not installed (pip install 'vfcli[viz]'); drawing it with matplotlib")
            return None
        tags = sorted(TAG_STYLE)
        tmp = tempfile.TemporaryDirectory()
        npz = Path(tmp.name) / "mesh.npz"
        np.savez(npz, nodes=mesh.nodes, faces=mesh.faces, face_tag=mesh.face_tag,
                 tags=np.array(tags), colours=np.array([TAG_STYLE[t][0] for t in tags]),
                 labels=np.array([TAG_STYLE[t][1] for t in tags]), window=np.array(_WINDOW),
                 title=np.array(_title(mesh)))
        env = dict(os.environ)
        env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
        try:
            proc = subprocess.Popen([sys.executable, "-c", _PYVISTA_SCRIPT, str(npz), str(path)], env=env,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        except OSError as exc:
            tmp.cleanup()
            log.warning("pyvista preview failed (%s); falling back to matplotlib", exc)
            return None
        return cls(proc, tmp, path)

    def done(self, timeout_s: float) -> bool:
        """Wait for the picture (at most ``timeout_s`` s from now); True when pyvista drew it."""
        try:
            _, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired as exc:
            self.cancel()
            log.warning("pyvista preview failed (%s); falling back to matplotlib", exc)
            return False
        finally:
            self.tmp.cleanup()
        if self.proc.returncode != 0 or not self.path.is_file() or self.path.stat().st_size == 0:
            log.warning("pyvista preview failed (exit %s: %s); falling back to matplotlib",
                        self.proc.returncode, err.strip().splitlines()[-1:] or "")
            return False
        return True

    def cancel(self) -> None:
        """End the process if it is still drawing (its picture is not wanted) and remove its files."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate()
        self.tmp.cleanup()


def _render_matplotlib(mesh: FoldMesh, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(_WINDOW[0] / 100, _WINDOW[1] / 100), dpi=100)
    tri = mesh.nodes[mesh.faces]
    colours = np.array([TAG_STYLE[int(t)][0] for t in mesh.face_tag])
    lo, hi = mesh.nodes.min(axis=0), mesh.nodes.max(axis=0)
    views = [("from anterior-superior", 35, np.array([-1.3, -0.7, 1.2])),
             ("from anterior-inferior", -30, np.array([-1.3, -0.7, -1.0]))]
    for col, (name, elev, view) in enumerate(views):
        ax = fig.add_subplot(1, 2, col + 1, projection="3d")
        order = np.argsort(tri.mean(axis=1) @ view)  # back to front: visible faces win
        ax.add_collection3d(Poly3DCollection(tri[order], facecolors=colours[order], edgecolors="#333333",
                                             linewidths=0.2))
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(hi - lo)
        ax.view_init(elev=elev, azim=-150)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        ax.set_title(name)
    fig.suptitle(_title(mesh))
    fig.legend(handles=[Patch(color=c, label=lab) for c, lab in TAG_STYLE.values()], loc="lower center", ncol=4)
    fig.savefig(path)
    plt.close(fig)


def render_mesh_png(mesh: FoldMesh, path: str | Path, backend: str = "auto", timeout_s: float = 120.0) -> str:
    """Render both folds, faces coloured by tag, to a PNG, off-screen.

    Parameters
    ----------
    mesh : FoldMesh.
    path : output PNG path.
    backend : ``"auto"`` (pyvista in a subprocess, matplotlib if that fails),
        ``"pyvista"`` or ``"matplotlib"``.
    timeout_s : time limit of the pyvista subprocess, s.

    Returns
    -------
    The renderer that produced the file: ``"pyvista"`` or ``"matplotlib"``.
    """
    return MeshPicture(mesh, path, backend).result(timeout_s)


class MeshPicture:
    """:func:`render_mesh_png` begun now and finished by :meth:`result`: the pyvista subprocess draws while the
    caller goes on (the report: 1.9 s of a tiny store's 6.2 s, session 45).  As a context manager it ends that
    process on leaving, so a caller that fails before :meth:`result` leaves no process drawing behind it."""

    def __init__(self, mesh: FoldMesh, path: str | Path, backend: str = "auto"):
        self.mesh, self.path = mesh, Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.job = _PyvistaJob.start(mesh, self.path) if backend in ("auto", "pyvista") else None

    def result(self, timeout_s: float = 120.0) -> str:
        """Wait for the picture (pyvista's at most ``timeout_s`` s from now; matplotlib's when that fails or
        pyvista is not there): ``"pyvista"`` or ``"matplotlib"``, the renderer that produced the file."""
        job, self.job = self.job, None
        if job is not None and job.done(timeout_s):
            return "pyvista"
        _render_matplotlib(self.mesh, self.path)
        return "matplotlib"

    def __enter__(self) -> "MeshPicture":
        return self

    def __exit__(self, *exc) -> None:
        if self.job is not None:      # :meth:`result` was never called: nobody waits for the picture
            self.job.cancel()
            self.job = None
