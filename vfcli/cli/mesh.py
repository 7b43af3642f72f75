"""`vfcli mesh FILE`: the M5 model of both folds."""
from __future__ import annotations

import click

from vfcli.cli.common import store_command


@click.command("mesh")
@store_command
@click.option("--preview", type=click.Path(dir_okay=False), help="Render the tagged mesh to this PNG.")
def mesh_cmd(ctx, preview: str | None):  # type: ignore[no-untyped-def]
    """Build and tetrahedralise the M5 model of both folds (config section [mesh]).

    Reads: the recording config. Writes: /mesh (nodes, tetrahedra, tagged boundary
    triangles, (u, v) maps of the inferior and superior sides).
    """
    from vfcli.cli.outputs import PREVIEW_FORMATS, check_output_file
    from vfcli.stages.mesh import run_mesh

    check_output_file(preview, "--preview", PREVIEW_FORMATS)

    return run_mesh(ctx, preview)
