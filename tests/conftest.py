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
