"""`vfcli schemas`: export the config JSON Schemas and the store-layout page."""
from __future__ import annotations

from pathlib import Path

import click

from vfcli.store import layout
from vfcli.config import example_toml, export_schemas


@click.command("schemas")
@click.option("--out", "out_dir", default="schemas", show_default=True, type=click.Path(file_okay=False), help="Folder for the JSON Schemas.")
@click.option("--layout-doc", default="docs/store-layout.md", show_default=True, type=click.Path(dir_okay=False), help="Where to write the store layout page.")
@click.option("--example", default="examples/recording.toml", show_default=True, type=click.Path(dir_okay=False), help="Where to write the example config with every default.")
def schemas_cmd(out_dir: str, layout_doc: str, example: str) -> None:
    """Write one JSON Schema per config model and the store layout page.

    Reads nothing; writes OUT_DIR/*.schema.json, the layout page and the example config.
    """
    for p in export_schemas(out_dir):
        click.echo(f"wrote {p}")
    Path(layout_doc).parent.mkdir(parents=True, exist_ok=True)
    Path(layout_doc).write_text(layout.layout_markdown() + "\n")
    click.echo(f"wrote {layout_doc}")
    Path(example).parent.mkdir(parents=True, exist_ok=True)
    Path(example).write_text(example_toml())
    click.echo(f"wrote {example}")
