"""The dataset file format (one HDF5 file per split), its version and its checks.

Layout of ``{split}.h5`` (all floats float64, SI units, world frame unless stated):

- root attributes: the scalars of :data:`ROOT_ATTRS` (scene name, MJCF hash, ``dt``,
  ``substeps``, integrator, MuJoCo version, seed, partition parameters, ...).
- ``/static``: the scene's MJCF text (``/static/assets``: the files it reads, includes,
  meshes, textures, each a byte array whose ``path`` attribute is the name the MJCF reads
  it by; only for user MJCF that reads files) and the graph's static description
  (:data:`STATIC_ARRAYS`: node-to-body map, element masses, volumes, ``tau``, inertia,
  centroids, adjacency, body table, joint-load attachment nodes).
- ``/frames``: per-frame arrays ``[trajectory, frame, ...]`` (:data:`FRAME_ARRAYS`).

Symbolic dimensions: ``T`` trajectories, ``F`` frames, ``N`` nodes (elements), ``B``
bodies other than the world (MuJoCo body ``id = b + 1``), ``E`` adjacency edges,
``nq``/``nv``/``nu``/``na`` MuJoCo's sizes.

Loads are means over a frame's ``substeps`` integrator steps (impulse divided by the
frame time ``frame_dt = dt * substeps``): the loads that take frame ``t`` to ``t+1``,
so that ``sum(loads) = m (v[t+1] - v[t]) / frame_dt`` up to the integrator's own
discretisation error. Torques are about the body's centre of mass. Gravity is static:
``body_mass * gravity`` and ``node_mass * gravity``.

Every dataset is written with the fletcher32 checksum filter, so a corrupted chunk
is detected when read; :func:`mdgs.data.io.open_dataset` checks the structure below
on load and raises one :class:`DatasetError` naming the file and the fix.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "SCHEMA_VERSION",
    "ArraySpec",
    "FRAME_ARRAYS",
    "STATIC_ARRAYS",
    "ROOT_ATTRS",
    "OPTIONAL_ATTRS",
    "DatasetError",
    "markdown_table",
]

SCHEMA_VERSION = 1


class DatasetError(Exception):
    """A dataset file that cannot be used; the message names the file and how to fix it."""


@dataclass(frozen=True)
class ArraySpec:
    name: str
    shape: tuple[str, ...]
    dtype: str
    unit: str
    doc: str


F8, I4, B1 = "float64", "int32", "bool"

FRAME_ARRAYS: tuple[ArraySpec, ...] = (
    ArraySpec("time", ("T", "F"), F8, "s", "simulation time of the frame"),
    ArraySpec("qpos", ("T", "F", "nq"), F8, "m, rad, quat", "MuJoCo generalized positions"),
    ArraySpec("qvel", ("T", "F", "nv"), F8, "m/s, rad/s", "MuJoCo generalized velocities"),
    ArraySpec(
        "ctrl", ("T", "F", "nu"), F8, "actuator units", "controls, held over the frame's substeps"
    ),
    ArraySpec("act", ("T", "F", "na"), F8, "-", "actuator activations"),
    ArraySpec("body_pos", ("T", "F", "B", "3"), F8, "m", "body frame origin"),
    ArraySpec(
        "body_quat",
        ("T", "F", "B", "4"),
        F8,
        "-",
        "body frame orientation, quaternion (w, x, y, z)",
    ),
    ArraySpec("body_com", ("T", "F", "B", "3"), F8, "m", "body centre of mass"),
    ArraySpec(
        "body_linvel", ("T", "F", "B", "3"), F8, "m/s", "linear velocity of the centre of mass"
    ),
    ArraySpec("body_angvel", ("T", "F", "B", "3"), F8, "rad/s", "angular velocity"),
    ArraySpec(
        "body_acc",
        ("T", "F", "B", "3"),
        F8,
        "m/s^2",
        "MuJoCo's centre-of-mass acceleration, mean over the frame's substeps",
    ),
    ArraySpec(
        "body_contact_force",
        ("T", "F", "B", "3"),
        F8,
        "N",
        "sum of contact forces on the body (frame mean)",
    ),
    ArraySpec(
        "body_contact_torque",
        ("T", "F", "B", "3"),
        F8,
        "N m",
        "their torque about the body's centre of mass",
    ),
    ArraySpec(
        "body_actuator_force",
        ("T", "F", "B", "3"),
        F8,
        "N",
        "actuator forces of slide joints (equal and opposite on parent and child)",
    ),
    ArraySpec(
        "body_actuator_torque",
        ("T", "F", "B", "3"),
        F8,
        "N m",
        "actuator torques of hinge joints (+ on the child, - on the parent) and moments of slide forces",
    ),
    ArraySpec(
        "body_joint_force",
        ("T", "F", "B", "3"),
        F8,
        "N",
        "joint reaction force: all that the body's joints transmit, minus actuation",
    ),
    ArraySpec(
        "body_joint_torque",
        ("T", "F", "B", "3"),
        F8,
        "N m",
        "joint reaction torque about the centre of mass",
    ),
    ArraySpec("node_pos", ("T", "F", "N", "3"), F8, "m", "element centroid"),
    ArraySpec("node_vel", ("T", "F", "N", "3"), F8, "m/s", "element centroid velocity"),
    ArraySpec(
        "node_contact_force",
        ("T", "F", "N", "3"),
        F8,
        "N",
        "contact forces, each on the element whose centroid is nearest the contact point (frame mean)",
    ),
    ArraySpec(
        "node_joint_force",
        ("T", "F", "N", "3"),
        F8,
        "N",
        "joint forces (reaction + actuation) on the element nearest each joint anchor (frame mean)",
    ),
    ArraySpec(
        "contact_count",
        ("T", "F"),
        F8,
        "-",
        "mean number of contact slots in use per substep (each contact counted once per body)",
    ),
    ArraySpec(
        "contact_overflow",
        ("T", "F"),
        "int64",
        "-",
        "body-substeps with more contacts than slots (the 4 largest act at their nodes, the rest of the body's contact force at the node nearest their mean point)",
    ),
)

STATIC_ARRAYS: tuple[ArraySpec, ...] = (
    ArraySpec(
        "node_body", ("N",), I4, "-", "MuJoCo body id of each element (0: static world geometry)"
    ),
    ArraySpec("node_geom", ("N",), I4, "-", "MuJoCo geom id the element was cut from"),
    ArraySpec(
        "node_static",
        ("N",),
        B1,
        "-",
        "element of the world or of a body welded to it (never moves)",
    ),
    ArraySpec(
        "node_mass",
        ("N",),
        F8,
        "kg",
        "element mass (uniform density per body; 0 for static elements)",
    ),
    ArraySpec("node_volume", ("N",), F8, "m^3", "element volume"),
    ArraySpec(
        "node_tau", ("N",), F8, "m", "largest distance from the centroid to a point of the element"
    ),
    ArraySpec(
        "node_inertia",
        ("N", "3", "3"),
        F8,
        "kg m^2",
        "inertia about the element centroid, body-frame axes",
    ),
    ArraySpec("node_centroid", ("N", "3"), F8, "m", "element centroid in its body's frame"),
    ArraySpec(
        "adjacency", ("E", "2"), I4, "-", "pairs (i < j) of elements of one body sharing a face"
    ),
    ArraySpec("body_id", ("B",), I4, "-", "MuJoCo body id"),
    ArraySpec("body_parent", ("B",), I4, "-", "MuJoCo id of the parent body"),
    ArraySpec("body_root", ("B",), I4, "-", "MuJoCo id of the kinematic tree's root body"),
    ArraySpec(
        "body_free", ("B",), B1, "-", "body is the root of a free-floating system (free joint)"
    ),
    ArraySpec("body_static", ("B",), B1, "-", "body welded to the world"),
    ArraySpec("body_mass", ("B",), F8, "kg", "MuJoCo body mass"),
    ArraySpec(
        "body_inertia",
        ("B", "3", "3"),
        F8,
        "kg m^2",
        "MuJoCo inertia about the centre of mass, body-frame axes",
    ),
    ArraySpec(
        "body_anchor_node",
        ("B",),
        I4,
        "-",
        "element receiving the load from the body's parent (-1: none)",
    ),
    ArraySpec(
        "body_parent_anchor_node",
        ("B",),
        I4,
        "-",
        "element of the parent receiving the reaction (-1: none)",
    ),
)

STRING_LISTS = ("body_names", "actuator_names", "joint_names")

ROOT_ATTRS: dict[str, str] = {
    "schema_version": "format version of this file (int)",
    "scene": "scene name (see `mdgs generate --list`)",
    "family": "scene family",
    "summary": "one-sentence description of the scene",
    "split": "train, valid or test",
    "mjcf_sha256": "SHA-256 of /static/mjcf",
    "mjcf_path": "path of the user's MJCF file, empty for built-in scenes",
    "dt": "integrator step h (s)",
    "substeps": "integrator steps between frames",
    "frame_dt": "time between frames, dt * substeps (s)",
    "integrator": "MuJoCo integrator (always Euler)",
    "mujoco_version": "MuJoCo version that generated the file",
    "mdgs_version": "version of the generating package",
    "seed": "base seed; trajectory i of a split uses SeedSequence([seed, split code, i])",
    "n_traj": "trajectories in the file",
    "n_frames": "frames per trajectory",
    "gravity": "gravity vector (m/s^2)",
    "has_contact": "whether contacts can occur in the scene",
    "free_floating": "whether the scene has free-floating systems",
    "partition": "partition parameters (JSON)",
    "node_counts": "nodes per body at the used resolution (JSON)",
    "scene_params": "builder parameters (JSON)",
    "notes": "changes made to a user's MJCF so loads match finite differences (JSON list)",
    "preset": "generation preset",
    "config_sha256": "hash of everything that determines the content (resume/merge refuse a mismatch)",
    "traj_start": "index of the file's first trajectory within the split",
    "complete": "True once every trajectory of the split is in the file",
}


OPTIONAL_ATTRS: dict[str, str] = {
    "mujoco_warnings": "MuJoCo's warnings while loading the model, e.g. deprecated attributes (JSON list; absent when none)",
    "contact_overflow": "body-substeps with more contacts than the recorded slots (see /frames/contact_overflow; absent when none)",
}
"""Root attributes written only when they have something to say (older files lack them)."""


def markdown_table(specs: tuple[ArraySpec, ...]) -> str:
    """The table of a group's arrays, as written in docs/scenes.md."""
    rows = ["| name | shape | unit | meaning |", "|---|---|---|---|"]
    rows += [f"| `{s.name}` | `[{', '.join(s.shape)}]` | {s.unit} | {s.doc} |" for s in specs]
    return "\n".join(rows)


if __name__ == "__main__":  # the tables of docs/scenes.md
    print("### /frames\n")
    print(markdown_table(FRAME_ARRAYS))
    print("\n### /static\n")
    print(markdown_table(STATIC_ARRAYS))
    print("\n### Root attributes\n")
    print("| attribute | meaning |\n|---|---|")
    print("\n".join(f"| `{k}` | {v} |" for k, v in ROOT_ATTRS.items()))
