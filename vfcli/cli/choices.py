"""The fixed choices of command-line options, spelled out here so that a command's ``--help``
imports no config model (pydantic), store or stage module (numpy, h5py).

Each tuple is a copy of its source of truth, named beside it; ``tests/test_startup.py``
checks that every copy equals its source, so they cannot drift apart.
"""
from __future__ import annotations

#: ``vfcli.config.SynthConfig.effect``
SYNTH_EFFECTS = ("none", "inertia", "damping", "contact", "asymmetry", "random")
#: ``vfcli.config.OptimizeConfig.setup``
OPTIMIZE_SETUPS = ("3x3x10-one-sided", "3x3x10-two-sided", "5x5x15-two-sided")
#: ``vfcli.config.OptimizeConfig.loads``
OPTIMIZE_LOADS = ("free", "free-regularised", "pressure")
#: ``vfcli.config.OptimizeConfig.method``
OPTIMIZE_METHODS = ("gauss-newton", "lbfgs", "paper")
#: ``vfcli.store.frames.COMPRESSIONS``
FRAME_COMPRESSIONS = ("gzip", "gzip4", "nbit", "none")
#: ``vfcli.stages.export_job.WHAT``
EXPORT_WHAT = ("paraview", "video", "figures", "tables")
#: ``vfcli.stages.run.STEPS``
RUN_STEPS = ("ingest-hsc", "ingest-ldv", "sync", "flow", "mesh", "optimize", "diagnose")
