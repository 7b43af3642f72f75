"""The collision candidate (vfcli.diagnose.candidates.contact) on forward cases.

- where the linear model's folds cross the midplane (the pressure case with a medial suction), the
  term at theta = 1 removes the crossing, its contact forces are those of the rigid-contact problem
  solved by an independent method (scipy's L-BFGS-B on the dual energy), and its column is the
  derivative of the predicted measurement (motion and gap rows) along that independent solution;
- where the folds never reach the midplane (the pressure case as fitted), the term does not act:
  a zero column, "never cross" in words, and the screening says "no evidence".
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from scipy.optimize import minimize

from _candidates_case import pressure_case
from _forward_case import F0_HZ
from vfcli.diagnose.candidate import Baseline, Candidate, screen
from vfcli.diagnose.candidates import CANDIDATES, Contact
from vfcli.diagnose.candidates.contact import closed_frames
from vfcli.inverse.terms.gap import gap_rows


@lru_cache(maxsize=1)
def crossing_case() -> Baseline:
    """The pressure case with a medial suction of 0.6 p_ref: the folds cross the midplane in every
    frame, by up to 0.26 mm (measured)."""
    base = pressure_case()
    load = base.problem.response.load_model
    c = load.control_matrix(base.x).copy()
    c[1, 0] = -0.6 * load.p_ref
    return Baseline.at(base.problem, c.ravel(), F0_HZ, model=base.model)


def _predicted(base: Baseline, disp: np.ndarray) -> np.ndarray:
    """Predicted measurement (motion rows mm/s, gap rows mm) at displacements disp, raster frozen at the baseline."""
    p = base.problem
    gaps = [gap_rows(p, p.mesh.nodes + disp[f], fr.sil, np.zeros((len(disp[f]), 3, 0)))[1] / p.camera.px_per_mm
            for f, fr in enumerate(base.frames)]
    return np.concatenate([base.motion_vector(disp), *gaps])


def _independent_forces(g0: np.ndarray, compliance: np.ndarray) -> np.ndarray:
    """Rigid-contact forces of one time by L-BFGS-B on ``1/2 l^T G l + g0^T l, l >= 0``, in the
    scaled unknown ``w = l d`` (d the mean diagonal of G: ``1/2 w^T (G / d) w + g0^T w``)."""
    d = float(np.diag(compliance).mean())
    gn = compliance / d
    res = minimize(lambda w: (0.5 * w @ gn @ w + g0 @ w, gn @ w + g0), np.zeros(len(g0)), jac=True,
                   method="L-BFGS-B", bounds=[(0.0, None)] * len(g0),
                   options={"ftol": 1e-16, "gtol": 1e-13, "maxiter": 50000, "maxcor": 50})
    return res.x / d


def test_contact_follows_the_protocol_and_is_screened_by_default():
    c = Contact()
    assert isinstance(c, Candidate) and c.n_params == 1 and "midplane" in c.signature
    assert any(isinstance(k, Contact) for k in CANDIDATES)


@pytest.mark.slow
def test_the_term_removes_the_crossing_with_the_forces_of_the_rigid_contact_problem():
    base = crossing_case()
    term = Contact()
    depth0 = term.overlap(base)
    assert 0.2 < depth0.max() < 0.3 and np.all(depth0 > 0), depth0        # measured 0.262 mm, every time
    u1 = base.displacements + term.extension(base, np.array([1.0]))
    sep1 = term.separation(base, u1)
    assert sep1.min() > -1e-7, sep1.min()                                   # no interpenetration left
    lam = term.forces(base)
    assert lam.min() >= 0.0
    # complementarity: a node pushed is a node touching (relative to the crossing removed)
    assert np.max(np.abs(lam * sep1)) < 1e-6 * np.max(lam) * depth0.max()
    # against an independent solver of the same problem (a few times)
    _, _, g = term.operators(base)
    g0 = term.separation(base)
    for t in (0, 5, 10):
        ref = _independent_forces(g0[t], g)
        err = np.linalg.norm(lam[t] - ref) / np.linalg.norm(ref)
        assert err < 1e-3, (t, err)
    # the deepest crossing is pushed back to its own side by about its depth
    _, cn, _ = term.operators(base)
    t, i = np.unravel_index(np.argmin(g0), g0.shape)
    push = cn.side[i] * (u1 - base.displacements)[t, cn.nodes[i], 1]
    assert abs(push / -g0[t, i] - 1) < 1e-6, (push, g0[t, i])


@pytest.mark.slow
def test_the_column_is_the_derivative_of_the_predicted_measurement():
    base = crossing_case()
    term = Contact()
    column = term.jacobian(base)[:, 0]
    # the independent rigid-contact displacement change of every time (forces from L-BFGS-B)
    _, _, g = term.operators(base)
    g0 = term.separation(base)
    ref = term.correction(base, np.array([_independent_forces(row, g) for row in g0]))
    h = 1e-3
    fd = (_predicted(base, base.displacements + h * ref) - _predicted(base, base.displacements - h * ref)) / (2 * h)
    n_motion = base.n_motion_rows
    for rows in (slice(0, n_motion), slice(n_motion, None)):
        err = np.linalg.norm(column[rows] - fd[rows]) / np.linalg.norm(fd[rows])
        assert 0 < np.linalg.norm(fd[rows]) and err < 2e-3, (rows, err)


@pytest.mark.slow
def test_where_the_folds_never_reach_the_midplane_the_term_does_not_act_and_has_no_evidence():
    base = pressure_case()
    term = Contact(base.model)
    assert term.overlap(base).max() == 0.0
    assert not np.any(term.jacobian(base))
    words = term.evidence(base)
    assert words.startswith("the folds of the no-contact fit never cross the midplane"), words
    (res,) = screen(None, [term], base)
    assert res.p_value == 1.0 and "no evidence (the term does not act" in res.words, res.words
    assert "never cross the midplane" in res.words


@pytest.mark.slow
def test_the_evidence_separates_closed_and_open_frames():
    base = crossing_case()
    term = Contact()
    depth = term.overlap(base)[:-1]
    closed = np.zeros(len(depth), bool)
    closed[np.argsort(depth)[-3:]] = True                                  # say the three deepest were closed
    words = term.evidence(base, closed)
    assert f"by up to {depth.max():.2g} mm during the closed phase (3 of 3 frames)" in words, words
    assert f"by up to {depth[~closed].max():.2g} mm while the glottis is open (9 of 9 frames)" in words, words
    assert closed_frames(base.problem.meas).shape == (len(depth),)


@pytest.mark.slow
def test_the_loads_gradient_under_contact_is_the_derivative_of_the_objective():
    """The refit's gradient in the loads with contact switched on (theta = 1) is E's derivative along a
    load direction (central differences, the raster frozen), pulled back through the contact forces;
    the baseline response's adjoint alone (the change of the forces with the loads left out) is not."""
    from vfcli.diagnose.refit import _blocks, _Extended, energy

    base = crossing_case()
    p = base.problem
    ext = _Extended(p, Contact(), base.f0_hz, base.model, None)
    st = ext.state(base.x, np.array([1.0]))
    g_l = _blocks(ext, st, loads_only=True)[0]
    plain = _blocks(_Extended(p, None, base.f0_hz, base.model, None), st, loads_only=True)[0]

    def e_at(x):
        u0 = p.displacements(x)
        return energy(p, x, u0 + ext.change(x, u0, st.theta), st.frames).total

    rng = np.random.default_rng(3)
    for _ in range(3):
        d = rng.standard_normal(len(base.x)) * np.abs(base.x).max()
        h = 1e-6
        fd = (e_at(base.x + h * d) - e_at(base.x - h * d)) / (2 * h)
        err = abs(g_l @ d - fd) / abs(fd)
        assert err < 1e-7, (err, g_l @ d, fd)                               # measured 1e-12 .. 3e-9
        assert abs(plain @ d - fd) / abs(fd) > 0.1, (plain @ d, fd)          # measured 29-56 % off


@pytest.mark.slow
def test_the_pullback_is_the_adjoint_of_the_contact_map():
    """<pullback(g), dU0> equals the derivative of <g, U0 + theta D(U0)> along dU0 (central differences
    small enough to keep every time's set of pushed nodes)."""
    base = crossing_case()
    term = Contact()
    rng = np.random.default_rng(5)
    g = rng.standard_normal(base.displacements.shape)
    theta = np.array([0.7])
    pulled = term.pullback(base, g, theta)

    def value(u0):
        moved = Baseline(base.problem, base.x, u0, base.frames, base.f0_hz, base.model)
        return float(np.sum(g * (u0 + term.extension(moved, theta))))

    for _ in range(3):
        du = rng.standard_normal(base.displacements.shape) * 1e-3
        h = 1e-4
        fd = (value(base.displacements + h * du) - value(base.displacements - h * du)) / (2 * h)
        err = abs(np.sum(pulled * du) - fd) / abs(fd)
        assert err < 1e-6, (err, np.sum(pulled * du), fd)                   # measured 1e-10 .. 2e-8
        assert abs(np.sum(g * du) - fd) / abs(fd) > 0.01                     # the forces' change matters


@pytest.mark.slow
def test_the_correction_is_the_elastic_solve_of_the_contact_forces():
    """The correction sums the unit pushes' displacements (computed once per model); against the FEM
    solve of the forces themselves, ``K^-1 N^T lambda``, to round-off."""
    base = crossing_case()
    term = Contact()
    model, cn, _ = term.operators(base)
    lam = term.forces(base)
    rows = [0, 5, 10]
    rhs = np.zeros((model.n_dofs, len(rows)))
    for j, t in enumerate(rows):
        rhs[cn.ydof, j] = cn.side * lam[t]
    direct = model.vertex_displacements(model.solve(rhs)).reshape(len(rows), -1, 3)
    got = term.correction(base, lam)[rows]
    assert np.abs(direct).max() > 0.1                          # the crossing is pushed back by about its depth
    assert np.abs(got - direct).max() < 1e-9 * np.abs(direct).max()
    assert not np.any(term.correction(base, np.zeros_like(lam)))


@pytest.mark.slow
def test_a_crossing_that_comes_with_the_closure_is_contacts_signature_and_one_that_stays_is_not():
    """Fresh null 2348 (session 76) was named "contact": its no-contact fit crossed the midplane by 0.33 mm in
    every frame, open or closed (its rest shape), and the contact refit's constant push passed both held-out
    comparisons.  Collision's signature is a crossing that comes with the closure: on the crossing case (0.004 to
    0.26 mm over the cycle) with its deepest frames recorded closed it is there; said closed in its shallowest
    frames, or the same crossing frozen at its deepest with a tenth of its swing left, it is not."""
    base = crossing_case()
    term = Contact()
    depth = term.overlap(base)[:-1]
    deep = np.zeros(len(depth), bool)
    deep[np.argsort(depth)[-3:]] = True
    assert term.missing_signature(base, deep) == ""
    shallow = np.zeros(len(depth), bool)
    shallow[np.argsort(depth)[:3]] = True
    assert "no deeper while the glottis is closed" in term.missing_signature(base, shallow)
    assert "closed in no frame" in term.missing_signature(base, np.zeros(len(depth), bool))
    # the same folds held near their deepest crossing: a tenth of the swing about it is left
    u = base.displacements
    k = int(np.argmax(depth))
    held = Baseline(base.problem, base.x, u[k] + 0.1 * (u - u[k]), base.frames, base.f0_hz, base.model)
    d_held = term.overlap(held)[:-1]
    assert d_held.min() > 0.2 and d_held.max() - d_held.min() < 0.1 * depth.max(), d_held   # 0.236-0.262 mm
    words = term.missing_signature(held, deep)
    assert "at every time of the window, open or closed" in words and "rest shape" in words, words


def test_a_refit_without_its_terms_signature_confirms_nothing_and_says_why():
    from vfcli.diagnose.confirmation import Confirmation, HeldOutError
    from vfcli.diagnose.decide import decide

    h = HeldOutError("cycles", "mm/s", np.array([2.0, 2.2, 1.8]), np.array([1.0, 1.2, 0.9]))
    found = Confirmation("contact", ("contact_share",), np.array([0.18]), np.array([0.05]), heldout=(h,))
    why = "the folds of the no-contact fit cross the midplane by 0.33 mm at every time of the window"
    held = Confirmation("contact", ("contact_share",), np.array([0.18]), np.array([0.05]), heldout=(h,),
                        signature_missing=why)
    assert found.improves and not held.improves
    assert held.shortfall == f"the baseline does not show its signature: {why}"
    assert held.as_dict()["signature_missing"] == why and found.as_dict()["signature_missing"] == ""
    names = ["inertia", "damping", "asymmetry", "contact"]
    d = decide(names, np.array([0.6, 0.9, 0.5, 0.01]), [True] * 4, 199, confirmations={"contact": held})
    assert d.findings == () and d.lines[-1] == "no missing physics detected (unconfirmed lead: contact)"
    line = next(x for x in d.lines if x.startswith("contact: "))
    assert line.endswith(f"a calibrated lead (family-wise p = 0.01), the baseline does not show its signature: {why}"), \
        line
    d = decide(names, np.array([0.6, 0.9, 0.5, 0.01]), [True] * 4, 199, confirmations={"contact": found})
    assert d.findings == ("contact",)
    # asked for by name (--refit contact) where contact is no lead: the line says why its refit cannot count
    d = decide(names, np.array([0.6, 0.9, 0.5, 0.7]), [True] * 4, 199, confirmations={"contact": held})
    line = next(x for x in d.lines if x.startswith("contact: "))
    assert line.endswith(f"; its refit, asked for by name, does not confirm it either: the baseline does not show its "
                         f"signature: {why}"), line


def _closed_at(base: Baseline) -> tuple[np.ndarray, np.ndarray]:
    """(F,) bool twice: the three frames at the frame times where ``base``'s folds cross the midplane deepest, and
    the three where they cross least."""
    order = np.argsort(Contact().overlap(base)[:-1])
    deep, shallow = np.zeros(len(order), bool), np.zeros(len(order), bool)
    deep[order[-3:]] = True
    shallow[order[:3]] = True
    return deep, shallow


def _recorded_closed(base: Baseline, closed: np.ndarray) -> Baseline:
    """``base`` with a recording whose gap masks show the glottis closed in the frames ``closed`` (F,) bool and
    open in the others (what :func:`closed_frames` reads)."""
    import copy
    import dataclasses

    problem = copy.copy(base.problem)
    gap = np.ones((len(closed), 4, 4), bool)
    gap[closed] = False
    problem.meas = dataclasses.replace(problem.meas, gap=gap)
    return Baseline(problem, base.x, base.displacements, base.frames, base.f0_hz, base.model)


@pytest.mark.slow
def test_a_lead_whose_baseline_lacks_its_signature_is_not_refitted_and_its_line_says_why():
    """`vfcli diagnose` (--refit auto) refits no lead whose baseline lacks its term's signature
    (:func:`vfcli.diagnose.confirm.without_signature`): its refit could confirm nothing (the test above) and
    contact's takes a minute or more.  On the crossing case recorded closed in its deepest frames contact keeps its
    refit; recorded closed in its shallowest it is dropped with the reason, a term that states no signature is kept,
    and the decision's line says "not refitted" with the reason."""
    from vfcli.diagnose.candidates import StiffnessAsymmetry
    from vfcli.diagnose.confirm import without_signature
    from vfcli.diagnose.confirmation import NotRefitted
    from vfcli.diagnose.decide import decide

    base = crossing_case()
    deep, shallow = _closed_at(base)
    assert closed_frames(_recorded_closed(base, deep).problem.meas).tolist() == deep.tolist()
    keep, missing = without_signature(_recorded_closed(base, deep), [Contact(), StiffnessAsymmetry()])
    assert [c.name for c in keep] == ["contact", "asymmetry"] and missing == {}
    keep, missing = without_signature(_recorded_closed(base, shallow), [Contact(), StiffnessAsymmetry()])
    assert [c.name for c in keep] == ["asymmetry"] and list(missing) == ["contact"]
    why = missing["contact"]
    assert "no deeper while the glottis is closed" in why, why
    skipped = NotRefitted("contact", why)
    assert not skipped.improves and skipped.as_dict() == {"candidate": "contact", "refitted": False,
                                                         "improves": False, "signature_missing": why}
    names = ["inertia", "damping", "asymmetry", "contact"]
    d = decide(names, np.array([0.6, 0.9, 0.5, 0.01]), [True] * 4, 199, confirmations={"contact": skipped})
    assert d.findings == () and d.lines[-1] == "no missing physics detected (unconfirmed lead: contact)"
    line = next(x for x in d.lines if x.startswith("contact: "))
    assert line == ("contact: a calibrated lead (family-wise p = 0.01), not refitted: the baseline does not show its "
                    f"signature: {why}"), line


@pytest.mark.slow
def test_a_lead_not_refitted_leaves_its_place_among_the_refits_to_the_next_and_a_named_refit_is_made():
    """The leads of blind-panel 2012 (contact and asymmetry calibrated leads, inertia and damping profile leads;
    tests/test_diagnose_decide.py): with contact's signature missing the three refits are asymmetry, inertia and
    damping, not asymmetry and inertia alone; with it present, contact, asymmetry and inertia; `--refit contact`
    refits contact whatever the baseline shows."""
    from vfcli.diagnose.candidate import Screening
    from vfcli.diagnose.confirm import MAX_REFITS, refits_to_make

    base = crossing_case()
    deep, shallow = _closed_at(base)
    cands = list(CANDIDATES)
    p = {"inertia": (0.065, 0.58), "damping": (1.0, 0.76), "asymmetry": (0.03, 0.22), "offset": (0.975, 0.78),
         "contact": (0.005, 0.17)}
    scr = [Screening(c.name, 1.0, p[c.name][1], True, p_family=p[c.name][0]) for c in cands]
    leads = ("inertia", "damping")
    tries, missing = refits_to_make(_recorded_closed(base, shallow), scr, cands, "auto", profile_leads=leads)
    assert MAX_REFITS == 3 and [c.name for c in tries] == ["asymmetry", "inertia", "damping"]
    assert list(missing) == ["contact"] and "no deeper while the glottis is closed" in missing["contact"]
    tries, missing = refits_to_make(_recorded_closed(base, deep), scr, cands, "auto", profile_leads=leads)
    assert [c.name for c in tries] == ["contact", "asymmetry", "inertia"] and missing == {}
    tries, missing = refits_to_make(_recorded_closed(base, shallow), scr, cands, "contact", profile_leads=leads)
    assert [c.name for c in tries] == ["contact"] and missing == {}
    assert refits_to_make(_recorded_closed(base, shallow), scr, cands, "none") == ([], {})
