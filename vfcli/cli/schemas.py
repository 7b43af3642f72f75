"""`vfcli schemas`: export the config JSON Schemas (and, when asked, the store-layout page and
the example config, which `make schemas` keeps in docs/ and examples/)."""
from __future__ import annotations

from pathlib import Path

import click


@click.command("schemas")
@click.option("--out", "out_dir", default="schemas", show_default=True, type=click.Path(file_okay=False), help="Folder for the JSON Schemas.")
@click.option("--layout-doc", type=click.Path(dir_okay=False), help="Also write the store layout page here (make schemas: docs/store-layout.md).")
@click.option("--example", type=click.Path(dir_okay=False), help="Also write the example config with every default here (make schemas: examples/recording.toml).")
def schemas_cmd(out_dir: str, layout_doc: str | None, example: str | None) -> None:
    """Write one JSON Schema per config model into OUT_DIR.

    Reads nothing; writes OUT_DIR/*.schema.json, and only when given, the layout page
    (--layout-doc) and the example config (--example).
    """
    from vfcli.config import export_schemas
    from vfcli.example_config import example_toml
    from vfcli.store import layout

    for p in export_schemas(out_dir):
        click.echo(f"wrote {p}")
    if layout_doc:
        Path(layout_doc).parent.mkdir(parents=True, exist_ok=True)
        Path(layout_doc).write_text(layout.layout_markdown() + "\n")
        click.echo(f"wrote {layout_doc}")
    if example:
        Path(example).parent.mkdir(parents=True, exist_ok=True)
        Path(example).write_text(example_toml())
        click.echo(f"wrote {example}")
