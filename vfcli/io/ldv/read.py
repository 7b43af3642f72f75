"""Scanning laser-Doppler vibrometer (Polytec PSV) scans: UFF, CSV and MAT readers.

:func:`read_ldv` returns an :class:`LdvScan`: node numbers, coordinates (mm),
velocity (mm/s) and reference signal per scan point, the sampling rate, per-point
start times, (row, col) grid indices inferred from the coordinates and dropout flags.

Accepted layouts
----------------
UFF (``.uff``/``.unv``, as PSV exports them; read with pyuff)
    dataset 151 header (optional), 164 units (optional), 2411 geometry (or
    legacy 15): node numbers and x, y, z; one dataset 58 per point and channel
    with time data (``func_type`` 1), ``rsp_node`` = scan point number. The
    velocity channel is recognised by ``id1`` = 'Response Time Trace' and
    ``id2`` matching ``^\\s*Vib`` ('Vib  Velocity', 'Vib  Geschwindigkeit'), the
    reference by ``id1`` = 'Reference Time Trace' and ``id2`` matching
    ``^\\s*Ref1`` ('Ref1  Voltage', 'Ref1  Pressure'); see :class:`LdvChannels`.
    Records are matched to geometry by node number, never by order. A velocity record's
    response direction -3 (-Z) turns its sign (vfcli's z points up, the standard's +Z);
    records flagged uneven (abscissa_spacing 0) with uniform abscissa values are read.
    Units: velocity from the 58 ordinate units label (m/s, mm/s, um/s; without
    a label ``velocity_unit``, default m/s); coordinates from dataset 164
    (length factor, SI = file / factor), else ``length_unit``
    (``ingest_ldv.length_unit``). The UFF standard defines no default length
    unit (files without 164 are written in m and in mm alike), so a file
    without 164 and no ``length_unit`` is refused, naming that field.
    The reference keeps its own unit (label, e.g. 'V' or 'Pa').
CSV (vfcli layout, written by :func:`vfcli.io.ldv.write.write_ldv_csv`)
    Comment lines ``# fs = <Hz>`` (required), ``# velocity_unit = mm/s``,
    ``# reference_unit = Pa``, ``# length_unit = mm`` (these defaults), then a
    header row ``node,x,y,z,channel,t0,s0,s1,...`` and one row per point and
    channel: node number, coordinates, ``velocity`` or ``reference``, start
    time (s), samples. Rows in any order, all of the same length, each ending
    with a line break (a last row without one may be cut off: refused).
MAT (``scipy.io.loadmat``, MATLAB v5/v7, not v7.3)
    ``coords`` (P, 3), ``velocity`` (P, S) and ``fs`` (Hz) are required;
    optional ``node_ids`` (P,) (default 1..P), ``reference`` (P, S), ``t0`` (P,)
    (s), and unit strings ``length_unit`` (default 'mm'), ``velocity_unit``
    (default 'mm/s'), ``reference_unit`` (default 'Pa').

Polytec's native ``.svd`` needs the vendor's Windows library: export to UFF.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vfcli.errors import InputDataError
from vfcli.io._common import check_finite, check_last_row_complete, numeric_rows, require_file
from vfcli.io.ldv.dropouts import detect_dropouts
from vfcli.io.ldv.grid import infer_grid
from vfcli.io.limits import (LDV_EXTENT_MM, LDV_FS_RANGE, LDV_MAX_ABS_VELOCITY_MM_S, MAX_ABS_PRESSURE_PA,
                             MAX_ABS_REFERENCE, check_abs_max, check_ldv_extent, check_range)
from vfcli.io.pressure import PA_PER_UNIT
from vfcli.io.pressure.record import uniform_rate

logger = logging.getLogger(__name__)

#: mm/s per unit of each velocity unit understood.
MM_S_PER_UNIT = {"m/s": 1e3, "mm/s": 1.0, "um/s": 1e-3, "µm/s": 1e-3, "μm/s": 1e-3,
                 "nm/s": 1e-6, "in/s": 25.4}
#: mm per unit of each length unit understood.
MM_PER_UNIT = {"m": 1e3, "cm": 10.0, "mm": 1.0, "um": 1e-3, "µm": 1e-3, "in": 25.4}

#: The units a PSV export without a units dataset is found in (metres and millimetres); 1000
#: apart, so at most one of them gives a plausible scan extent (vfcli.io.limits.LDV_EXTENT_MM).
UNSTATED_UNITS = ("m", "mm")


def infer_length_unit(span: float) -> str | None:
    """The one unit of :data:`UNSTATED_UNITS` in which a scan ``span`` (file units, the larger
    of the x and y extents) is a plausible extent for the folds, else None."""
    lo, hi = LDV_EXTENT_MM
    fits = [u for u in UNSTATED_UNITS if lo <= span * MM_PER_UNIT[u] <= hi]
    return fits[0] if len(fits) == 1 else None

DEFAULT_GRID = (17, 22)


@dataclass(frozen=True)
class LdvChannels:
    """How to tell the UFF 58 channels apart (id1 exact, case-insensitive; id2 regex)."""

    velocity_id1: str = "Response Time Trace"
    velocity_id2: str = r"^\s*Vib"
    reference_id1: str = "Reference Time Trace"
    reference_id2: str = r"^\s*Ref1"


@dataclass
class LdvScan:
    """One LDV scan, points in node-number order.

    Attributes
    ----------
    node_ids : (P,) int64
        Scan point numbers (UFF node numbers).
    coords_mm : (P, 3) float64
        Point coordinates in the vibrometer's frame, mm.
    velocity_mm_s : (P, S) float64
        Vibrometer velocity, mm/s.
    fs : float
        Sampling rate, Hz.
    reference : (P, S) float64 or None
        Reference channel (subglottal pressure) per point, in ``reference_unit``.
    reference_unit : str
        Unit of ``reference`` as in the file ('V', 'Pa', ...).
    t0 : (P,) float64 or None
        Start time of each point's record, s (UFF abscissa minimum).
    grid_index : (P, 2) int64 or None
        (row, col) of each point on the scan grid.
    grid_shape : (int, int) or None
        (rows, cols) found.
    dropout : (P,) bool or None
        Points whose velocity drops out (see :func:`detect_dropouts`).
    dropout_reasons : list of str
        Why each point was flagged ("" when not).
    source : str
        One-line description of the file.
    notes : list of str
        Things the reader noticed (grid mismatch, ignored geometry nodes).
    """

    node_ids: np.ndarray
    coords_mm: np.ndarray
    velocity_mm_s: np.ndarray
    fs: float
    reference: np.ndarray | None = None
    reference_unit: str = ""
    t0: np.ndarray | None = None
    grid_index: np.ndarray | None = None
    grid_shape: tuple[int, int] | None = None
    dropout: np.ndarray | None = None
    dropout_reasons: list[str] = field(default_factory=list)
    source: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def n_points(self) -> int:
        return int(self.node_ids.size)

    @property
    def n_samples(self) -> int:
        return int(self.velocity_mm_s.shape[1])


def _unit_factor(table: dict, unit: str, what: str, path: Path) -> float:
    key = unit.strip().replace(" ", "")
    for k, f in table.items():
        if k.lower() == key.lower():
            return f
    raise InputDataError(f"{what} unit {unit!r} not understood (known: {', '.join(table)})", path)


def _round_rate(fs: float) -> float:
    """Snap to an integer Hz when within 10 ppm (UFF stores the increment with 6 digits)."""
    r = round(fs)
    return float(r) if r > 0 and abs(fs - r) <= 1e-5 * fs else float(fs)


def node_numbers(values, path: Path, what: str = "node numbers") -> np.ndarray:
    """``values`` as (N,) int64 node numbers; InputDataError unless every one is a whole number
    below 2**53 in magnitude (a NaN, inf, fraction or text is a corrupt file, not a node)."""
    try:
        x = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise InputDataError(f"{what} are not integers: {np.asarray(values).reshape(-1)[:3]}", path) from None
    bad = ~(np.isfinite(x) & (np.abs(x) < 2.0**53) & (x == np.round(x)))
    if bad.any():
        raise InputDataError(f"{what} are not integers: {x[bad][:3]}", path)
    return x.astype(np.int64)


def finish_scan(node_ids, coords_mm, velocity_mm_s, fs, reference, reference_unit, t0,
                source: str, path: Path, expected_grid: tuple[int, int] | None,
                notes: list[str] | None = None, unit_hint: str = "", velocity_hint: str = "") -> LdvScan:
    """Validate arrays (plausible ranges: vfcli/io/limits.py), sort by node number, infer
    the grid and flag dropouts. ``unit_hint`` ends the message of an implausible extent,
    ``velocity_hint`` that of an implausible velocity."""
    notes = list(notes or [])
    node_ids = node_numbers(node_ids, path)
    coords = np.asarray(coords_mm, dtype=np.float64)
    vel = np.asarray(velocity_mm_s, dtype=np.float64)
    p = node_ids.size
    if p == 0:
        raise InputDataError("scan has no points", path)
    if coords.shape != (p, 3):
        raise InputDataError(f"coordinates have shape {coords.shape}, expected ({p}, 3)", path)
    if vel.ndim != 2 or vel.shape[0] != p or vel.shape[1] < 2:
        raise InputDataError(f"velocity has shape {vel.shape}, expected ({p}, S >= 2)", path)
    if np.unique(node_ids).size != p:
        raise InputDataError("duplicate node numbers", path)
    if not (np.isfinite(fs) and fs > 0):
        raise InputDataError(f"sampling rate {fs} Hz is not positive", path)
    check_range(fs, *LDV_FS_RANGE, "vibrometer sampling rate", "Hz", path)
    check_finite(coords, path, "coordinates")
    check_finite(vel, path, "velocity")
    check_ldv_extent(coords, path, unit_hint)
    try:
        check_abs_max(vel, LDV_MAX_ABS_VELOCITY_MM_S, "velocity", "mm/s", path)
    except InputDataError as exc:
        if not velocity_hint:
            raise
        raise InputDataError(f"{exc.args[0]}{velocity_hint}") from None
    ref = None
    if reference is not None:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.shape != vel.shape:
            raise InputDataError(f"reference has shape {ref.shape}, velocity {vel.shape}", path)
        check_finite(ref, path, "reference")
        ref_key = re.sub(r"[\s_]", "", reference_unit or "").lower()
        if ref_key in PA_PER_UNIT:  # a pressure reference: the same bound as the pressure readers
            with np.errstate(over="ignore"):
                ref_pa = ref * PA_PER_UNIT[ref_key]
            check_abs_max(ref_pa, MAX_ABS_PRESSURE_PA, "reference pressure", "Pa", path)
        else:  # volts from the transducer's amplifier (+-10 V), or a unit vfcli does not know
            check_abs_max(ref, MAX_ABS_REFERENCE, "reference", reference_unit or "(no unit)", path)
    if t0 is not None:
        t0 = np.asarray(t0, dtype=np.float64).reshape(-1)
        if t0.shape != (p,):
            raise InputDataError(f"t0 has shape {t0.shape}, expected ({p},)", path)
        check_finite(t0, path, "start times")
    order = np.argsort(node_ids, kind="stable")
    node_ids, coords, vel = node_ids[order], coords[order], vel[order]
    ref = None if ref is None else ref[order]
    t0 = None if t0 is None else t0[order]
    grid = infer_grid(coords, expected_grid)
    if grid.message:
        notes.append(grid.message)
    if grid.turned:
        logger.info("%s: scan grid read as %d x %d with its rows along the coordinates' x axis (turned by %.0f deg)",
                    path, grid.shape[0], grid.shape[1], grid.angle_deg)
    flags, reasons = detect_dropouts(vel, fs)
    if flags.any():
        notes.append(f"{int(flags.sum())} of {p} points flagged for signal dropout")
    return LdvScan(node_ids=node_ids, coords_mm=coords, velocity_mm_s=vel, fs=_round_rate(fs),
                   reference=ref, reference_unit=reference_unit, t0=t0,
                   grid_index=grid.index, grid_shape=grid.shape, dropout=flags,
                   dropout_reasons=reasons, source=source, notes=notes)


def read_ldv(
    path: str | Path,
    channels: LdvChannels = LdvChannels(),
    expected_grid: tuple[int, int] | None = DEFAULT_GRID,
    velocity_unit: str | None = None,
    length_unit: str | None = None,
    kind: str | None = None,
) -> LdvScan:
    """Read an LDV scan (UFF, CSV or MAT, by extension).

    Parameters
    ----------
    path : str or Path
    channels : LdvChannels
        id1/id2 patterns of the velocity and reference 58 records (UFF).
    expected_grid : (rows, cols) or None
        Expected scan grid (default 17 x 22); a different grid is reported in
        ``LdvScan.notes`` and logged, not raised.
    velocity_unit, length_unit : str or None
        Units when the file does not state them (see module docstring); a UFF
        without dataset 164 needs ``length_unit``.
    kind : {'uff', 'csv', 'mat'} or None
        Force the format; default from the extension (.uff/.unv/.csv/.mat).

    Returns
    -------
    LdvScan

    Raises
    ------
    InputDataError
        Unreadable file, missing channels or geometry, unknown units,
        inconsistent records, NaN/Inf samples.
    """
    p = require_file(path, "LDV file")
    kind = kind or {".uff": "uff", ".unv": "uff", ".csv": "csv", ".mat": "mat"}.get(
        p.suffix.lower())
    if kind == "uff":
        return _read_uff(p, channels, expected_grid, velocity_unit, length_unit)
    if kind == "csv":
        return _read_csv(p, expected_grid)
    if kind == "mat":
        return _read_mat(p, expected_grid)
    raise InputDataError(f"unsupported LDV file type {p.suffix!r} (uff, unv, csv, mat)", p)


# --------------------------------------------------------------------------- UFF

def _read_uff(p: Path, ch: LdvChannels, expected_grid, velocity_unit, length_unit) -> LdvScan:
    import pyuff

    with open(p, "rb") as fh:
        head = fh.read(200)
    if b"    -1" not in head:
        raise InputDataError("not a UFF file (no '    -1' dataset delimiter at the start)", p)
    try:
        uff = pyuff.UFF(str(p))
        types = list(np.asarray(uff.get_set_types()).astype(int))
        wanted = [i for i, t in enumerate(types) if t in (15, 164, 2411, 58)]
        sets = uff.read_sets(wanted) if wanted else []
        if isinstance(sets, dict):
            sets = [sets]
    except Exception as exc:  # pyuff raises bare Exception / AttributeError on bad files
        raise InputDataError(f"unreadable UFF: {type(exc).__name__}: {exc}", p) from None
    geo = [s for s in sets if s.get("type") in (2411, 15)]
    units = [s for s in sets if s.get("type") == 164]
    recs = [s for s in sets if s.get("type") == 58]
    if not geo:
        raise InputDataError("no geometry dataset (2411 or 15) with the scan point coordinates",
                             p)
    if not recs:
        raise InputDataError("no dataset 58 (time records)", p)
    try:
        g_nodes = node_numbers(np.concatenate([np.asarray(g["node_nums"]) for g in geo]), p, "geometry node numbers")
        g_xyz = np.concatenate([np.column_stack([g["x"], g["y"], g["z"]]) for g in geo])
    except (KeyError, ValueError, TypeError) as exc:
        raise InputDataError(f"incomplete geometry dataset: {exc}", p) from None
    if units:
        factor = float(units[0].get("length", 1.0))
        if not (np.isfinite(factor) and factor > 0):
            raise InputDataError(f"dataset 164 length factor {factor} is not positive", p)
        mm_per = 1e3 / factor
        unit_hint = " (dataset 164 states the unit)"
    elif length_unit is None:
        span = float(np.max(np.ptp(g_xyz[:, :2], axis=0))) if len(g_xyz) else 0.0
        unit = infer_length_unit(span)
        if unit is None:
            raise InputDataError(
                f"no units dataset (164): the length unit of the point coordinates (spanning {span:.4g} "
                "file units) is unknown; set ingest_ldv.length_unit (m, mm, ...)", p)
        logger.warning("%s: no units dataset (164); the points span %.4g file units, which only %s makes a "
                       "plausible scan of the folds: read as %s (set ingest_ldv.length_unit to say otherwise)",
                       p.name, span, unit, unit)
        mm_per = MM_PER_UNIT[unit]
        unit_hint = f" (no dataset 164; inferred {unit}: set ingest_ldv.length_unit)"
    else:
        mm_per = _unit_factor(MM_PER_UNIT, length_unit, "length", p)
        unit_hint = f" (ingest_ldv.length_unit = {length_unit!r})"
    vel_re = re.compile(ch.velocity_id2, re.IGNORECASE)
    ref_re = re.compile(ch.reference_id2, re.IGNORECASE)
    vel, ref = {}, {}
    for r in recs:
        id1 = str(r.get("id1", "")).strip().lower()
        id2 = str(r.get("id2", "")).strip()
        if id1 == ch.velocity_id1.lower() and vel_re.search(id2) and not _other_quantity(r):
            target = vel
        elif id1 == ch.reference_id1.lower() and ref_re.search(id2):
            target = ref
        else:
            continue
        node = int(r.get("rsp_node", -1))
        if node in target:
            what, key = ("velocity", "velocity_id2") if target is vel else ("reference", "reference_id2")
            raise InputDataError(f"two {what} records for node {node} (id2 {str(target[node].get('id2', '')).strip()!r} "
                                 f"and {id2!r}): set ingest_ldv.{key} to a pattern only one of them matches", p)
        if int(r.get("func_type", -1)) != 1:
            raise InputDataError(f"node {node}: dataset 58 func_type {r.get('func_type')} is "
                                 "not time data (export time signals, func_type 1)", p)
        data = np.asarray(r.get("data"))
        if data is None or data.ndim != 1 or np.iscomplexobj(data):
            raise InputDataError(f"node {node}: record data is not a real time series", p)
        target[node] = r
    if not vel:
        seen = sorted({(str(r.get("id1", "")).strip(), str(r.get("id2", "")).strip())
                       for r in recs})[:6]
        raise InputDataError(f"no velocity records (id1 {ch.velocity_id1!r}, id2 "
                             f"/{ch.velocity_id2}/); the file has (id1, id2): {seen}", p)
    nodes = np.array(sorted(vel), dtype=np.int64)
    missing = np.setdiff1d(nodes, g_nodes)
    if missing.size:
        raise InputDataError(f"{missing.size} scan point(s) have no geometry (nodes "
                             f"{missing[:5].tolist()}...)", p)
    if ref and set(ref) != set(vel):
        diff = sorted(set(vel) ^ set(ref))[:5]
        raise InputDataError(f"velocity and reference records cover different nodes "
                             f"(e.g. {diff})", p)
    first = vel[int(nodes[0])]
    n_s = np.asarray(first["data"]).size
    inc = _abscissa(first, p)[0]
    rows, starts = [], []
    for n in nodes:
        for tab in (vel, ref) if ref else (vel,):
            r = tab[int(n)]
            if np.asarray(r["data"]).size != n_s:
                raise InputDataError(f"node {n}: {np.asarray(r['data']).size} samples, node "
                                     f"{nodes[0]} has {n_s}", p)
            r_inc, r_start = _abscissa(r, p)
            if abs(r_inc - inc) > 1e-6 * abs(inc):
                raise InputDataError(f"node {n}: sample interval {r_inc} s differs from {inc} s",
                                     p)
            if tab is vel:
                starts.append(r_start)
        rows.append(vel[int(n)])
    if not inc > 0:
        raise InputDataError(f"sample interval (abscissa_inc) {inc} is not positive", p)
    v_label = str(first.get("ordinate_axis_units_lab", "")).strip()
    v_label = "" if v_label.upper() == "NONE" else v_label
    if velocity_unit and v_label and _unit_factor(MM_S_PER_UNIT, v_label, "velocity", p) != \
            _unit_factor(MM_S_PER_UNIT, velocity_unit, "velocity", p):
        raise InputDataError(f"velocity unit mismatch: the records say {v_label!r}, ingest_ldv.velocity_unit "
                             f"{velocity_unit!r}", p)
    v_unit = v_label or velocity_unit or "m/s"
    v_fac = _unit_factor(MM_S_PER_UNIT, v_unit, "velocity", p)
    velocity_hint = "" if v_label or velocity_unit else \
        "; the velocity records state no unit (ordinate axis label) and were read as m/s: set ingest_ldv.velocity_unit"
    g_index = {int(nd): i for i, nd in enumerate(g_nodes)}
    coords = g_xyz[[g_index[int(n)] for n in nodes]] * mm_per
    # UFF 58 response direction: 3 is +Z (up, towards the camera), -3 -Z: a record measured along -Z holds the
    # +Z velocity with its sign turned
    turned = np.array([int(r.get("rsp_dir", 3) or 3) == -3 for r in rows])
    velocity = np.stack([np.asarray(r["data"], dtype=np.float64) for r in rows]) * v_fac
    velocity[turned] *= -1.0
    t0 = np.array(starts)
    reference, ref_unit = None, ""
    if ref:
        reference = np.stack([np.asarray(ref[int(n)]["data"], dtype=np.float64) for n in nodes])
        ref_unit = str(ref[int(nodes[0])].get("ordinate_axis_units_lab", "")).strip()
        ref_unit = "" if ref_unit.upper() == "NONE" else ref_unit
    notes = []
    extra = np.setdiff1d(g_nodes, nodes)
    if extra.size:
        notes.append(f"{extra.size} geometry node(s) without velocity records ignored")
    if not ref:
        notes.append("no reference records")
    if turned.any():
        notes.append(f"{int(turned.sum())} of {turned.size} velocity records measured along -Z (response direction -3): "
                     "their sign turned to +Z, vfcli's vertical axis")
    if not (v_label or velocity_unit):
        notes.append("the velocity records state no unit (ordinate axis label): read as m/s, as the vibrometer "
                     "exports; if it is another, set ingest_ldv.velocity_unit")
    src = f"UFF {p.name}: {nodes.size} points, {n_s} samples, velocity in {v_unit}"
    return finish_scan(nodes, coords, velocity, 1.0 / inc, reference, ref_unit, t0, src, p,
                       expected_grid, notes, unit_hint, velocity_hint)


#: UFF 58 ordinate specific data types that are not a velocity (8 displacement, 12 acceleration), and id2 words
#: of such records (Polytec's English and German labels), which the default id2 pattern ('^Vib') matches too.
_NOT_VELOCITY_TYPES = (8, 12)
_NOT_VELOCITY_ID2 = re.compile(r"displacement|acceleration|\bweg\b|beschleunigung", re.IGNORECASE)


def _other_quantity(record: dict) -> bool:
    """True for a 58 record that states another quantity than velocity (its type or its id2)."""
    try:
        kind = int(record.get("ordinate_spec_data_type", 0) or 0)
    except (TypeError, ValueError):
        kind = 0
    return kind in _NOT_VELOCITY_TYPES or bool(_NOT_VELOCITY_ID2.search(str(record.get("id2", ""))))


def _abscissa(record: dict, p: Path) -> tuple[float, float]:
    """(sample interval s, start time s) of a 58 record: its ``abscissa_inc`` / ``abscissa_min``, or, for a record
    flagged uneven (``abscissa_spacing`` 0, pyuff's default when a writer leaves it out) whose abscissa values
    are uniform, those values' own (:func:`vfcli.io.pressure.record.uniform_rate`)."""
    inc = float(record.get("abscissa_inc") or 0.0)
    if inc > 0 or int(record.get("abscissa_spacing", 1) or 0) == 1 or record.get("x") is None:
        return inc, float(record.get("abscissa_min") or 0.0)
    x = np.asarray(record["x"], dtype=np.float64).ravel()
    try:
        fs, t0 = uniform_rate(x, p)
    except InputDataError as exc:
        raise InputDataError(f"{exc.args[0].split(': ', 1)[-1]} (UFF 58 abscissa values, abscissa_spacing 0)", p) \
            from None
    return 1.0 / fs, t0


# --------------------------------------------------------------------------- CSV

def _comment_meta(lines: list[str]) -> tuple[dict, int]:
    """The ``# key = value`` comments above the header, and the number of lines they and blank lines take."""
    meta, n_skip = {}, 0
    for line in lines:
        s = line.strip()
        if s.startswith("#"):
            m = re.match(r"^#\s*([A-Za-z_0-9]+)\s*[=:]\s*(.+?)\s*$", s)
            if m:
                meta[m.group(1).lower()] = m.group(2)
            n_skip += 1
        elif not s:
            n_skip += 1
        else:
            break
    return meta, n_skip


def _read_csv(p: Path, expected_grid) -> LdvScan:
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputDataError("not a text CSV file", p) from None
    check_last_row_complete(text, p)
    lines = text.splitlines()
    meta, n_skip = _comment_meta(lines)
    header = lines[n_skip].strip().lower().split(",") if n_skip < len(lines) else [""]
    if header[:6] != ["node", "x", "y", "z", "channel", "t0"]:
        raise InputDataError("CSV header must start with node,x,y,z,channel,t0", p)
    codes = {"velocity": 0.0, "reference": 1.0}

    def conv(s):
        s = s.strip().strip('"').lower()
        if s not in codes:
            raise ValueError(f"channel {s!r} is not velocity/reference")
        return codes[s]

    rows = [(k, line) for k, line in enumerate(lines[n_skip + 1:], n_skip + 2)
            if line.strip() and not line.lstrip().startswith("#")]
    table = numeric_rows(rows, ",", p, header, converters={4: conv})
    if "fs" not in meta:
        raise InputDataError("missing '# fs = <Hz>' comment", p)
    try:
        fs = float(meta["fs"])
    except ValueError:
        raise InputDataError(f"'# fs = {meta['fs']}' is not a number", p) from None
    check_finite(table, p, "CSV table")
    node_numbers(table[:, 0], p)
    is_ref = table[:, 4] == 1.0
    vel_rows, ref_rows = table[~is_ref], table[is_ref]
    v_nodes = vel_rows[:, 0].astype(np.int64)
    if np.unique(v_nodes).size != v_nodes.size:
        raise InputDataError("two velocity rows for the same node", p)
    reference = None
    if ref_rows.shape[0]:
        r_nodes = ref_rows[:, 0].astype(np.int64)
        if np.unique(r_nodes).size != r_nodes.size or set(r_nodes) != set(v_nodes):
            raise InputDataError("reference rows must cover the velocity nodes once each", p)
        reference = ref_rows[np.argsort(r_nodes)][:, 6:]
    order = np.argsort(v_nodes)
    vel_rows = vel_rows[order]
    v_fac = _unit_factor(MM_S_PER_UNIT, meta.get("velocity_unit", "mm/s"), "velocity", p)
    l_fac = _unit_factor(MM_PER_UNIT, meta.get("length_unit", "mm"), "length", p)
    return finish_scan(vel_rows[:, 0], vel_rows[:, 1:4] * l_fac, vel_rows[:, 6:] * v_fac, fs,
                       reference, meta.get("reference_unit", "Pa"), vel_rows[:, 5],
                       f"CSV {p.name}: {vel_rows.shape[0]} points", p, expected_grid)


# --------------------------------------------------------------------------- MAT

def _mat_str(m: dict, key: str, default: str) -> str:
    v = m.get(key)
    if v is None:
        return default
    return str(np.asarray(v).reshape(-1)[0]).strip() if np.asarray(v).size else default


def _read_mat(p: Path, expected_grid) -> LdvScan:
    from scipy.io import loadmat

    from vfcli.io._matcheck import check_mat5

    check_mat5(p)  # scipy's loadmat can segfault on corrupt files
    try:
        m = loadmat(p)
    except NotImplementedError:
        raise InputDataError("MATLAB v7.3 (HDF5) .mat files are not supported: save with "
                             "-v7", p) from None
    except Exception as exc:
        raise InputDataError(f"unreadable .mat file: {type(exc).__name__}: {exc}", p) from None
    for key in ("coords", "velocity", "fs"):
        if key not in m:
            structs = [k for k, v in m.items() if not k.startswith("__") and getattr(v, "dtype", None) is not None
                       and v.dtype.names and key in v.dtype.names]
            inside = f"; it is a field of the struct {structs[0]!r}: save the fields as variables (save(f, '-struct', " \
                     f"'{structs[0]}'))" if structs else ""
            raise InputDataError(f"variable {key!r} missing (need coords, velocity, fs){inside}", p)
    try:
        vel = np.asarray(m["velocity"], dtype=np.float64)
        coords = np.asarray(m["coords"], dtype=np.float64)
        fs = float(np.asarray(m["fs"], dtype=np.float64).reshape(-1)[0])
        nodes = (np.asarray(m["node_ids"]).reshape(-1) if "node_ids" in m
                 else np.arange(1, vel.shape[0] + 1))
        ref = np.asarray(m["reference"], dtype=np.float64) if "reference" in m else None
        t0 = np.asarray(m["t0"], dtype=np.float64).reshape(-1) if "t0" in m else None
    except (ValueError, TypeError, IndexError) as exc:
        raise InputDataError(f"variable of the wrong type: {exc}", p) from None
    if vel.ndim == 2 and coords.ndim == 2 and vel.shape[0] != coords.shape[0] and vel.shape[1] == coords.shape[0]:
        raise InputDataError(f"velocity has shape {vel.shape} and coords {coords.shape}: one row per point is "
                             f"expected, ({coords.shape[0]}, samples); save velocity transposed (velocity.')", p)
    v_fac = _unit_factor(MM_S_PER_UNIT, _mat_str(m, "velocity_unit", "mm/s"), "velocity", p)
    l_fac = _unit_factor(MM_PER_UNIT, _mat_str(m, "length_unit", "mm"), "length", p)
    return finish_scan(nodes, coords * l_fac, vel * v_fac, fs, ref,
                       _mat_str(m, "reference_unit", "Pa"), t0,
                       f"MAT {p.name}: {vel.shape[0] if vel.ndim else 0} points", p,
                       expected_grid)


__all__ = ["LdvChannels", "LdvScan", "read_ldv", "detect_dropouts", "infer_grid",
           "finish_scan"]
