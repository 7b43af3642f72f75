"""`vfcli info FILE`: stages present, provenance, sizes, stale and interrupted writes."""
from __future__ import annotations

import json

import click

from vfcli.errors import StoreDamagedError
from vfcli.store.info import store_info


@click.command("info")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print the same as JSON.")
@click.option("--verify", is_flag=True, help="Check every dataset against its stored SHA-256 too (reads the whole store).")
def info_cmd(file: str, as_json: bool, verify: bool) -> None:
    """Show the stages in FILE with their provenance, sizes, staleness, figures and warnings.

    Reads every group; writes nothing. Exit 4 when a stage is damaged (its structure, or with
    --verify its data, differs from what vfcli wrote).
    """
    info = store_info(file, verify=verify)
    if as_json:
        click.echo(json.dumps(info, indent=2, default=str))
        _refuse_damaged(info)
        return
    click.echo(f"{info['path']}  ({info['size_bytes'] / 1e6:.1f} MB, format {info['format']} v{info['format_version']}, created {info['created_utc']})")
    for leftover in info["interrupted_writes"]:
        click.echo(f"  ! interrupted write left {leftover} (the store itself is intact; the next write removes it)")
    if not info["stages"]:
        click.echo("  no stages yet")
    for st in info["stages"]:
        prov = st["provenance"]
        if st.get("damaged"):
            click.echo(f"  {st['path']:<22} DAMAGED: " + "; ".join(st["damaged"]))
            continue
        flag = "incomplete" if not st["complete"] else ("STALE: " + "; ".join(st["stale_because"]) if st["stale"] else "ok")
        click.echo(f"  {st['path']:<22} {st['size_bytes'] / 1e6:9.2f} MB  {flag}")
        click.echo(f"      written {prov.get('created_utc', '?')} by vfcli {prov.get('vfcli_version', '?')}: {prov.get('command', '?')}")
        for path, meta in prov.get("inputs", {}).items():
            click.echo(f"      input {path}  sha256 {meta['sha256'][:16]}...")
        for path, digest in prov.get("upstream", {}).items():
            click.echo(f"      uses {path} @ {digest}")
        summary = st.get("summary") or {}
        figures = ", ".join(f"{k}={v}" for k, v in summary.get("figures", {}).items() if not isinstance(v, (dict, list)))
        if figures:
            click.echo(f"      figures: {figures}")
        for warning in summary.get("warnings", []):
            click.echo(f"      warning: {warning}")
    missing = info["missing_stages"]
    if missing:
        click.echo("  not yet written: " + ", ".join(missing))
    _refuse_damaged(info)


def _refuse_damaged(info: dict) -> None:
    """Exit 4 (one line on stderr) after showing the store when a stage is damaged."""
    damaged = [st["damaged"][0] for st in info["stages"] if st.get("damaged")]
    if damaged:
        more = f" (and {len(damaged) - 1} more damaged stages)" if len(damaged) > 1 else ""
        raise StoreDamagedError(f"damaged store: {damaged[0]}{more}", info["path"])
