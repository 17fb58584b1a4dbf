"""Shared building blocks: the injected clock, the error hierarchy, checksums."""
