"""Shared test configuration: hypothesis profiles.

``default``: fast, for local runs. ``ci``: more examples, no deadline (CI sets
HYPOTHESIS_PROFILE=ci via .ci/run's environment or pytest ``--hypothesis-profile=ci``).
"""

import os

from hypothesis import HealthCheck, settings

settings.register_profile("default", max_examples=40, deadline=None)
settings.register_profile(
    "ci",
    max_examples=200,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,
)
settings.load_profile(
    os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "default")
)


import pytest  # noqa: E402


@pytest.fixture(scope="module")
def one_torch_thread():
    """One intra-op torch thread for a module: the peers' message-passing ops are small, and on two
    cores shared by several jobs two threads thrash (GNS overfit step: 23 ms with one, 1.3 s with two)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def tiny_cubli(tmp_path_factory):
    """A ``tiny`` cubli-triple dataset (train/valid/test), generated once per test session; tests read it."""
    from mdgs.data.generate import GenerateConfig, generate

    out = tmp_path_factory.mktemp("tiny-cubli")
    generate(GenerateConfig(scene="cubli-triple", out=str(out), preset="tiny"))
    return out
