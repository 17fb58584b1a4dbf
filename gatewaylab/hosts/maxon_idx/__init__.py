"""Host side of the maxon USB protocol: ``IdxClient`` over pyserial or pyusb (the ``gatewaylab idx``
command is :mod:`gatewaylab.cli.idx`)."""

__all__ = []
