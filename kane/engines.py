"""Element and geom counterexamples evaluated by MuJoCo and Pinocchio, independently of the sympy expressions.

* ``element``: a point-mass element state (masses, offsets, forces, omega, alpha), rebuilt as a
  MuJoCo body of small spheres; MuJoCo and Pinocchio each supply its mass, inertia and the
  resultant/moment of the forces (MuJoCo: ``mj_applyFT``), and both sides of the claim are
  evaluated from those engine quantities.
* ``mujoco_geom``: an element that is one MuJoCo geom; its inertia comes from MuJoCo.

Used by :mod:`kane.counterexamples` (replay) and by :mod:`kane.claims` (an independent route).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ReplayReport", "Side", "replay_element", "replay_geom"]

_SPHERE = 1e-4  # radius of the point-mass spheres, m: adds (2/5) m r^2 ~ 4e-9 m to the inertia


def _g(x, digits: int = 4) -> str:
    """A number or a vector to ``digits`` significant digits, as the replay prints it."""
    if np.ndim(x):
        return "(" + ", ".join(f"{float(c):.{digits}g}" for c in np.ravel(x)) + ")"
    return f"{float(x):.{digits}g}"


@dataclass(frozen=True)
class Side:
    """One equality of a claim at a counterexample, ``lhs = rhs`` (numbers or 3-vectors).

    ``margin`` is ``lhs - rhs`` as the check computes it (its own difference, not a re-subtraction
    of the rounded sides); the relative margin is the largest ``|margin|`` entry over ``scale``:
    the number the validation report lists. ``key`` names the comparison for the docs
    (:func:`validation.render.counterexample_view`); the ``*_text`` fields are what the terminal prints.
    """

    key: str
    lhs_text: str
    rhs_text: str
    lhs: object
    rhs: object
    margin: object
    scale: float
    scale_text: str
    unit: str = ""

    @property
    def absolute(self) -> float:
        """The largest ``|lhs - rhs|`` entry."""
        return float(np.abs(np.asarray(self.margin, float)).max())

    @property
    def relative(self) -> float:
        """:attr:`absolute` over :attr:`scale`: the report's residual at this point."""
        return self.absolute / self.scale

    def lines(self) -> list[str]:
        u = f" {self.unit}" if self.unit else ""
        return [f"  {self.lhs_text} = {_g(self.lhs)}{u}", f"  {self.rhs_text} = {_g(self.rhs)}{u}",
                f"    lhs - rhs = {_g(self.margin)}{u}; largest |lhs - rhs| = {self.absolute:.4g}{u}; "
                f"relative margin = largest |lhs - rhs| / ({self.scale_text} = {self.scale:.4g}{u}) = {self.relative:.3g}"]


@dataclass(frozen=True)
class ReplayReport:
    """Both sides of a claim at a counterexample, per engine."""

    claim_id: str
    kind: str
    rows: list = field(default_factory=list)  # (engine, lhs, rhs)
    note: str = ""
    #: the normalisation of the check's margin: the report lists (lhs - rhs) / scale
    scale: float | None = None
    scale_text: str = ""
    #: equality claims re-evaluated at the recorded point: where, as (name, value, unit), and both sides
    context: list = field(default_factory=list)
    sides: list = field(default_factory=list)  # [Side]

    def relative(self, lhs: float, rhs: float) -> float | None:
        """(lhs - rhs) / scale: the number the validation report lists (``None`` without a scale)."""
        return None if not self.scale else (lhs - rhs) / self.scale

    @property
    def refuted(self) -> bool:
        return any(lhs > rhs for _, lhs, rhs in self.rows)

    def __str__(self) -> str:
        lines = [f"claim {self.claim_id} ({self.kind}): the claim says lhs <= rhs"]
        for eng, lhs, rhs in self.rows:
            rel = self.relative(lhs, rhs)
            lines.append(f"  {eng:10s} lhs = {lhs:.10g}   rhs = {rhs:.10g}   lhs - rhs = {lhs - rhs:.3g}"
                         + ("" if rel is None else f"   (lhs - rhs) / scale = {rel:.3g}"))
        if self.scale:
            lines.append(f"  scale = {self.scale_text} = {self.scale:.4g}; the report's margin is (lhs - rhs) / scale")
        lines.append(f"  => {'refuted' if self.refuted else 'holds'} at this point" + (f"; {self.note}" if self.note else ""))
        if self.sides:
            where = ", ".join(f"{k} = {v if isinstance(v, str) else _g(v)}" + (f" {u}" if u else "") for k, v, u in self.context)
            lines.append(f"both sides at the recorded point ({where}); the claim says lhs = rhs:")
            for sd in self.sides:
                lines += sd.lines()
        return "\n".join(lines)


def _element_sides(cid: str, M, I, R, Mc, tau, F_abs, w, a):
    """Both sides of the Appendix A.2 inequalities from aggregate quantities (rotational speed e_z)."""
    Ia = I @ a
    Ls = Ia + np.cross(w, I @ w)
    na, nw = np.linalg.norm(a), np.linalg.norm(w)
    base = cid.replace(".corrected", "")
    corr = cid.endswith(".corrected")
    if base == "eq34":
        return Mc[2], tau * (F_abs if corr else np.linalg.norm(R))
    if base == "eq35":
        return Ls[2], np.linalg.norm(Ia) + (M * tau**2 * nw**2 / 2 if corr else 0.0)
    if base == "eq36":
        return I[2, 2], (1.0 if corr else 0.4) * M * tau**2
    if base == "eq37":
        return Ls[2], M * tau**2 * (na + nw**2 / 2) if corr else 0.4 * M * tau**2 * na
    if base == "eq12":
        psi = Mc[2] - Ls[2]
        return psi, (tau * F_abs + M * tau**2 * (na + nw**2 / 2)) if corr else tau * np.linalg.norm(R) + 0.4 * M * tau**2 * na
    raise ValueError(f"no element replay for claim {cid!r}")


def _element_mjcf(masses, offsets) -> str:
    geoms = "\n".join(
        f'<geom type="sphere" size="{_SPHERE}" mass="{m:.17g}" pos="{p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" contype="0" conaffinity="0"/>'
        for m, p in zip(masses, offsets, strict=True))
    return (f'<mujoco model="element"><option gravity="0 0 0"/><worldbody><body name="element" pos="0 0 0">'
            f'<freejoint name="root"/>{geoms}</body></worldbody></mujoco>')


def replay_element(cex: dict) -> ReplayReport:
    import mujoco
    import pinocchio as pin

    s = cex["sample"]
    masses = np.asarray(s["masses"], float)
    offs = np.asarray(s["offsets"], float)
    F = np.asarray(s["forces"], float)
    w = np.asarray(s["omega"], float)
    a = np.asarray(s["alpha"], float)
    if masses.ndim != 1 or offs.shape != (len(masses), 3) or F.shape != offs.shape or w.shape != (3,) or a.shape != (3,):
        raise ValueError("counterexample 'sample' needs masses [L], offsets [L,3], forces [L,3], omega [3], alpha [3]")
    xml = _element_mjcf(masses, offs)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    com = d.xipos[1].copy()
    Rq = np.zeros(9)
    mujoco.mju_quat2Mat(Rq, m.body_iquat[1])
    Rq = Rq.reshape(3, 3)
    I_mj = Rq @ np.diag(m.body_inertia[1]) @ Rq.T
    qfrc = np.zeros(m.nv)
    for p, f in zip(offs, F, strict=True):
        mujoco.mj_applyFT(m, d, f, np.zeros(3), p, 1, qfrc)
    R_mj = qfrc[:3]
    Mc_mj = qfrc[3:6] - np.cross(com, R_mj)  # free joint torque is about the body origin; move to the centroid
    tau = float(np.linalg.norm(offs - com, axis=1).max())
    F_abs = float(np.linalg.norm(F, axis=1).sum())
    rows = [("mujoco", *_element_sides(cex["claim_id"], float(m.body_mass[1]), I_mj, R_mj, Mc_mj, tau, F_abs, w, a))]
    # Pinocchio composes the point masses with its own spatial-inertia algebra (parallel axis theorem)
    inert = pin.Inertia.Zero()
    for mm, p in zip(masses, offs, strict=True):
        inert = inert + pin.Inertia(float(mm), np.asarray(p, float), np.zeros((3, 3)))
    I_pin = np.asarray(inert.inertia)
    rows.append(("pinocchio", *_element_sides(cex["claim_id"], float(inert.mass), I_pin, F.sum(0),
                                              np.cross(offs - np.asarray(inert.lever), F).sum(0), tau, F_abs, w, a)))
    from kane.adversarial import SCALE_TEXT, Sample

    scale = Sample(masses, offs, F, w, a).scale()
    return ReplayReport(cex["claim_id"], "element", rows,
                        f"MuJoCo: body of spheres; Pinocchio: sum of pin.Inertia point masses; spheres of radius {_SPHERE} m add <= {0.4 * _SPHERE**2:.0e} m to inertia",
                        scale, SCALE_TEXT)


def replay_geom(cex: dict) -> ReplayReport:
    import mujoco

    Rr, hh = cex["size"]
    m = mujoco.MjModel.from_xml_string(
        f'<mujoco><worldbody><body><freejoint/><geom type="{cex["geom"]}" size="{Rr} {hh}" density="{cex["density"]}"/></body></worldbody></mujoco>')
    mass, I = float(m.body_mass[1]), m.body_inertia[1]
    tau = float(np.hypot(Rr, hh))
    k = 1.0 if cex["claim_id"].endswith(".corrected") else 0.4
    return ReplayReport(cex["claim_id"], "mujoco_geom", [("mujoco", float(I.max()), k * mass * tau**2)],
                        f"{cex['geom']} element: MuJoCo inertia {np.round(I, 8).tolist()} kg m^2, tau = {tau:.5g} m",
                        mass * tau**2, "M tau^2")
