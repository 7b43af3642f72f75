"""Stage runners: read upstream stages from the store, call the core, write one stage.

Each runner is the library function behind one subcommand; the CLI only parses options
and calls it. A runner reads what it needs from the store (:mod:`vfcli.store`, typed readers
included), calls one function of the numerical core (:mod:`vfcli.flow.pipeline`,
:mod:`vfcli.inverse.setup`, :mod:`vfcli.sync.align` ...) and writes the result; no stage
imports another stage. Runners share :func:`vfcli.stages.base.run_stage`, which provides
idempotence (skip when inputs, config and upstream are unchanged), provenance, the stored
summary (figures and warnings, shown by ``vfcli info``) and the all-or-nothing write.
"""
