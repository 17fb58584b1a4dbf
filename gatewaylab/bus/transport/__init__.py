"""Thin I/O adapters around the sans-I/O bus: python-can in process, socket server, plugin."""

__all__ = []
