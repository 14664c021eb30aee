"""kane: Kane's method, the MDGS paper's claims, and the checks that decide them.

Imports without torch. Public API (import from the submodules):

* :mod:`kane.claims` — ``CLAIMS``, ``run_checks``: every claim, its corrected statement, its checks.
* :mod:`kane.terms` — Kane terms of element sets and the sympy loss expressions (Eqs. 11-15);
  ``loss_functions(backend)`` gives their generated numpy/torch/CasADi functions.
* :mod:`kane.elements` — point-mass elements and box partitions.
* :mod:`kane.systems` — analytic systems (sympy model + MJCF), ``get_system``, ``simulate``.
* :mod:`kane.crosscheck` — Kane's equation and Lemma A.1 against Pinocchio and MuJoCo.
* :mod:`kane.mjcf` — ``from_mjcf``: Kane's equations of a user's MJCF tree, ``crosscheck_mjcf``;
  :mod:`kane.mjcf_checks` — ``run_mjcf_checks``: the claims that apply to that tree.
* :mod:`kane.counterexamples` — ``replay`` of recorded counterexamples.
* :mod:`kane.results` — ``CheckResult``, ``Verdict``, ``Route``, ``decide``.
"""

__all__ = ["claims", "terms", "elements", "systems", "crosscheck", "counterexamples", "results", "codegen", "mjcf", "mjcf_checks"]
