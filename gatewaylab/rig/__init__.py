"""Rig files, the runtime that runs them, and the `gatewaylab` command line."""
