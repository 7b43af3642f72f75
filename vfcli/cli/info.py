"""`vfcli info FILE...`: stages present, provenance, sizes, staleness, writers at work."""
from __future__ import annotations

import json
import shlex
from typing import Any

import click

from vfcli.errors import StoreDamagedError


def _flag(st: dict[str, Any]) -> str:
    if st.get("damaged"):
        return "DAMAGED"
    if not st["complete"]:
        return "incomplete"
    return "STALE: " + "; ".join(st["stale_because"]) if st["stale"] else "ok"


def _details(info: dict[str, Any]) -> None:
    from vfcli.store.info import plain_warnings

    click.echo(f"{info['path']}  ({info['size_bytes'] / 1e6:.1f} MB, format {info['format']} v{info['format_version']}, created {info['created_utc']})")
    if info.get("parts_folder"):
        click.echo(f"  + parts folder {info['parts_folder']} ({info['parts_bytes'] / 1e6:.1f} MB): the store is this file "
                   "plus this folder; move or copy both and keep the names, or `vfcli share` it into one self-contained file")
    for tmp in info["write_in_progress"]:
        click.echo(f"  ~ a vfcli process is writing now (lock held): {tmp} is its work in progress")
    if info["writer_active"] and not info["write_in_progress"]:
        click.echo("  ~ a vfcli process is writing now (lock held)")
    for leftover in info["interrupted_writes"]:
        click.echo(f"  ! interrupted write left {leftover} (the store itself is intact; the next write removes it)")
    for fit in info.get("stopped_fits", []):
        at = "" if fit["iteration"] is None else f" at iteration {fit['iteration']}"
        flags = "".join(f" {f}" for f in fit.get("resume_flags", []))
        click.echo(f"  ! optimize run '{fit['run']}' was stopped{at}: `vfcli optimize {shlex.quote(info['path'])} --run "
                   f"{fit['run']} --resume{flags}` continues it (checkpoint {fit['path']})")
    if not info["stages"]:
        click.echo("  no stages yet")
    for st in info["stages"]:
        prov = st["provenance"]
        if st.get("damaged"):
            click.echo(f"  {st['path']:<22} DAMAGED: " + "; ".join(st["damaged"]))
            continue
        click.echo(f"  {st['path']:<22} {st['size_bytes'] / 1e6:9.2f} MB  {_flag(st)}")
        click.echo(f"      written {prov.get('created_utc', '?')} by vfcli {prov.get('vfcli_version', '?')}: {prov.get('command', '?')}")
        for path, meta in prov.get("inputs", {}).items():
            click.echo(f"      input {path}  sha256 {meta['sha256'][:16]}...")
        for path, digest in prov.get("upstream", {}).items():
            click.echo(f"      uses {path} @ {digest}")
        summary = st.get("summary") or {}
        decision = summary.get("figures", {}).get("decision")      # a diagnosis' verdict: a line of its own
        if decision:
            click.echo(f"      decision: {decision}")
        figures = ", ".join(f"{k}={v}" for k, v in summary.get("figures", {}).items()
                            if not isinstance(v, (dict, list)) and k != "decision")
        if figures:
            click.echo(f"      figures: {figures}")
        for warning in plain_warnings(summary.get("warnings", [])):
            click.echo(f"      warning: {warning}")
    missing = info["missing_stages"]
    if missing:
        click.echo("  not yet written: " + ", ".join(missing))


def _table(infos: list[dict[str, Any]]) -> None:
    """One row per store, one column per stage: ok, STALE, incomplete, or - (absent)."""
    from vfcli.store import layout

    names = list(layout.STAGES)
    rows = []
    for info in infos:
        by_stage: dict[str, list[str]] = {}
        for st in info["stages"]:
            word = _flag(st).split(":")[0]
            by_stage.setdefault(st["path"].split("/")[1], []).append(word)
        cells = [",".join(sorted(set(by_stage[n]))) if n in by_stage else "-" for n in names]
        state = "writing" if info["writer_active"] else ("interrupted" if info["interrupted_writes"] else "")
        rows.append([info["path"], f"{(info['size_bytes'] + info.get('parts_bytes', 0)) / 1e6:.1f}", *cells, state])
    header = ["store", "MB", *names, "writer"]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, *rows]:
        click.echo("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())


@click.command("info")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the same as JSON (a list for several stores).")
@click.option("--verify", is_flag=True, help="Check every dataset against its stored SHA-256 too (reads the whole store).")
def info_cmd(files: tuple[str, ...], as_json: bool, verify: bool) -> None:
    """Show the stages in FILE with their provenance, sizes, staleness, figures and warnings;
    several FILEs: one row per store, one column per stage.

    A stage is STALE when a stage it used was rewritten or is stale itself, when the
    recording config now gives it other settings, or when an older vfcli method wrote it
    (e.g. an optimize run fitted before the model's velocity moved to the frame times).
    Reads every group; writes nothing. Exit 4 when a stage is damaged (its structure, or with
    --verify its data, differs from what vfcli wrote), after showing them all.
    """
    from vfcli.stages.base import default_settings, expected_configs
    from vfcli.store.info import store_info

    infos = [store_info(f, expected_configs, verify=verify, defaults=default_settings) for f in files]
    if as_json:
        click.echo(json.dumps(infos[0] if len(infos) == 1 else infos, indent=2, default=str))
    elif len(infos) == 1:
        _details(infos[0])
    else:
        _table(infos)
    damaged = [(info["path"], st["damaged"][0]) for info in infos for st in info["stages"] if st.get("damaged")]
    if damaged:
        more = f" (and {len(damaged) - 1} more damaged stages)" if len(damaged) > 1 else ""
        raise StoreDamagedError(f"damaged store: {damaged[0][1]}{more}", damaged[0][0])
