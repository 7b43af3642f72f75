"""`vfcli report`."""
from __future__ import annotations

import click


@click.command("report")
def report_cmd():  # type: ignore[no-untyped-def]
    """placeholder"""
