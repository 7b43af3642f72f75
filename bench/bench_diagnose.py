"""## Diagnose, blind panel: widened phantoms with hidden effects through the whole pipeline (issue 16).

The panel: for each effect (``none``, ``inertia``, ``damping``, ``contact``, ``asymmetry``)
``--per-effect`` recordings, plus ``--nulls`` more ``none`` recordings, every one a widened phantom
(``synth.panel='widened'``: camera, zoom, blur, fixture, M5 geometry, material and load drawn from
the seed, vfcli/synth/widened.py). The recordings are ordered in rounds (one of each effect per
round, the extra nulls last) and take the seeds in that order, so a panel cut short still holds
every effect.

Strengths (drawn by this script from the seed, :func:`draw_strength`): the k-th recording of an
effect (k = 0 .. n-1) takes its strength from the k-th of n equal strata of the effect's realistic
range (:data:`vfcli.synth.effects.STRENGTH_RANGE`: inertia density factor 0.25-2, damping loss factor
at f0 0.05-0.5, contact adduction factor 0.5-2, asymmetry left softening 0.05-0.4), uniformly
within the stratum from ``default_rng([seed, 0x16])``: low, middle and high strengths with three
seeds, none of them chosen by hand.

Phase 1, blind (a pool of ``--jobs`` workers, each command under ``nice -n 5``): per recording
``vfcli synth`` (its truth.h5 is moved out of the raw folder into ``truth/`` at once), ``vfcli run
STORE --raw RAW --until optimize --json`` (when ingest-ldv refuses a turned camera's scan grid
with exit 3 and names ``ingest_ldv.grid_rows``, the run is repeated once with the grid it found,
as a user following the message would; reported), then ``vfcli diagnose STORE --json --map``.
Nothing reads a truth.h5 until every recording's diagnosis is done.

Phase 2, scoring (reads truth.h5, :func:`score_case`):

* the named effect: the findings of the diagnosis ("none" = no missing physics detected) against
  the hidden effect; the confusion matrix (:func:`confusion`);
* the parameter of the named effect against truth, in the candidate's own units
  (:func:`true_parameter`): within 25 % and inside its stated interval;
* the held-out error before/after the extended refit (as the diagnosis states it): a drop of at
  least 30 % where an effect is present;
* the inferior surface (which no instrument sees): RMS error of the displacement over the run's
  window relative to the RMS true displacement, for the baseline run (``default``) and for the
  extended refit's run, against truth;
* both in the fit's own frame: the two folds look alike from above, so a pose estimated from the video
  may come out half a turn off (its left fold the phantom's right); such a recording is scored against
  the truth turned by half a turn (:func:`vfcli.synth.scoring.half_turned`, the asymmetry's softening
  as ``-s / (1 - s)``) and marked in the table;
* the false-alarm rate on the null recordings (any finding) against the family-wise alpha the
  diagnosis states it calibrated for, with its 95 % Clopper-Pearson interval (:func:`false_alarms`);
* wall time per stage (synth, each step of ``vfcli run``, diagnose).

Reproduce (prints a markdown section for docs/benchmarks.md)::

    .venv/bin/python bench/bench_diagnose.py --seeds 2001 [--effects none inertia ...] [--per-effect 3]
        [--nulls 6] [--duration 0.04] [--jobs 2] [--keep DIR] [--json OUT] [--stop-after MIN]
    .venv/bin/python bench/bench_diagnose.py ... --keep DIR --prepare    # phantoms and fits, ahead
    .venv/bin/python bench/bench_diagnose.py ... --keep DIR --only-prepared  # diagnose what is prepared
    .venv/bin/python bench/bench_diagnose.py ... --keep DIR --rescore    # score a kept panel again

The phantoms and the baseline fits do not depend on the diagnosis under test, so ``--prepare`` may
make them ahead (synth and ``vfcli run --until optimize`` into the same ``--keep DIR``; every
truth.h5 sealed in ``truth/`` at once, nothing scored); the panel's run then checks with ``vfcli
run`` that they are up to date, diagnoses, and reports the prepared wall times.

Seeds 2001-2100 are reserved for this panel (develop on 3001+).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from vfcli.synth.effects import EFFECTS, STRENGTH_RANGE  # noqa: E402

#: seed-sequence tag of the strength draw (issue 16)
STREAM = 0x16
#: the effect names a diagnosis may give, as the phantom's effects (a candidate not listed keeps its own name)
CANDIDATE_EFFECT = {"inertia": "inertia", "density": "inertia", "damping": "damping", "kelvin_voigt": "damping",
                    "contact": "contact", "collision": "contact", "asymmetry": "asymmetry",
                    "stiffness_asymmetry": "asymmetry"}
#: targets of issue 16
PARAM_TOL, HELDOUT_DROP = 0.25, 0.30
#: the steps of `vfcli run` the panel times (then diagnose)
RUN_STEPS = ("ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize")
GRID_RETRY = ["ingest_ldv.grid_rows=22", "ingest_ldv.grid_cols=17"]


@dataclass(frozen=True)
class Case:
    """One recording of the panel: seed, hidden effect, its strength, and its stratum (k of n)."""

    seed: int
    effect: str
    strength: float
    stratum: int
    strata: int

    @property
    def name(self) -> str:
        return f"seed{self.seed}_{self.effect}"


# ---------------------------------------------------------------------------------------------- the panel


def draw_strength(seed: int, effect: str, stratum: int, strata: int) -> float:
    """The effect's strength: uniform in the ``stratum``-th of ``strata`` equal parts of its realistic
    range, from the seed's own generator (module docstring); 0 for ``none``."""
    lo, hi = STRENGTH_RANGE[effect]
    if hi <= lo:
        return float(lo)
    if not 0 <= stratum < strata:
        raise ValueError(f"stratum {stratum} not in 0..{strata - 1}")
    u = np.random.default_rng([seed, STREAM]).uniform()
    return float(round(lo + (hi - lo) * (stratum + u) / strata, 4))


def panel_cases(seeds: list[int], effects: Iterable[str], per_effect: int, nulls: int) -> list[Case]:
    """The panel's recordings in running order (rounds of one per effect, then the extra nulls).

    seeds : the seeds in order; a single seed: consecutive seeds from it.
    """
    effects = list(effects)
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; effects: {', '.join(EFFECTS)}")
    n_of = {e: per_effect + (nulls if e == "none" else 0) for e in effects}
    order = [(e, k) for k in range(per_effect) for e in effects]
    order += [("none", per_effect + k) for k in range(nulls if "none" in effects else 0)]
    if len(seeds) == 1:
        seeds = [seeds[0] + i for i in range(len(order))]
    if len(seeds) < len(order):
        raise ValueError(f"{len(order)} recordings need {len(order)} seeds, got {len(seeds)}")
    return [Case(s, e, draw_strength(s, e, k, n_of[e]), k, n_of[e]) for s, (e, k) in zip(seeds, order)]


def parse_seeds(items: list[str]) -> list[int]:
    """``["2001"]``, ``["2001-2021"]`` or ``["3001", "3005"]`` -> seeds."""
    out: list[int] = []
    for it in items:
        a, _, b = it.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


# ----------------------------------------------------------------------------------- phase 1: blind pipeline


def _vfcli(args: list, log: Path) -> tuple[int, float, str, str]:
    """(exit code, wall s, stdout, stderr) of ``nice -n 5 vfcli ARGS``; stderr appended to ``log``."""
    t = time.perf_counter()
    res = subprocess.run(["nice", "-n", "5", sys.executable, "-m", "vfcli.cli.main", *map(str, args)],
                         capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    wall = time.perf_counter() - t
    with open(log, "a") as fh:
        fh.write(f"$ vfcli {' '.join(map(str, args))}\n# exit {res.returncode}, {wall:.1f} s\n{res.stderr}\n")
    return res.returncode, wall, res.stdout, res.stderr


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""


def synth_case(case: Case, work: Path, duration: float, synth_sets: list[str]) -> dict[str, Any]:
    """``vfcli synth`` of one recording into ``work/raw``, its truth.h5 moved at once into ``work/truth/``
    (sealed until phase 2); {rc, seconds, note}, also kept in ``work/synth.json``. A phantom already
    made for the same case and settings (``--prepare``) is kept: the phantoms do not depend on the
    method under test."""
    key = {"case": asdict(case), "duration": duration, "sets": synth_sets}
    done = work / "synth.json"
    if done.exists() and (work / "truth" / "truth.h5").exists():
        old = json.loads(done.read_text())
        if old.get("key") == key and old["step"]["rc"] == 0:
            return {**old["step"], "note": "made beforehand (--prepare)"}
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    raw = work / "raw"
    rc, wall, _, err = _vfcli(["synth", raw, "--seed", case.seed, "--effect", case.effect, "--strength",
                               case.strength, "-q", *_sets(["synth.panel='widened'", f"synth.duration_s={duration}",
                                                            *synth_sets])], work / "stderr.log")
    step = {"rc": rc, "seconds": wall, "note": _last_line(err) if rc else ""}
    if rc == 0:
        (work / "truth").mkdir()
        shutil.move(raw / "truth.h5", work / "truth" / "truth.h5")
    done.write_text(json.dumps({"key": key, "step": step}))
    return step


def _sets(items: list[str]) -> list[str]:
    return sum((["--set", s] for s in items), [])


def run_case(case: Case, work: Path, duration: float, synth_sets: list[str], run_sets: list[str],
             diag_args: list[str], prepare: bool = False) -> dict[str, Any]:
    """Phase 1 for one recording (reads no truth): synth (:func:`synth_case`), ``vfcli run --until
    optimize``, ``vfcli diagnose``. Writes and returns ``work/case.json``: {case, steps: {name: {rc,
    seconds, note}}, run, diagnosis, retried}.

    prepare : stop after the run (``work/prepared.json``; kept when it is there for the same case and
        settings); a later call with the same case and settings
        keeps that run (``vfcli run`` then finds every step up to date: checked, not assumed) and
        reports the prepared run's wall times."""
    out: dict[str, Any] = {"case": asdict(case), "steps": {}, "run": None, "diagnosis": None, "retried": None}
    out["steps"]["synth"] = synth_case(case, work, duration, synth_sets)
    store, log = work / "recording.h5", work / "stderr.log"

    def save() -> dict[str, Any]:
        (work / ("prepared.json" if prepare else "case.json")).write_text(json.dumps(out, indent=1))
        return out

    if out["steps"]["synth"]["rc"]:
        return save()
    key = {"case": asdict(case), "duration": duration, "synth": synth_sets, "run": run_sets}
    prepared = json.loads((work / "prepared.json").read_text()) if (work / "prepared.json").exists() else None
    if prepare and prepared is not None and prepared.get("key") == key and "run" in prepared["steps"]:
        return prepared
    reuse = not prepare and prepared is not None and prepared.get("key") == key and "run" in prepared["steps"]
    if reuse and prepared["steps"]["run"]["rc"]:      # the prepared run failed: the same code fails again
        out.update(retried=prepared.get("retried"), steps={**out["steps"], **{
            k: v for k, v in prepared["steps"].items() if k != "synth"}})
        return save()
    if not reuse:
        for old in (store, work / "recording.h5.parts"):
            shutil.rmtree(old) if old.is_dir() else old.unlink(missing_ok=True)
    run_args = ["run", store, "--raw", work / "raw", "--until", "optimize", "--json", *_sets(run_sets)]
    if reuse and prepared.get("retried"):
        run_args += _sets(prepared["retried"]["set"])
    rc, wall, stdout, err = _vfcli(run_args, log)
    if rc == 3 and "ingest_ldv.grid_rows" in err:
        out["retried"] = {"first_exit": rc, "message": _last_line(err), "set": GRID_RETRY, "seconds": wall}
        rc, wall2, stdout, err = _vfcli(run_args + _sets(GRID_RETRY), log)
        wall += wall2
    if reuse and rc == 0 and not any(st["action"] == "ran" for st in json.loads(stdout)["stages"]):
        out["retried"], out["run"] = prepared.get("retried"), prepared["run"]
        out["steps"].update({k: {**v, "note": v["note"] + " (prepared)"} for k, v in prepared["steps"].items()
                             if k not in ("synth", "diagnose")})
    else:
        out["steps"]["run"] = {"rc": rc, "seconds": wall, "note": _last_line(err) if rc else ""}
        if rc == 0:
            out["run"] = json.loads(stdout)
            for st in out["run"]["stages"]:
                if st["action"] != "skipped":
                    out["steps"][st["name"]] = {"rc": 0, "seconds": st["seconds"], "note": st["action"]}
    if prepare:
        out["key"] = key
    if rc or prepare:
        return save()
    rc, wall, stdout, err = _vfcli(["diagnose", store, "--json", "--force", "--map", work / "residual_map.png",
                                    *diag_args], log)
    out["steps"]["diagnose"] = {"rc": rc, "seconds": wall, "note": _last_line(err) if rc else ""}
    if rc == 0:
        out["diagnosis"] = json.loads(stdout)
    return save()


# ------------------------------------------------------------------ reading a diagnosis (its --json output)


def findings(diag: dict[str, Any] | None) -> list[dict[str, Any]] | None:
    """The diagnosis's findings, each a dict with at least ``name``; [] = "no missing physics detected";
    None when the output holds no decision (a diagnosis without one)."""
    if not diag:
        return None
    for holder in (diag, *(diag[k] for k in ("candidates", "decision") if isinstance(diag.get(k), dict))):
        if "findings" in holder:
            return [f if isinstance(f, dict) else {"name": str(f)} for f in holder["findings"] or []]
    return None


def leads_label(diag: dict[str, Any] | None) -> str:
    """The calibrated leads of the diagnosis (``candidates.leads``: family-wise calibrated, identifiable,
    not yet confirmed by a refit) as a confusion-matrix column ("none": no lead; "no decision")."""
    cand = (diag or {}).get("candidates")
    if not isinstance(cand, dict) or "leads" not in cand:
        return "no decision"
    return named_label([{"name": n} for n in cand["leads"]])


def family_p(diag: dict[str, Any] | None, effect: str) -> float | None:
    """The calibrated family-wise p-value of the candidate that models ``effect`` (None: not tested)."""
    cand = (diag or {}).get("candidates")
    for t in (cand.get("tests", []) if isinstance(cand, dict) else []):
        if CANDIDATE_EFFECT.get(t["name"], t["name"]) == effect:
            return float(t["p_family"])
    return None


def family_alpha(diag: dict[str, Any] | None) -> float | None:
    """The family-wise false-alarm rate the diagnosis's decision was calibrated for (``candidates.alpha_family``;
    else the locate step's ``alpha``)."""
    if not diag:
        return None
    cand = diag.get("candidates") if isinstance(diag.get("candidates"), dict) else {}
    return cand.get("alpha_family", diag.get("alpha"))


def named_label(found: list[dict[str, Any]] | None) -> str:
    """The confusion matrix's column of a diagnosis: "none", one effect, several joined by "+",
    "no decision" (no findings list in the output), "failed" (no diagnosis)."""
    if found is None:
        return "no decision"
    names = sorted({CANDIDATE_EFFECT.get(str(f.get("name", "?")), str(f.get("name", "?"))) for f in found})
    return "+".join(names) if names else "none"


def refit_figures(refit: dict[str, Any] | None) -> dict[str, Any]:
    """The confirmation refit as the diagnosis states it (``--json``'s ``refit``: candidate, run,
    parameters {name: {estimate, sd, interval}}, heldout [{kind, baseline, extended, reduction}]):
    candidate, run, the first parameter's estimate and stated interval (lo, hi), and per held-out kind
    the RMS error over its splits before (baseline) and after (extended) and the reduction the
    diagnosis computed. {} without a refit."""
    if not refit:
        return {}
    params = list((refit.get("parameters") or {}).items())
    out: dict[str, Any] = {"candidate": refit.get("candidate"), "run": refit.get("run") or None,
                           "improves": refit.get("improves")}
    if params:
        name, p = params[0]
        iv = p.get("interval") or [float("nan"), float("nan")]
        out.update(parameter=name, estimate=float(p["estimate"]), lo=float(iv[0]), hi=float(iv[1]))
    for h in refit.get("heldout") or []:
        b, e = np.asarray(h["baseline"], float), np.asarray(h["extended"], float)
        out[f"heldout_{h['kind']}"] = {"before": float(np.sqrt(np.mean(b ** 2))), "after": float(np.sqrt(np.mean(e ** 2))),
                                       "drop": float(h.get("reduction", 1 - np.sqrt(np.mean(e ** 2) / np.mean(b ** 2)))),
                                       "units": h.get("units", ""), "beyond_spread": h.get("beyond_spread")}
    return out


# --------------------------------------------------------------------------------------- phase 2: scoring


def true_parameter(effect: str, strength: float, attrs: dict[str, Any], turned: bool = False) -> float | None:
    """The hidden effect's parameter in the candidate's units, from the phantom's truth attributes.

    inertia : the density factor a model with the nominal E needs for the same ``rho / E`` (the fit
        cannot tell density from stiffness; the loads take the static scale): strength x
        (batch density / nominal) / (batch E / nominal).
    damping : the retardation time tau (ms) of ``1 + i w tau``: the phantom's loss factor at f0 over
        ``2 pi f0``.
    asymmetry : the left softening s of ``E_left = (1 - s) E_right`` (the strength itself); with the pose
        fitted half a turn off (``turned``) the model's left fold is the phantom's right, so the truth in
        the model's frame is ``E_right = (1 - s) E_left``: ``-s / (1 - s)``.
    contact : 1, the share of the rigid contact (the phantom's folds never interpenetrate: its contact is
        the rigid contact of the linear folds at the midplane, whatever its adduction factor).
    none : None.
    """
    from vfcli.config import MeshConfig

    nominal = MeshConfig()
    if effect == "inertia":
        rho = float(attrs.get("widened_density_kg_m3", nominal.density_kg_m3)) / nominal.density_kg_m3
        e = float(attrs.get("widened_youngs_modulus_pa", nominal.youngs_modulus_pa)) / nominal.youngs_modulus_pa
        return strength * rho / e
    if effect == "damping":
        return 1e3 * strength / (2 * np.pi * float(attrs["f0_hz"]))
    if effect == "asymmetry":
        return float(-strength / (1.0 - strength)) if turned else float(strength)
    if effect == "contact":
        return 1.0
    return None


def inferior_error(store: Path, run: str, truth: Path) -> tuple[float, bool]:
    """RMS error of the run's inferior-surface displacement over its window relative to the RMS true
    displacement there (the reconstruction mesh's inferior nodes inside the phantom's (u, v) range, the window's
    frames inside the truth's time range; :func:`_runner.side_truth_at`), and whether the run's pose is half a turn
    off the phantom's: then the truth is compared in the run's frame (:func:`vfcli.synth.scoring.pose_half_turned`,
    :func:`vfcli.synth.scoring.half_turned`)."""
    from _runner import side_truth_at
    from vfcli.store.mesh import read_mesh
    from vfcli.store.transaction import Store
    from vfcli.store.truth import read_truth
    from vfcli.synth.scoring import pose_half_turned, rms

    t, attrs = read_truth(truth, ["frames/time"])
    with Store(store).read() as r:
        mesh = read_mesh(r)
        disp = r.read("optimize", "displacements", run).astype(float)
        sim_time = r.read("optimize", "sim_time", run)
        rotation = float(r.attrs("optimize", run)["camera_rotation_deg"])
    n = min(len(disp), len(sim_time))
    inside = sim_time[:n] <= t["frames/time"][-1] + 1e-9
    nodes, ref = side_truth_at(truth, mesh, sim_time[:n][inside], 1, rotation_deg=rotation)
    return (rms(disp[:n][inside][:, nodes] - ref) / rms(ref),
            pose_half_turned(rotation, float(attrs["camera_rotation_deg"])))


def score_case(work: Path, phase1: dict[str, Any]) -> dict[str, Any]:
    """The figures of one recording (module docstring); reads its truth.h5."""
    from vfcli.store.truth import read_truth

    case = Case(**phase1["case"])
    diag = phase1.get("diagnosis")
    found = findings(diag)
    label = named_label(found) if diag else "failed"
    s: dict[str, Any] = {"seed": case.seed, "effect": case.effect, "strength": case.strength, "named": label,
                         "correct": label == case.effect, "alpha": family_alpha(diag),
                         "leads": leads_label(diag) if diag else "failed", "p_family": family_p(diag, case.effect),
                         "steps": phase1["steps"], "retried": phase1.get("retried") is not None}
    truth = work / "truth" / "truth.h5"
    if not truth.exists():
        return s
    _, attrs = read_truth(truth, [])
    s["draw"] = {k.removeprefix("widened_"): (v.tolist() if hasattr(v, "tolist") else v)
                 for k, v in attrs.items() if k.startswith("widened_")}
    store = work / "recording.h5"
    turned = False
    if diag is not None and store.exists():
        s["inferior_before"], turned = inferior_error(store, "default", truth)
    s["pose_turned"] = turned
    s["true_parameter"] = true_parameter(case.effect, case.strength, attrs, turned)
    fig = refit_figures((diag or {}).get("refit"))
    if fig:
        s["refit"] = {k: v for k, v in fig.items() if not k.startswith("heldout_")}
        s["refit_candidate"] = CANDIDATE_EFFECT.get(str(fig["candidate"]), str(fig["candidate"]))
        run = fig["run"] or _extended_run(store)
        if run:
            s["inferior_after"] = inferior_error(store, run, truth)[0]
        if s["refit_candidate"] == case.effect:
            s.update({k: fig[k] for k in ("estimate", "lo", "hi", "parameter") if k in fig})
            tp = s["true_parameter"]
            if tp is not None and "estimate" in fig:
                s["param_rel_err"] = abs(fig["estimate"] - tp) / abs(tp)
                s["param_within"] = bool(s["param_rel_err"] <= PARAM_TOL)
                s["param_inside"] = bool(fig["lo"] <= tp <= fig["hi"]) if np.isfinite(fig["lo"]) else None
            held = fig.get("heldout_cycles") or fig.get("heldout_instruments")
            for kind in ("cycles", "instruments"):
                if f"heldout_{kind}" in fig:
                    s[f"heldout_{kind}"] = fig[f"heldout_{kind}"]
            if held:
                s["heldout_before"], s["heldout_after"], s["heldout_drop"] = held["before"], held["after"], held["drop"]
    return s


def _extended_run(store: Path) -> str | None:
    """The run the diagnosis refitted (an /optimize run besides ``default``), if exactly one."""
    from vfcli.store.transaction import Store

    with Store(store).read() as r:
        runs = [p.split("/")[-1] for p in r.stage_paths() if p.startswith("/optimize/") and p != "/optimize/default"]
    return runs[0] if len(runs) == 1 else None


# ------------------------------------------------------------------------------------------ the summary


def confusion(results: list[dict[str, Any]], effects: Iterable[str], key: str = "named"
              ) -> tuple[list[str], list[str], np.ndarray]:
    """(rows: true effects, columns: labels of ``key`` ("named": the findings; "leads": the calibrated
    leads), counts (rows, columns)). The columns are the effects in order, then any other label met
    (several names, "no decision", "failed")."""
    rows = list(effects)
    cols = rows + sorted({r[key] for r in results} - set(rows))
    m = np.zeros((len(rows), len(cols)), int)
    for r in results:
        if r["effect"] in rows:
            m[rows.index(r["effect"]), cols.index(r[key])] += 1
    return rows, cols, m


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided confidence interval of a binomial proportion k / n."""
    from scipy.stats import beta

    a = 1 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def false_alarms(results: list[dict[str, Any]], key: str = "named") -> dict[str, Any]:
    """On the null recordings with a decision: how many name any effect (a false alarm; ``key`` "named":
    the findings, "leads": the calibrated leads), the rate and its 95 % interval, and the family-wise
    alpha the diagnoses state."""
    nulls = [r for r in results if r["effect"] == "none" and r.get(key) not in (None, "failed", "no decision")]
    k = sum(r[key] != "none" for r in nulls)
    n = len(nulls)
    alphas = sorted({float(r["alpha"]) for r in nulls if r.get("alpha") is not None})
    lo, hi = clopper_pearson(k, n) if n else (float("nan"), float("nan"))
    return {"alarms": k, "nulls": n, "rate": k / n if n else float("nan"), "ci95": (lo, hi), "alpha": alphas}


def targets(results: list[dict[str, Any]]) -> dict[str, tuple[int, int]]:
    """(met, of) for each target of issue 16 over the panel."""
    eff = [r for r in results if r["effect"] != "none"]
    nul = [r for r in results if r["effect"] == "none"]
    param = [r for r in eff if r.get("param_within") is not None]
    inside = [r for r in eff if r.get("param_inside") is not None]
    held = [r for r in eff if r.get("heldout_drop") is not None and np.isfinite(r["heldout_drop"])]
    inf = [r for r in eff if r.get("inferior_after") is not None]
    return {
        "hidden effect named": (sum(r["correct"] for r in eff), len(eff)),
        "'none' on nulls": (sum(r["correct"] for r in nul), len(nul)),
        "parameter within 25 %": (sum(r["param_within"] for r in param), len(param)),
        "truth inside the stated interval": (sum(r["param_inside"] for r in inside), len(inside)),
        "held-out error down >= 30 %": (sum(r["heldout_drop"] >= HELDOUT_DROP for r in held), len(held)),
        "inferior surface closer to truth after the refit": (
            sum(r["inferior_after"] < r["inferior_before"] for r in inf), len(inf)),
    }


def _f(v: Any, fmt: str = "{:.3g}") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return fmt.format(v)


def markdown(results: list[dict[str, Any]], effects: list[str], meta: dict[str, Any]) -> str:
    """The section for docs/benchmarks.md."""
    out = [f"Command: `{meta.get('command', '?')}`  ", f"Commit: {meta.get('commit', '?')}; {meta['n']} of "
           f"{meta['of']} recordings finished, videos of {meta.get('duration', float('nan')) * 1e3:.0f} ms, "
           f"{meta.get('jobs', '?')} at a time; machine load average {meta['load']}; "
           f"wall time {meta['wall_min']:.1f} min.", ""]
    out += ["| seed | hidden effect | strength | camera rotation (deg) | field of view / length (mm) | blur (px) | E / nominal |",
            "| ---: | --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in results:
        d = r.get("draw", {})
        turned = " (fitted half a turn off: scored in the fit's frame)" if r.get("pose_turned") else ""
        out.append(f"| {r['seed']} | {r['effect']} | {r['strength']:.3g} | {_f(d.get('rotation_deg'), '{:.0f}')}{turned} | "
                   f"{_f(d.get('fov_mm'), '{:.1f}')} / {_f(d.get('length_mm'), '{:.1f}')} | "
                   f"{_f(d.get('psf_sigma_px'), '{:.2f}')} | "
                   f"{_f(d.get('youngs_modulus_pa', float('nan')) / 4400, '{:.3f}')} |")
    for key, what in (("named", "what the diagnosis named (its findings; 'none' = no missing physics detected)"),
                      ("leads", "the calibrated leads (family-wise calibrated screening, before any confirmation)")):
        rows, cols, m = confusion(results, effects, key)
        out += ["", f"Confusion matrix (rows: hidden effect; columns: {what}):", "",
                "| hidden \\ " + key + " | " + " | ".join(cols) + " |", "| --- |" + " ---: |" * len(cols)]
        out += [f"| {row} | " + " | ".join(str(v) for v in m[i]) + " |" for i, row in enumerate(rows)]
    out += ["", "| seed | hidden (strength) | named | calibrated leads | family-wise p of its candidate | refitted | "
                "parameter: estimate [95 % interval] / truth | within 25 % | inside | held-out error, cycles: before "
                "-> after (drop) | held-out, vibrometer: before -> after (drop) | inferior error: baseline -> refit "
                "| exits |",
            "| ---: | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    yn = lambda v: "-" if v is None else ("yes" if v else "no")  # noqa: E731

    def held(h: dict[str, Any] | None) -> str:
        return "-" if not h else (f"{_f(h['before'])} -> {_f(h['after'])} {h.get('units', '')} "
                                  f"({_f(h['drop'], '{:.0%}')})")

    for r in results:
        exits = ", ".join(f"{k} {v['rc']}" for k, v in r["steps"].items() if v["rc"]) or "all 0"
        if r.get("retried"):
            exits += " (ingest-ldv retried with the grid it found)"
        par = (f"{_f(r.get('estimate'))} [{_f(r.get('lo'))}, {_f(r.get('hi'))}] / {_f(r.get('true_parameter'))}"
               if "estimate" in r else f"- / {_f(r.get('true_parameter'))}")
        inf = f"{_f(r.get('inferior_before'), '{:.0%}')} -> {_f(r.get('inferior_after'), '{:.0%}')}"
        out.append(f"| {r['seed']} | {r['effect']} ({r['strength']:.3g}) | {r['named']} | {r.get('leads', '-')} | "
                   f"{_f(r.get('p_family'))} | {r.get('refit_candidate') or '-'} | {par} | {yn(r.get('param_within'))} | "
                   f"{yn(r.get('param_inside'))} | {held(r.get('heldout_cycles'))} | "
                   f"{held(r.get('heldout_instruments'))} | {inf} | {exits} |")
    out += ["", "| target | met |", "| --- | ---: |"]
    out += [f"| {k} | {a} of {b} |" for k, (a, b) in targets(results).items()]
    for key, what in (("named", "findings"), ("leads", "calibrated leads")):
        fa = false_alarms(results, key)
        out.append(f"| false-alarm rate on nulls, {what} (95 % interval) vs the calibrated alpha | {fa['alarms']} of "
                   f"{fa['nulls']}: {_f(fa['rate'], '{:.2f}')} ({_f(fa['ci95'][0], '{:.2f}')}-"
                   f"{_f(fa['ci95'][1], '{:.2f}')}) vs {', '.join(f'{a:g}' for a in fa['alpha']) or '-'} |")
    steps = ["synth", *RUN_STEPS, "diagnose"]
    out += ["", "Wall time per stage, s (median and largest over the recordings, loaded machine):", "",
            "| " + " | ".join(steps) + " | whole recording |", "|" + " ---: |" * (len(steps) + 1)]
    med, mx = [], []
    for st in steps + ["total"]:
        v = [sum(x["seconds"] for k, x in r["steps"].items() if k in ("synth", "run", "diagnose")) if st == "total"
             else r["steps"][st]["seconds"] for r in results if st == "total" or st in r["steps"]]
        med.append(_f(float(np.median(v)) if v else None, "{:.0f}"))
        mx.append(_f(float(np.max(v)) if v else None, "{:.0f}"))
    out.append("| " + " | ".join(f"{a} ({b})" for a, b in zip(med, mx)) + " |")
    fails = [(r["seed"], k, v["note"]) for r in results for k, v in r["steps"].items() if v["rc"]]
    if fails:
        out += ["", "Failures:"] + [f"- seed {s}, {k}: {note}" for s, k, note in fails]
    return "\n".join(out)


def _commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True,
                               cwd=ROOT).stdout.strip()
        return sha + (" (with uncommitted changes)" if dirty else "")
    except OSError:
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", nargs="+", default=["2001"], help="seeds in order, or the first one, or A-B")
    ap.add_argument("--effects", nargs="+", default=list(EFFECTS), choices=list(EFFECTS))
    ap.add_argument("--per-effect", type=int, default=3)
    ap.add_argument("--nulls", type=int, default=6, help="'none' recordings besides --per-effect")
    ap.add_argument("--duration", type=float, default=0.04, help="video length, s (synth.duration_s)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", type=Path, help="work folder (else a temporary one, removed)")
    ap.add_argument("--json", dest="json_out", type=Path, help="write every figure here")
    ap.add_argument("--set", dest="synth_sets", action="append", default=[], help="synth.X=Y for every phantom")
    ap.add_argument("--run-set", dest="run_sets", action="append", default=[], help="X=Y for `vfcli run`")
    ap.add_argument("--diagnose-arg", dest="diag_args", action="append", default=[], help="extra `vfcli diagnose` argument")
    ap.add_argument("--stop-after", type=float, help="start no recording after this many minutes; score those done")
    ap.add_argument("--rescore", action="store_true", help="score the case.json files in --keep DIR again")
    ap.add_argument("--only-prepared", action="store_true",
                    help="diagnose only the recordings --prepare has finished (call again for the others)")
    ap.add_argument("--only", type=int, nargs="+", help="run only these seeds of the panel (score every one done)")
    ap.add_argument("--again", action="store_true", help="diagnose recordings that have a case.json again")
    ap.add_argument("--prepare", action="store_true",
                    help="only synth and `vfcli run --until optimize` into --keep DIR, for a later run to use")
    args = ap.parse_args()
    if (args.rescore or args.prepare) and args.keep is None:
        ap.error("--rescore and --prepare need --keep DIR")
    cases = panel_cases(parse_seeds(args.seeds), args.effects, args.per_effect, args.nulls)
    base = args.keep or Path(tempfile.mkdtemp(prefix="bench_diagnose_"))
    base.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    phase1: dict[str, dict[str, Any]] = {}
    meta_file = base / ("meta_prepare.json" if args.prepare else "meta.json")
    if args.rescore:
        for c in cases:
            f = base / c.name / "case.json"
            if f.exists():
                phase1[c.name] = json.loads(f.read_text())
        meta = json.loads(meta_file.read_text()) if meta_file.exists() else {}
    else:
        meta = {"command": "python bench/bench_diagnose.py " + " ".join(sys.argv[1:]), "commit": _commit(),
                "duration": args.duration, "jobs": args.jobs, "load_start": os.getloadavg()[0], "t0": t0}
        meta_file.write_text(json.dumps(meta))
        print(f"{len(cases)} recordings, work folder {base}", file=sys.stderr)
        # recordings whose phantom and fit were made ahead first (only their diagnosis is left)
        ordered = sorted(cases, key=lambda c: not (base / c.name / "prepared.json").exists())
        with ThreadPoolExecutor(args.jobs) as pool:
            futures = {pool.submit(_guarded, c, base, args, t0): c for c in ordered}
            for fut in as_completed(futures):
                c, res = futures[fut], fut.result()
                if res is None:
                    print(f"  {c.name}: not started (--stop-after or --only-prepared)", file=sys.stderr)
                    continue
                if not args.prepare:
                    phase1[c.name] = res
                st = res["steps"]
                print(f"  {c.name} ({c.strength:g}): " + ", ".join(f"{k} {v['rc']} {v['seconds']:.0f} s"
                      for k, v in st.items() if k in ("synth", "run", "diagnose")), file=sys.stderr, flush=True)
        meta.update(load_end=os.getloadavg()[0], wall_min=(time.time() - t0) / 60)
        meta_file.write_text(json.dumps(meta))
    if args.prepare:
        return
    # every diagnosis is done: only now is truth read
    results = [score_case(base / c.name, phase1[c.name]) for c in cases if c.name in phase1]
    meta = {**meta, "n": len(results), "of": len(cases),
            "load": f"{meta.get('load_start', float('nan')):.0f} at the start, "
                    + (f"{meta['load_end']:.0f} at the end" if "load_end" in meta else "still running"),
            "wall_min": meta.get("wall_min", (time.time() - meta.get("t0", t0)) / 60)}
    print(markdown(results, args.effects, meta))
    if args.json_out:
        args.json_out.write_text(json.dumps({"meta": meta, "results": results, "false_alarms": false_alarms(results),
                                             "targets": targets(results)}, indent=1, default=str))
    if args.keep is None:
        shutil.rmtree(base, ignore_errors=True)


def _guarded(case: Case, base: Path, args: argparse.Namespace, t0: float) -> dict[str, Any] | None:
    work = base / case.name
    if args.stop_after is not None and time.time() - t0 > 60 * args.stop_after:
        return None
    if not args.prepare and (work / "case.json").exists() and not args.again:
        return json.loads((work / "case.json").read_text())     # diagnosed by an earlier call
    if args.only_prepared and not (work / "prepared.json").exists():
        return None
    if args.only and case.seed not in args.only:
        return None
    return run_case(case, base / case.name, args.duration, args.synth_sets, args.run_sets, diagnose_args(args),
                    args.prepare)


def diagnose_args(args: argparse.Namespace) -> list[str]:
    """The `vfcli diagnose` arguments of every recording: ``--diagnose-arg`` ones, and, unless they set it, ``--jobs``
    so that the recordings diagnosed at once share the cores (each diagnosis forks its pieces over ``--jobs``
    workers, default every core: ``--jobs 2`` recordings at once on 2 cores would run four)."""
    from vfcli.parallel import available_cores

    extra = list(args.diag_args)
    if not any(a == "--jobs" or a.startswith("--jobs=") or a == "-j" for a in extra):
        extra += ["--jobs", str(max(1, available_cores() // max(int(args.jobs), 1)))]
    return extra


if __name__ == "__main__":
    main()
