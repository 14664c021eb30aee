"""kane.elements, kane.terms and kane.codegen: element mass properties, Kane terms, generated code."""

import subprocess
import sys

import numpy as np
import pytest
import sympy as sp
from hypothesis import given
from hypothesis import strategies as st

from kane import terms
from kane.elements import Element, body_mass_properties, partition_box, partition_box_k
from kane.results import decide


def test_lattice_box_inertia_matches_closed_form():
    """n^3 equal point masses at cell centres of [-a, a]^3: <x^2> = a^2 (1 - 1/n^2) / 3 per axis."""
    h = np.array([0.1, 0.2, 0.3])
    for n in (1, 2, 3):
        els = partition_box(h, (n, n, n), mass=2.0, points_per_axis=1)
        m, com, I = body_mass_properties(els)
        x2 = h**2 * (1 - 1 / n**2) / 3
        expected = 2.0 * np.diag([x2[1] + x2[2], x2[0] + x2[2], x2[0] + x2[1]])
        assert m == pytest.approx(2.0)
        np.testing.assert_allclose(com, 0, atol=1e-15)
        np.testing.assert_allclose(I, expected, rtol=1e-12, atol=1e-15)


def test_partition_does_not_change_body_mass_properties():
    """Lemma A.1's premise: grouping the same point masses into k elements keeps the body's mass properties."""
    h = (0.1, 0.15, 0.2)
    ref = body_mass_properties(partition_box_k(h, 1, points_per_axis=6))
    for k, ppa in ((8, 3), (27, 2)):  # same 6x6x6 lattice of point masses, grouped into k cells
        got = body_mass_properties(partition_box_k(h, k, points_per_axis=ppa))
        assert got[0] == pytest.approx(ref[0])
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-12, atol=1e-15)


def test_element_rejects_bad_input():
    with pytest.raises(ValueError, match="as many masses as points"):
        Element(np.ones(2), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="positive"):
        Element(np.array([1.0, -1.0]), np.zeros((2, 3)))


@given(st.integers(0, 10_000))
def test_generalized_inertia_force_by_elements_equals_point_masses(seed):
    """Eqs. (18) and (19) agree for random bodies, motions and partitions (Lemma A.1)."""
    rng = np.random.default_rng(seed)
    els = partition_box_k(
        rng.uniform(0.05, 0.5, 3), int(rng.choice([1, 2, 8, 27])), mass=1.3, rng=rng, jitter=0.5
    )
    R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    kin = terms.element_kinematics(els, R, rng.standard_normal(3), *rng.standard_normal((4, 3)))
    com = (np.array([e.mass for e in els])[:, None] * kin.centroid).sum(0) / sum(
        e.mass for e in els
    )
    u, w = terms.free_body_partials(kin, com)
    t = terms.kane_terms(
        els, kin, terms.ElementLoads([rng.standard_normal((len(e.masses), 3)) for e in els]), u, w
    )
    np.testing.assert_allclose(t.K, t.K_points, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(t.Kstar, t.Kstar_points, rtol=1e-10, atol=1e-10)


def test_symbolic_element_identities_simplify_to_zero():
    ids = terms.symbolic_element_identities(3)
    assert ids["eq17"] == 0 and ids["eq19"] == 0 and all(c == 0 for c in ids["Lstar"])


@pytest.mark.parametrize(
    "name",
    ["eq11_term", "paper_bound_term", "corrected_bound_term", "loss_sup", "loss_inf", "loss_cst"],
)
def test_generated_numpy_and_torch_functions_agree_with_sympy(name):
    torch = pytest.importorskip("torch")
    names, _ = terms.loss_functions("numpy")[name]
    expr = terms._TERM_ARGS[name][1]
    f_np = terms.loss_functions("numpy")[name][1]
    f_t = terms.loss_functions("torch")[name][1]
    rng = np.random.default_rng(1)
    for _ in range(20):
        vals = {
            n: float(rng.uniform(0.1, 2.0) if n in ("delta", "M", "tau") else rng.uniform(-2, 2))
            for n in names
        }
        exact = float(
            expr.subs({terms.LOSS_SYMBOLS[n]: sp.Float(v, 30) for n, v in vals.items()}).evalf(30)
        )
        got_np = float(f_np(*[vals[n] for n in names]))
        got_t = float(f_t(*[torch.tensor(vals[n], dtype=torch.float64) for n in names]))
        assert got_np == pytest.approx(exact, rel=1e-12, abs=1e-12)
        assert got_t == pytest.approx(exact, rel=1e-12, abs=1e-12)


def test_generated_torch_loss_is_differentiable():
    torch = pytest.importorskip("torch")
    f = terms.loss_functions("torch")["loss_cst"][1]
    S = torch.tensor([0.7, -0.3], requires_grad=True)
    f(S, torch.tensor(0.5)).sum().backward()
    assert S.grad.tolist() == [1.0, 0.0]


def test_kane_imports_without_torch():
    code = "import sys; sys.modules['torch'] = None; import kane.claims, kane.terms, kane.counterexamples; print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_nan_residual_is_an_error_not_a_verdict():
    assert decide(float("nan"), 1.0) == "error"
    assert decide(0.5, 1.0) == "holds"
    assert decide(2.0, 1.0) == "refuted"
