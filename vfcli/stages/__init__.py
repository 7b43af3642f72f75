"""Stage runners: read upstream stages from the store, call the core, write one stage.

Each runner is the library function behind one subcommand; the CLI only parses options
and calls it. Runners share :func:`vfcli.stages.base.run_stage`, which provides
idempotence (skip when inputs, config and upstream are unchanged), provenance and the
all-or-nothing write.
"""
