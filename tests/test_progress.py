"""vfcli.progress.Phases: a stage's named phases on one bar, each timed and logged."""
from __future__ import annotations

import logging

from vfcli.progress import Phases, make_progress, no_progress


def test_phases_are_timed_in_order_shown_on_the_bar_and_logged(capsys, caplog):
    ticks = iter([0.0, 1.5, 1.5, 4.0, 4.0, 4.25, 9.0, 10.0])
    log = logging.getLogger("vfcli.test_progress")
    with caplog.at_level(logging.INFO, logger="vfcli.test_progress"):
        phases = Phases(make_progress(True), "diagnose", 3, log, clock=lambda: next(ticks))
        phases("read")
        phases("calibrate")
        phases("read")                 # a phase started again adds up
        phases.expect(1)               # a refit found on the way
        phases("refit asymmetry")
        seconds = phases.close()
    assert list(seconds) == ["read", "calibrate", "refit asymmetry"]
    assert seconds == {"read": 1.5 + 0.25, "calibrate": 2.5, "refit asymmetry": 1.0}
    err = capsys.readouterr().err
    assert "diagnose: 0 of 3 steps done" in err            # before the first phase ("diagnose0 of 3" before)
    assert "diagnose: calibrate: 1 of 3 steps done" in err
    assert "diagnose: refit asymmetry: 3 of 4 steps done" in err
    assert [r.getMessage() for r in caplog.records] == [
        "diagnose: read took 1.5 s", "diagnose: calibrate took 2.5 s", "diagnose: read took 0.2 s",
        "diagnose: refit asymmetry took 1.0 s"]


def test_phases_without_a_bar_still_time_and_print_nothing(capsys):
    ticks = iter([0.0, 2.0])
    phases = Phases(no_progress, "optimize default", 1, clock=lambda: next(ticks))
    phases("stated uncertainty")
    assert phases.close() == {"stated uncertainty": 2.0}
    assert capsys.readouterr().err == ""
