"""Every `gatewaylab` subcommand: argument parsing and printing around the library (docs/cli.md)."""

__all__ = []
