"""The collision candidate's evidence on phantoms run through the whole pipeline, as a user runs it.

`vfcli synth --effect contact` (the folds pressed together and kept from interpenetrating by an
exact contact solution) and a null phantom whose glottis closes without the folds being pressed
through ingest, sync, flow, mesh, a short optimize (the paper's free force field, 3x3x10 one-sided)
and `vfcli diagnose`: the contact line reports the no-contact fit's folds crossing the midplane
during the closed phase (0.31 mm on seed 41, 0.5 mm on seed 31).  A null's short fit crosses too
(0.23 mm on seed 42, 0.17 mm on seed 33: the fit's overshoot where the glottis closes), so the
crossing alone does not separate the two (docs/diagnose.md).  Seed 41 (outside the reserved panels).
"""
from __future__ import annotations

import re

import pytest

from _diagnose_phantom import CONTACT_PHANTOM, ONE_SIDED_FIT, shared_diagnosed_phantom

CROSSING = re.compile(r"cross the midplane (?:by up to ([0-9.e-]+) mm|not at all) during the closed phase")


def _diagnose(tmp_path_factory) -> str:
    """The contact line `vfcli diagnose --run fit` prints: the one diagnosis of the fitted phantom,
    run once and shared with tests/test_diagnose_stage.py."""
    seed, synth = CONTACT_PHANTOM
    out = shared_diagnosed_phantom(tmp_path_factory, seed, ONE_SIDED_FIT, synth) / "stdout.txt"
    return next(line for line in out.read_text().splitlines() if line.startswith("contact: "))


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_the_no_contact_fit_of_a_contact_phantom_crosses_the_midplane_while_closed(tmp_path_factory):
    line = _diagnose(tmp_path_factory)
    print(line)
    m = CROSSING.search(line)
    assert m and m.group(1) and float(m.group(1)) > 0.2, line        # measured 0.31 mm (seed 41), 0.5 (seed 31)
