"""The targets table of the unseen-recordings benchmark (bench/bench_unseen.py): flow's doubt on the gap read from the
attributes its stage stores, and which of issue 15's targets a seed's figures meet, on hand-made figures at and beside
each target's edge."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np

from conftest import ROOT

_spec = importlib.util.spec_from_file_location("bench_unseen", ROOT / "bench" / "bench_unseen.py")
bu = importlib.util.module_from_spec(_spec)
sys.modules["bench_unseen"] = bu
_spec.loader.exec_module(bu)


def test_the_gap_doubt_is_what_flow_stored():
    """Never resolved outranks the readings; a reading counts above flow's own 5 % line (the store's fraction)."""
    assert bu.gap_doubt({"gap_level_resolved": np.False_, "edge_disagreement": 0.30}) == "never resolved"
    assert bu.gap_doubt({"gap_level_resolved": True, "edge_disagreement": 0.2607, "level_disagreement": 0.0003}) \
        == "edge reading 26 % off"
    assert bu.gap_doubt({"edge_disagreement": 0.093, "level_disagreement": 0.096}) \
        == "edge reading 9 % off; level reading 10 % off"
    assert bu.gap_doubt({"edge_disagreement": 0.05, "level_disagreement": 0.049}) == "none (edges 5.0 %, level 4.9 %)"
    # a store written before the level reading (session 68) has no level_disagreement
    assert bu.gap_doubt({"edge_disagreement": 0.013}) == "none (edges 1.3 %)"
    assert bu.gap_doubt({}) == "none"


def _figures(iou=0.95, area=0.01, inferior=0.03, coverage=0.93, doubt="none (edges 1.0 %, level 0.5 %)"):
    return {"gap_iou": iou, "area_total_err": area, "inf_osc_err": inferior, "coverage90": coverage,
            "gap_doubt": doubt}


def test_each_target_is_met_at_its_edge_and_missed_beside_it():
    t = bu.targets(_figures(iou=0.9, area=-0.05, inferior=0.10, coverage=0.85), [])
    assert t == {"gap": True, "inferior": True, "coverage": True, "no_empty": True, "warned": False}
    assert bu.targets(_figures(coverage=0.95), [])["coverage"] is True
    assert bu.targets(_figures(iou=0.899), [])["gap"] is False                 # 4300 of session 69: IoU 0.899
    assert bu.targets(_figures(area=0.0501), [])["gap"] is False
    assert bu.targets(_figures(area=-0.0501), [])["gap"] is False
    assert bu.targets(_figures(inferior=0.1001), [])["inferior"] is False
    assert bu.targets(_figures(coverage=0.9501), [])["coverage"] is False
    assert bu.targets(_figures(coverage=0.8499), [])["coverage"] is False
    assert bu.targets(_figures(), ["gap term exactly 0"])["no_empty"] is False


def test_a_missed_gap_reads_warned_only_where_flow_doubted_it_and_a_stage_not_run_meets_nothing():
    assert bu.targets(_figures(iou=0.364, area=1.737, doubt="edge reading 26 % off"), [])["warned"] is True
    assert bu.targets(_figures(iou=0.863, area=-0.012), [])["warned"] is False
    assert bu.targets(_figures(iou=0.476, area=0.645, doubt="never resolved"), [])["warned"] is True
    t = bu.targets({}, [])                                                     # flow and optimize did not run
    assert t["gap"] is None and t["inferior"] is None and t["coverage"] is None
    assert bu.targets(_figures(iou=float("nan")), [])["gap"] is None
