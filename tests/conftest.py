"""Hypothesis profiles.

``deterministic`` (loaded by default, what ``make test`` and CI run): every property test draws
the same examples on every run, so the test command never passes or fails by luck. ``explore``
(``make test-explore``, ``pytest --hypothesis-profile=explore``): new random examples on every
run, and more of them where a test does not set its own count.
"""

from __future__ import annotations

from hypothesis import settings

settings.register_profile("deterministic", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, max_examples=500, print_blob=True)
settings.load_profile("deterministic")
