"""Diagnose: locate where a fitted run disagrees with its recording, explain it by candidate physics.

The stage ``vfcli diagnose FILE --run RUN`` (:mod:`vfcli.stages.diagnose`) reads a fitted run
(``/optimize/<run>``), rebuilds its residual and writes ``/diagnose/<run>``.  The steps are
pure numpy in / numpy out:

1. **Locate** (this package):

   * :mod:`vfcli.diagnose.residual` - the residual of a fitted run as a
     :class:`~vfcli.diagnose.residual.Residual` (measured minus simulated velocity per frame,
     pixel and component, with each pixel's fold, depth band and length band);
   * :mod:`vfcli.diagnose.cycles` - the glottal cycle from the gap area: f0, cycle index
     and phase of each frame, and the four phases (opening, closing, closed, open);
   * :mod:`vfcli.diagnose.noise` - the noise floor from the recording itself (cycle-to-cycle
     variation; the vibrometer's noise above the band of motion);
   * :mod:`vfcli.diagnose.locate` - the decomposition by where / when / component / harmonic,
     each part tested against the noise floor (F statistics with cycle-based degrees of
     freedom, p-values), and the ranked hotspots;
   * :mod:`vfcli.diagnose.words` - the plain-words lines the command prints;
   * :mod:`vfcli.diagnose.maps` - the residual map images (PNG).

2. **Explain / decide**: :mod:`vfcli.diagnose.candidate` declares the seam - the
   :class:`~vfcli.diagnose.candidate.Candidate` protocol every candidate physics term implements
   (:mod:`vfcli.diagnose.candidates`), the :class:`~vfcli.diagnose.candidate.Baseline` it is
   linearised at, and :func:`~vfcli.diagnose.candidate.screen` which takes the located residual
   and the candidates and returns their screening results.

Units: velocities mm/s, displacements mm, times s, phases in cycles.
"""
