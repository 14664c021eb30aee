"""Analytic mechanical systems: one parameterised description gives a sympy Kane model and an MJCF scene.

Each system (pendulum, free box, Cubli, rolling disc, ...) is written once, as a tuple of
:class:`BodySpec` whose numbers are sympy expressions in named parameter symbols. From that
one description this package produces

* :meth:`AnalyticSystem.symbolic`: Kane's equations ``fr + frstar = 0`` (Kane & Levinson
  1985; sympy ``KanesMethod``), with mass matrix, forcing and a lambdified residual, cached
  on disk;
* :meth:`AnalyticSystem.mjcf`: an MJCF string with explicit ``<inertial>`` elements, the
  Euler integrator and no damping/armature, loadable by MuJoCo and by Pinocchio's
  ``buildModelFromMJCF``, so that both engines see exactly the sympy mass properties;
* :func:`simulate`: a MuJoCo trajectory (state, acceleration, actuator forces, contact
  wrenches) along which the cross-checks in :mod:`kane.crosscheck` evaluate the equations.

Modules (one job each)
----------------------
* :mod:`~kane.systems.specs`: the parts of a description (``JointSpec``, ``GeomSpec``,
  ``BodySpec``, ``ActuatorSpec``) and ``symbol``;
* :mod:`~kane.systems.system`: ``AnalyticSystem``, the description and its products;
* :mod:`~kane.systems.tree`: kinematics of joint trees (hinge, slide, ball, free) and their
  MuJoCo coordinate maps;
* :mod:`~kane.systems.rolling_disc`: kinematics of the nonholonomic rolling disc and its maps;
* :mod:`~kane.systems.derive`: ``KanesMethod`` -> ``SymbolicModel`` (plain symbols, numpy
  functions), the disk cache (``cache_dir``);
* :mod:`~kane.systems.bodyframe`: Kane's equations of a joint tree written out in
  body-frame components (partial velocities, F_r, F*_r) without ``KanesMethod``;
* :mod:`~kane.systems.mjcf_export`: the MJCF writer;
* :mod:`~kane.systems.catalogue`: the built-in systems, ``SYSTEMS``, ``get_system``;
* :mod:`~kane.systems.simulate`: ``Trajectory``, ``contact_wrenches``, ``simulate``.

Conventions (the mapping between sympy q/u and engine coordinates)
-------------------------------------------------------------------
* World frame N: z up, gravity ``-g N.z``. Units: SI (m, kg, s, rad, N, N m).
* hinge / slide joint: one coordinate ``q`` (rad or m) equal to MuJoCo ``qpos``; the
  generalized speed is ``u = dq/dt`` (equal to MuJoCo ``qvel``), ``udot`` = MuJoCo ``qacc``.
  Joint axes are body-frame vectors; several joints in one body compose in order (each
  axis in the frame left by the previous joints), exactly as MuJoCo composes them.
* ball joint: body-fixed Z-Y-X angles of the joint's rotation (MuJoCo: quaternion), speeds =
  angular velocity relative to the parent in the body's components (MuJoCo's ball ``qvel``).
* free joint (top-level bodies only): coordinates ``(x, y, z, yaw, pitch, roll)``: the
  body-origin position in N (m) and body-fixed Z-Y-X Euler angles, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)`` (rad). The speeds follow MuJoCo's free-joint ``qvel`` exactly:
  ``(vx, vy, vz)`` = velocity of the body origin in **world** components (m/s) and
  ``(wx, wy, wz)`` = angular velocity in **body** components (rad/s), so ``udot`` is
  MuJoCo's ``qacc`` unchanged. MuJoCo stores the orientation as a quaternion ``(w, x, y,
  z)``; Euler angles are recovered with scipy (``as_euler('ZYX')``, intrinsic).
  The Euler angles enter only the kinematic differential equations (singular at
  pitch = +-pi/2); Kane's ``fr`` and ``frstar`` depend on them only through the rotation
  matrix, which stays exact there.
* Pinocchio (used in :mod:`kane.crosscheck`): quaternion ``(x, y, z, w)``, and a free
  joint's linear velocity/acceleration and force are in the **local** (body) frame:
  ``v_pin = R^T v_world``, ``a_pin = R^T a_world - w_body x v_pin``, ``f_world = R f_pin``.
* Generalized inputs: actuator forces ``tau_<actuator>`` (N m for hinges, N for slides;
  MuJoCo ``<motor>`` with gear 1, so equal to ``actuator_force``), then, for each body
  with ``external_wrench=True``, an external force ``F`` (N, world components) applied at
  the body origin and a torque ``T`` (N m, world components). Contact forces from MuJoCo
  enter Kane's equations through these.
* Rolling disc (nonholonomic, see :func:`rolling_disc`): coordinates ``(yaw, lean, spin,
  x, y)`` with ``R = Rz(yaw) Rx(lean) Ry(spin)`` (disc axis = body y) and (x, y) the
  ground contact point; independent speeds ``(u1, u2, u3)`` = disc angular velocity in the
  lean frame L; dependent speeds ``(dx/dt, dy/dt)`` eliminated with the rolling
  constraints.

Symbolic expressions in :class:`SymbolicModel` use plain symbols (``q_<joint>``,
``u_<joint>``, ``ud_<joint>``) for the time-dependent ``q(t)``, ``u(t)``, ``du/dt``, so that
they pickle and lambdify; :meth:`AnalyticSystem.kanes_method` returns a fresh
``KanesMethod`` in sympy's dynamicsymbols.
"""

from kane.systems.catalogue import (
    SYSTEMS,
    box_on_plane,
    cubli,
    double_pendulum,
    element_union_box,
    flywheel_box_planar,
    free_box,
    get_system,
    particle,
    partitioned_box,
    pendulum,
    rolling_disc,
    undivided_box,
)
from kane.systems.derive import SymbolicModel, cache_dir
from kane.systems.simulate import Trajectory, contact_wrenches, simulate
from kane.systems.specs import ActuatorSpec, BodySpec, GeomSpec, JointSpec, symbol
from kane.systems.system import AnalyticSystem

__all__ = [
    "JointSpec",
    "GeomSpec",
    "BodySpec",
    "ActuatorSpec",
    "AnalyticSystem",
    "SymbolicModel",
    "Trajectory",
    "SYSTEMS",
    "get_system",
    "simulate",
    "symbol",
    "cache_dir",
    "contact_wrenches",
    "particle",
    "pendulum",
    "double_pendulum",
    "free_box",
    "partitioned_box",
    "element_union_box",
    "undivided_box",
    "flywheel_box_planar",
    "cubli",
    "rolling_disc",
    "box_on_plane",
]
