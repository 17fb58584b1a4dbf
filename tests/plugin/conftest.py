"""Fixtures of the plugin tests: ``start_rig`` (a ``gatewaylab run`` process) from rig_testkit.py."""

from rig_testkit import start_rig  # noqa: F401  (re-exported as a fixture)
