"""`vfcli config FILE`: store or update a recording's config, or show it."""
from __future__ import annotations

import dataclasses

import click

from vfcli.cli.common import store_command
from vfcli.errors import ConfigError


@click.command("config")
@store_command
@click.option("--show", is_flag=True, help="Print the effective config (stored + --set) as JSON.")
def config_cmd(ctx, show: bool):  # type: ignore[no-untyped-def]
    """Store the recording config given with --config (creates FILE if needed); --set
    section.field=value updates the stored config (here, unlike in other commands, it is kept).

    Reads and writes the root attribute with the recording config; no stage.
    """
    from vfcli.config import persist_overrides
    from vfcli.stages.base import StageResult, save_recording_config

    if show:
        if not ctx.store.exists() and ctx.config_file_sha256 is None:
            # only the defaults to show: a mistyped store name must not look like a recording's config
            raise ConfigError("no such store file (give --config FILE to show the config a file gives)",
                              ctx.store.path)
        click.echo(ctx.config.model_dump_json(indent=2))
        return []
    overrides = list(click.get_current_context().params.get("overrides") or ())
    summary = {}
    if overrides:
        stored = persist_overrides(ctx.stored_config, overrides)
        ctx = dataclasses.replace(ctx, stored_config=stored, config=stored)
        summary = {"set": " ".join(overrides)}
    changed = save_recording_config(ctx)
    return StageResult("/ (recording config)", "written" if changed else "up-to-date", summary)


for _param in config_cmd.params:        # the shared --set help says "for this run"; here the value is stored
    if _param.name == "overrides":
        _param.help = "Store one config value (repeatable; null unsets a field that may be unset)."
