"""What every stage runner shares: the run context and the idempotent, atomic write."""
from __future__ import annotations

import json
import logging
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Literal

from vfcli.config import FlowConfig, RecordingConfig, fields_shaping, load_config
from vfcli.errors import MissingStageError
from vfcli.parallel import Mapper
from vfcli.progress import Progress, no_progress
from vfcli.store.provenance import describe_inputs, sha256_file
from vfcli.store import StageWriter, Store, StoreReader

log = logging.getLogger(__name__)


@dataclass
class RunContext:
    """One command's view of a recording: its store, its configs and how to report.

    map : where the recording's independent pieces of work run (:mod:`vfcli.parallel`; the
        optimize basis solves, the diagnosis's bootstrap replicates); None: one after the other in this process.
    local_map : where the pieces that share this process's memory run (the diagnosis's profile values and refits:
        each uses the run's baseline, half a GB on the demo recording, and reads the open store): forked children or
        threads (:func:`vfcli.parallel.local_map`, the command line's ``--jobs``); None: one after the other.
    """

    store: Store
    stored_config: RecordingConfig
    config: RecordingConfig
    command: str = "vfcli"
    force: bool = False
    progress: Progress = no_progress
    map: Mapper | None = None
    local_map: Mapper | None = None
    #: SHA-256 of the config file the stored config was read from now (None: the store's own was used)
    config_file_sha256: str | None = None

    @classmethod
    def open(
        cls,
        path: str | Path,
        config_path: str | Path | None = None,
        overrides: list[str] | None = None,
        **kwargs: Any,
    ) -> "RunContext":
        """Load the recording config (file, else the stored one, else defaults) plus overrides."""
        store = Store(path)
        stored_json = None
        if store.exists():
            with store.read() as r:
                stored_json = r.recording_config_json()
        stored, effective = load_config(config_path, stored_json, overrides)
        file_sha = sha256_file(config_path) if config_path is not None else None   # load_config read it just now
        return cls(store=store, stored_config=stored, config=effective, config_file_sha256=file_sha, **kwargs)

    def config_is_stored(self, reader: StoreReader, stored_json: str) -> bool:
        """Whether the store holds this config already (and, read from a file now, that file's hash)."""
        from vfcli.store import layout

        return reader.recording_config_json() == stored_json and (
            self.config_file_sha256 is None
            or reader.root_attrs().get(layout.ROOT_CONFIG_FILE_ATTR) == self.config_file_sha256)


def stage_config_json(name: str, config: RecordingConfig) -> str | None:
    """The settings stage ``name`` records (and compares to decide it is current), as JSON; None
    for a stage whose settings are its run's own (``optimize``, ``diagnose``: command-line
    options, not the recording config). ``vfcli info`` compares them with the recording config."""
    dump = lambda section: getattr(config, section).model_dump(mode="json")  # noqa: E731
    if name == "hsc":  # the pose is optimize's, not /hsc's
        return json.dumps({"ingest_hsc": dump("ingest_hsc"),
                           "camera": config.camera.model_dump(mode="json", exclude={"pose"})}, sort_keys=True)
    if name == "ldv":
        return json.dumps({"ingest_ldv": dump("ingest_ldv"), "ldv_frame": dump("ldv_frame")}, sort_keys=True)
    if name == "sync":
        return json.dumps({"sync": dump("sync")}, sort_keys=True)
    if name in ("flow", "fields"):
        out = {"flow": config.flow.model_dump(mode="json", include=set(fields_shaping(FlowConfig, name)))}
        if name == "flow":  # camera.pose decides whether the lateral axis may follow the gap (flow_pipeline)
            out["camera"] = {"pose": config.camera.pose}
        return json.dumps(out, sort_keys=True)
    if name == "mesh":
        return config.mesh.model_dump_json()
    return None


#: The optimisation run the recording config makes (`vfcli run`, `vfcli optimize` without --run): compared with
#: the config by `vfcli run`, `info` and `report`; other runs hold their own command-line options.
DEFAULT_RUN = "default"


def optimize_settings_json(config: RecordingConfig) -> str:
    """The settings an optimisation run records (and compares to decide it is current), as JSON:
    [optimize] and [camera]; the mesh and its material are /mesh's (an upstream stage), not the
    live [mesh] section's."""
    return json.dumps({"optimize": config.optimize.model_dump(mode="json"),
                       "camera": config.camera.model_dump(mode="json")}, sort_keys=True)


def expected_settings(name: str, run: str | None, config: RecordingConfig) -> str | None:
    """The settings JSON stage ``name`` (run ``run``) would record under ``config``: :func:`stage_config_json`,
    and for the default optimisation run :func:`optimize_settings_json`; None: not compared (other runs, and
    diagnose: their own command-line options, compared by the stage itself when it runs)."""
    if name == "optimize":
        return optimize_settings_json(config) if run == DEFAULT_RUN else None
    return stage_config_json(name, config)


def default_settings(name: str, run: str | None) -> str | None:
    """The settings JSON stage ``name`` records under the default config (every optimisation run's under
    :func:`optimize_settings_json`): what a setting it lacks, added to vfcli since it was written, counts as
    (:func:`vfcli.store.reader.settings_change`)."""
    if name == "optimize":
        return optimize_settings_json(RecordingConfig())
    return stage_config_json(name, RecordingConfig())


def _warn_stale_upstream(ctx: RunContext, path: str, upstream: list[tuple[str, str | None]]) -> None:
    """Warn when a stage found up to date with its own inputs uses a stage `vfcli info` calls STALE (a config
    change upstream that no command has applied yet): `vfcli diagnose` said "up to date" and printed the old verdict
    while info said the diagnosis was stale."""
    from vfcli.store import layout

    if not upstream:
        return
    with ctx.store.read() as r:
        status = {st.path: st for st in r.statuses(lambda n, run: expected_settings(n, run, ctx.config),
                                                   default_settings)}
    for name, run in upstream:
        st = status.get(layout.stage(name).group_path(run))
        if st is not None and st.stale:
            log.warning("%s is up to date with what it read, but %s is STALE (%s): `vfcli run` redoes the stages in "
                        "order", path, st.path, "; ".join(st.stale_because))
            return


def expected_configs(recording_config_json: str | None) -> Callable[[str, str | None], str | None]:
    """``(stage name, run) -> settings JSON`` each stage would record under the stored recording config
    (:func:`expected_settings`: the rules `vfcli run` decides by, so that `info` and the report say what it does)."""
    _, config = load_config(None, recording_config_json, None)
    return lambda name, run: expected_settings(name, run, config)


@dataclass
class StageResult:
    """What a stage run did, for the CLI's summary (``--json``)."""

    stage: str
    status: Literal["written", "up-to-date"]
    summary: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"stage": self.stage, "status": self.status, **self.summary}


Body = Callable[[StoreReader, StageWriter], dict[str, Any]]


def run_stage(
    ctx: RunContext,
    name: str,
    *,
    config_json: str,
    body: Body,
    input_paths: list[str | Path] | None = None,
    upstream: list[tuple[str, str | None]] | None = None,
    run: str | None = None,
) -> StageResult:
    """Write stage ``name`` with ``body`` unless it is up to date (``ctx.force`` reruns).

    ``body(reader, stage_writer)`` reads what it needs through ``reader`` (the store as it
    is inside the transaction), writes through ``stage_writer`` and returns a summary.
    """
    from vfcli.store import layout

    path = layout.stage(name).group_path(run)
    upstream = upstream or []
    input_paths = list(input_paths or [])
    stored_json = ctx.stored_config.model_dump_json(exclude_unset=True)
    previous: dict[str, Any] = {}
    stored_summary: dict[str, Any] = {}
    inputs: dict[str, Any] | None = None if input_paths else {}  # None: hashed while the stage is written
    if ctx.store.exists():
        with ctx.store.read() as r:
            r.upstream_digests(upstream)  # MissingStageError when an upstream stage is absent
            previous = r.previous_inputs(name, run)
            current = False
            if not ctx.force and r.has_stage(name, run):  # only then do the hashes decide
                inputs = describe_inputs(input_paths, previous) if input_paths else {}
                current = r.is_current(name, config_json, inputs, upstream, run, default_settings(name, run))
            stored_summary = (r.summary(name, run) or {}) if current else {}
            config_changed = not ctx.config_is_stored(r, stored_json)
    elif upstream:
        up = layout.stage(upstream[0][0])
        raise MissingStageError(f"stage /{up.name} is missing; run `vfcli {up.written_by}` first", ctx.store.path)
    else:
        current, config_changed = False, True
    if current:
        if config_changed:
            with ctx.store.write(ctx.command) as w:
                w.set_recording_config(stored_json, ctx.config_file_sha256)
        log.info("%s is up to date (inputs and config unchanged); --force reruns", path)
        _warn_stale_upstream(ctx, path, upstream)
        return StageResult(path, "up-to-date", dict(stored_summary.get("figures", {})))
    hashed = _Background(describe_inputs, input_paths, previous) if inputs is None else None
    with ctx.store.write(ctx.command) as w:
        w.set_recording_config(stored_json, ctx.config_file_sha256)
        with w.stage(name, config_json=config_json, inputs=inputs if hashed is None else hashed.result,
                     upstream=upstream, run=run) as s:
            with captured_warnings() as warnings:
                summary = body(w.reader, s)
            s.set_summary(summary, warnings)
    return StageResult(path, "written", summary)


@dataclass
class StageSpec:
    """One stage of :func:`run_stages`: what :func:`run_stage` takes, for a stage without raw inputs."""

    name: str
    config_json: str | None
    body: Body
    upstream: list[tuple[str, str | None]] = field(default_factory=list)
    run: str | None = None


def _group_path(sp: StageSpec) -> str:
    from vfcli.store import layout

    return layout.stage(sp.name).group_path(sp.run)


def run_stages(ctx: RunContext, specs: list[StageSpec]) -> list[StageResult]:
    """Write several stages, in order, in ONE transaction: each unless it is up to date (judged
    inside the transaction, so a later stage sees the earlier ones as written); all of them
    reach the store or none does (``vfcli flow``: /flow and /fields). The store must exist
    (these stages read upstream ones); ``ctx.force`` rewrites them all."""
    stored_json = ctx.stored_config.model_dump_json(exclude_unset=True)

    def current(r: StoreReader, sp: StageSpec) -> bool:
        return (not ctx.force and r.has_stage(sp.name, sp.run)
                and r.is_current(sp.name, sp.config_json, {}, sp.upstream, sp.run, default_settings(sp.name, sp.run)))

    def up_to_date(r: StoreReader, sp: StageSpec) -> StageResult:
        log.info("%s is up to date (inputs and config unchanged); --force reruns", _group_path(sp))
        return StageResult(_group_path(sp), "up-to-date", dict((r.summary(sp.name, sp.run) or {}).get("figures", {})))

    with ctx.store.read() as r:
        if all(current(r, sp) for sp in specs):
            results = [up_to_date(r, sp) for sp in specs]
            if ctx.config_is_stored(r, stored_json):
                return results
        else:
            results = []
    with ctx.store.write(ctx.command) as w:
        w.set_recording_config(stored_json, ctx.config_file_sha256)
        if results:  # only the recording config changed
            return results
        for sp in specs:
            if current(w.reader, sp):
                results.append(up_to_date(w.reader, sp))
                continue
            with w.stage(sp.name, config_json=sp.config_json, inputs={}, upstream=sp.upstream, run=sp.run) as s:
                with captured_warnings() as warnings:
                    summary = sp.body(w.reader, s)
                s.set_summary(summary, warnings)
            results.append(StageResult(_group_path(sp), "written", summary))
    return results


class _Capture(logging.Handler):
    """Collects the messages of WARNING and above; passes on every record the logger would
    have handled without the capture (see :func:`captured_warnings`)."""

    def __init__(self, logger: logging.Logger, old_level: int) -> None:
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []
        self._logger, self._old_level = logger, old_level

    def _would_log(self, record: logging.LogRecord) -> bool:
        """Whether the record's own logger would have created it at the level before the capture."""
        lg: logging.Logger | None = logging.getLogger(record.name)
        while lg is not None:
            level = self._old_level if lg is self._logger else lg.level
            if level:
                return record.levelno >= level
            lg = lg.parent
        return record.levelno >= logging.WARNING

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno >= logging.WARNING:
            self.messages.append(f"{record.levelname} {record.name}: {record.getMessage()}")
        if self._would_log(record) and self._logger.parent is not None:
            self._logger.parent.handle(record)


@contextmanager
def captured_warnings(name: str = "vfcli") -> Iterator[list[str]]:
    """The warnings logged under logger ``name`` while the block runs, whatever the verbosity.

    The records still reach the usual handlers exactly as without the capture (``--quiet``
    hides warnings from the terminal, not from the stored summary).
    """
    logger = logging.getLogger(name)
    old_level, old_propagate = logger.level, logger.propagate
    handler = _Capture(logger, old_level)
    logger.addHandler(handler)
    logger.setLevel(min(logger.getEffectiveLevel(), logging.WARNING))
    logger.propagate = False
    try:
        yield handler.messages
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
        logger.propagate = old_propagate


class _Background:
    """``fn(*args)`` in a daemon thread (a failed or interrupted command does not wait for it).

    Used to hash a stage's raw input files while the stage reads them: the file is read
    from disk once, by whichever comes first, and hashing (about 1 GB/s, GIL released)
    overlaps the decoding.
    """

    def __init__(self, fn: Callable[..., Any], *args: Any) -> None:
        self._value: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, args), daemon=True, name="vfcli-hash")
        self._thread.start()

    def _run(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            self._value = fn(*args)
        except BaseException as exc:  # re-raised in the caller's thread by result()
            self._error = exc

    def result(self) -> Any:
        """Wait for ``fn`` and return its value (or raise its exception)."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


def save_recording_config(ctx: RunContext) -> bool:
    """Store the recording config (``--config``) in the store, creating it if needed.

    Returns True when the store changed.
    """
    stored_json = ctx.stored_config.model_dump_json(exclude_unset=True)
    if ctx.store.exists():
        with ctx.store.read() as r:
            if ctx.config_is_stored(r, stored_json):
                return False
    with ctx.store.write(ctx.command) as w:
        w.set_recording_config(stored_json, ctx.config_file_sha256)
    return True
