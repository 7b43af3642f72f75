"""A batch manifest: which recordings to run, from which raw folder into which store, with
which config overrides and up to which stage.

Two formats, chosen by the file's suffix.

TOML (``.toml``)::

    [batch]                        # optional: defaults for every recording
    until = "optimize"             # last stage to run (default: every stage)
    workers = 2                    # LocalCluster processes (the CLI's --workers wins)
    retries = 2                    # times a recording is resubmitted after its worker died
    set = { "optimize.max_iterations" = 20 }   # config overrides for every recording

    [batch.slurm]                  # optional: dask-jobqueue SLURMCluster arguments (--slurm)
    queue = "normal"
    cores = 1
    memory = "4GB"
    walltime = "01:00:00"
    jobs = 8                       # jobs to scale to (not a SLURMCluster argument)

    [[recording]]
    name = "rec01"                 # unique; default: the raw folder's name
    raw = "raw/rec01"              # instrument files + recording.toml (relative to the manifest)
    store = "work/rec01.h5"        # default: work/<name>.h5 beside the manifest
    until = "flow"                 # optional, overrides [batch] until
    config = "raw/rec01/lab.toml"  # optional recording.toml to use instead of the raw folder's
    set = { "flow.median_px" = 5 } # optional, added to (and winning over) [batch] set

CSV (``.csv``): a header row with ``name,raw`` and optionally ``store,until,config,set``;
``set`` holds ``section.field=value`` items separated by ``;``. Relative paths are relative
to the manifest's folder. Pure parsing: no file other than the manifest is opened.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from vfcli.errors import ConfigError

_RECORDING_KEYS = {"name", "raw", "store", "until", "config", "set"}
_BATCH_KEYS = {"until", "workers", "retries", "set", "slurm", "pbs"}


@dataclass(frozen=True)
class RecordingEntry:
    """One recording of a batch: what a worker passes to :func:`vfcli.stages.run.run_recording`."""

    name: str
    raw: Path
    store: Path
    until: str | None = None
    config: Path | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def key(self) -> str:
        """SHA-256 of everything that defines this recording's task (the ledger matches on it)."""
        text = json.dumps(self.to_json(), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "raw": str(self.raw), "store": str(self.store), "until": self.until,
                "config": None if self.config is None else str(self.config), "overrides": dict(self.overrides)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "RecordingEntry":
        return cls(name=d["name"], raw=Path(d["raw"]), store=Path(d["store"]), until=d.get("until"),
                   config=None if d.get("config") is None else Path(d["config"]),
                   overrides=dict(d.get("overrides") or {}))


@dataclass(frozen=True)
class Manifest:
    """A parsed manifest: its recordings in file order and the ``[batch]`` settings."""

    path: Path
    recordings: list[RecordingEntry]
    workers: int | None = None
    retries: int = 2
    slurm: Mapping[str, Any] = field(default_factory=dict)
    pbs: Mapping[str, Any] = field(default_factory=dict)

    @property
    def ledger_path(self) -> Path:
        """``<manifest>.ledger.json`` beside the manifest."""
        return self.path.with_name(self.path.name + ".ledger.json")


def flatten_overrides(table: Mapping[str, Any], where: str, prefix: str = "") -> dict[str, Any]:
    """``{"flow": {"median_px": 5}}`` or ``{"flow.median_px": 5}`` -> ``{"flow.median_px": 5}``."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: 'set' must be a table of section.field = value, got {table!r}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        full = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_overrides(value, where, full + "."))
        elif "." not in full:
            raise ConfigError(f"{where}: override {full!r} names no config field (expected section.field)")
        else:
            out[full] = value
    return out


def _csv_overrides(text: str, where: str) -> dict[str, Any]:
    from vfcli.overrides import parse_value

    out: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in text.split(";"))):
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise ConfigError(f"{where}: set item {item!r}: expected section.field=value")
        out[key.strip()] = parse_value(value.strip())
    return out


def _path(base: Path, value: Any, where: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: expected a path, got {value!r}")
    p = Path(value.strip()).expanduser()
    return p if p.is_absolute() else base / p


def _entry(row: Mapping[str, Any], base: Path, defaults: Mapping[str, Any], where: str) -> RecordingEntry:
    unknown = set(row) - _RECORDING_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(_RECORDING_KEYS))}")
    if not row.get("raw"):
        raise ConfigError(f"{where}: 'raw' (the recording's raw folder) is missing")
    raw = _path(base, row["raw"], where)
    name = str(row.get("name") or raw.name).strip()
    if not name or "/" in name:
        raise ConfigError(f"{where}: bad recording name {name!r}")
    store = _path(base, row["store"], where) if row.get("store") else base / "work" / f"{name}.h5"
    until = row.get("until") or defaults.get("until")
    if until is not None:
        from vfcli.stages.run import STEPS

        if until not in STEPS:
            raise ConfigError(f"{where}: until = {until!r} is not a step (steps: {', '.join(STEPS)})")
    config = _path(base, row["config"], where) if row.get("config") else None
    overrides = dict(defaults.get("set") or {})
    own = row.get("set") or {}
    overrides.update(_csv_overrides(own, where) if isinstance(own, str) else flatten_overrides(own, where))
    return RecordingEntry(name=name, raw=raw, store=store, until=until, config=config, overrides=overrides)


def _check_unique(recordings: list[RecordingEntry], path: Path) -> None:
    for attr in ("name", "store"):
        seen: dict[Any, str] = {}
        for rec in recordings:
            value = getattr(rec, attr)
            if attr == "store":
                value = value.resolve()
            if value in seen:
                what = "store file (two workers must never write one file)" if attr == "store" else "name"
                raise ConfigError(f"recordings {seen[value]!r} and {rec.name!r} have the same {what}: {value}", path)
            seen[value] = rec.name


def parse_manifest(path: Path, text: str) -> Manifest:
    """Parse a manifest's ``text`` (TOML or CSV by ``path``'s suffix); relative paths are
    taken from ``path``'s folder.

    Raises
    ------
    ConfigError
        Unknown suffix or field, a missing raw folder name, two recordings with one name
        or one store, a malformed value; the message names the manifest and the recording.
    """
    base = path.parent.resolve()
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"not valid TOML: {exc}", path) from None
        unknown_top = set(doc) - {"batch", "recording"}
        if unknown_top:
            raise ConfigError(f"unknown table(s) {', '.join(sorted(unknown_top))}; expected [batch] and [[recording]]", path)
        batch = doc.get("batch", {})
        unknown = set(batch) - _BATCH_KEYS
        if unknown:
            raise ConfigError(f"[batch]: unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(_BATCH_KEYS))}", path)
        defaults = {"until": batch.get("until"), "set": flatten_overrides(batch.get("set", {}), f"{path}: [batch]")}
        rows = doc.get("recording", [])
        if not isinstance(rows, list):
            raise ConfigError("'recording' must be an array of tables ([[recording]])", path)
        recs = [_entry(r, base, defaults, f"{path}: recording {i + 1}") for i, r in enumerate(rows)]
    elif suffix == ".csv":
        batch = {}
        reader = csv.DictReader(io.StringIO(text))
        if reader.fieldnames is None or "raw" not in [f.strip() for f in reader.fieldnames]:
            raise ConfigError("a CSV manifest needs a header row with at least 'raw' (and name, store, until, config, set)", path)
        recs = []
        for i, row in enumerate(reader):
            clean = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
            clean = {k: v for k, v in clean.items() if v}
            if clean:
                recs.append(_entry(clean, base, {}, f"{path}: line {i + 2}"))
    else:
        raise ConfigError("a manifest is a .toml or a .csv file", path)
    if not recs:
        raise ConfigError("the manifest lists no recording", path)
    _check_unique(recs, path)
    workers = batch.get("workers")
    retries = batch.get("retries", 2)
    for key, value, low in (("workers", workers, 1), ("retries", retries, 0)):
        if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < low):
            raise ConfigError(f"[batch] {key} = {value!r}: expected an integer >= {low}", path)
    for key in ("slurm", "pbs"):
        if not isinstance(batch.get(key, {}), Mapping):
            raise ConfigError(f"[batch.{key}] must be a table", path)
    return Manifest(path=path.resolve(), recordings=recs, workers=workers, retries=retries,
                    slurm=dict(batch.get("slurm", {})), pbs=dict(batch.get("pbs", {})))


def read_manifest(path: str | Path) -> Manifest:
    """Read and parse the manifest file at ``path`` (see :func:`parse_manifest`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read the manifest: {getattr(exc, 'strerror', None) or exc}", path) from None
    return parse_manifest(path, text)
