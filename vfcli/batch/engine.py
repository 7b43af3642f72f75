"""Run a manifest's recordings on a Dask client, one task per recording, and keep the ledger.

Each recording is one coarse task (:func:`vfcli.batch.task.run_entry`): a worker runs every
stale stage of that recording into its own store and returns a small JSON summary. How a
recording ends:

- ``done`` / ``up to date``: the run completed (a stage ran / every stage was current);
- ``failed``: a user error (bad data, locked store, bad config: its one line and exit code)
  or a bug (its traceback is kept in the ledger); not retried, since it would fail the same
  way;
- a worker that dies (SIGKILL, out of memory, a lost node) is not the recording's fault:
  the scheduler runs the task again on another worker, up to ``retries`` times
  (``distributed.scheduler.allowed-failures``), then the recording fails with
  ``KilledWorker``. A killed writer leaves the store as it was (its commit is atomic) and
  the retry starts from there.

The ledger (:mod:`vfcli.batch.ledger`) is held for the whole batch (one batch of a manifest at
a time) and written after each recording, so a rerun resumes.
"""
from __future__ import annotations

import logging
import time
import uuid
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from typing import Any, Callable

from vfcli.batch.ledger import Ledger
from vfcli.batch.manifest import Manifest, RecordingEntry
from vfcli.batch.task import run_entry
from vfcli.errors import EXIT_INTERNAL

log = logging.getLogger(__name__)

STATUSES = ("done", "up to date", "failed")


@dataclass
class BatchSummary:
    """What became of every recording of a manifest, in manifest order."""

    manifest: str
    outcomes: list[dict[str, Any]]
    seconds: float
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return all(o["status"] != "failed" for o in self.outcomes)

    @property
    def exit_code(self) -> int:
        """0 when none failed, else the largest exit code among the failed recordings."""
        return max((o.get("exit_code") or EXIT_INTERNAL for o in self.outcomes if o["status"] == "failed"), default=0)

    def to_json(self) -> dict[str, Any]:
        return {"manifest": self.manifest, "ok": self.ok, "seconds": round(self.seconds, 3), "counts": self.counts,
                "recordings": self.outcomes}

    def table(self) -> str:
        """One line per recording (name, status, seconds, stages run, error) and a count line."""
        rows = [("recording", "status", "seconds", "stages run", "error")]
        for o in self.outcomes:
            stages = [s["name"] for s in (o.get("summary") or {}).get("stages", []) if s.get("action") == "ran"]
            status = o["status"] + (" (ledger)" if o.get("resumed") else "")
            rows.append((o["name"], status, f"{o.get('seconds') or 0:.1f}", ",".join(stages) or "-", o.get("error") or ""))
        widths = [max(len(r[i]) for r in rows) for i in range(4)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r[:4], widths)) + ("  " + r[4] if r[4] else "") for r in rows]
        count = ", ".join(f"{self.counts.get(s, 0)} {s}" for s in STATUSES)
        lines.append(f"{len(self.outcomes)} recordings: {count} ({self.seconds:.1f} s)")
        return "\n".join(line.rstrip() for line in lines)


def _lost(entry: RecordingEntry, exc: BaseException, retries: int) -> dict[str, Any]:
    """The outcome of a recording whose task could not finish on any worker."""
    name = type(exc).__name__
    why = (f"its worker died {retries + 1} times (killed, out of memory, or a lost node; see the worker logs)"
           if name == "KilledWorker" else f"the task was lost: {name}: {exc}")
    return {"name": entry.name, "store": str(entry.store), "status": "failed", "error": why,
            "exit_code": EXIT_INTERNAL, "summary": None, "seconds": None}


def use_inner_map(n_recordings: int, client: Any) -> bool:
    """Whether the recordings of a batch spread their own pieces over the cluster: when fewer
    recordings run than the cluster has worker threads now (``client.nthreads()``), so that
    threads would otherwise idle; never for a single-threaded cluster, or one whose workers
    have not started yet (SLURM jobs still queued: 0 threads)."""
    threads = sum(client.nthreads().values())
    return 0 < n_recordings < threads


def run_batch(
    manifest: Manifest,
    client: Any,
    *,
    until: str | None = None,
    fresh: bool = False,
    retries: int | None = None,
    on_outcome: Callable[[dict[str, Any]], None] | None = None,
    inner_map: bool | None = False,
    hold_ledger: bool = True,
) -> BatchSummary:
    """Run every recording of ``manifest`` on ``client`` and return how each ended.

    Parameters
    ----------
    manifest : the parsed manifest (:func:`vfcli.batch.manifest.read_manifest`).
    client : a ``distributed.Client`` (:func:`vfcli.batch.cluster.open_client`).
    until : last stage for every recording (wins over the manifest's).
    fresh : ignore the ledger (run every recording; ``vfcli run`` still skips current stages).
    retries : reruns after a worker died that the client's scheduler allows (for the message
        of a recording that ran out of them); default the manifest's.
    on_outcome : called with each recording's outcome as it ends (progress lines).
    inner_map : whether each recording spreads its own independent pieces (optimize's basis
        solves) over the cluster (:func:`vfcli.batch.cluster.worker_map`); None: when
        :func:`use_inner_map` says so. Default False: each worker would factorise the elastic
        model again for its share of the solves, which costs more than it saves unless the load
        model has thousands of spatial patterns (docs/cluster.md).
    hold_ledger : take the ledger's lock here (:meth:`Ledger.hold`); False when the caller
        already holds it (the CLI takes it before it starts a cluster).

    The ledger ``<manifest>.ledger.json`` is held for the whole batch (a second batch of the
    same manifest raises :class:`vfcli.errors.StoreLockedError`) and rewritten after each
    recording.
    """
    from distributed import as_completed

    t0 = time.perf_counter()
    ledger = Ledger(manifest.ledger_path, manifest.path)
    # one batch of this manifest at a time (a second one stops here, exit 4)
    with ledger.hold() if hold_ledger else nullcontext():
        if not fresh:  # read under the lock: what a batch that just ended wrote counts
            ledger = Ledger.load(manifest.ledger_path, manifest.path)
        entries = [replace(e, until=until) if until else e for e in manifest.recordings]
        outcomes: dict[str, dict[str, Any]] = {}
        todo: list[RecordingEntry] = []
        for entry in entries:
            if not fresh and ledger.is_finished(entry):
                prev = ledger.recordings[entry.name]
                outcomes[entry.name] = {"name": entry.name, "store": str(entry.store), "status": prev["status"],
                                        "error": None, "exit_code": 0, "summary": prev.get("summary"),
                                        "seconds": 0.0, "resumed": True}
                if on_outcome:
                    on_outcome(outcomes[entry.name])
            else:
                todo.append(entry)
        spread = use_inner_map(len(todo), client) if inner_map is None else inner_map
        futures: dict[Any, RecordingEntry] = {}
        for entry in todo:
            # pure=False and a unique key: a rerun in the same cluster runs again; retries=0: a
            # task raises only when its worker died, which the scheduler's allowed-failures handles
            key = f"vfcli-run-{entry.name}-{uuid.uuid4().hex[:8]}"
            futures[client.submit(run_entry, entry.to_json(), spread, key=key, pure=False, retries=0)] = entry
        for future in as_completed(list(futures)):
            entry = futures[future]
            try:
                outcome = future.result()
            except Exception as exc:  # KilledWorker after allowed-failures, a lost scheduler connection
                outcome = _lost(entry, exc, manifest.retries if retries is None else retries)
            ledger.record(entry, outcome)
            outcomes[entry.name] = outcome
            log.info("batch: %s %s", entry.name, outcome["status"])
            if on_outcome:
                on_outcome(outcome)
    ordered = [outcomes[e.name] for e in entries]
    counts = {s: sum(o["status"] == s for o in ordered) for s in STATUSES}
    return BatchSummary(str(manifest.path), ordered, time.perf_counter() - t0, counts)
