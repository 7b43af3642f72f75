"""`vfcli share FILE OUT`: a copy of a store whose video other tools read fast."""
from __future__ import annotations

import click

from vfcli.cli.common import setup_logging
from vfcli.cli.choices import FRAME_COMPRESSIONS


@click.command("share")
@click.argument("file", type=click.Path(dir_okay=False))
@click.argument("out", type=click.Path(dir_okay=False))
@click.option("--compression", default="gzip", show_default=True, type=click.Choice(FRAME_COMPRESSIONS),
              help="Filter of the copy's video frames.")
@click.option("--quiet", "-q", is_flag=True, help="Errors only.")
def share_cmd(file: str, out: str, compression: str, quiet: bool) -> None:
    """Write OUT, a copy of the store FILE with its video re-encoded (gzip by default), for
    HDFView, MATLAB or h5py users: they decode the default 12-bit N-bit video about 10x
    slower than gzip. Same values, same provenance: no stage becomes stale.

    Reads FILE (never writes it); writes OUT (a new file).
    """
    from vfcli.cli.outputs import check_output_file
    from vfcli.store.share import copy_for_sharing

    setup_logging(0, quiet)
    check_output_file(out, "OUT")
    s = copy_for_sharing(file, out, compression)
    if not quiet:
        click.echo(f"{out}: {s['frames']} frames as {s['compression']}, "
                   f"{s['size_bytes'] / 1e6:.1f} MB (source {s['source_size_bytes'] / 1e6:.1f} MB)")
