"""Read-only view of a store: stages, datasets, provenance and staleness.

Every stage group records its validated config (JSON), the vfcli version, the command
line, the time, the SHA-256 of each raw input file, and the digest of each upstream
stage it used. :meth:`StoreReader.is_current` tells a command that its inputs, config
and upstream stages are unchanged, so it can skip the work; a stage whose upstream was
rewritten since is reported as stale.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import h5py
import numpy as np

from vfcli.errors import MissingStageError, StoreDamagedError, StoreFormatError, StoreLockedError
from vfcli.store import integrity, layout, locking
from vfcli.store.frames import FrameReader
from vfcli.store.provenance import same_inputs


def open_h5(path: Path, mode: str, **kwargs: Any) -> h5py.File:
    """The HDF5 file at ``path`` (``kwargs`` to :class:`h5py.File`); :class:`StoreFormatError` when
    it is not one, :class:`StoreLockedError` when another program holds it open for writing."""
    if path.exists() and not path.is_file():  # a FIFO would block the open; a directory is no store
        raise StoreFormatError("not a regular file, so not a store", path)
    try:
        return h5py.File(path, mode, **kwargs)
    except OSError as exc:
        code = locking.lock_unsupported(exc)
        if code:  # the file system has no locks (NFS, Lustre): not a lock held by another program
            raise locking.hdf5_lock_unsupported_error(code, path) from None
        if "lock" in str(exc).lower():  # libhdf5's own file lock, held by a program writing the file
            raise StoreLockedError(f"another program holds the store open for writing ({_lock_holder(path)}; "
                                   "HDF5 file lock); close it and try again", path) from None
        raise StoreFormatError(f"cannot open as an HDF5 store ({exc})", path) from None


def _lock_holder(path: Path) -> str:
    """Which process holds a lock on ``path`` ("process 123: python writer.py"), from /proc/locks."""
    try:
        st = path.stat()
        inode = f":{st.st_ino}"
        for line in Path("/proc/locks").read_text().splitlines():
            fields = line.split()
            pid = next((x for x in fields if x.isdigit()), None)
            dev_ino = next((x for x in fields if x.count(":") == 2), "")
            if pid and dev_ino.endswith(inode) and int(pid) > 0:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                cmd = " ".join(cmd.split())
                return f"process {pid}: {cmd[:80]}" if cmd else f"process {pid}"
    except (OSError, ValueError):
        pass
    return "holder unknown"


def check_format(f: h5py.File, path: Path) -> None:
    """:class:`StoreFormatError` unless ``f`` is a vfcli store this vfcli can read."""
    try:
        name, version = f.attrs.get("format"), int(f.attrs.get("format_version", -1))
    except integrity.H5_ERRORS as exc:
        raise StoreDamagedError(f"damaged store: its root attributes cannot be read ({integrity.why(exc)})", path) from None
    if name != layout.FORMAT_NAME:
        raise StoreFormatError("not a vfcli store (no 'format' attribute)", path)
    if version > layout.FORMAT_VERSION:
        raise StoreFormatError(
            f"written by a newer vfcli (store format {version}, this vfcli reads up to "
            f"{layout.FORMAT_VERSION}); upgrade vfcli",
            path,
        )


@dataclass
class StageStatus:
    """What ``vfcli info`` shows of one stage."""

    path: str
    complete: bool
    provenance: dict[str, Any]
    size_bytes: int
    stale_because: list[str] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    damaged: list[str] = field(default_factory=list)

    @property
    def stale(self) -> bool:
        return bool(self.stale_because)

    def to_json(self) -> dict[str, Any]:
        prov = dict(self.provenance)
        for k in ("config_json", "inputs_json", "upstream_json"):
            if k in prov:
                prov[k.removesuffix("_json")] = json.loads(prov.pop(k))
        return {
            "path": self.path,
            "complete": self.complete,
            "stale": self.stale,
            "stale_because": self.stale_because,
            "size_bytes": self.size_bytes,
            "provenance": prov,
            "summary": self.summary,
            "damaged": self.damaged,
        }


def _group_size(g: h5py.Group) -> int:
    total = 0

    def visit(_name: str, obj: Any) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += obj.id.get_storage_size()

    g.visititems(visit)
    return total


def _method_changes(path: str, written: int) -> list[str]:
    """Why a stage group at ``path`` written by method version ``written`` is stale under the installed
    vfcli (:attr:`vfcli.store.layout.Stage.method`): one reason naming what changed since, or none."""
    st = layout.stage(path.strip("/").split("/")[0])
    if written == st.method:
        return []
    if written > st.method:
        return [f"method changed: written by a newer vfcli (method {written}, this one has {st.method})"]
    changes = "; ".join(text for v, text in sorted(st.method_changes.items()) if written < v <= st.method)
    return [f"method changed: {st.name} method {written} -> {st.method}" + (f" ({changes})" if changes else "")]


def _fill_missing(had: Any, template: Any, want: Any) -> Any:
    """``had`` (recorded settings) read against ``template`` (the settings under the default config, every key)
    and ``want`` (those the stage would record now): a key ``had`` lacks takes the template's value (a setting
    added since the stage was written, whose default keeps what the stage did); a key neither the template nor
    ``want`` has is dropped (a setting since removed); a key of ``had`` and ``want`` the template lacks stays (a
    run's own, e.g. a refit run's ``refit``)."""
    if not (isinstance(had, dict) and isinstance(template, dict)):
        return had
    want = want if isinstance(want, dict) else {}
    out = {k: _fill_missing(had[k], v, want.get(k)) if k in had else v for k, v in template.items()}
    out.update({k: v for k, v in had.items() if k not in template and k in want})
    return out


def settings_change(had_json: str, want_json: str, defaults_json: str | None = None) -> str | None:
    """The settings that differ between those a stage recorded (``had_json``) and those it would record now
    (``want_json``), as ``key: old -> new``; None when they agree. With ``defaults_json`` (the stage's settings
    under the default config) a setting the stage's vfcli did not have counts as its default: a store written
    before a setting existed stays current (session 38: a new ingest_hsc.pressure_unit, null, made every stage
    of every store STALE with the reason "config changed: " and nothing after it)."""
    had, want = json.loads(had_json), json.loads(want_json)
    if defaults_json is not None:
        had = _fill_missing(had, json.loads(defaults_json), want)
    return None if had == want else _config_diff(had, want)


def _config_diff(had: Any, want: Any, prefix: str = "") -> str:
    """The settings that differ between two config dicts, as ``key: old -> new``."""
    if isinstance(had, dict) and isinstance(want, dict):
        parts = [_config_diff(had.get(k), want.get(k), f"{prefix}{k}.") for k in sorted(set(had) | set(want))
                 if had.get(k) != want.get(k)]
        return ", ".join(parts)
    return f"{prefix.rstrip('.')} {had!r} -> {want!r}"


class StoreReader:
    """Read-only view of a store (an open HDF5 file)."""

    def __init__(self, f: h5py.File, path: Path) -> None:
        self._f = f
        self.path = path
        self._checked: dict[str, list[str]] = {}

    # -- integrity (vfcli/store/integrity.py) ------------------------------
    def problems(self, path: str, contents: bool = False) -> list[str]:
        """What is wrong with stage group ``path``: its structure and provenance (no data read),
        and with ``contents`` every dataset's SHA-256 too (reads every stored byte)."""
        if path not in self._checked or (contents and not self._checked[path]):
            check = integrity.check_contents if contents else integrity.check_structure
            self._checked[path] = check(self._f, path)
        return self._checked[path]

    def _damaged(self, problem: str) -> StoreDamagedError:
        stage = problem.split("/")[1].split()[0].rstrip(":") if problem.startswith("/") else ""
        fix = (f"; rewrite it with `vfcli {layout.STAGES[stage].written_by}` or restore the store from a copy"
               if stage in layout.STAGES else "")
        return StoreDamagedError(f"damaged store: {problem}{fix}", self.path)

    def forget(self, path: str) -> None:
        """Drop what :meth:`problems` found of ``path`` (the stage was rewritten)."""
        self._checked.pop(path, None)

    def refuse_damaged(self, keep: str | None = None) -> None:
        """:class:`StoreDamagedError` naming the first damaged stage other than ``keep``."""
        try:
            paths = self.stage_paths()
        except integrity.H5_ERRORS as exc:
            raise self._damaged(f"its stage groups cannot be listed ({integrity.why(exc)})") from None
        for p in paths:
            if p != keep and self.problems(p):
                raise self._damaged(self.problems(p)[0])

    # -- stages -----------------------------------------------------------
    def stage_paths(self) -> list[str]:
        """Paths of every stage group present (``/hsc``, ``/optimize/run1`` ...)."""
        out = []
        for name, st in layout.STAGES.items():
            if name not in self._f:
                continue
            if st.has_runs:
                out.extend(f"/{name}/{run}" for run in self._f[name])
            else:
                out.append(f"/{name}")
        return out

    def runs(self, name: str) -> list[str]:
        """Names of the runs of a stage with runs (``/optimize/<run>``), complete or not."""
        if not layout.stage(name).has_runs:
            raise ValueError(f"stage {name!r} has no runs")
        return list(self._f[name]) if name in self._f else []

    def has_stage(self, name: str, run: str | None = None, complete: bool = True) -> bool:
        path = layout.stage(name).group_path(run)
        if path not in self._f:
            return False
        return bool(self._f[path].attrs.get("complete", False)) or not complete

    def group(self, name: str, run: str | None = None) -> h5py.Group:
        """The stage group; :class:`MissingStageError` when it is absent or incomplete."""
        st = layout.stage(name)
        if not self.has_stage(name, run):
            # a missing run: the runs there are, and the command that writes this one (`vfcli optimize`, which
            # the advice named alone, writes the run "default")
            runs = [x for x in self.runs(name) if self.has_stage(name, x)] if (run and st.has_runs) else []
            how = (f"run `vfcli {st.written_by}{'' if run == 'default' else f' --run {run}'}` first"
                   + (f", or choose one of its runs: {', '.join(runs)}" if runs else "")) if run else \
                f"run `vfcli {st.written_by}` first"
            raise MissingStageError(
                f"stage {st.group_path(run) if (run or not st.has_runs) else '/' + name} is missing; {how}",
                self.path,
            )
        if self.problems(st.group_path(run)):
            raise self._damaged(self.problems(st.group_path(run))[0])
        return self._f[st.group_path(run)]

    def read(self, name: str, key: str, run: str | None = None) -> np.ndarray:
        """A whole dataset as a numpy array (text datasets as ``str``)."""
        ds = self.dataset(name, key, run)
        g = self._f[layout.stage(name).group_path(run)]
        problem = integrity.check_dataset(ds, g.name, integrity.stage_manifest(self._f, g.name))
        if problem:  # a whole read is checked against the stage's SHA-256 (frames: by `vfcli info --verify`)
            raise self._damaged(problem)
        try:
            if h5py.check_string_dtype(ds.dtype):
                return ds.asstr()[()]
            return FrameReader(ds)[()]
        except OSError as exc:
            raise self._damaged(f"{ds.name} cannot be read ({integrity.why(exc)})") from None

    def frames(self, name: str, key: str, run: str | None = None) -> FrameReader:
        """A per-frame dataset, lazily, for reading frames by index (:class:`FrameReader`)."""
        return FrameReader(self.dataset(name, key, run))

    def dataset(self, name: str, key: str, run: str | None = None) -> h5py.Dataset:
        """A dataset, lazily (for streaming frame by frame)."""
        g = self.group(name, run)
        path = layout.dataset_path(name, key, run)
        if path not in self._f:
            raise MissingStageError(f"{path} is missing from the stage", self.path)
        return g[key]

    def attrs(self, name: str, run: str | None = None) -> dict[str, Any]:
        return dict(self.group(name, run).attrs)

    def digest(self, name: str, run: str | None = None) -> str:
        return str(self.group(name, run).attrs["digest"])

    def root_attrs(self) -> dict[str, Any]:
        """The store's own attributes (format, version, creation time ...)."""
        return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in self._f.attrs.items()}

    def recording_config_json(self) -> str | None:
        """The recording's config as stored (JSON); :class:`StoreDamagedError` when it is not a JSON object."""
        v = self._f.attrs.get(layout.ROOT_CONFIG_ATTR)
        if v is None:
            return None
        try:
            if not isinstance(json.loads(str(v)), dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            raise self._damaged(f"root attribute '{layout.ROOT_CONFIG_ATTR}' is not valid "
                                f"({integrity.why(exc)})") from None
        return str(v)

    # -- provenance checks ---------------------------------------------------
    def status(self, path: str) -> StageStatus:
        """What `vfcli info` shows of stage group ``path``; a damaged stage shows its problems only."""
        if self.problems(path):
            return StageStatus(path, False, {}, 0, damaged=self.problems(path))
        g = self._f[path]
        prov = {k: g.attrs[k] for k in layout.PROVENANCE_ATTRS if k in g.attrs}
        prov = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in prov.items()}
        stale = _method_changes(path, int(g.attrs.get(layout.METHOD_ATTR, 1)))
        for up_path, up_digest in json.loads(prov.get("upstream_json", "{}")).items():
            if up_path not in self._f:
                stale.append(f"{up_path} is gone")
            elif str(self._f[up_path].attrs.get("digest")) != up_digest:
                stale.append(f"{up_path} was rewritten")
        summary = json.loads(str(g.attrs[layout.SUMMARY_ATTR])) if layout.SUMMARY_ATTR in g.attrs else None
        return StageStatus(path, bool(g.attrs.get("complete", False)), prov, _group_size(g), stale, summary)

    def statuses(self, expected_config: Callable[[str, str | None], str | None] | None = None,
                 defaults: Callable[[str, str | None], str | None] | None = None) -> list[StageStatus]:
        """:meth:`status` of every stage, with staleness made honest: a stage is also stale when
        the settings it would record under the stored recording config differ from those it
        recorded (``expected_config(name, run)``, None: not compared; ``defaults(name, run)``: its
        settings under the default config, for settings added since it was written, :func:`settings_change`),
        and when a stage it used is stale (transitively; stages are listed upstream first)."""
        out: dict[str, StageStatus] = {}
        for path in self.stage_paths():
            st = self.status(path)
            name, _, run = path[1:].partition("/")
            want = expected_config(name, run or None) if expected_config else None
            had = st.provenance.get("config_json")
            change = None if want is None or had is None else \
                settings_change(had, want, defaults(name, run or None) if defaults else None)
            if change is not None:
                st.stale_because.append("config changed: " + change)
            for up in json.loads(st.provenance.get("upstream_json", "{}")):
                if up in out and out[up].stale and not any(r.startswith(up + " ") for r in st.stale_because):
                    st.stale_because.append(f"{up} is stale")
            out[path] = st
        return list(out.values())

    def summary(self, name: str, run: str | None = None) -> dict[str, Any] | None:
        """What the stage's run reported, ``{"figures": {...}, "warnings": [...]}``; None for a
        stage written before vfcli stored it."""
        attrs = self.group(name, run).attrs
        return json.loads(str(attrs[layout.SUMMARY_ATTR])) if layout.SUMMARY_ATTR in attrs else None

    def is_current(
        self,
        name: str,
        config_json: str,
        inputs: Mapping[str, Mapping[str, Any]] | None = None,
        upstream: list[tuple[str, str | None]] | None = None,
        run: str | None = None,
        defaults_json: str | None = None,
    ) -> bool:
        """True when the stage exists, is complete, and its config, inputs and upstream are unchanged
        (``defaults_json``: its settings under the default config, :func:`settings_change`).

        :class:`StoreDamagedError` when another stage of the store is damaged: a command never
        reports "up to date" on a damaged store (its own damaged stage is rewritten)."""
        self.refuse_damaged(keep=layout.stage(name).group_path(run))
        if not self.has_stage(name, run):
            return False
        st = self.status(layout.stage(name).group_path(run))
        had = st.provenance.get("config_json")
        if st.stale or (had != config_json if had is None or config_json is None
                        else settings_change(had, config_json, defaults_json) is not None):
            return False
        if inputs is not None and not same_inputs(json.loads(st.provenance["inputs_json"]), inputs):
            return False
        recorded = json.loads(st.provenance.get("upstream_json", "{}"))
        wanted = self.upstream_digests(upstream or [])
        return recorded == wanted

    def previous_inputs(self, name: str, run: str | None = None) -> dict[str, Any]:
        if not self.has_stage(name, run) or self.problems(layout.stage(name).group_path(run)):
            return {}
        return json.loads(self.group(name, run).attrs.get("inputs_json", "{}"))

    def upstream_digests(self, upstream: list[tuple[str, str | None]]) -> dict[str, str]:
        """``{group path: digest}`` of the upstream stages ``[(name, run), ...]`` (must be present)."""
        return {layout.stage(n).group_path(r): self.digest(n, r) for n, r in upstream}

