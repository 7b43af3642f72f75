"""`vfcli run`: every stage of one recording in one process, doing only what is stale.

The steps are the stage commands in order (:data:`STEPS`): ingest-hsc, ingest-ldv, sync,
flow, mesh, optimize (run ``default``), diagnose (of run ``default``, with the command's default
settings). Each step is its stage's own runner, which rewrites
its store group(s) only when they are not current (the rule of :meth:`StoreReader.is_current`:
raw inputs by content, the stage's settings, the digests of the stages it used). Before
running, :func:`plan` names for every step why it would run (missing, input changed, config
changed, an upstream stage rewritten or stale) with the rules `vfcli info` uses; a dry run
stops there and writes nothing. The diagnose step is skipped, with its reason, when the
recording holds too few whole glottal cycles outside the fitted window (:func:`diagnose_skip_reason`).

This is the unit `vfcli batch` runs per recording: :func:`run_recording`.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from vfcli.errors import ConfigError, VfcliError, interruption
from vfcli.io.raw_folder import RawFiles, find_raw_files
from vfcli.parallel import Mapper
from vfcli.progress import Progress, no_progress
from vfcli.stages.base import DEFAULT_RUN, RunContext, StageResult, default_settings, expected_settings
from vfcli.store import Store, layout
from vfcli.store.provenance import describe_inputs, same_inputs, sha256_file
from vfcli.store.reader import StageStatus

log = logging.getLogger(__name__)

#: The optimisation run `vfcli run` writes.
RUN_NAME = DEFAULT_RUN
#: The steps in order: command name -> the store groups it writes ``[(stage, run)]`` (from the layout).
STEPS: dict[str, list[tuple[str, str | None]]] = {
    step: [(st.name, RUN_NAME if st.has_runs else None) for st in layout.STAGES.values() if st.written_by == step]
    for step in ("ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize", "diagnose")
}
_RAW_STEPS = ("ingest-hsc", "ingest-ldv")


@dataclass
class StageOutcome:
    """What happened to one step.

    action : "ran" | "up to date" | "would run" (dry run) | "skipped" (after --until, or an
        ingest step without a raw folder) | "failed" (the step that stopped the run: its error as reason) |
        "would fail" (dry run: a group it needs is missing and no earlier step writes it).  reason : why (for "ran"/"would run": what was
        missing or changed).  seconds : wall time of the step.  warnings : the warnings it logged.
    """

    name: str
    action: str
    reason: str
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)


@dataclass
class RunSummary:
    """The outcome of :func:`run_recording`: one :class:`StageOutcome` per step, in order."""

    store: Path
    stages: list[StageOutcome]
    ok: bool
    seconds: float

    def to_json(self) -> dict[str, Any]:
        return {"store": str(self.store), "ok": self.ok, "seconds": round(self.seconds, 3),
                "stages": [{**asdict(s), "seconds": round(s.seconds, 3)} for s in self.stages]}


def _override_items(overrides: Mapping[str, Any] | Sequence[str] | None) -> list[str]:
    """``--set`` items: a mapping ``{"camera.px_per_mm": 12}`` (values as JSON literals) or
    ``["camera.px_per_mm=12", ...]`` as given on the command line."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [f"{k}={json.dumps(v)}" for k, v in overrides.items()]
    return [str(o) for o in overrides]


def keep_overrides(store: Path, overrides: Mapping[str, Any] | Sequence[str] | None, command: str) -> bool:
    """Store ``overrides`` in the recording's stored config, as `vfcli config --set` does (a batch manifest's
    ``set``: the settings its recording is processed with, not one run's). Without it `info` and the report called
    the stages a batch had just made STALE ("config changed: flow.median_px 3 -> 5"), and a later plain `vfcli run`
    undid the values. Returns True when the stored config changed."""
    import dataclasses

    from vfcli.config import persist_overrides
    from vfcli.stages.base import save_recording_config

    items = _override_items(overrides)
    if not items or not Path(store).exists():
        return False
    ctx = RunContext.open(store, None, [], command=command)
    stored = persist_overrides(ctx.stored_config, items)
    return save_recording_config(dataclasses.replace(ctx, stored_config=stored, config=stored))


def _steps_until(until: str | None) -> list[str]:
    names = list(STEPS)
    if until is None:
        return names
    if until not in STEPS:
        raise ConfigError(f"--until {until!r}: not a step (steps: {', '.join(names)})")
    return names[: names.index(until) + 1]


def _input_paths(step: str, raw: RawFiles) -> list[Path]:
    if step == "ingest-hsc":
        from vfcli.stages.ingest import video_files

        return video_files(raw.video) + ([raw.pressure] if raw.pressure else [])
    return [raw.ldv]


def _upstream(name: str, ctx: RunContext) -> list[str]:
    """Group paths stage ``name`` uses (as recorded in its provenance): the layout's ``reads``;
    optimize reads /hsc (the pressure) only with the pressure loads."""
    reads = layout.stage(name).reads
    if name == "optimize" and ctx.config.optimize.loads != "pressure":
        reads = tuple(r for r in reads if r != "hsc")
    return [layout.stage(r).group_path(RUN_NAME if layout.stage(r).has_runs else None) for r in reads]


def missing_upstream(ctx: RunContext, active: list[str], step: str) -> str | None:
    """The group ``step`` needs that neither the store holds nor a step of this run before it writes
    (a dry run said "would run" where the run then stopped with exit 5); None when there is none."""
    have: set[str] = set()
    if ctx.store.exists():
        with ctx.store.read() as r:
            have = set(r.stage_paths())
    for earlier in active[:active.index(step)]:
        have |= {layout.stage(n).group_path(run) for n, run in STEPS[earlier]}
    own = {layout.stage(n).group_path(run) for n, run in STEPS[step]}
    return next((up for n, _ in STEPS[step] for up in _upstream(n, ctx) if up not in have | own), None)


def plan(ctx: RunContext, raw: RawFiles | None, steps: list[str]) -> dict[str, str | None]:
    """Why each step would run: ``{step: reason}``, None for a step that is current.

    The reasons are those of `vfcli info` (missing, incomplete, config changed, an upstream
    stage rewritten, gone or stale), plus raw inputs whose content changed and upstream
    stages this run rewrites. A stage rewritten with identical content leaves the stages
    that use it current, so a step said to run because of its upstream may end up current.
    Reads the store; hashes a raw file only when its size or times changed.
    """
    groups = {layout.stage(n).group_path(r): (step, n, r) for step in steps for n, r in STEPS[step]}
    reasons: dict[str, list[str]] = {step: [] for step in steps}
    statuses: dict[str, StageStatus] = {}
    previous: dict[str, dict[str, Any]] = {}
    if ctx.store.exists():
        with ctx.store.read() as r:
            statuses = {st.path: st for st in r.statuses(lambda n, run: expected_settings(n, run, ctx.config),
                                                         default_settings)}
            for step in _RAW_STEPS:
                if step in steps:
                    previous[step] = r.previous_inputs(*STEPS[step][0])
    rewritten: set[str] = set()
    for path, (step, name, _run) in groups.items():
        why: list[str] = []
        st = statuses.get(path)
        # a step writing several groups (flow: /flow and /fields) says which group a reason is about
        prefix = f"{path}: " if len(STEPS[step]) > 1 else ""
        if ctx.force:
            why.append("--force")
        elif st is None:
            why.append(f"{path} missing")
        elif not st.complete or st.damaged:
            why.append(f"{path} incomplete or damaged")
        else:
            why += [f"{path}: {w}" if w.startswith("config") else prefix + w for w in st.stale_because]
            if step in _RAW_STEPS and raw is not None:
                old = previous.get(step, {})
                new = describe_inputs(_input_paths(step, raw), old)
                if not same_inputs(old, new):
                    known = {v["sha256"] for v in old.values()}
                    changed = [Path(p).name for p, v in new.items() if v["sha256"] not in known]
                    why.append("input changed: " + (", ".join(changed) or "a file was removed"))
            for up in _upstream(name, ctx):
                if up in rewritten and not any(w.startswith(up + " ") or f": {up} " in w for w in why):
                    why.append(f"{prefix}{up} is rewritten first")
        if why:
            rewritten.add(path)
            reasons[step] += why
    return {step: "; ".join(dict.fromkeys(w)) or None for step, w in reasons.items()}


def _run_step(step: str, ctx: RunContext, raw: RawFiles | None) -> list[StageResult]:
    if step == "ingest-hsc":
        from vfcli.stages.ingest import run_ingest_hsc

        assert raw is not None
        return [run_ingest_hsc(ctx, raw.video, raw.pressure)]
    if step == "ingest-ldv":
        from vfcli.stages.ingest import run_ingest_ldv

        assert raw is not None
        return [run_ingest_ldv(ctx, raw.ldv)]
    if step == "sync":
        from vfcli.stages.sync import run_sync

        return [run_sync(ctx)]
    if step == "flow":
        from vfcli.stages.flow import run_flow

        return run_flow(ctx)
    if step == "mesh":
        from vfcli.stages.mesh import run_mesh

        return [run_mesh(ctx)]
    if step == "optimize":
        from vfcli.stages.optimize import run_optimize

        return [run_optimize(ctx, RUN_NAME)]
    if step == "diagnose":
        from vfcli.stages.diagnose import run_diagnose

        return [run_diagnose(ctx, RUN_NAME)]
    raise ValueError(f"unknown step {step!r}")


def diagnose_skip_reason(ctx: RunContext) -> str | None:
    """Why the diagnose step cannot decide on this recording's fitted window, by diagnose's own checks
    (:func:`vfcli.diagnose.calibrate_run.uncalibrated_reason`: a noise floor of 2 whole glottal cycles and 3
    stretches of the window's length at whole cycles from it), or None (also when /flow is not there
    yet: the stage then names what is missing)."""
    with ctx.store.read() as r:
        if not r.has_stage("flow"):
            return None
        from vfcli.store.fit import pressure_f0_hz, window_frames

        area, times = r.read("flow", "glottal_area"), r.read("flow", "frame_time")
        f0 = pressure_f0_hz(r)
        if len(area) < 4:
            return f"the recording holds {len(area)} frames: no glottal cycle to judge a residual against"
        dt = float(np.median(np.diff(times)))
        n = window_frames(r, ctx.config, dt)
    first = ctx.config.optimize.first_frame
    if first + n > len(area):
        return None                   # optimize refuses the window, naming it
    from vfcli.diagnose.cycles import too_few_advice
    from vfcli.diagnose.calibrate_run import uncalibrated_reason

    reason = uncalibrated_reason(area, dt, f0, first, n)
    if reason is None:
        return None
    # a shorter window leaves room for more stretches, down to one glottal cycle (shorter, its harmonics are not
    # told apart: vfcli.diagnose.locate.MIN_HARMONIC_CYCLES)
    cycles = n * dt * f0 if np.isfinite(f0) else float("nan")
    shorter = (f", or fit one glottal cycle (the window holds {cycles:.1f}; leave optimize.n_frames unset)"
               if "stretch(es)" in reason and cycles > 1.05 else "")
    return (f"its decision on the fitted window (frames {first}-{first + n - 1}) could not be calibrated: {reason}; "
            f"{too_few_advice(area, dt, f0)}{shorter}")


class _Collect(logging.Handler):
    """Collects the WARNING+ messages logged under ``vfcli`` (forwards nothing: the logger's
    own handlers and propagation print them as usual)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(f"{record.levelname} {record.name}: {record.getMessage()}")


def _warnings(ctx: RunContext, step: str, logged: list[str]) -> list[str]:
    """The warnings a step that ran stored with its groups (also under ``--quiet``, which keeps
    them from being logged), then those it logged besides, each once."""
    stored: list[str] = []
    with ctx.store.read() as r:
        for name, run in STEPS[step]:
            if r.has_stage(name, run):
                stored += (r.summary(name, run) or {}).get("warnings", [])
    return list(dict.fromkeys([*stored, *logged]))


def _changed_raw_config(store: Path, config: Path) -> Path | None:
    """The raw folder's recording.toml when it is to replace the stored config: the store has none yet, or the
    file's content differs from the file the stored config was last read from (then a log line says it replaces
    it); None when it is that file, so values set since with `vfcli config` stay."""
    st = Store(store)
    if not st.exists():
        return config
    with st.read() as r:
        if r.recording_config_json() is None:
            return config
        last = r.root_attrs().get(layout.ROOT_CONFIG_FILE_ATTR)
    try:
        if last == sha256_file(config):
            return None
    except OSError:
        return config     # unreadable: loading it says so, in one line
    log.warning("%s differs from the config file last stored with %s: it replaces the stored recording config "
                "(values set with `vfcli config` since then too)", config, store)
    return config


def run_recording(
    store: Path,
    raw: Path | None,
    *,
    until: str | None = None,
    overrides: Mapping[str, Any] | Sequence[str] | None = None,
    config_path: Path | None = None,
    dry_run: bool = False,
    force: bool = False,
    command: str | None = None,
    progress: Progress = no_progress,
    map: Mapper | None = None,
    local_map: Mapper | None = None,
) -> RunSummary:
    """Run the pipeline on one recording: the steps up to ``until`` that are not current.

    Parameters
    ----------
    store : the recording's store (created by the first step).
    raw : its raw folder (:func:`vfcli.io.raw_folder.find_raw_files`); None: the ingest steps
        are skipped (the store's /hsc and /ldv are used as they are).
    until : last step (a name of :data:`STEPS`); default: all.
    overrides : config values for this run, ``{"section.field": value}`` (or ``--set`` items).
    config_path : recording.toml (stored with the recording); default: the raw folder's own.
    dry_run : say what would run and why, write nothing.
    force : rerun every step.
    command : the command line recorded in the stages' provenance.
    map : runs the independent pieces of work of the steps (:mod:`vfcli.parallel`: optimize's
        basis solves), e.g. a Dask client's map; default one after the other. The stored
        results are the same whatever the map.
    local_map : runs the pieces that stay in this process (the diagnosis's profile values and refits), e.g.
        :func:`vfcli.parallel.local_map`; default one after the other. The same results whatever it is.

    Raises
    ------
    VfcliError
        A user error of a step (with its exit code); the steps before it are committed.
    """
    t_start = time.perf_counter()
    store = Path(store)
    steps = _steps_until(until)
    raw_files = None
    if raw is not None and any(s in _RAW_STEPS for s in steps):
        raw_files = find_raw_files(raw, need_pressure="sync" in steps or "ingest-hsc" in steps)
    if config_path is None and raw_files is not None and raw_files.config is not None:
        config_path = _changed_raw_config(store, Path(raw_files.config))
    items = _override_items(overrides)
    command = command or f"vfcli run {store}" + (f" --raw {raw}" if raw is not None else "")

    def context() -> RunContext:  # reopened per step: each step sees the store as the last one left it
        return RunContext.open(store, config_path, items, command=command, force=force, progress=progress,
                               map=map, local_map=local_map)

    ctx = context()
    active = [s for s in steps if raw_files is not None or s not in _RAW_STEPS]
    why = plan(ctx, raw_files, active)
    outcomes: list[StageOutcome] = []
    for step in STEPS:
        if step not in steps:
            outcomes.append(StageOutcome(step, "skipped", f"after --until {until}"))
        elif step not in active:
            outcomes.append(StageOutcome(step, "skipped", "no raw folder given (--raw): the store's group is used"))
        elif dry_run:
            # the diagnose step's skip is known ahead when /flow is there; judged on it also when flow would rewrite
            # it (the cycles are the glottal area's), and saying so (it said "would run", and the run skipped it)
            skip = diagnose_skip_reason(ctx) if step == "diagnose" and ctx.store.exists() else None
            if skip and why.get("flow"):
                skip += " (judged on the /flow stored now, which this run would rewrite first)"
            gone = missing_upstream(ctx, active, step) if why[step] else None
            if gone:
                raw_groups = {layout.stage(n).group_path(r) for s in _RAW_STEPS for n, r in STEPS[s]}
                hint = " (no raw folder given: --raw)" if raw_files is None and gone in raw_groups else ""
                outcomes.append(StageOutcome(step, "would fail", f"{gone} missing{hint}"))
            else:
                outcomes.append(StageOutcome(step, "skipped", skip) if skip else
                                StageOutcome(step, "would run" if why[step] else "up to date",
                                             why[step] or "inputs and config unchanged"))
    if dry_run:
        return RunSummary(store, outcomes, True, time.perf_counter() - t_start)
    done: list[StageOutcome] = []
    for step in active:
        if step == "diagnose":
            skip = diagnose_skip_reason(context())
            if skip:
                done.append(StageOutcome(step, "skipped", skip))
                log.info("diagnose: skipped (%s)", skip)
                continue
        collect = _Collect()
        logger = logging.getLogger("vfcli")
        logger.addHandler(collect)
        t0 = time.perf_counter()
        try:
            results = _run_step(step, context(), raw_files)
        except BaseException as exc:
            # what the run did before the step that failed (or was interrupted), for the command's output (the
            # error is its one line; the steps before are committed, the interrupted one left as it was); a Ctrl-C
            # that came out wrapped in another exception is raised as itself (vfcli.errors.interruption)
            stop = exc if isinstance(exc, VfcliError) else interruption(exc)
            if stop is None or isinstance(stop, SystemExit):
                raise
            why_not = "interrupted (Ctrl-C)" if isinstance(stop, KeyboardInterrupt) else str(stop)
            failed = StageOutcome(step, "failed", why_not, time.perf_counter() - t0, collect.messages)
            stop.partial = RunSummary(store, [*done, failed], False, time.perf_counter() - t_start)
            if stop is exc:
                raise
            raise stop from exc
        finally:
            logger.removeHandler(collect)
        ran = any(r.status == "written" for r in results)
        reason = (why[step] or "rewritten with unchanged inputs") if ran else "inputs and config unchanged"
        if not ran and why[step]:
            reason = f"unchanged after all ({why[step]}, with the same content)"
        done.append(StageOutcome(step, "ran" if ran else "up to date", reason, time.perf_counter() - t0,
                                 _warnings(ctx, step, collect.messages) if ran else collect.messages))
        log.info("%s: %s (%s)", step, done[-1].action, reason)
    by_name = {o.name: o for o in [*outcomes, *done]}
    ordered = [by_name[s] for s in STEPS]
    return RunSummary(store, ordered, True, time.perf_counter() - t_start)
