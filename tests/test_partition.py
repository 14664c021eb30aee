"""Element partition (mdgs.partition): exact mass properties, face adjacency, default rule."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mdgs.partition import PartitionError, PartitionParams, default_level, partition_model

SHAPES = """
<mujoco><asset>
  <mesh name="oct" vertex="1 0 0  -1 0 0  0 1 0  0 -1 0  0 0 1.5  0 0 -1" scale=".1 .1 .1"/>
  <mesh name="dent" vertex="0 0 0  1 0 0  0 1 0  0 0 1  1 1 1  .2 .2 .2" scale=".1 .1 .1"/>
</asset><worldbody>
  <geom type="plane" size="1 1 .1"/>
  <body name="box"><freejoint/><geom type="box" size=".2 .1 .05" pos=".1 .2 .3" euler="10 20 30"/></body>
  <body name="sphere" pos="1 0 0"><freejoint/><geom type="sphere" size=".1" pos="0 .1 0"/></body>
  <body name="cylinder" pos="2 0 0"><freejoint/><geom type="cylinder" size=".1 .02" euler="30 0 0"/></body>
  <body name="capsule" pos="3 0 0"><freejoint/><geom type="capsule" size=".05 .2" euler="0 40 0" pos=".1 0 0"/></body>
  <body name="ellipsoid" pos="4 0 0"><freejoint/><geom type="ellipsoid" size=".1 .2 .05"/></body>
  <body name="mesh" pos="5 0 0"><freejoint/><geom type="mesh" mesh="oct"/></body>
  <body name="two_geoms" pos="6 0 0"><freejoint/><geom type="box" size=".1 .1 .1"/><geom type="capsule" size=".03 .2" pos="0 0 .25"/></body>
</worldbody></mujoco>
"""


@pytest.fixture(scope="module")
def shapes() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(SHAPES)


@pytest.mark.parametrize("level", [1, 2, 3, None])
def test_cells_sum_to_mujoco_mass_properties(shapes, level):
    """Mass, centre of mass and inertia of the cells equal MuJoCo's own body inertia
    (an independent computation from the geoms) to round-off at every level."""
    part = partition_model(shapes, PartitionParams(level=level))
    for r in part.reports:
        if r.body == 0:
            continue
        tol = _tol(r.name)
        assert r.mass_error < 1e-12, r
        assert r.com_error < tol, r
        assert r.inertia_error < tol, r


def _tol(body: str) -> float:
    """Round-off for primitives; MuJoCo stores mesh vertices in float32 (relative 6e-8)."""
    return 1e-6 if body == "mesh" else 1e-12


def test_parallel_axis_sum_of_node_arrays_equals_body_inertia(shapes):
    """The stored arrays (not only the report) reproduce MuJoCo's inertia: sum of own inertias + point masses."""
    part = partition_model(shapes)
    for b in range(1, shapes.nbody):
        i = part.nodes_of(b)
        m, c = part.mass[i], part.centroid[i]
        com = (m[:, None] * c).sum(0) / m.sum()
        d = c - com
        I = part.inertia[i].sum(0) + (
            m[:, None, None]
            * ((d * d).sum(1)[:, None, None] * np.eye(3) - d[:, :, None] * d[:, None, :])
        ).sum(0)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, shapes.body_iquat[b])
        R = R.reshape(3, 3)
        tol = _tol(shapes.body(b).name)
        np.testing.assert_allclose(com, shapes.body_ipos[b], atol=tol * 0.1)
        np.testing.assert_allclose(
            I,
            R @ np.diag(shapes.body_inertia[b]) @ R.T,
            atol=tol * np.abs(shapes.body_inertia[b]).max(),
        )


def test_adjacency_of_2x2x1_box_is_a_ring_of_four_faces():
    """A 2 x 2 x 1 grid: each cell shares a face with two others; diagonal cells share only an edge."""
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom type="box" size="1 1 .5"/></body></worldbody></mujoco>'
    )
    part = partition_model(m, PartitionParams(level=2, static_geoms=False))
    assert part.n_nodes == 4
    c = part.centroid
    edges = {tuple(e) for e in part.adjacency.tolist()}
    assert len(edges) == 4
    for i, j in edges:  # face neighbours differ in exactly one coordinate by one cell (1 m)
        assert np.isclose(np.abs(c[i] - c[j]).sum(), 1.0)
    np.testing.assert_allclose(part.volume, 1.0)
    np.testing.assert_allclose(part.tau, np.sqrt(0.5**2 + 0.5**2 + 0.5**2))


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_cube_nodes_miss_one_over_n_squared_of_the_inertia(n):
    """n^3 cubic cells: each cell's own inertia is (1/n^2) of the cube's scaled by 1/n^3 (parallel axis theorem)."""
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom type="box" size=".1 .1 .1"/></body></worldbody></mujoco>'
    )
    part = partition_model(m, PartitionParams(level=n, static_geoms=False))
    assert part.n_nodes == n**3
    assert np.isclose(part.reports[0].point_mass_deficit, 1 / n**2)


def test_default_level_is_the_coarsest_meeting_both_tolerances(shapes):
    params = PartitionParams()
    from mdgs.partition import _body_geoms, _body_length, _body_metrics, _cells_of_body

    for b in range(1, shapes.nbody):
        n = default_level(shapes, b, params)
        geoms = _body_geoms(shapes, b, False)
        L = _body_length(shapes, geoms)
        deficit, gap = _body_metrics(shapes, b, _cells_of_body(shapes, geoms, L / n))
        assert deficit <= params.inertia_tol and gap <= params.contact_tol + 1e-9
        if n > 1:
            d0, g0 = _body_metrics(shapes, b, _cells_of_body(shapes, geoms, L / (n - 1)))
            assert d0 > params.inertia_tol or g0 > params.contact_tol


def test_refine_gives_more_nodes_with_the_same_mass_properties(shapes):
    coarse = partition_model(shapes)
    fine = partition_model(shapes, PartitionParams(refine=2))
    assert fine.n_nodes > coarse.n_nodes
    assert all(r.inertia_error < _tol(r.name) for r in fine.reports if r.body)


def test_nonconvex_mesh_is_partitioned_through_its_convex_hull():
    from scipy.spatial import ConvexHull

    m = mujoco.MjModel.from_xml_string(SHAPES.replace('mesh="oct"', 'mesh="dent"'))
    part = partition_model(m, PartitionParams(level=3))
    b = m.body("mesh").id
    verts = m.mesh_vert[m.mesh_vertadr[1] : m.mesh_vertadr[1] + m.mesh_vertnum[1]]
    assert np.isclose(part.volume[part.nodes_of(b)].sum(), ConvexHull(verts).volume, rtol=1e-12)


def test_every_body_graph_is_connected(shapes):
    from mdgs.partition import _components

    part = partition_model(shapes)
    for b in range(1, shapes.nbody):
        i = part.nodes_of(b)
        local = {int(x): k for k, x in enumerate(i)}
        edges = [
            (local[a], local[c]) for a, c in part.adjacency.tolist() if a in local and c in local
        ]
        assert _components(len(i), edges).max() == 0


def test_unsupported_geom_on_a_moving_body_is_one_clear_error():
    xml = '<mujoco><asset><hfield name="h" nrow="3" ncol="3" size="1 1 .1 .1"/></asset><worldbody><body><freejoint/><geom type="hfield" hfield="h"/></body></worldbody></mujoco>'
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(PartitionError, match="hfield.*cannot be partitioned"):
        partition_model(m)


def test_refine_beyond_the_level_limit_is_refused_before_any_cutting():
    from mdgs.partition import MAX_LEVEL

    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="slab"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>'
        "</worldbody></mujoco>")
    base = default_level(m, 1, PartitionParams(), [0])
    ok = MAX_LEVEL // base
    partition_model(m, PartitionParams(refine=1))  # the default passes
    with pytest.raises(PartitionError, match=f"limit is {MAX_LEVEL} divisions: use --refine {ok} or less"):
        partition_model(m, PartitionParams(refine=ok + 1))
