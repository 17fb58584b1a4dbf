"""Fixtures of the rig tests; the helpers live in rig_testkit.py (a unique module name)."""

from rig_testkit import start_rig  # noqa: F401  (re-exported as a fixture)
